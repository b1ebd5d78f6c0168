//! `railmon fleet` (issue 29 item 3) against a real NATS JetStream server: a service with the
//! uplink on sends its health summary, simulated vehicles' events are published as the uplink
//! publishes them (subjects, message ids, payloads), and the fleet view answers a vehicle's
//! events (ids, order, pages, time range), the latest health summary, and which vehicles have
//! an active alarm, as alarms are raised and then cleared, from events alone and from an alarm
//! snapshot plus the events after it.
//!
//! `fleet_queries_at_1000_vehicles` (ignored: a minute and a half, prints numbers) measures the
//! latency of the active-alarms query and of one vehicle's events for a day at 1,000 vehicles'
//! worth of stored events (docs/fleet.md).
//!
//! Needs `nats-server` (`scripts/install-test-deps`); without it the tests say so and pass.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use async_nats::jetstream;
use railmon_system_tests::monitoring::{free_addr, wait_for};
use railmon_system_tests::nats::{self, start_nats_server, uplink_settings, with_client};
use railmon_system_tests::{binaries, http_get, PrivateBus, Process, Service};
use serde_json::{json, Value};

const STREAM: &str = "RAILMON_FLEET_TEST";

/// `railmon fleet` reading `stream` at `url`, and its address.
fn start_fleet(url: &str, stream: &str, work: &Path) -> (Process, String) {
    let addr_file = work.join("fleet-addr");
    let _ = std::fs::remove_file(&addr_file);
    let child = Command::new(&binaries().railmon)
        .args(["fleet", "--addr-file"])
        .arg(&addr_file)
        .env("RAILMON_FLEET__URL", url)
        .env("RAILMON_FLEET__STREAM", stream)
        .env("RAILMON_FLEET__LISTEN", "127.0.0.1:0")
        .env("RAILMON_LOG", "warn")
        .stdin(Stdio::null())
        .spawn()
        .expect("starting railmon fleet");
    let mut process = Process {
        child,
        name: "railmon fleet".into(),
    };
    let start = Instant::now();
    let addr = loop {
        if let Ok(addr) = std::fs::read_to_string(&addr_file) {
            if !addr.is_empty() {
                break addr;
            }
        }
        if let Some(status) = process.child.try_wait().unwrap() {
            panic!("railmon fleet exited early: {status}");
        }
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "railmon fleet did not start"
        );
        std::thread::sleep(Duration::from_millis(10));
    };
    (process, addr)
}

fn get_json(addr: &str, path: &str) -> Value {
    let (status, body) = http_get(addr, path);
    assert_eq!(status, 200, "GET {path}: {body}");
    serde_json::from_str(&body).unwrap_or_else(|e| panic!("GET {path}: {e}: {body}"))
}

/// An event as the uplink publishes it: `(vehicle, fleet, stream, id, kind, subject, hour)`,
/// acquired at `hour`:00 on 2026-11-27.
type SimEvent<'a> = (&'a str, &'a str, &'a str, u64, &'a str, &'a str, u32);

fn event_message(e: &SimEvent) -> (String, String, Vec<u8>) {
    let (vehicle, fleet, stream, id, kind, subject, hour) = *e;
    let payload = json!({
        "id": id, "stream": stream, "kind": kind, "subject": subject,
        "time_utc": format!("2026-11-27T{hour:02}:00:00Z"),
        "time_s": f64::from(hour) * 3600.0, "run": 0, "run_time_s": f64::from(hour) * 3600.0,
        "vehicle_id": vehicle, "fleet": fleet,
    });
    (
        format!("railmon.{fleet}.{vehicle}.{stream}.events"),
        format!("{vehicle}:{id}"),
        serde_json::to_vec(&payload).unwrap(),
    )
}

/// Publishes `messages` (subject, message id or empty, payload), awaiting every
/// acknowledgement.
async fn publish_all(client: async_nats::Client, messages: Vec<(String, String, Vec<u8>)>) {
    let js = jetstream::new(client);
    let mut acks = Vec::with_capacity(messages.len());
    for (subject, id, payload) in messages {
        let mut message = jetstream::message::PublishMessage::build().payload(payload.into());
        if !id.is_empty() {
            message = message.message_id(id);
        }
        acks.push(js.send_publish(subject, message).await.expect("publish"));
        // Bounded in flight: the acknowledgements of a big simulation come back in order.
        if acks.len() >= 4096 {
            for ack in acks.drain(..) {
                ack.await.expect("acknowledged");
            }
        }
    }
    for ack in acks {
        ack.await.expect("acknowledged");
    }
}

fn publish_events(url: &str, events: &[SimEvent]) {
    let messages = events.iter().map(event_message).collect();
    with_client(url, async |client| publish_all(client, messages).await);
}

/// An alarm snapshot as the health publisher sends it.
fn snapshot_message(
    vehicle: &str,
    fleet: &str,
    last_event_id: u64,
    alarms: Value,
) -> (String, String, Vec<u8>) {
    let payload = json!({
        "vehicle_id": vehicle, "fleet": fleet, "generated_utc": "2026-11-27T12:00:00Z",
        "last_event_id": last_event_id, "alarms": alarms,
    });
    (
        format!("railmon.{fleet}.{vehicle}.alarms"),
        String::new(),
        serde_json::to_vec(&payload).unwrap(),
    )
}

/// An active alarm: stream, subject, alarm, the id of the event that raised it.
type Alarm = (String, String, String, u64);

/// `(vehicle, its alarms)` of the fleet's active alarms.
fn active(addr: &str) -> Vec<(String, Vec<Alarm>)> {
    let answer = get_json(addr, "/api/v1/alarms");
    answer["vehicles"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| {
            let alarms = v["alarms"]
                .as_array()
                .unwrap()
                .iter()
                .map(|a| {
                    (
                        a["stream"].as_str().unwrap().to_string(),
                        a["subject"].as_str().unwrap().to_string(),
                        a["alarm"].as_str().unwrap().to_string(),
                        a["event_id"].as_u64().unwrap(),
                    )
                })
                .collect();
            (v["vehicle_id"].as_str().unwrap().to_string(), alarms)
        })
        .collect()
}

fn ids(page: &Value) -> Vec<u64> {
    page["events"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["id"].as_u64().unwrap())
        .collect()
}

fn alarm(stream: &str, subject: &str, alarm: &str, id: u64) -> Alarm {
    (stream.into(), subject.into(), alarm.into(), id)
}

#[test]
fn the_fleet_view_answers_events_health_and_active_alarms_from_the_stream() {
    let Some(nats_binary) = nats::skip_without_nats_server() else {
        return;
    };
    let bus = PrivateBus::new();
    let work = std::env::temp_dir().join(format!("railmon-fleet-{}", bus.prefix));
    let _ = std::fs::remove_dir_all(&work);
    std::fs::create_dir_all(&work).unwrap();
    let nats_addr = free_addr();
    let url = format!("nats://{nats_addr}");
    let _nats = start_nats_server(&nats_binary, &nats_addr, &work.join("nats"));
    let data_dir = work.join("data");
    let data_dir = data_dir.to_str().unwrap();
    let mut settings = uplink_settings(data_dir, &url, STREAM).to_vec();
    settings.push(("RAILMON_UPLINK__HEALTH_INTERVAL_S", "1"));
    let service = Service::start(&bus, &settings);
    // The uplink creates the stream; the fleet view only reads it.
    wait_for("the uplink's stream", Duration::from_secs(20), || {
        with_client(&url, async |client| {
            jetstream::new(client).get_stream(STREAM).await.is_ok()
        })
    });
    let (_fleet, addr) = start_fleet(&url, STREAM, &work);

    // The service's health summary, as its API serves the same views.
    let started = Instant::now();
    let health = loop {
        let (status, body) = http_get(&addr, "/api/v1/vehicles/unit-7/health");
        if status == 200 {
            break serde_json::from_str::<Value>(&body).unwrap();
        }
        assert_eq!(status, 404, "{body}");
        assert!(
            started.elapsed() < Duration::from_secs(15),
            "no health summary: {body}"
        );
        std::thread::sleep(Duration::from_millis(100));
    };
    let summary = &health["summary"];
    assert_eq!(summary["vehicle_id"], "unit-7");
    assert_eq!(summary["fleet"], "north");
    let drives = service.get_json("/api/v1/drives");
    assert_eq!(summary["drives"]["drives"], drives["drives"], "{summary}");
    // The streams the service runs (by default the drives): the others are null.
    assert!(
        summary.get("bogies").is_some_and(Value::is_null),
        "{summary}"
    );
    assert!(
        summary.get("vehicle").is_some_and(Value::is_null),
        "{summary}"
    );
    // Latest wins: a later summary replaces it.
    let first = health["stream_sequence"].as_u64().unwrap();
    wait_for("a newer health summary", Duration::from_secs(10), || {
        get_json(&addr, "/api/v1/vehicles/unit-7/health")["stream_sequence"].as_u64() > Some(first)
    });
    assert!(service.metric("railmon_uplink_health_sent_total").unwrap() >= 2.0);

    // Simulated vehicles: sim-a from its events alone; sim-b from an alarm snapshot (after
    // event 10: bogie 2's anti-yaw damper degraded by event 8) and the events after it.
    let sim_a: Vec<SimEvent> = vec![
        ("sim-a", "north", "drive", 1, "slip_started", "1", 1),
        ("sim-a", "north", "vehicle", 2, "regime_changed", "", 2),
        ("sim-a", "north", "drive", 3, "slip_ended", "1", 3),
        ("sim-a", "north", "drive", 4, "slip_started", "2", 4),
    ];
    publish_events(&url, &sim_a);
    let snapshot = json!([{"stream": "bogie", "subject": "2/csay", "alarm": "degraded",
                           "event_id": 8, "since_utc": "2026-11-27T08:00:00Z"}]);
    with_client(&url, async |client| {
        let sim_b_before = event_message(&("sim-b", "south", "drive", 9, "slip_started", "1", 9));
        // Event 9 is before the snapshot's last id: the snapshot already holds its effect
        // (none active: the snapshot says so), so it must not be applied again.
        publish_all(
            client,
            vec![
                sim_b_before,
                snapshot_message("sim-b", "south", 10, snapshot),
            ],
        )
        .await
    });
    assert_eq!(
        active(&addr),
        [
            (
                "sim-a".to_string(),
                vec![alarm("drive", "2", "slipping", 4)]
            ),
            (
                "sim-b".to_string(),
                vec![alarm("bogie", "2/csay", "degraded", 8)]
            ),
        ]
    );
    publish_events(
        &url,
        &[("sim-a", "north", "bogie", 5, "damper_degraded", "1/csy", 5)],
    );
    assert_eq!(
        active(&addr)[0],
        (
            "sim-a".to_string(),
            vec![
                alarm("bogie", "1/csy", "degraded", 5),
                alarm("drive", "2", "slipping", 4)
            ]
        )
    );
    // Every alarm cleared.
    publish_events(
        &url,
        &[
            ("sim-a", "north", "bogie", 6, "damper_recovered", "1/csy", 6),
            ("sim-a", "north", "drive", 7, "slip_ended", "2", 7),
            (
                "sim-b",
                "south",
                "bogie",
                11,
                "damper_recovered",
                "2/csay",
                11,
            ),
        ],
    );
    assert_eq!(active(&addr), []);
    let alarms = get_json(&addr, "/api/v1/alarms");
    assert_eq!(alarms["vehicles_seen"], 3, "{alarms}");

    // A vehicle's events: all, in id order, each once; one stream; a kind; a time range.
    let base = "/api/v1/vehicles/sim-a/events";
    let all = get_json(&addr, base);
    assert_eq!(ids(&all), [1, 2, 3, 4, 5, 6, 7]);
    assert!(all["events"]
        .as_array()
        .unwrap()
        .iter()
        .all(|e| e["vehicle_id"] == "sim-a"));
    assert_eq!(
        ids(&get_json(&addr, &format!("{base}?stream=drive"))),
        [1, 3, 4, 7]
    );
    assert_eq!(
        ids(&get_json(&addr, &format!("{base}?kind=slip_started"))),
        [1, 4]
    );
    let range = format!("{base}?since=2026-11-27T02:00:00Z&until=2026-11-27T05:00:00Z");
    assert_eq!(ids(&get_json(&addr, &range)), [2, 3, 4]);
    // Pages of 3 by stream sequence, then an empty page that keeps the cursor.
    let mut paged = Vec::new();
    let mut after = 0;
    loop {
        let page = get_json(&addr, &format!("{base}?limit=3&after_seq={after}"));
        let got = ids(&page);
        let next = page["next_after_seq"].as_u64().unwrap();
        if got.is_empty() {
            assert_eq!(next, after);
            break;
        }
        assert!(next > after);
        paged.extend(got);
        after = next;
    }
    assert_eq!(paged, [1, 2, 3, 4, 5, 6, 7]);
    assert_eq!(
        ids(&get_json(&addr, "/api/v1/vehicles/sim-b/events")),
        [9, 11]
    );
    assert_eq!(
        ids(&get_json(&addr, "/api/v1/vehicles/nobody/events")),
        Vec::<u64>::new()
    );

    let vehicles = get_json(&addr, "/api/v1/vehicles");
    let sim_a = vehicles["vehicles"]
        .as_array()
        .unwrap()
        .iter()
        .find(|v| v["vehicle_id"] == "sim-a")
        .expect("sim-a listed");
    assert_eq!(
        sim_a["events"],
        json!({"bogie": 2, "drive": 4, "vehicle": 1})
    );

    // Bad requests are named; a vehicle without a summary is 404; the document is served.
    for bad in [
        "?stream=wheels",
        "?limit=0",
        "?since=yesterday",
        "?colour=red",
    ] {
        let (status, body) = http_get(&addr, &format!("{base}{bad}"));
        assert_eq!(status, 400, "{bad}: {body}");
        assert!(body.contains("bad_query"), "{body}");
    }
    assert_eq!(http_get(&addr, "/api/v1/vehicles/sim-a/health").0, 404);
    let document = get_json(&addr, "/openapi.json");
    assert!(document["paths"]["/api/v1/alarms"]["get"].is_object());
    drop(service);
    let _ = std::fs::remove_dir_all(&work);
}

/// compose.yaml's fleet logins (issue 29 item 4) on one local server: the `authorization`
/// block of dashboards/nats/nats.conf as it is (its cluster needs compose's host names). A
/// service logged in as `vehicle` may not create the stream: its uplink retries until
/// `railmon fleet --create-stream 1`, logged in as `ground`, created it, then forwards every
/// event exactly once; `vehicle` can neither create nor delete a stream itself.
#[test]
fn the_compose_fleets_logins_let_the_fleet_view_create_the_stream_and_not_the_vehicles() {
    let Some(nats_binary) = nats::skip_without_nats_server() else {
        return;
    };
    let bus = PrivateBus::new();
    let work = std::env::temp_dir().join(format!("railmon-fleet-logins-{}", bus.prefix));
    let _ = std::fs::remove_dir_all(&work);
    std::fs::create_dir_all(work.join("nats")).unwrap();
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
    let compose_config = std::fs::read_to_string(repo.join("dashboards/nats/nats.conf")).unwrap();
    let logins = &compose_config[compose_config
        .find("authorization {")
        .expect("nats.conf has an authorization block")..];
    let nats_addr = free_addr();
    let config = work.join("nats.conf");
    std::fs::write(
        &config,
        format!(
            "listen: \"{nats_addr}\"\njetstream {{ store_dir: \"{}\" }}\n{logins}",
            work.join("nats").display()
        ),
    )
    .unwrap();
    let child = Command::new(&nats_binary)
        .arg("-c")
        .arg(&config)
        .env("NATS_GROUND_PASSWORD", "ground-pw")
        .env("NATS_VEHICLE_PASSWORD", "vehicle-pw")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("starting nats-server");
    let _nats = Process {
        child,
        name: "nats-server".into(),
    };
    wait_for("nats-server listening", Duration::from_secs(10), || {
        std::net::TcpStream::connect(&nats_addr).is_ok()
    });
    let url = format!("nats://{nats_addr}");
    let ground = format!("nats://ground:ground-pw@{nats_addr}");
    let vehicle = format!("nats://vehicle:vehicle-pw@{nats_addr}");
    let stream_exists = || {
        with_client(&ground, async |client| {
            jetstream::new(client).get_stream(STREAM).await.is_ok()
        })
    };

    let data_dir = work.join("data");
    let data_dir = data_dir.to_str().unwrap();
    let mut settings = uplink_settings(data_dir, &url, STREAM).to_vec();
    settings.extend([
        ("RAILMON_UPLINK__USER", "vehicle"),
        ("RAILMON_UPLINK__PASSWORD", "vehicle-pw"),
    ]);
    let service = Service::start(&bus, &settings);
    let mut replay = railmon_system_tests::start_replay(&bus, "drive", &nats::LOOPING_DRIVE_REPLAY);
    wait_for(
        "the uplink refused the stream",
        Duration::from_secs(20),
        || nats::uplink_status(&service)["failures"]["stream"].as_u64() > Some(0),
    );
    assert!(!stream_exists(), "a vehicle created the stream");

    let addr_file = work.join("fleet-addr");
    let child = Command::new(&binaries().railmon)
        .args(["fleet", "--create-stream", "1", "--addr-file"])
        .arg(&addr_file)
        .env("RAILMON_FLEET__URL", &url)
        .env("RAILMON_FLEET__USER", "ground")
        .env("RAILMON_FLEET__PASSWORD", "ground-pw")
        .env("RAILMON_FLEET__STREAM", STREAM)
        .env("RAILMON_FLEET__LISTEN", "127.0.0.1:0")
        .env("RAILMON_LOG", "warn")
        .stdin(Stdio::null())
        .spawn()
        .expect("starting railmon fleet");
    let _fleet = Process {
        child,
        name: "railmon fleet".into(),
    };
    wait_for("railmon fleet listening", Duration::from_secs(20), || {
        std::fs::read_to_string(&addr_file).is_ok_and(|a| !a.is_empty())
    });
    let config = with_client(&ground, async |client| {
        let mut stream = jetstream::new(client).get_stream(STREAM).await.unwrap();
        stream.info().await.unwrap().config.clone()
    });
    assert_eq!(config.subjects, ["railmon.>"]);
    assert_eq!(config.num_replicas, 1);
    assert_eq!(config.duplicate_window, Duration::from_secs(120));
    // No new events while the stream and the store are compared (as tests/uplink.rs).
    replay.terminate(Duration::from_secs(10));
    nats::wait_caught_up(&service, Duration::from_secs(30));
    let events = nats::assert_exactly_once(&ground, STREAM, &service);
    assert!(events > 0);

    // Refused to `vehicle` however asked: a second stream, deleting this one.
    with_client(&vehicle, async |client| {
        let js = jetstream::new(client);
        let created = js
            .create_stream(jetstream::stream::Config {
                name: "RAILMON_OTHER".into(),
                subjects: vec!["other.>".into()],
                ..Default::default()
            })
            .await;
        assert!(created.is_err(), "vehicle created a stream");
        assert!(
            js.delete_stream(STREAM).await.is_err(),
            "vehicle deleted the stream"
        );
    });
    assert!(stream_exists());
    drop(service);
    let _ = std::fs::remove_dir_all(&work);
}

/// Percentiles of `samples` (ms): p50, p99, max.
fn percentiles(mut samples: Vec<f64>) -> (f64, f64, f64) {
    samples.sort_by(f64::total_cmp);
    let at = |q: f64| samples[((samples.len() - 1) as f64 * q).round() as usize];
    (at(0.5), at(0.99), samples[samples.len() - 1])
}

fn time_ms(addr: &str, path: &str) -> (f64, Value) {
    let start = Instant::now();
    let answer = get_json(addr, path);
    (start.elapsed().as_secs_f64() * 1e3, answer)
}

#[test]
#[ignore = "a measurement (about 90 s), not a check: `cargo test -p railmon-system-tests --test fleet -- --ignored --nocapture`"]
fn fleet_queries_at_1000_vehicles() {
    let Some(nats_binary) = nats::skip_without_nats_server() else {
        return;
    };
    const VEHICLES: u64 = 1000;
    const EVENTS_PER_DAY: u64 = 200;
    const QUERIES: usize = 200;
    let work = std::env::temp_dir().join(format!("railmon-fleet-measure-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&work);
    std::fs::create_dir_all(&work).unwrap();
    let nats_addr = free_addr();
    let url = format!("nats://{nats_addr}");
    let _nats = start_nats_server(&nats_binary, &nats_addr, &work.join("nats"));
    with_client(&url, async |client| {
        // As the uplink creates it.
        jetstream::new(client)
            .create_stream(jetstream::stream::Config {
                name: STREAM.into(),
                subjects: vec!["railmon.>".into()],
                duplicate_window: Duration::from_secs(120),
                storage: jetstream::stream::StorageType::File,
                ..Default::default()
            })
            .await
            .unwrap();
    });
    // A day of each vehicle's events: drive slips, damper changes, regime changes; every
    // 20th vehicle ends the day with a drive slipping.
    let kinds = [
        ("drive", "slip_started", "1"),
        ("drive", "slip_ended", "1"),
        ("vehicle", "regime_changed", ""),
        ("bogie", "damper_degraded", "1/csy"),
        ("bogie", "damper_recovered", "1/csy"),
    ];
    let mut messages = Vec::new();
    for v in 0..VEHICLES {
        let vehicle = format!("sim-{v:04}");
        for id in 1..=EVENTS_PER_DAY {
            let (stream, mut kind, subject) = kinds[(id as usize - 1) % kinds.len()];
            if id == EVENTS_PER_DAY && v % 20 == 0 {
                kind = "slip_started";
            }
            let stream = if kind.starts_with("slip") {
                "drive"
            } else {
                stream
            };
            let seconds = id * 86_400 / (EVENTS_PER_DAY + 1);
            let payload = json!({
                "id": id, "stream": stream, "kind": kind, "subject": subject,
                "time_utc": format!("2026-11-27T{:02}:{:02}:{:02}Z", seconds / 3600, seconds / 60 % 60, seconds % 60),
                "time_s": seconds as f64, "run": 0, "run_time_s": seconds as f64,
                "slip_probability": 0.97, "vehicle_id": vehicle, "fleet": "north",
            });
            messages.push((
                format!("railmon.north.{vehicle}.{stream}.events"),
                format!("{vehicle}:{id}"),
                serde_json::to_vec(&payload).unwrap(),
            ));
        }
    }
    let total = messages.len();
    let start = Instant::now();
    with_client(&url, async |client| publish_all(client, messages).await);
    println!(
        "published {total} events of {VEHICLES} vehicles in {:.1} s",
        start.elapsed().as_secs_f64()
    );
    let (_fleet, addr) = start_fleet(&url, STREAM, &work);

    // Without alarm snapshots: every vehicle's events replayed (the naive way); it may take
    // longer than the fleet's request timeout (`http.request_timeout_ms`, 10 s).
    let start = Instant::now();
    let (status, _) = http_get(&addr, "/api/v1/alarms");
    println!(
        "active alarms, no snapshots (replay of all {total} events): status {status} after {:.1} s",
        start.elapsed().as_secs_f64()
    );

    // The day's events were stored before the vehicles' last snapshots, as on a running
    // ground: wait out the snapshot margin, then every vehicle's snapshot.
    std::thread::sleep(Duration::from_secs(31));
    let snapshots = (0..VEHICLES)
        .map(|v| {
            let vehicle = format!("sim-{v:04}");
            let alarms = match v % 20 == 0 {
                true => json!([{"stream": "drive", "subject": "1", "alarm": "slipping",
                                "event_id": EVENTS_PER_DAY, "since_utc": "2026-11-27T23:52:50Z"}]),
                false => json!([]),
            };
            snapshot_message(&vehicle, "north", EVENTS_PER_DAY, alarms)
        })
        .collect();
    with_client(&url, async |client| publish_all(client, snapshots).await);
    let mut alarms = Vec::new();
    for _ in 0..QUERIES {
        let (ms, answer) = time_ms(&addr, "/api/v1/alarms");
        assert_eq!(
            answer["vehicles"].as_array().unwrap().len() as u64,
            VEHICLES / 20
        );
        alarms.push(ms);
    }
    let (p50, p99, max) = percentiles(alarms);
    println!("active alarms, {VEHICLES} vehicles with snapshots: p50 {p50:.1} ms, p99 {p99:.1} ms, max {max:.1} ms ({QUERIES} queries)");
    alarms_query_breakdown(&url, VEHICLES);

    let mut day = Vec::new();
    for q in 0..QUERIES {
        let vehicle = format!("sim-{:04}", (q as u64 * 7919) % VEHICLES);
        let path = format!(
            "/api/v1/vehicles/{vehicle}/events?since=2026-11-27T00:00:00Z&until=2026-11-28T00:00:00Z&limit=1000"
        );
        let (ms, answer) = time_ms(&addr, &path);
        assert_eq!(
            answer["events"].as_array().unwrap().len() as u64,
            EVENTS_PER_DAY
        );
        day.push(ms);
    }
    let (p50, p99, max) = percentiles(day);
    println!("one vehicle's events for a day ({EVENTS_PER_DAY} events): p50 {p50:.1} ms, p99 {p99:.1} ms, max {max:.1} ms ({QUERIES} queries)");
    day_query_breakdown(&url, VEHICLES, EVENTS_PER_DAY);
    let _ = std::fs::remove_dir_all(&work);
}

/// Where a vehicle's day goes, read with a client of its own (the steps `railmon fleet` takes,
/// timed one by one): the subjects lookup, a consumer's creation and its fetch, for a filter with
/// wildcards (`railmon.*.<vehicle>.*.events`) and for each literal subject of the vehicle; and
/// the decoding of the payloads.
fn day_query_breakdown(url: &str, vehicles: u64, events_per_day: u64) {
    use async_nats::jetstream::consumer::DeliverPolicy;
    use futures_util::StreamExt;
    const SAMPLES: u64 = 50;
    let start_time = time_of("2026-11-26T23:55:00Z");
    with_client(url, async |client| {
        let js = jetstream::new(client);
        let stream = js.get_stream(STREAM).await.unwrap();
        let start_policy = || DeliverPolicy::ByStartTime { start_time };
        let (mut info, mut wc_create, mut wc_fetch) = (Vec::new(), Vec::new(), Vec::new());
        let (mut lit_create, mut lit_fetch, mut decode) = (Vec::new(), Vec::new(), Vec::new());
        for q in 0..SAMPLES {
            let vehicle = format!("sim-{:04}", (q * 7919) % vehicles);
            let filter = format!("railmon.*.{vehicle}.*.events");
            let (created, fetched, messages) = read_to_end(&stream, &filter, start_policy()).await;
            assert_eq!(messages.len() as u64, events_per_day);
            wc_create.push(created);
            wc_fetch.push(fetched);
            let start = Instant::now();
            let subjects: Vec<String> = stream
                .info_with_subjects(format!("railmon.*.{vehicle}.*.events"))
                .await
                .unwrap()
                .map(|s| s.unwrap().0)
                .collect()
                .await;
            info.push(start.elapsed().as_secs_f64() * 1e3);
            let (mut created, mut fetched, mut n) = (0.0, 0.0, 0);
            for subject in subjects {
                let (c, f, p) = read_to_end(&stream, &subject, start_policy()).await;
                (created, fetched, n) = (created + c, fetched + f, n + p.len());
            }
            assert_eq!(n as u64, events_per_day);
            lit_create.push(created);
            lit_fetch.push(fetched);
            let start = Instant::now();
            let events: Vec<Value> = messages
                .iter()
                .map(|m| serde_json::from_slice(&m.payload).unwrap())
                .collect();
            let body = serde_json::to_vec(&events).unwrap();
            assert!(!body.is_empty());
            decode.push(start.elapsed().as_secs_f64() * 1e3);
        }
        println!("a vehicle's day, step by step ({SAMPLES} vehicles, a client of the test's own):");
        show(
            "consumer on railmon.*.<vehicle>.*.events: created",
            wc_create,
        );
        show(
            "consumer on railmon.*.<vehicle>.*.events: its messages fetched",
            wc_fetch,
        );
        show(
            "the vehicle's subjects (stream info, subjects filter)",
            info,
        );
        show(
            "a consumer per literal subject (3): created, summed",
            lit_create,
        );
        show(
            "a consumer per literal subject (3): fetched, summed",
            lit_fetch,
        );
        show("decoding the 200 payloads and encoding the answer", decode);
    });
}

/// Where the active-alarms query goes, read with a client of its own: the server round trips
/// `railmon fleet` makes (the last alarm snapshot per subject, the stream's event subjects, a
/// consumer over every vehicle's events from the oldest snapshot minus 30 s), timed one by one,
/// and the plain stream info for comparison.
fn alarms_query_breakdown(url: &str, vehicles: u64) {
    use async_nats::jetstream::consumer::DeliverPolicy;
    use futures_util::StreamExt;
    const SAMPLES: usize = 50;
    with_client(url, async |client| {
        let js = jetstream::new(client);
        let stream = js.get_stream(STREAM).await.unwrap();
        let mut for_info = stream.clone();
        let (mut snap_create, mut snap_fetch, mut subjects) = (Vec::new(), Vec::new(), Vec::new());
        let (mut recent_create, mut recent_fetch, mut info) = (Vec::new(), Vec::new(), Vec::new());
        let mut one_page = Vec::new();
        for _ in 0..SAMPLES {
            let (c, f, snapshots) =
                read_to_end(&stream, "railmon.*.*.alarms", DeliverPolicy::LastPerSubject).await;
            assert_eq!(snapshots.len() as u64, vehicles);
            let stored = snapshots.iter().map(|m| m.info().unwrap().published);
            snap_create.push(c);
            snap_fetch.push(f);
            let start = Instant::now();
            let n = stream
                .info_with_subjects("railmon.*.*.*.events")
                .await
                .unwrap()
                .count()
                .await;
            assert_eq!(n as u64, vehicles * 3);
            subjects.push(start.elapsed().as_secs_f64() * 1e3);
            let start = Instant::now();
            let page: jetstream::response::Response<Value> = js
                .request(
                    format!("STREAM.INFO.{STREAM}"),
                    &json!({"subjects_filter": "railmon.*.*.*.events"}),
                )
                .await
                .unwrap();
            let jetstream::response::Response::Ok(page) = page else {
                panic!("stream info: {page:?}");
            };
            let listed = page["state"]["subjects"].as_object().map_or(0, |s| s.len());
            assert_eq!(listed as u64, vehicles * 3);
            if one_page.is_empty() {
                println!(
                    "  one STREAM.INFO page: {listed} subjects, total {}",
                    page["total"]
                );
            }
            one_page.push(start.elapsed().as_secs_f64() * 1e3);
            let start_time = stored.min().unwrap() - Duration::from_secs(30);
            let (c, f, _) = read_to_end(
                &stream,
                "railmon.*.*.*.events",
                DeliverPolicy::ByStartTime { start_time },
            )
            .await;
            recent_create.push(c);
            recent_fetch.push(f);
            let start = Instant::now();
            for_info.info().await.unwrap();
            info.push(start.elapsed().as_secs_f64() * 1e3);
        }
        println!(
            "the active alarms, step by step ({SAMPLES} samples, a client of the test's own):"
        );
        show(
            "(1) consumer on railmon.*.*.alarms, last per subject: created",
            snap_create,
        );
        show(&format!("(1) its {vehicles} snapshots fetched"), snap_fetch);
        show(
            "(2) the event subjects (stream info, subjects filter)",
            subjects,
        );
        show(
            "(2) one STREAM.INFO request of those (its first page alone)",
            one_page,
        );
        show(
            "(3) consumer on railmon.*.*.*.events from the oldest snapshot - 30 s: created",
            recent_create,
        );
        show("(3) its messages fetched", recent_fetch);
        show("plain stream info (no subjects), for comparison", info);
    });
}

/// A step's samples (ms) as the breakdowns print them.
fn show(what: &str, samples: Vec<f64>) {
    let (p50, p99, max) = percentiles(samples);
    println!("  {what}: p50 {p50:.2} ms, p99 {p99:.2} ms, max {max:.2} ms");
}

/// A consumer on `filter` from `deliver_policy` read to its end, then deleted: the ms to
/// create it, the ms to fetch its messages, and the messages.
async fn read_to_end(
    stream: &jetstream::stream::Stream,
    filter: &str,
    deliver_policy: async_nats::jetstream::consumer::DeliverPolicy,
) -> (f64, f64, Vec<jetstream::Message>) {
    use async_nats::jetstream::consumer::{pull, AckPolicy};
    use futures_util::StreamExt;
    let start = Instant::now();
    let consumer: jetstream::consumer::Consumer<pull::Config> = stream
        .create_consumer(pull::Config {
            filter_subject: filter.into(),
            deliver_policy,
            ack_policy: AckPolicy::None,
            inactive_threshold: Duration::from_secs(30),
            memory_storage: true,
            num_replicas: 1,
            ..Default::default()
        })
        .await
        .unwrap();
    let created = start.elapsed().as_secs_f64() * 1e3;
    let start = Instant::now();
    let mut messages = Vec::new();
    let mut pending = consumer.cached_info().num_pending;
    while pending > 0 {
        let mut batch = consumer
            .fetch()
            .max_messages(1000)
            .messages()
            .await
            .unwrap();
        while let Some(message) = batch.next().await {
            let message = message.unwrap();
            pending = message.info().unwrap().pending;
            messages.push(message);
            if pending == 0 {
                break;
            }
        }
    }
    let fetched = start.elapsed().as_secs_f64() * 1e3;
    let name = consumer.cached_info().name.clone();
    stream.delete_consumer(&name).await.unwrap();
    (created, fetched, messages)
}

fn time_of(rfc3339: &str) -> time::OffsetDateTime {
    let ns = railmon_bus::utc::parse_rfc3339(rfc3339).unwrap();
    time::OffsetDateTime::from_unix_timestamp_nanos(i128::from(ns)).unwrap()
}
