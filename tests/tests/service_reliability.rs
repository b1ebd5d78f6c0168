//! The service's part of reliability (issue 11): readiness that tells the truth, one source at
//! a time, refused frames counted once, and HTTP limits (header/idle timeout, connection cap,
//! shutdown deadline) against the real binary.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use railmon_bus::{BusNode, DriveChannels, DriveFrame, FramePublisher};
use railmon_slip::{AdhesionScenario, DriveSimulator};
use railmon_system_tests::{workspace_root, PrivateBus, Service};

fn seed() -> AdhesionScenario {
    let path = workspace_root().join("config/scenarios/adhesion-seed.toml");
    AdhesionScenario::from_toml_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// Frames of the seed scenario, their step in ns.
struct Frames {
    simulator: DriveSimulator,
    dt_ns: u64,
}

impl Frames {
    fn new() -> Self {
        let scenario = seed();
        Self {
            dt_ns: (scenario.dt_s() * 1e9).round() as u64,
            simulator: DriveSimulator::new(&scenario).unwrap(),
        }
    }

    fn next(&mut self) -> DriveFrame {
        let (samples, _) = self.simulator.step().unwrap();
        let drives: Vec<DriveChannels> = samples.iter().map(DriveChannels::from).collect();
        DriveFrame::new(self.dt_ns, &drives).unwrap()
    }
}

fn publisher(bus: &PrivateBus, name: &str) -> (BusNode, FramePublisher<DriveFrame>) {
    let node = BusNode::create(&bus.config(), name).unwrap();
    let publisher = node.publisher::<DriveFrame>().unwrap();
    publisher
        .wait_for_subscriber(Some(Duration::from_secs(20)), &|| false)
        .unwrap();
    (node, publisher)
}

fn readyz_reason(service: &Service) -> (u16, String) {
    let (code, body) = service.get("/readyz");
    let json: serde_json::Value = serde_json::from_str(&body).unwrap();
    (
        code,
        json["streams"][0]["readiness"]
            .as_str()
            .unwrap()
            .to_string(),
    )
}

#[test]
fn frames_that_are_all_refused_make_the_stream_not_ready_and_count_no_gaps() {
    let bus = PrivateBus::new();
    let service = Service::start(&bus, &[]);
    let (_node, mut publisher) = publisher(&bus, "test-publisher");
    let mut frames = Frames::new();
    let dt_ns = frames.dt_ns;
    for step in 0..20 {
        publisher.send(&frames.next(), step * dt_ns).unwrap();
    }
    publisher.notify().unwrap();
    service.wait_for_status("drive", Duration::from_secs(5), "20 good frames", |s| {
        s["estimator_steps"] == 20
    });
    assert_eq!(readyz_reason(&service), (200, "ready".into()));
    // Time stamps half a period off (data at another rate) and NaN values, alternately:
    // every frame refused, none counted as a gap.
    let start = Instant::now();
    let mut step = 20;
    while start.elapsed() < Duration::from_millis(1200) {
        let mut frame = frames.next();
        let mut time_ns = step * dt_ns;
        match step % 2 {
            0 => frame.drives[0].i_alpha_a = f64::NAN,
            _ => time_ns += dt_ns / 2,
        }
        publisher.send(&frame, time_ns).unwrap();
        publisher.notify().unwrap();
        step += 1;
        std::thread::sleep(Duration::from_millis(10));
    }
    let status = service.status("drive");
    assert_eq!(status["sequence_gaps"], 0, "{status}");
    assert_eq!(status["estimator_steps"], 20, "{status}");
    assert!(
        status["samples_rejected"].as_u64().unwrap() >= 50,
        "{status}"
    );
    assert_eq!(readyz_reason(&service), (503, "rejecting".into()));
}

#[test]
fn a_second_publisher_is_refused_while_the_first_is_alive() {
    let bus = PrivateBus::new();
    let service = Service::start(&bus, &[]);
    let (_node_a, mut first) = publisher(&bus, "first");
    let (_node_b, mut second) = publisher(&bus, "second");
    let mut frames = Frames::new();
    let dt_ns = frames.dt_ns;
    // Interleaved like two replays on one stream: before, every switch restarted the estimator.
    for step in 0..200 {
        first.send(&frames.next(), step * dt_ns).unwrap();
        second.send(&frames.next(), step * dt_ns).unwrap();
    }
    first.notify().unwrap();
    service.wait_for_status("drive", Duration::from_secs(5), "400 frames", |s| {
        s["samples_received"] == 400
    });
    let status = service.status("drive");
    assert_eq!(status["sources"], 1, "{status}");
    assert_eq!(status["estimator_steps"], 200, "{status}");
    assert_eq!(
        status["last_rejection"]["reason"], "second_source",
        "{status}"
    );
    assert_eq!(readyz_reason(&service), (503, "competing_sources".into()));
}

/// Sends raw bytes on a new connection; returns the stream.
fn connect(addr: &str, bytes: &[u8]) -> TcpStream {
    let mut stream = TcpStream::connect(addr).unwrap();
    stream.write_all(bytes).unwrap();
    stream
}

/// Whether the server closed `stream` within `timeout` (a read returns 0 or an error).
fn closed_within(stream: &mut TcpStream, timeout: Duration) -> bool {
    stream.set_read_timeout(Some(timeout)).unwrap();
    let mut buf = [0u8; 4096];
    loop {
        match stream.read(&mut buf) {
            Ok(0) => return true,
            Ok(_) => continue,
            Err(e)
                if e.kind() == std::io::ErrorKind::WouldBlock
                    || e.kind() == std::io::ErrorKind::TimedOut =>
            {
                return false
            }
            Err(_) => return true,
        }
    }
}

#[test]
fn idle_and_half_open_connections_are_closed_and_capped() {
    let bus = PrivateBus::new();
    let service = Service::start(
        &bus,
        &[
            ("RAILMON_HTTP__HEADER_TIMEOUT_MS", "400"),
            ("RAILMON_HTTP__MAX_CONNECTIONS", "4"),
        ],
    );
    // Half-open: headers never finished.
    let mut held: Vec<TcpStream> = (0..10)
        .map(|_| connect(&service.addr, b"GET /healthz HTTP/1.1\r\nHost: x\r\n"))
        .collect();
    let closed: usize = held
        .iter_mut()
        .map(|s| usize::from(closed_within(s, Duration::from_millis(1500))))
        .sum();
    assert_eq!(
        closed, 10,
        "every half-open connection closed by the header timeout"
    );
    // Each connection beyond the cap took the slot of the longest-idle one (none was serving).
    let status = service.get_json("/api/v1/status");
    assert!(
        status["http_connections_evicted"].as_u64().unwrap() >= 6,
        "{status}"
    );
    // Idle keep-alive after a complete request: closed by the same timeout.
    let mut idle = connect(&service.addr, b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n");
    assert!(closed_within(&mut idle, Duration::from_millis(1500)));
    assert_eq!(service.get("/healthz").0, 200);
}

/// One client holding every connection slot (half-open, or idle after a request) cannot keep
/// the probes and scrapes out: the newcomer takes the slot of the longest-idle connection
/// (issue 26: 2 of 61 probes were answered).
#[test]
fn a_client_holding_every_slot_cannot_keep_the_probes_out() {
    let bus = PrivateBus::new();
    let service = Service::start(
        &bus,
        &[
            ("RAILMON_HTTP__HEADER_TIMEOUT_MS", "60000"),
            ("RAILMON_HTTP__MAX_CONNECTIONS", "4"),
        ],
    );
    let mut held: Vec<TcpStream> = Vec::new();
    let mut answered = 0;
    for probe in 0..20 {
        // The attacker tops the house up before every probe: half-open and idle alike.
        for i in 0..4 {
            let request: &[u8] = match (probe + i) % 2 {
                0 => b"GET /healthz HTTP/1.1\r\nHost: x\r\n",
                _ => b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n",
            };
            held.push(connect(&service.addr, request));
        }
        std::thread::sleep(Duration::from_millis(20));
        if service.get("/healthz").0 == 200 {
            answered += 1;
        }
    }
    assert_eq!(
        answered, 20,
        "probes answered while one client held every slot"
    );
    let status = service.get_json("/api/v1/status");
    assert_eq!(status["http_connections_refused"], 0, "{status}");
    drop(held);
}

#[test]
fn sigterm_cuts_an_unfinished_request_at_the_shutdown_deadline() {
    let bus = PrivateBus::new();
    let mut service = Service::start(
        &bus,
        &[
            ("RAILMON_HTTP__HEADER_TIMEOUT_MS", "60000"),
            ("RAILMON_HTTP__SHUTDOWN_DEADLINE_MS", "500"),
        ],
    );
    let _unfinished = connect(&service.addr, b"GET /api/v1/drives HTTP/1.1\r\nHost: x\r\n");
    std::thread::sleep(Duration::from_millis(100));
    let start = Instant::now();
    let status = service.process.terminate(Duration::from_secs(10));
    assert!(status.success(), "{status}");
    assert!(
        start.elapsed() < Duration::from_secs(3),
        "{:?}",
        start.elapsed()
    );
}

/// A bus root path open to others, or a symlink, is refused at start with exit 1 and the key
/// named (issue 26: it was retried for ever by the ingest threads, the service up but blind).
#[test]
fn an_unsafe_bus_root_path_is_refused_at_start() {
    let scratch = std::env::temp_dir().join(format!("railmon-root-refused-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&scratch);
    std::fs::create_dir_all(scratch.join("private")).unwrap();
    std::os::unix::fs::symlink(scratch.join("private"), scratch.join("link")).unwrap();
    for (root, why) in [
        ("/tmp".to_string(), "world-writable"),
        (scratch.join("link").display().to_string(), "symbolic link"),
    ] {
        let out = std::process::Command::new(&railmon_system_tests::binaries().railmon)
            .arg("serve")
            .env("RAILMON_BUS__ROOT_PATH", &root)
            .env("RAILMON_HTTP__LISTEN", "127.0.0.1:0")
            .env("RAILMON_STORAGE__DATA_DIR", scratch.join("data"))
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{root}: {stderr}");
        assert!(
            stderr.contains("bus.root_path") && stderr.contains(why),
            "{root}: {stderr}"
        );
    }
    let _ = std::fs::remove_dir_all(&scratch);
}
