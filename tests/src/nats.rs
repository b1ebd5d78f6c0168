//! The event uplink's tests against real `nats-server`s (tests/tests/uplink.rs: one server;
//! tests/tests/uplink_cluster.rs: a three-node cluster): where the server binary is, what the
//! uplink's stream holds, and the check that every stored event is in it exactly once and in
//! order.
//!
//! Needs `nats-server` (Debian package `nats-server`, 2.9 with JetStream;
//! `scripts/install-test-deps` installs it, or set NATS_SERVER to its path). The tests say so
//! and pass without checking when it is missing.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use serde_json::Value;

use crate::Service;

/// The vehicle and fleet both tests run as.
pub const VEHICLE: &str = "unit-7";
pub const FLEET: &str = "north";

/// A drive replay that raises events until it is stopped (a few tens per second).
pub const LOOPING_DRIVE_REPLAY: [&str; 7] = [
    "--scenario",
    "config/scenarios/adhesion-seed.toml",
    "--speed",
    "max",
    "--loop",
    "--wait-subscriber-s",
    "5",
];

/// The settings of a service that stores its events in `data_dir` and forwards them to
/// `stream` at `url`, as [`VEHICLE`] of [`FLEET`], with no pacing to speak of.
pub fn uplink_settings<'a>(
    data_dir: &'a str,
    url: &'a str,
    stream: &'a str,
) -> [(&'static str, &'a str); 6] {
    [
        ("RAILMON_STORAGE__DATA_DIR", data_dir),
        ("RAILMON_IDENTITY__VEHICLE_ID", VEHICLE),
        ("RAILMON_IDENTITY__FLEET", FLEET),
        ("RAILMON_UPLINK__URL", url),
        ("RAILMON_UPLINK__STREAM", stream),
        ("RAILMON_UPLINK__MAX_EVENTS_PER_S", "100000"),
    ]
}

/// `nats-server`: $NATS_SERVER, else on the PATH, /usr/sbin (Debian) or /usr/bin.
pub fn nats_server_binary() -> Option<PathBuf> {
    if let Some(path) = std::env::var_os("NATS_SERVER") {
        return Some(path.into());
    }
    let path = std::env::var_os("PATH").unwrap_or_default();
    std::env::split_paths(&path)
        .chain(["/usr/sbin".into(), "/usr/bin".into()])
        .map(|dir| dir.join("nats-server"))
        .find(|p| p.is_file())
}

/// [`nats_server_binary`], or None after saying that the test checks nothing without it.
pub fn skip_without_nats_server() -> Option<PathBuf> {
    let binary = nats_server_binary();
    if binary.is_none() {
        eprintln!(
            "SKIPPED: nats-server is not installed (scripts/install-test-deps installs Debian's \
             `nats-server`, or set NATS_SERVER=/path/to/nats-server)"
        );
    }
    binary
}

/// Runs `f` on a one-thread tokio runtime with a client connected to `url`.
pub fn with_client<T>(url: &str, f: impl AsyncFnOnce(async_nats::Client) -> T) -> T {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    runtime.block_on(async {
        // async-nats ignores a url's user and password: `nats://user:password@host:port` logs
        // in with them here (the compose fleet's logins, tests/fleet.rs).
        let login = url.split_once("://").and_then(|(scheme, rest)| {
            let (login, host) = rest.split_once('@')?;
            let (user, password) = login.split_once(':').unwrap_or((login, ""));
            Some((format!("{scheme}://{host}"), user, password))
        });
        let client = match login {
            Some((url, user, password)) => {
                async_nats::ConnectOptions::with_user_and_password(user.into(), password.into())
                    .connect(url)
                    .await
            }
            None => async_nats::connect(url).await,
        };
        f(client.expect("connecting to NATS")).await
    })
}

/// A `nats-server -js` on `addr` with its store in `store_dir`, once it accepts connections.
pub fn start_nats_server(
    binary: &std::path::Path,
    addr: &str,
    store_dir: &std::path::Path,
) -> crate::Process {
    let (host, port) = addr.rsplit_once(':').unwrap();
    let child = std::process::Command::new(binary)
        .args(["-js", "-a", host, "-p", port, "-sd"])
        .arg(store_dir)
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("starting nats-server");
    let process = crate::Process {
        child,
        name: "nats-server".into(),
    };
    crate::monitoring::wait_for("nats-server listening", Duration::from_secs(10), || {
        std::net::TcpStream::connect(addr).is_ok()
    });
    process
}

/// The uplink's stream as [`VEHICLE`]'s events: the event ids of its messages in stream order
/// (each message's subject, message id and payload checked against [`FLEET`] and [`VEHICLE`]).
pub fn stream_event_ids(url: &str, stream: &str) -> Vec<u64> {
    with_client(url, async |client| {
        let js = async_nats::jetstream::new(client);
        let mut stream = js.get_stream(stream).await.expect("the uplink's stream");
        let info = stream.info().await.unwrap().clone();
        let mut ids = Vec::new();
        if info.state.messages == 0 {
            return ids;
        }
        let subjects = format!("railmon.{FLEET}.{VEHICLE}.");
        for seq in info.state.first_sequence..=info.state.last_sequence {
            let message = stream
                .get_raw_message(seq)
                .await
                .expect("message by sequence");
            assert!(
                message.subject.as_str().starts_with(&subjects),
                "{}",
                message.subject
            );
            // The health summaries and alarm snapshots share the stream (latest wins, no
            // message ids): not events.
            if !message.subject.as_str().ends_with(".events") {
                continue;
            }
            let message_id = message
                .headers
                .get("Nats-Msg-Id")
                .expect("Nats-Msg-Id")
                .to_string();
            let body: Value = serde_json::from_slice(&message.payload).unwrap();
            let id = body["id"].as_u64().expect("event id");
            assert_eq!(format!("{VEHICLE}:{id}"), message_id);
            ids.push(id);
        }
        ids
    })
}

/// Every stored event's id, from the service's API.
pub fn stored_ids(service: &Service) -> Vec<u64> {
    let mut ids = Vec::new();
    let mut after_id = 0;
    loop {
        let page = service.get_json(&format!("/api/v1/events?after_id={after_id}&limit=1000"));
        let events = page["events"].as_array().unwrap();
        if events.is_empty() {
            return ids;
        }
        ids.extend(events.iter().map(|e| e["id"].as_u64().unwrap()));
        after_id = page["next_after_id"].as_u64().unwrap();
    }
}

pub fn uplink_status(service: &Service) -> Value {
    service.get_json("/api/v1/status")["uplink"].clone()
}

/// Waits until every stored event is acknowledged; returns how long that took.
pub fn wait_caught_up(service: &Service, timeout: Duration) -> Duration {
    let start = Instant::now();
    loop {
        let status = service.get_json("/api/v1/status");
        let last = status["events"]["last_event_id"].as_u64().unwrap();
        let uplink = &status["uplink"];
        if uplink["acknowledged_event_id"].as_u64() == Some(last)
            && uplink["backlog_events"].as_u64() == Some(0)
            && status["events"]["events_pending"].as_u64() == Some(0)
        {
            return start.elapsed();
        }
        assert!(
            start.elapsed() < timeout,
            "uplink not caught up within {timeout:?}: {status}"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Checks that `stream` holds every event `service` stored exactly once (by message id),
/// nothing else, and in the order of their ids (stream sequence increasing with the event id);
/// returns how many.
pub fn assert_exactly_once(url: &str, stream: &str, service: &Service) -> usize {
    let in_stream_order = stream_event_ids(url, stream);
    let mut on_ground: BTreeMap<u64, u32> = BTreeMap::new();
    for id in &in_stream_order {
        *on_ground.entry(*id).or_insert(0) += 1;
    }
    let repeated: Vec<_> = on_ground.iter().filter(|(_, n)| **n > 1).collect();
    assert!(repeated.is_empty(), "stored more than once: {repeated:?}");
    let stored = stored_ids(service);
    let missing: Vec<_> = stored
        .iter()
        .filter(|id| !on_ground.contains_key(*id))
        .collect();
    assert!(missing.is_empty(), "never arrived: {missing:?}");
    assert_eq!(on_ground.len(), stored.len(), "messages of unknown events");
    let out_of_order: Vec<_> = in_stream_order
        .windows(2)
        .filter(|w| w[1] <= w[0])
        .collect();
    assert!(
        out_of_order.is_empty(),
        "stream order is not event id order: {out_of_order:?}"
    );
    stored.len()
}
