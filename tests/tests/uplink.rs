//! The event uplink (issue 29) against a real NATS JetStream server: `railmon serve` forwards
//! every stored event exactly once (counted by message id, `<vehicle>:<event id>`), also the
//! events raised while the server was down, and a restart of the service resumes from its
//! cursor without sending anything again.
//!
//! Needs `nats-server` (Debian package `nats-server`, 2.9 with JetStream; `scripts/install-test-deps`
//! installs it, CI runs that first; or set NATS_SERVER to its path). Without it the test says so
//! and passes without checking anything.
//!
//! The server is stopped with SIGTERM, not SIGKILL: its file store acknowledges a message
//! before the write reaches the file (it flushes in the background), so a SIGKILL can lose
//! messages the server acknowledged, which no client can see. For the vehicle a stopped server
//! and a cut link are the same: the connection drops.

use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::Duration;

use railmon_system_tests::monitoring::{free_addr, wait_for};
use railmon_system_tests::nats::{self, uplink_status, wait_caught_up, LOOPING_DRIVE_REPLAY};
use railmon_system_tests::{start_replay, PrivateBus, Process, Service};

const STREAM: &str = "RAILMON_TEST";

/// A `nats-server -js` on `addr` with its store in `store_dir` (kept across restarts).
fn start_nats(binary: &PathBuf, addr: &str, store_dir: &std::path::Path) -> Process {
    let (host, port) = addr.rsplit_once(':').unwrap();
    let child = Command::new(binary)
        .args(["-js", "-a", host, "-p", port, "-sd"])
        .arg(store_dir)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("starting nats-server");
    let process = Process {
        child,
        name: "nats-server".into(),
    };
    wait_for("nats-server listening", Duration::from_secs(10), || {
        std::net::TcpStream::connect(addr).is_ok()
    });
    process
}

fn assert_exactly_once(url: &str, service: &Service) -> usize {
    nats::assert_exactly_once(url, STREAM, service)
}

#[test]
fn every_event_arrives_exactly_once_across_a_server_outage_and_a_restart() {
    let Some(nats_binary) = nats::skip_without_nats_server() else {
        return;
    };
    let bus = PrivateBus::new();
    let work = std::env::temp_dir().join(format!("railmon-uplink-{}", bus.prefix));
    let _ = std::fs::remove_dir_all(&work);
    let nats_store = work.join("nats");
    let data_dir = work.join("data");
    let nats_addr = free_addr();
    let url = format!("nats://{nats_addr}");
    let mut server = start_nats(&nats_binary, &nats_addr, &nats_store);
    let data = data_dir.to_str().unwrap().to_string();
    let settings = nats::uplink_settings(&data, &url, STREAM);
    let mut service = Service::start(&bus, &settings);
    let mut replay = start_replay(&bus, "drive", &LOOPING_DRIVE_REPLAY);

    // 1. Connected: events are forwarded as they are stored.
    wait_for("events forwarded", Duration::from_secs(30), || {
        uplink_status(&service)["events_acknowledged"].as_u64() >= Some(20)
    });
    assert_eq!(uplink_status(&service)["link_up"], true);

    // 2. The server goes away while events keep coming: they wait in the store.
    server.terminate(Duration::from_secs(10));
    let acked_at_outage = uplink_status(&service)["acknowledged_event_id"]
        .as_u64()
        .unwrap();
    wait_for("link down", Duration::from_secs(10), || {
        uplink_status(&service)["link_up"] == false
    });
    let last_at_outage = service.get_json("/api/v1/status")["events"]["last_event_id"]
        .as_u64()
        .unwrap();
    wait_for("events raised while down", Duration::from_secs(30), || {
        service.get_json("/api/v1/status")["events"]["last_event_id"].as_u64()
            >= Some(last_at_outage + 20)
    });
    // The backlog is a count of the store's rows, refreshed once a second (and after every
    // page sent), not per event: at `--speed max` the 20 events above take a few hundred ms,
    // less than one refresh. Wait for a count that includes them; it must cover every event
    // after the cursor, which cannot move while the server is down.
    let raised_after_cursor = last_at_outage + 20 - acked_at_outage;
    wait_for("backlog counted while down", Duration::from_secs(5), || {
        uplink_status(&service)["backlog_events"].as_u64() >= Some(raised_after_cursor)
    });
    let down = uplink_status(&service);
    assert_eq!(down["acknowledged_event_id"], acked_at_outage, "{down}");
    assert!(
        down["failures"]["disconnected"].as_u64() >= Some(1),
        "{down}"
    );
    assert!(
        service.metric("railmon_uplink_link_up") == Some(0.0),
        "link_up metric"
    );

    // 3. The server comes back (same store): the backlog drains, oldest first.
    let _server = start_nats(&nats_binary, &nats_addr, &nats_store);
    replay.terminate(Duration::from_secs(10));
    let drained = wait_caught_up(&service, Duration::from_secs(60));
    let status = service.get_json("/api/v1/status");
    let last = status["events"]["last_event_id"].as_u64().unwrap();
    eprintln!(
        "backlog after the outage: ids {acked_at_outage}..{last} drained in {drained:?}; {}",
        status["uplink"]
    );
    let forwarded = assert_exactly_once(&url, &service);
    assert!(forwarded >= 40, "{forwarded} events");
    assert_eq!(service.metric("railmon_uplink_backlog_events"), Some(0.0));
    assert_eq!(
        service.metric("railmon_uplink_acknowledged_event_id"),
        Some(last as f64)
    );

    // 4. A restart resumes from the cursor: nothing is sent again.
    assert!(service.process.terminate(Duration::from_secs(10)).success());
    drop(service);
    let service = Service::start(&bus, &settings);
    wait_for("link up after the restart", Duration::from_secs(10), || {
        uplink_status(&service)["link_up"] == true
    });
    std::thread::sleep(Duration::from_secs(1));
    let restarted = uplink_status(&service);
    assert_eq!(restarted["events_sent"], 0, "{restarted}");
    assert_eq!(restarted["acknowledged_event_id"], last, "{restarted}");
    assert_eq!(assert_exactly_once(&url, &service), forwarded);

    // 5. Killed (SIGKILL) while forwarding, then restarted: still exactly once.
    let mut replay = start_replay(&bus, "drive", &LOOPING_DRIVE_REPLAY);
    wait_for("new events forwarded", Duration::from_secs(30), || {
        uplink_status(&service)["acknowledged_event_id"].as_u64() >= Some(last + 10)
    });
    let mut service = service;
    service.process.kill_hard();
    replay.terminate(Duration::from_secs(10));
    drop(service);
    let service = Service::start(&bus, &settings);
    wait_caught_up(&service, Duration::from_secs(60));
    let total = assert_exactly_once(&url, &service);
    assert!(total > forwarded, "{total} events after the kill");
    drop(service);
    let _ = std::fs::remove_dir_all(&work);
}

/// A ground that never answers (no server listening at the uplink's url): the service runs as
/// without the uplink, its events wait in the store (counted as the backlog), and the failed
/// attempts count as `unreachable`, not as a stream the ground refused.
#[test]
fn with_no_server_the_events_wait_and_the_attempts_count_as_unreachable() {
    let bus = PrivateBus::new();
    let work = std::env::temp_dir().join(format!("railmon-uplink-none-{}", bus.prefix));
    let _ = std::fs::remove_dir_all(&work);
    let data = work.join("data").to_str().unwrap().to_string();
    let url = format!("nats://{}", free_addr());
    let service = Service::start(&bus, &nats::uplink_settings(&data, &url, STREAM));
    let _replay = start_replay(&bus, "drive", &LOOPING_DRIVE_REPLAY);
    wait_for("attempts counted", Duration::from_secs(30), || {
        uplink_status(&service)["failures"]["unreachable"].as_u64() >= Some(2)
    });
    wait_for("events waiting", Duration::from_secs(30), || {
        uplink_status(&service)["backlog_events"].as_u64() >= Some(10)
    });
    let status = uplink_status(&service);
    assert_eq!(status["link_up"], false, "{status}");
    assert_eq!(status["events_sent"], 0, "{status}");
    for kind in ["stream", "publish", "ack", "store"] {
        assert_eq!(status["failures"][kind], 0, "{kind}: {status}");
    }
    // The estimates are served as ever: the uplink waits beside them.
    let drives = service.get_json("/api/v1/drives");
    assert!(
        drives["drives"].as_array().is_some_and(|d| !d.is_empty()),
        "{drives}"
    );
    drop(service);
    let _ = std::fs::remove_dir_all(&work);
}

/// A page published before its acknowledgements are awaited can leave a hole on the ground: a
/// message lost with a dropped connection while the next ones were stored (or a publish during
/// a leader election). Here the ground already holds every stored event but two, and its
/// duplicate window has passed: the uplink must send exactly those two, not move its cursor
/// past them (they would never arrive) and not send the rest again (stored twice).
#[test]
fn events_missing_between_events_the_ground_holds_are_sent_and_nothing_else() {
    let Some(nats_binary) = nats::skip_without_nats_server() else {
        return;
    };
    let bus = PrivateBus::new();
    let work = std::env::temp_dir().join(format!("railmon-uplink-hole-{}", bus.prefix));
    let _ = std::fs::remove_dir_all(&work);
    let data_dir = work.join("data");
    let nats_addr = free_addr();
    let url = format!("nats://{nats_addr}");
    let _server = start_nats(&nats_binary, &nats_addr, &work.join("nats"));
    let data = data_dir.to_str().unwrap().to_string();
    let settings = nats::uplink_settings(&data, &url, STREAM);

    // 1. Events stored with the uplink off.
    let service = Service::start(&bus, &settings[..3]);
    let mut replay = start_replay(&bus, "drive", &LOOPING_DRIVE_REPLAY);
    wait_for("events stored", Duration::from_secs(30), || {
        service.get_json("/api/v1/status")["events"]["last_event_id"].as_u64() >= Some(30)
    });
    replay.terminate(Duration::from_secs(10));
    let mut service = service;
    assert!(service.process.terminate(Duration::from_secs(10)).success());
    drop(service);

    // 2. The ground holds all of them but two (as one vehicle's uplink would have sent them),
    // and its duplicate window is over.
    let events: Vec<serde_json::Value> = {
        let mut service = Service::start(&bus, &settings[..3]);
        let mut events = Vec::new();
        loop {
            let after_id = events
                .last()
                .map_or(0, |e: &serde_json::Value| e["id"].as_u64().unwrap());
            let page = service.get_json(&format!("/api/v1/events?after_id={after_id}&limit=1000"));
            let page = page["events"].as_array().unwrap();
            if page.is_empty() {
                break;
            }
            events.extend(page.iter().cloned());
        }
        assert!(service.process.terminate(Duration::from_secs(10)).success());
        events
    };
    let ids: Vec<u64> = events.iter().map(|e| e["id"].as_u64().unwrap()).collect();
    let missing = [ids[4], ids[ids.len() - 3]];
    nats::with_client(&url, async |client| {
        let js = async_nats::jetstream::new(client);
        js.create_stream(async_nats::jetstream::stream::Config {
            name: STREAM.into(),
            subjects: vec!["railmon.>".into()],
            duplicate_window: Duration::from_secs(1),
            ..Default::default()
        })
        .await
        .expect("creating the stream");
        for event in events
            .iter()
            .filter(|e| !missing.contains(&e["id"].as_u64().unwrap()))
        {
            let subject = format!(
                "railmon.{}.{}.{}.events",
                nats::FLEET,
                nats::VEHICLE,
                event["stream"].as_str().unwrap()
            );
            let mut payload = event.clone();
            payload["vehicle_id"] = nats::VEHICLE.into();
            payload["fleet"] = nats::FLEET.into();
            let message = async_nats::jetstream::message::PublishMessage::build()
                .message_id(format!("{}:{}", nats::VEHICLE, event["id"]))
                .payload(serde_json::to_vec(&payload).unwrap().into());
            js.send_publish(subject, message)
                .await
                .unwrap()
                .await
                .expect("stored");
        }
    });
    std::thread::sleep(Duration::from_secs(2));

    // 3. The uplink on: the two missing events arrive, once each, and nothing else is sent.
    let service = Service::start(&bus, &settings);
    wait_caught_up(&service, Duration::from_secs(60));
    let status = uplink_status(&service);
    let in_stream_order = nats::stream_event_ids(&url, STREAM);
    let stored = nats::stored_ids(&service);
    let mut on_ground = in_stream_order.clone();
    on_ground.sort_unstable();
    assert_eq!(
        on_ground, stored,
        "the ground's events, once each: {status}"
    );
    // Stored since the restart (the service's own events) come after the holes are filled.
    let sent_now: Vec<u64> = in_stream_order[ids.len() - missing.len()..].to_vec();
    assert_eq!(&sent_now[..2], &missing, "{status}");
    assert_eq!(
        status["events_sent"].as_u64(),
        Some(sent_now.len() as u64),
        "{status}"
    );
    drop(service);
    let _ = std::fs::remove_dir_all(&work);
}
