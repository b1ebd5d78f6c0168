//! A bogie snapshot of another format version is refused, not misread: the service starts the
//! bogies from their prior, logs why, counts it and stores a `snapshot_refused` event naming
//! the file and the version (issue 9: never silently).

use std::time::Duration;

use railmon_system_tests::{start_replay, PrivateBus, Service};

/// FNV-1a 64, the snapshot file's checksum of its payload (`service/src/snapshot.rs`).
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// Rewrites the bogie state's format version in `file` to `version`, with a checksum that
/// fits, so that only the version is wrong.
fn set_format_version(file: &std::path::Path, version: u32) {
    let bytes = std::fs::read(file).unwrap();
    let mut parts = bytes.splitn(3, |&b| b == b'\n');
    let (magic, header, payload) = (
        parts.next().unwrap(),
        parts.next().unwrap(),
        parts.next().unwrap(),
    );
    // The payload is the ingest state; the bogie state is its last field, its bytes whole.
    let mut payload = payload.to_vec();
    let magic_bogies = b"railmon-bogies\0";
    let at = payload
        .windows(magic_bogies.len())
        .position(|w| w == magic_bogies)
        .expect("a versioned bogie state in the snapshot")
        + magic_bogies.len();
    assert_eq!(
        payload[at..at + 4],
        3u32.to_le_bytes(),
        "this build writes format 3"
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

#[test]
fn a_bogie_snapshot_of_a_newer_format_is_refused_with_an_event_and_a_count() {
    let bus = PrivateBus::new();
    let data_dir = std::env::temp_dir().join(format!("railmon-bogie-snap-{}", bus.prefix));
    let _ = std::fs::remove_dir_all(&data_dir);
    let data = data_dir.to_str().unwrap().to_string();
    let settings = [
        ("RAILMON_STORAGE__DATA_DIR", data.as_str()),
        ("RAILMON_BOGIE__ENABLED", "true"),
        ("RAILMON_DRIVE__ENABLED", "false"),
        ("RAILMON_BOGIE__BOGIES", "[1]"),
        ("RAILMON_BOGIE__ESTIMATOR__RBPF__PARTICLES", "50"),
    ];
    let mut service = Service::start(&bus, &settings);
    let mut replay = start_replay(
        &bus,
        "bogie",
        &[
            "--scenario",
            "config/scenarios/damper-seed.toml",
            "--bogies",
            "1",
            "--duration-s",
            "2",
            "--speed",
            "max",
        ],
    );
    assert!(replay.wait(Duration::from_secs(120)).success());
    service.wait_for_status("bogie", Duration::from_secs(60), "every frame", |s| {
        s["estimator_steps"].as_u64() == Some(2000)
    });
    assert!(service.process.terminate(Duration::from_secs(10)).success());
    let file = data_dir.join("snapshots/bogie.snapshot");
    assert!(file.exists());
    set_format_version(&file, 7);

    let service = Service::start(&bus, &settings);
    let start = std::time::Instant::now();
    let refused = loop {
        let page = service.get_json("/api/v1/bogies/events?kind=snapshot_refused");
        if let Some(e) = page["events"].as_array().and_then(|e| e.first()) {
            break e.clone();
        }
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "no event: {page}"
        );
        std::thread::sleep(Duration::from_millis(100));
    };
    let reason = refused["reason"].as_str().unwrap();
    assert!(
        reason.contains("format 7 (newer") && reason.contains("reads format 3"),
        "{refused}"
    );
    assert!(
        refused["file"]
            .as_str()
            .unwrap()
            .ends_with("snapshots/bogie.snapshot"),
        "{refused}"
    );
    assert_eq!(
        service.metric("railmon_bogie_snapshot_refused_total"),
        Some(1.0)
    );
    // Started clean: no monitor until a frame comes.
    let bogies = service.get_json("/api/v1/bogies");
    assert_eq!(bogies["bogies"][0]["samples"], 0, "{bogies}");
    drop(service);
    let _ = std::fs::remove_dir_all(&data_dir);
}
