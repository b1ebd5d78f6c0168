//! A snapshot of another format version is refused, not misread: the service starts that
//! stream's estimator from its prior, logs why, counts it and stores a `snapshot_refused` event
//! naming the file and the version (issue 9: never silently). One service runs the three
//! streams; each stream's state carries its own magic and version (`snapshot::StateFormat`).

use std::time::Duration;

use railmon_system_tests::{start_replay, PrivateBus, Service};

/// FNV-1a 64, the snapshot file's checksum of its payload (`service/src/snapshot.rs`).
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// Rewrites the format version of the stream state behind `state_magic` in `file` to
/// `version`, with a checksum that fits, so that only the version is wrong.
fn set_format_version(file: &std::path::Path, stream: &Stream, version: u32) {
    let state_magic = stream.state_magic;
    let bytes = std::fs::read(file).unwrap();
    let mut parts = bytes.splitn(3, |&b| b == b'\n');
    let (magic, header, payload) = (
        parts.next().unwrap(),
        parts.next().unwrap(),
        parts.next().unwrap(),
    );
    // The payload is the ingest state; the stream state is its last field, its bytes whole.
    let mut payload = payload.to_vec();
    let at = payload
        .windows(state_magic.len())
        .position(|w| w == state_magic)
        .expect("a versioned stream state in the snapshot")
        + state_magic.len();
    assert_eq!(
        payload[at..at + 4],
        stream.format.to_le_bytes(),
        "this build writes {} format {}",
        stream.name,
        stream.format
    );
    payload[at..at + 4].copy_from_slice(&version.to_le_bytes());
    let mut header: serde_json::Value = serde_json::from_slice(header).unwrap();
    header["checksum"] = format!("{:016x}", fnv1a(&payload)).into();
    let mut out = magic.to_vec();
    out.push(b'\n');
    out.extend(serde_json::to_vec(&header).unwrap());
    out.push(b'\n');
    out.extend(payload);
    std::fs::write(file, out).unwrap();
}

/// One stream: its replay, its snapshot's state magic, where its events are listed.
struct Stream {
    name: &'static str,
    replay: &'static [&'static str],
    steps: u64,
    state_magic: &'static [u8],
    /// The format version this build writes of the pipeline's part (`SAVED_<STREAM>` in
    /// `service/src/<stream>/pipeline.rs`; the estimator's own version follows it and is
    /// checked by `snapshot::tests`).
    format: u32,
    events: &'static str,
}

const STREAMS: [Stream; 3] = [
    Stream {
        name: "drive",
        replay: &[
            "--scenario",
            "config/scenarios/adhesion-seed.toml",
            "--max-frames",
            "2000",
        ],
        steps: 2000,
        state_magic: b"railmon-drives\0",
        format: 5,
        events: "/api/v1/drives/events",
    },
    Stream {
        name: "bogie",
        replay: &[
            "--scenario",
            "config/scenarios/damper-seed.toml",
            "--bogies",
            "1",
            "--duration-s",
            "2",
        ],
        steps: 2000,
        state_magic: b"railmon-bogies\0",
        format: 4,
        events: "/api/v1/bogies/events",
    },
    Stream {
        name: "vehicle",
        replay: &[
            "--scenario",
            "config/scenarios/fuel-cycles.toml",
            "--max-frames",
            "200",
        ],
        steps: 200,
        state_magic: b"railmon-vehicle\0",
        format: 13,
        events: "/api/v1/vehicle/events",
    },
];

/// Per stream a format newer than the one it reads, a different one for each stream (so that a
/// reason naming another stream's number would show). A fixed list went stale when the vehicle's
/// format reached the number the list gave it.
fn newer_formats() -> impl Iterator<Item = (u32, &'static Stream)> {
    (1..).zip(&STREAMS).map(|(i, s)| (s.format + i, s))
}

#[test]
fn a_snapshot_of_a_newer_format_is_refused_with_an_event_and_a_count_on_every_stream() {
    let bus = PrivateBus::new();
    let data_dir = std::env::temp_dir().join(format!("railmon-snap-versions-{}", bus.prefix));
    let _ = std::fs::remove_dir_all(&data_dir);
    let data = data_dir.to_str().unwrap().to_string();
    let settings = [
        ("RAILMON_STORAGE__DATA_DIR", data.as_str()),
        ("RAILMON_BOGIE__ENABLED", "true"),
        ("RAILMON_DRIVE__ENABLED", "true"),
        ("RAILMON_VEHICLE__ENABLED", "true"),
        ("RAILMON_BOGIE__BOGIES", "[1]"),
        ("RAILMON_BOGIE__ESTIMATOR__RBPF__PARTICLES", "50"),
    ];
    let mut service = Service::start(&bus, &settings);
    for stream in &STREAMS {
        let mut args = stream.replay.to_vec();
        args.extend(["--speed", "max"]);
        let mut replay = start_replay(&bus, stream.name, &args);
        assert!(
            replay.wait(Duration::from_secs(120)).success(),
            "{}",
            stream.name
        );
        service.wait_for_status(stream.name, Duration::from_secs(60), "every frame", |s| {
            s["estimator_steps"].as_u64() == Some(stream.steps)
        });
    }
    assert!(service.process.terminate(Duration::from_secs(10)).success());
    for (version, stream) in newer_formats() {
        let file = data_dir.join(format!("snapshots/{}.snapshot", stream.name));
        assert!(file.exists(), "{}", file.display());
        set_format_version(&file, stream, version);
    }

    let service = Service::start(&bus, &settings);
    for (version, stream) in newer_formats() {
        let start = std::time::Instant::now();
        let refused = loop {
            let page = service.get_json(&format!("{}?kind=snapshot_refused", stream.events));
            if let Some(e) = page["events"].as_array().and_then(|e| e.first()) {
                break e.clone();
            }
            assert!(
                start.elapsed() < Duration::from_secs(30),
                "{}: no event: {page}",
                stream.name
            );
            std::thread::sleep(Duration::from_millis(100));
        };
        let reason = refused["reason"].as_str().unwrap();
        assert!(
            reason.contains(&format!("{} state format {version} (newer", stream.name))
                && reason.contains(&format!("reads format {}", stream.format)),
            "{refused}"
        );
        assert!(
            refused["file"]
                .as_str()
                .unwrap()
                .ends_with(&format!("snapshots/{}.snapshot", stream.name)),
            "{refused}"
        );
        assert_eq!(
            service.metric(&format!("railmon_{}_snapshot_refused_total", stream.name)),
            Some(1.0),
            "{}",
            stream.name
        );
    }
    // Started clean: no estimate until a frame comes.
    let bogies = service.get_json("/api/v1/bogies");
    assert_eq!(bogies["bogies"][0]["samples"], 0, "{bogies}");
    drop(service);
    let _ = std::fs::remove_dir_all(&data_dir);
}
