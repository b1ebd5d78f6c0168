//! The event uplink (issue 29 item 5) against a three-node NATS JetStream cluster on loopback,
//! without Docker: every event the service stores reaches the ground exactly once and in order
//! (per message id, stream order = event id order) across
//! 1. a cut link (a TCP proxy between the service and its NATS node closes every connection and
//!    refuses new ones for a few seconds while events keep coming),
//! 2. a kill -9 of the service (restarted on the same event database),
//! 3. a kill -9 of one NATS node: the stream's leader (made to be a node the service is not
//!    connected to), while events flow.
//!
//! Why a kill -9 of a node is safe here when tests/tests/uplink.rs stops its single server
//! with SIGTERM: a server acknowledges a message before its file store writes it (it flushes in
//! the background), so a kill -9 of the only server can lose acknowledged messages. The
//! stream here has 3 replicas: a clustered stream acknowledges a message only after a quorum
//! (2 of 3) holds it, and a new leader is elected among the survivors with the longest log, so
//! losing one node loses nothing acknowledged. Killing the leader (not a follower) is the
//! harder case: publishes fail until the two survivors elect a new one.
//!
//! The service gets the proxy as its only server (`uplink.url`), so a cut is a real cut (its
//! client cannot fail over to another node). The proxy closes connections (the client sees the
//! link drop at once) rather than dropping packets silently (which it would notice only by its
//! ping timeout, minutes): the same for exactly-once, and it keeps the test short.
//!
//! Needs `nats-server` (see railmon_system_tests::nats); without it the test says so and passes
//! without checking. Run: `cargo test -p railmon-system-tests --test uplink_cluster --
//! --nocapture` (prints what it measured).

use std::io::{Read, Write};
use std::net::{Shutdown, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use railmon_system_tests::monitoring::wait_for;
use railmon_system_tests::nats::{
    self, uplink_status, wait_caught_up, with_client, LOOPING_DRIVE_REPLAY,
};
use railmon_system_tests::nats_cluster::{create_replicated_stream, start_cluster, NODES};
use railmon_system_tests::{start_replay, PrivateBus, Service};

const STREAM: &str = "RAILMON_CLUSTER_TEST";

/// The name of the server that leads the stream now (None during an election).
fn stream_leader(url: &str) -> Option<String> {
    with_client(url, async |client| {
        let js = async_nats::jetstream::new(client);
        let mut stream = js.get_stream(STREAM).await.ok()?;
        let info = stream.info().await.ok()?;
        info.cluster.as_ref()?.leader.clone()
    })
}

/// Asks the stream's leader to hand over to another replica.
fn step_down(url: &str) {
    with_client(url, async |client| {
        let subject = format!("$JS.API.STREAM.LEADER.STEPDOWN.{STREAM}");
        let _ = client.request(subject, "".into()).await;
    })
}

/// A TCP proxy to `upstream` that the test can cut: `cut()` closes every live connection and
/// closes new ones as soon as they are accepted, `restore()` forwards again.
struct Proxy {
    addr: String,
    cut: Arc<AtomicBool>,
    live: Arc<Mutex<Vec<TcpStream>>>,
}

impl Proxy {
    fn start(upstream: &str) -> Proxy {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap().to_string();
        let cut = Arc::new(AtomicBool::new(false));
        let live = Arc::new(Mutex::new(Vec::<TcpStream>::new()));
        let (upstream, accept_cut, accept_live) = (upstream.to_string(), cut.clone(), live.clone());
        // Lives until the test process ends (a blocked accept cannot be interrupted portably).
        std::thread::spawn(move || {
            for client in listener.incoming().flatten() {
                if accept_cut.load(Ordering::SeqCst) {
                    continue; // dropped: closed at once
                }
                let Ok(server) = TcpStream::connect(&upstream) else {
                    continue;
                };
                let mut live = accept_live.lock().unwrap();
                live.push(client.try_clone().unwrap());
                live.push(server.try_clone().unwrap());
                for (from, to) in [
                    (client.try_clone().unwrap(), server.try_clone().unwrap()),
                    (server, client),
                ] {
                    std::thread::spawn(move || pipe(from, to));
                }
            }
        });
        Proxy { addr, cut, live }
    }

    fn cut(&self) {
        self.cut.store(true, Ordering::SeqCst);
        for stream in self.live.lock().unwrap().drain(..) {
            let _ = stream.shutdown(Shutdown::Both);
        }
    }

    fn restore(&self) {
        self.cut.store(false, Ordering::SeqCst);
    }
}

/// Copies `from` to `to` until either side closes, then closes both.
fn pipe(mut from: TcpStream, mut to: TcpStream) {
    let mut buffer = [0u8; 16 * 1024];
    while let Ok(n) = from.read(&mut buffer) {
        if n == 0 || to.write_all(&buffer[..n]).is_err() {
            break;
        }
    }
    let _ = from.shutdown(Shutdown::Both);
    let _ = to.shutdown(Shutdown::Both);
}

fn last_event_id(service: &Service) -> u64 {
    service.get_json("/api/v1/status")["events"]["last_event_id"]
        .as_u64()
        .unwrap()
}

fn counter(status: &serde_json::Value, key: &str) -> u64 {
    status[key].as_u64().unwrap_or(0)
}

#[test]
fn every_event_arrives_exactly_once_across_a_cut_link_a_killed_service_and_a_killed_node() {
    let Some(nats_binary) = nats::skip_without_nats_server() else {
        return;
    };
    let bus = PrivateBus::new();
    let work = std::env::temp_dir().join(format!("railmon-uplink-cluster-{}", bus.prefix));
    let _ = std::fs::remove_dir_all(&work);
    std::fs::create_dir_all(&work).unwrap();
    let mut nodes = start_cluster(&nats_binary, &work);
    for node in &nodes {
        wait_for(
            &format!("nats-server {} listening", node.name),
            Duration::from_secs(10),
            || TcpStream::connect(&node.client_addr).is_ok(),
        );
    }
    // The service's node is n0 (through the proxy); the test reads the stream from n0 too.
    let url = format!("nats://{}", nodes[0].client_addr);
    let formed = create_replicated_stream(&url, STREAM, Duration::from_secs(30));
    let proxy = Proxy::start(&nodes[0].client_addr);
    let proxy_url = format!("nats://{}", proxy.addr);

    let data_dir = work.join("data");
    let data = data_dir.to_str().unwrap().to_string();
    let settings = nats::uplink_settings(&data, &proxy_url, STREAM);
    let mut service = Service::start(&bus, &settings);
    let mut replay = start_replay(&bus, "drive", &LOOPING_DRIVE_REPLAY);

    // Events flowing.
    wait_for("events forwarded", Duration::from_secs(30), || {
        uplink_status(&service)["events_acknowledged"].as_u64() >= Some(20)
    });

    // 1. The link is cut while events keep coming: they wait in the store.
    proxy.cut();
    wait_for("link down", Duration::from_secs(10), || {
        uplink_status(&service)["link_up"] == false
    });
    let acked_at_cut = counter(&uplink_status(&service), "acknowledged_event_id");
    let last_at_cut = last_event_id(&service);
    wait_for("events raised while cut", Duration::from_secs(30), || {
        last_event_id(&service) >= last_at_cut + 20
    });
    std::thread::sleep(Duration::from_secs(2));
    let cut = uplink_status(&service);
    assert_eq!(
        counter(&cut, "acknowledged_event_id"),
        acked_at_cut,
        "{cut}"
    );
    let backlog_at_restore = last_event_id(&service) - acked_at_cut;
    proxy.restore();
    let restored_at = Instant::now();
    wait_for("backlog forwarded", Duration::from_secs(30), || {
        uplink_status(&service)["acknowledged_event_id"].as_u64() >= Some(last_at_cut + 20)
    });
    let backlog_drained = restored_at.elapsed();

    // 2. kill -9 of the service while it forwards; restarted on the same event database.
    let before_kill = uplink_status(&service);
    service.process.kill_hard();
    replay.terminate(Duration::from_secs(10));
    drop(service);
    let service = Service::start(&bus, &settings);
    let mut replay = start_replay(&bus, "drive", &LOOPING_DRIVE_REPLAY);
    let after_restart = last_event_id(&service);
    wait_for(
        "forwarding after the restart",
        Duration::from_secs(30),
        || uplink_status(&service)["acknowledged_event_id"].as_u64() >= Some(after_restart + 10),
    );

    // 3. kill -9 of the stream's leader, made to be a node the service is not connected to.
    let leader = {
        let start = Instant::now();
        loop {
            match stream_leader(&url) {
                Some(name) if name != nodes[0].name => break name,
                Some(_) => step_down(&url),
                None => {}
            }
            assert!(
                start.elapsed() < Duration::from_secs(30),
                "no stream leader other than {}",
                nodes[0].name
            );
            std::thread::sleep(Duration::from_millis(500));
        }
    };
    let killed = nodes.iter().position(|n| n.name == leader).unwrap();
    let last_at_node_kill = last_event_id(&service);
    nodes[killed].process.kill_hard();
    let node_killed_at = Instant::now();
    wait_for("a new stream leader", Duration::from_secs(30), || {
        stream_leader(&url).is_some_and(|l| l != leader)
    });
    let elected = node_killed_at.elapsed();
    let new_leader = stream_leader(&url).unwrap_or_default();
    wait_for(
        "events raised after the node kill",
        Duration::from_secs(30),
        || last_event_id(&service) >= last_at_node_kill + 20,
    );
    replay.terminate(Duration::from_secs(10));
    let caught_up = wait_caught_up(&service, Duration::from_secs(60));
    let since_node_kill = node_killed_at.elapsed();

    let status = uplink_status(&service);
    let total = nats::assert_exactly_once(&url, STREAM, &service);
    assert!(
        total as u64 > last_at_node_kill,
        "{total} events, {last_at_node_kill} before the node kill"
    );
    eprintln!(
        "cluster of {NODES} formed, stream with {NODES} replicas created in {formed:?}\n\
         cut: {backlog_at_restore} events after the cursor ({acked_at_cut}) at restore, \
         forwarded {backlog_drained:?} after it\n\
         kill -9 of the service at {before_kill}\n\
         kill -9 of the stream leader {leader} (new leader {new_leader} within {elected:?}); \
         caught up {since_node_kill:?} after the kill ({caught_up:?} after the replay stopped)\n\
         on the ground: {total} events, each once, in id order; restarted service: {status}"
    );
    drop(service);
    drop(nodes);
    let _ = std::fs::remove_dir_all(&work);
}
