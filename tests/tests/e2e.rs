//! End to end: the real `railmon serve` and `sensors-replay` processes on a private bus and a
//! free port. Each test has its own bus prefix, so they run in parallel.

use std::process::Command;
use std::time::Duration;

use railmon_bus::{BusNode, DriveChannels, DriveFrame};
use railmon_records::drive::DriveCsvReader;
use railmon_slip::{AdhesionScenario, DriveSimulator};
use railmon_system_tests::{binaries, start_replay, workspace_root, PrivateBus, Service};
use serde_json::Value;

const SEED: &str = "config/scenarios/adhesion-seed.toml";

fn seed() -> AdhesionScenario {
    AdhesionScenario::from_toml_str(&std::fs::read_to_string(workspace_root().join(SEED)).unwrap())
        .unwrap()
}

/// Largest slip probability of `drive` over history points with run time in `[from_s, to_s]`.
fn max_probability(service: &Service, drive: usize, from_s: f64, to_s: f64) -> f64 {
    let history = service.get_json(&format!("/api/v1/drives/{drive}/history?seconds=100"));
    let points: Vec<&Value> = history["points"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|p| (from_s..=to_s).contains(&p["run_time_s"].as_f64().unwrap()))
        .collect();
    assert!(
        points.len() > 50,
        "only {} history points in the interval",
        points.len()
    );
    points
        .iter()
        .map(|p| p["slip_probability"].as_f64().unwrap())
        .fold(f64::NEG_INFINITY, f64::max)
}

#[test]
fn seed_replay_reaches_the_service_complete_and_flags_drive_1() {
    let bus = PrivateBus::new();
    let mut service = Service::start(&bus, &[("RAILMON_DRIVE__HISTORY_INTERVAL_MS", "1")]);
    let record = std::env::temp_dir().join(format!("railmon-e2e-record-{}.csv", bus.prefix));
    let record_arg = record.to_str().unwrap();
    let args = [
        "--scenario",
        SEED,
        "--speed",
        "10",
        "--record",
        record_arg,
        "--start-utc",
        "2026-01-01T06:00:00Z",
    ];
    let mut replay = start_replay(&bus, "drive", &args);
    assert!(
        replay.wait(Duration::from_secs(60)).success(),
        "sensors-replay failed"
    );

    let scenario = seed();
    let n_steps = scenario.n_steps() as u64;
    let status = service.wait_for_status("drive", Duration::from_secs(10), "every frame", |s| {
        s["samples_received"].as_u64() == Some(n_steps)
    });
    assert_eq!(status["sequence_gaps"], 0, "{status}");
    assert_eq!(status["samples_rejected"], 0, "{status}");
    assert_eq!(
        status["estimator_steps"].as_u64(),
        Some(n_steps),
        "{status}"
    );

    // Drive 1 loses adhesion on steps [500, 1500]; look at its core, away from the edges
    // smoothed over ~3 x 30 steps and the estimator's reaction time.
    let dt = scenario.dt_s();
    let (from_s, to_s) = (700.0 * dt, 1400.0 * dt);
    let p1 = max_probability(&service, 1, from_s, to_s);
    assert!(p1 > 0.9, "drive 1: {p1}");
    for drive in [2, 3] {
        let p = max_probability(&service, drive, from_s, to_s);
        assert!(p < 0.1, "drive {drive}: {p}");
    }

    // /metrics carries the same numbers as the API.
    let drives = service.get_json("/api/v1/drives");
    for d in drives["drives"].as_array().unwrap() {
        let series = format!(
            "railmon_drive_slip_probability_ratio{{drive=\"{}\"}}",
            d["id"]
        );
        assert_eq!(
            service.metric(&series),
            d["slip_probability"].as_f64(),
            "{series}"
        );
        let series = format!(
            "railmon_drive_load_torque_newton_meters{{drive=\"{}\"}}",
            d["id"]
        );
        assert_eq!(
            service.metric(&series),
            d["load_torque_nm"].as_f64(),
            "{series}"
        );
    }
    let received = "railmon_stream_samples_received_total{stream=\"drive\"}";
    assert_eq!(service.metric(received), Some(n_steps as f64));
    let gaps = "railmon_stream_sequence_gaps_total{stream=\"drive\"}";
    assert_eq!(service.metric(gaps), Some(0.0));
    let events = service.get_json("/api/v1/drives/events?drive=1");
    let first = &events["events"][0];
    assert_eq!(first["kind"], "slip_started", "{events}");
    // Acquisition time in UTC: the replay's start plus the sample's time (slip from ~60 ms).
    let utc = first["time_utc"].as_str().unwrap();
    assert!(utc.starts_with("2026-01-01T06:00:00.0"), "{utc}");
    let millis: f64 = utc[20..23].parse().unwrap();
    assert!(
        (millis * 1e-3 - first["time_s"].as_f64().unwrap()).abs() < 2e-3,
        "{first}"
    );

    // --record wrote every frame sent, with the simulator's truth.
    let mut reader = DriveCsvReader::open(&record, Some(scenario.n_drives())).unwrap();
    assert!(reader.has_truth());
    let mut frames = 0u64;
    while reader.next_frame().unwrap().is_some() {
        frames += 1;
    }
    assert_eq!(frames, n_steps);

    // Replaying the recording is a new source with the same data: the estimator restarts and
    // ends on exactly the same estimate (Rust prints floats so that they parse back exactly).
    let mut replay = start_replay(&bus, "drive", &["--csv", record_arg, "--speed", "max"]);
    assert!(
        replay.wait(Duration::from_secs(60)).success(),
        "CSV replay failed"
    );
    let status = service.wait_for_status("drive", Duration::from_secs(10), "the recording", |s| {
        s["samples_received"].as_u64() == Some(2 * n_steps)
    });
    assert_eq!(status["sequence_gaps"], 0, "{status}");
    assert_eq!(status["sources"], 2, "{status}");
    let again = service.get_json("/api/v1/drives");
    assert_eq!(again["drives"], drives["drives"]);
    assert_eq!(again["run_time_s"], drives["run_time_s"]);
    let _ = std::fs::remove_file(record);

    let exit = service.process.terminate(Duration::from_secs(10));
    assert!(exit.success(), "railmon serve exited with {exit}");
}

#[test]
fn bad_command_lines_and_settings_fail_with_the_culprit_named() {
    let binaries = binaries();
    let replay = Command::new(&binaries.replay)
        .args(["drive", "--scenario", "no/such/scenario.toml"])
        .output()
        .unwrap();
    assert!(!replay.status.success());
    let stderr = String::from_utf8_lossy(&replay.stderr);
    assert!(stderr.contains("no/such/scenario.toml"), "{stderr}");

    let replay = Command::new(&binaries.replay)
        .args(["drive", "--scenario", SEED, "--speed", "fast"])
        .output()
        .unwrap();
    assert!(!replay.status.success());
    assert!(String::from_utf8_lossy(&replay.stderr).contains("fast"));

    let service = Command::new(&binaries.railmon)
        .arg("serve")
        .env("RAILMON_DRIVE__ESTIMATOR__ALARM__ON_PROBABILITY", "2")
        .output()
        .unwrap();
    assert!(!service.status.success());
    let stderr = String::from_utf8_lossy(&service.stderr);
    assert!(stderr.contains("alarm.on_probability"), "{stderr}");
}

#[test]
fn killed_replay_makes_readyz_fail_within_a_second_and_a_new_one_recovers() {
    let bus = PrivateBus::new();
    let service = Service::start(&bus, &[("RAILMON_DRIVE__STALE_AFTER_MS", "300")]);
    let mut replay = start_replay(
        &bus,
        "drive",
        &["--scenario", SEED, "--speed", "1", "--loop"],
    );
    service.wait_for_readyz(200, Duration::from_secs(20));
    replay.kill_hard();
    let stale_after = service.wait_for_readyz(503, Duration::from_secs(5));
    assert!(stale_after < Duration::from_secs(1), "{stale_after:?}");

    let mut replay = start_replay(
        &bus,
        "drive",
        &["--scenario", SEED, "--speed", "1", "--loop"],
    );
    service.wait_for_readyz(200, Duration::from_secs(20));
    let status = service.status("drive");
    assert!(status["sources"].as_u64().unwrap() >= 2, "{status}");
    assert_eq!(status["sequence_gaps"], 0, "{status}");
    assert!(replay.terminate(Duration::from_secs(10)).success());
}

#[test]
fn sigkilled_service_restarts_and_the_running_replay_reconnects() {
    let bus = PrivateBus::new();
    let mut first = Service::start(&bus, &[]);
    let mut replay = start_replay(
        &bus,
        "drive",
        &["--scenario", SEED, "--speed", "1", "--loop"],
    );
    first.wait_for_readyz(200, Duration::from_secs(20));
    first.process.kill_hard();

    let mut second = Service::start(&bus, &[]);
    second.wait_for_readyz(200, Duration::from_secs(20));
    let status = second.wait_for_status("drive", Duration::from_secs(5), "frames", |s| {
        s["samples_received"].as_u64() > Some(100)
    });
    assert_eq!(status["samples_rejected"], 0, "{status}");
    // Exit 5: the frames the killed service held are counted as lost by the replay
    // (docs/reliability.md); 0 if it happened to hold none.
    let code = replay.terminate(Duration::from_secs(10)).code();
    assert!(matches!(code, Some(0) | Some(5)), "replay exit {code:?}");
    assert!(
        second.process.terminate(Duration::from_secs(10)).success(),
        "service"
    );
}

#[test]
fn bad_frames_are_rejected_counted_and_leave_the_estimate_alone() {
    let bus = PrivateBus::new();
    let service = Service::start(&bus, &[]);
    let node = BusNode::create(&bus.config(), "test-publisher").unwrap();
    let mut publisher = node.publisher::<DriveFrame>().unwrap();
    publisher
        .wait_for_subscriber(Some(Duration::from_secs(20)), &|| false)
        .unwrap();

    let scenario = seed();
    let dt_ns = (scenario.dt_s() * 1e9).round() as u64;
    let mut simulator = DriveSimulator::new(&scenario).unwrap();
    let mut next_frame = || {
        let (samples, _) = simulator.step().unwrap();
        let drives: Vec<DriveChannels> = samples.iter().map(DriveChannels::from).collect();
        DriveFrame::new(dt_ns, &drives).unwrap()
    };
    for step in 0..10 {
        assert_eq!(publisher.send(&next_frame(), step * dt_ns).unwrap(), 1);
    }
    publisher.notify().unwrap();
    service.wait_for_status("drive", Duration::from_secs(5), "10 good frames", |s| {
        s["estimator_steps"] == 10
    });
    let before = service.get_json("/api/v1/drives");

    let mut nan = next_frame();
    nan.drives[2].u_beta_v = f64::NAN;
    let mut too_many = next_frame();
    too_many.n_drives = 40; // above the configured maximum (and the frame's capacity)
    publisher.send(&nan, 10 * dt_ns).unwrap();
    publisher.send(&too_many, 11 * dt_ns).unwrap();
    publisher.notify().unwrap();

    service.assert_rejections("drive", 10, &["not_finite", "too_many_drives"]);
    assert_eq!(service.get_json("/api/v1/drives"), before);
}
