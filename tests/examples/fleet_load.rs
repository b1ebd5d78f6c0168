//! Many vehicles' uplinks against a three-node JetStream cluster on loopback (issue 29 item 6):
//! how many events per second the ground stores, and how long from publish to stored (the
//! acknowledgement: with 3 replicas, after a quorum of 2 holds the message).
//!
//! Each simulated vehicle is what the uplink is without an estimator: its own NATS connection
//! (to the nodes in turn), events published on `railmon.sim.<vehicle>.<stream>.events` with the
//! message id `<vehicle>:<event id>`, in pages of 256 whose acknowledgements are awaited
//! before the next page (the uplink's `PAGE_EVENTS`), at most `--rate` events/s (the uplink's
//! `max_events_per_s`, default 200: a backlog after an outage drains at that rate). An
//! acknowledgement not within 5 s (the uplink's `ACK_TIMEOUT`) fails the page, which is sent
//! again from its first event not acknowledged after a backoff, as the uplink does. Payloads
//! are event-sized JSON (~330 bytes). At the end the stream must hold exactly
//! vehicles x events messages (nothing lost, nothing twice).
//!
//! ```text
//! cargo run --release -p railmon-system-tests --example fleet_load -- \
//!     [--vehicles 300] [--events 200] [--rate 200] [--replicas 3]
//! ```
//! Prints offered and stored events/s, publish-to-acknowledgement latency percentiles, and the
//! CPU the three servers used. Needs `nats-server` (see railmon_system_tests::nats).

use std::time::{Duration, Instant};

use async_nats::jetstream;
use railmon_system_tests::nats::nats_server_binary;
use railmon_system_tests::nats_cluster::{create_replicated_stream, start_cluster, NODES};

const STREAM: &str = "RAILMON_FLEET_LOAD";
const PAGE_EVENTS: usize = 256;

struct Args {
    vehicles: usize,
    events: usize,
    rate: f64,
    replicas: usize,
}

fn parse_args() -> Args {
    let mut args = Args {
        vehicles: 300,
        events: 200,
        rate: 200.0,
        replicas: NODES,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let value = it.next().unwrap_or_default();
        let bad = || -> ! {
            eprintln!("fleet_load: {flag} `{value}`: expected a positive number");
            std::process::exit(2)
        };
        match flag.as_str() {
            "--vehicles" => args.vehicles = value.parse().unwrap_or_else(|_| bad()),
            "--events" => args.events = value.parse().unwrap_or_else(|_| bad()),
            "--rate" => args.rate = value.parse().unwrap_or_else(|_| bad()),
            "--replicas" => args.replicas = value.parse().unwrap_or_else(|_| bad()),
            _ => {
                eprintln!(
                    "usage: fleet_load [--vehicles N] [--events N] [--rate EVENTS_PER_S] \
                     [--replicas 1..3]"
                );
                std::process::exit(2)
            }
        }
    }
    if args.vehicles == 0 || args.events == 0 || args.rate <= 0.0 || args.replicas == 0 {
        eprintln!("fleet_load: every value must be positive");
        std::process::exit(2)
    }
    args
}

/// What one vehicle saw.
#[derive(Default)]
struct VehicleRun {
    /// Per event, from its first publish to its acknowledgement.
    latencies: Vec<Duration>,
    /// Pages sent again after a failed or late acknowledgement.
    retries: u64,
    /// Acknowledged as already stored (a re-send the duplicate window dropped).
    duplicates: u64,
}

/// One vehicle's uplink: its events in pages, each page's acknowledgements awaited in order;
/// on a failure (an acknowledgement not within 5 s) it backs off (0.25 s doubling to 5 s) and
/// sends again from the first event not acknowledged, with the same message ids, as the
/// uplink does.
async fn vehicle(
    url: String,
    vehicle: usize,
    events: usize,
    rate: f64,
) -> Result<VehicleRun, String> {
    let client = async_nats::connect(&url)
        .await
        .map_err(|e| format!("vehicle {vehicle}: {e}"))?;
    let js = jetstream::new(client);
    let streams = ["drive", "bogie", "vehicle", "service"];
    let interval = Duration::from_secs_f64(1.0 / rate);
    let mut next = Instant::now();
    let mut run = VehicleRun {
        latencies: Vec::with_capacity(events),
        ..VehicleRun::default()
    };
    let mut first_sent: Vec<Option<Instant>> = vec![None; events + 1];
    let mut acked = 0;
    let mut backoff = Duration::from_millis(250);
    while acked < events {
        let mut in_flight = Vec::with_capacity(PAGE_EVENTS);
        for id in acked + 1..=(acked + PAGE_EVENTS).min(events) {
            let now = Instant::now();
            if next > now {
                tokio::time::sleep(next - now).await;
            }
            next = next.max(now) + interval;
            let stream = streams[id % streams.len()];
            let payload = format!(
                "{{\"id\":{id},\"stream\":\"{stream}\",\"kind\":\"damper_degraded\",\
                 \"subject\":\"bogie-1\",\"time_utc\":\"2026-11-28T01:00:00.000000000Z\",\
                 \"detail\":{{\"damper\":\"anti_yaw\",\"health_ratio\":0.62,\
                 \"interval_90\":[0.58,0.66],\"speed_m_s\":41.7}},\"vehicle_id\":\
                 \"sim-{vehicle}\",\"fleet\":\"sim\"}}"
            );
            let sent = *first_sent[id].get_or_insert_with(Instant::now);
            let publish = js
                .send_publish(
                    format!("railmon.sim.sim-{vehicle}.{stream}.events"),
                    jetstream::message::PublishMessage::build()
                        .message_id(format!("sim-{vehicle}:{id}"))
                        .payload(payload.into()),
                )
                .await;
            let Ok(ack) = publish else { break };
            // Awaited in its own task, so that its latency is taken when it arrives, not
            // when the page is done.
            in_flight.push(tokio::spawn(async move {
                let ack = ack.await;
                (ack, sent.elapsed())
            }));
        }
        let page_len = in_flight.len();
        let mut page_acked = 0;
        for task in in_flight {
            let (ack, latency) = task.await.map_err(|e| format!("vehicle {vehicle}: {e}"))?;
            let Ok(ack) = ack else { break };
            run.duplicates += u64::from(ack.duplicate);
            run.latencies.push(latency);
            page_acked += 1;
        }
        acked += page_acked;
        if page_acked < page_len || page_len == 0 {
            run.retries += 1;
            tokio::time::sleep(backoff).await;
            backoff = (backoff * 2).min(Duration::from_secs(5));
        } else {
            backoff = Duration::from_millis(250);
        }
    }
    Ok(run)
}

fn percentile(sorted: &[Duration], q: f64) -> Duration {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

/// CPU seconds (user + system) of process `pid`, from /proc.
fn cpu_s(pid: u32) -> f64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    let fields: Vec<&str> = stat
        .rsplit_once(')')
        .map(|(_, rest)| rest.split_whitespace().collect())
        .unwrap_or_default();
    let ticks = |i: usize| {
        fields
            .get(i)
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(0.0)
    };
    // utime and stime are fields 14 and 15 of stat; 11 and 12 after the `)`.
    (ticks(11) + ticks(12)) / 100.0
}

fn main() {
    let args = parse_args();
    let Some(binary) = nats_server_binary() else {
        eprintln!("fleet_load: nats-server is not installed (scripts/install-test-deps)");
        std::process::exit(1)
    };
    let work = std::env::temp_dir().join(format!("railmon-fleet-load-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&work);
    let nodes = start_cluster(&binary, &work);
    for node in &nodes {
        railmon_system_tests::monitoring::wait_for(
            "nats-server listening",
            Duration::from_secs(10),
            || std::net::TcpStream::connect(&node.client_addr).is_ok(),
        );
    }
    let urls: Vec<String> = nodes
        .iter()
        .map(|n| format!("nats://{}", n.client_addr))
        .collect();
    let formed = create_replicated_stream(&urls[0], STREAM, Duration::from_secs(30));
    if args.replicas != NODES {
        eprintln!("fleet_load: --replicas other than {NODES} is not built; using {NODES}");
    }
    let cpu_before: Vec<f64> = nodes.iter().map(|n| cpu_s(n.process.child.id())).collect();

    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .unwrap();
    let start = Instant::now();
    let results = runtime.block_on(async {
        let tasks: Vec<_> = (0..args.vehicles)
            .map(|v| {
                let url = urls[v % urls.len()].clone();
                tokio::spawn(vehicle(url, v, args.events, args.rate))
            })
            .collect();
        let mut results = Vec::with_capacity(tasks.len());
        for task in tasks {
            results.push(task.await.expect("vehicle task"));
        }
        results
    });
    let elapsed = start.elapsed();
    let cpu: f64 = nodes
        .iter()
        .zip(&cpu_before)
        .map(|(n, before)| cpu_s(n.process.child.id()) - before)
        .sum();
    let mut latencies = Vec::new();
    let (mut retries, mut duplicates) = (0, 0);
    let mut failures = Vec::new();
    for result in results {
        match result {
            Ok(run) => {
                latencies.extend(run.latencies);
                retries += run.retries;
                duplicates += run.duplicates;
            }
            Err(e) => failures.push(e),
        }
    }
    let stored = railmon_system_tests::nats::with_client(&urls[0], async |client| {
        let js = jetstream::new(client);
        let mut stream = js.get_stream(STREAM).await.expect("the stream");
        stream.info().await.expect("stream info").state.messages
    });
    latencies.sort_unstable();
    let expected = (args.vehicles * args.events) as u64;
    let offered = args.vehicles as f64 * args.rate;
    println!(
        "cluster of {NODES} (stream with {NODES} replicas) formed in {formed:.1?}; \
         {} vehicles x {} events, each at most {} events/s (offered {offered:.0} events/s)",
        args.vehicles, args.events, args.rate
    );
    println!(
        "stored {stored} of {expected} messages in {elapsed:.2?}: {:.0} events/s; \
         servers' CPU {cpu:.1} s ({:.0} us per event, {:.2} cores)",
        stored as f64 / elapsed.as_secs_f64(),
        cpu * 1e6 / stored.max(1) as f64,
        cpu / elapsed.as_secs_f64()
    );
    if !latencies.is_empty() {
        println!(
            "publish to stored (acknowledged): p50 {:.1?}, p90 {:.1?}, p99 {:.1?}, max {:.1?} \
             ({} events)",
            percentile(&latencies, 0.5),
            percentile(&latencies, 0.9),
            percentile(&latencies, 0.99),
            latencies[latencies.len() - 1],
            latencies.len()
        );
    }
    println!(
        "pages sent again after a late or failed acknowledgement: {retries}; acknowledged as \
         duplicates (dropped by the stream): {duplicates}"
    );
    for failure in failures.iter().take(5) {
        eprintln!("failed: {failure}");
    }
    drop(nodes);
    let _ = std::fs::remove_dir_all(&work);
    if stored != expected || !failures.is_empty() {
        eprintln!(
            "fleet_load: the stream holds {stored} messages, expected {expected}; {} vehicles \
             failed",
            failures.len()
        );
        std::process::exit(1);
    }
}
