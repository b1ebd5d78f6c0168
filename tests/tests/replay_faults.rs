//! The replay's part of reliability (issue 11), against the real binaries: signals end it
//! within a bound in every state with the documented exit code, a paced replay starts at its
//! first sample whatever its time and shortens long gaps, an existing recording survives a
//! replay that sent nothing, the frame before a bad row is sent, and the frames a killed
//! service took with it are counted by the replay.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::{Duration, Instant};

use railmon_system_tests::{start_replay_with_stderr, PrivateBus, Process, Service};

const SEED: &str = "config/scenarios/adhesion-seed.toml";

/// `sensors-replay` with its stderr captured (the summary lines are read by the tests).
fn replay(bus: &PrivateBus, stream: &str, args: &[&str]) -> Process {
    start_replay_with_stderr(bus, stream, args, Stdio::piped())
}

fn stderr_of(process: &mut Process) -> String {
    let mut text = String::new();
    if let Some(mut stderr) = process.child.stderr.take() {
        stderr.read_to_string(&mut text).unwrap();
    }
    text
}

/// The number after `key ` in the replay's summary (`taken 10 lost 0 unconfirmed 0`).
fn counter(summary: &str, key: &str) -> u64 {
    summary
        .split_whitespace()
        .skip_while(|w| *w != key)
        .nth(1)
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no `{key} N` in {summary}"))
}

fn scratch(name: &str, bus: &PrivateBus) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("railmon-replay-{name}-{}", bus.prefix));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// SIGTERM, then how long the exit took and its code.
fn terminate(process: &mut Process) -> (Duration, Option<i32>) {
    let start = Instant::now();
    let status = process.terminate(Duration::from_secs(10));
    (start.elapsed(), status.code())
}

#[test]
fn sigterm_while_waiting_for_a_subscriber_exits_0_every_time() {
    let bus = PrivateBus::new();
    let mut slowest = Duration::ZERO;
    for _ in 0..8 {
        let mut process = replay(&bus, "drive", &["--scenario", SEED]);
        std::thread::sleep(Duration::from_millis(400));
        let (took, code) = terminate(&mut process);
        let stderr = stderr_of(&mut process);
        assert_eq!(code, Some(0), "{stderr}");
        assert!(stderr.contains("waiting for a subscriber"), "{stderr}");
        slowest = slowest.max(took);
    }
    eprintln!("SIGTERM while waiting: slowest exit after {slowest:?} (8 tries)");
    // 100 ms is the design bound (a 10 ms poll); the margin is for a loaded CI machine.
    assert!(slowest < Duration::from_secs(2), "{slowest:?}");
}

#[test]
fn an_existing_recording_is_untouched_when_nothing_was_sent() {
    let bus = PrivateBus::new();
    let dir = scratch("keep", &bus);
    let record = dir.join("recording.csv");
    std::fs::write(&record, "an earlier recording\n").unwrap();
    let record_arg = record.to_str().unwrap();
    let args = [
        "--scenario",
        SEED,
        "--record",
        record_arg,
        "--wait-subscriber-s",
        "0.3",
    ];
    let mut process = replay(&bus, "drive", &args);
    let status = process.wait(Duration::from_secs(20));
    let stderr = stderr_of(&mut process);
    assert_eq!(status.code(), Some(3), "no subscriber: exit 3\n{stderr}");
    assert_eq!(
        std::fs::read_to_string(&record).unwrap(),
        "an earlier recording\n"
    );
    let names: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name())
        .collect();
    assert_eq!(names.len(), 1, "no temporary file left: {names:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A vehicle recording stamped with epoch seconds, with a gap of a million seconds.
fn epoch_recording(dir: &Path) -> PathBuf {
    let path = dir.join("epoch.csv");
    let t0 = 1_763_900_000u64;
    let mut text = String::from("time_s,fuel_cm3_s,speed_m_s\n");
    for t in [t0, t0 + 1, t0 + 2, t0 + 1_000_002, t0 + 1_000_003] {
        text.push_str(&format!("{t},0.5,3\n"));
    }
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn a_paced_replay_starts_at_its_first_sample_shortens_gaps_and_stops_at_once_in_one() {
    let bus = PrivateBus::new();
    let dir = scratch("epoch", &bus);
    let csv = epoch_recording(&dir);
    let csv_arg = csv.to_str().unwrap();
    let _service = Service::start(
        &bus,
        &[
            ("RAILMON_VEHICLE__ENABLED", "true"),
            ("RAILMON_DRIVE__ENABLED", "false"),
        ],
    );
    // 1 + 1 + 5 (the gap, shortened) + 1 s of data at 10x: 0.8 s.
    let start = Instant::now();
    let mut process = replay(&bus, "vehicle", &["--csv", csv_arg, "--speed", "10"]);
    let status = process.wait(Duration::from_secs(30));
    let took = start.elapsed();
    let stderr = stderr_of(&mut process);
    assert_eq!(status.code(), Some(0), "{stderr}");
    assert!(stderr.contains("sent 5 frames"), "{stderr}");
    assert_eq!(counter(&stderr, "lost"), 0, "{stderr}");
    assert!(took >= Duration::from_millis(800), "{took:?}");
    eprintln!("epoch time stamps with a 1e6 s gap at 10x: {took:?}");

    // In real time with gaps kept up to an hour: SIGTERM in the gap ends it at once.
    let args = ["--csv", csv_arg, "--speed", "1", "--max-gap-s", "3600"];
    let mut process = replay(&bus, "vehicle", &args);
    std::thread::sleep(Duration::from_millis(3500));
    let (took, code) = terminate(&mut process);
    let stderr = stderr_of(&mut process);
    assert_eq!(code, Some(0), "{stderr}");
    assert!(stderr.contains("sent 3 frames"), "{stderr}");
    eprintln!("SIGTERM in a paced gap: exit after {took:?}");
    assert!(took < Duration::from_secs(2), "{took:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_last_good_drive_frame_before_a_bad_row_is_sent() {
    let bus = PrivateBus::new();
    let dir = scratch("bad-row", &bus);
    let csv = dir.join("drives.csv");
    let mut text = String::from("step,drive,u_alpha_v,u_beta_v,i_alpha_a,i_beta_a\n");
    for step in 0..3 {
        for drive in 1..=3 {
            text.push_str(&format!("{step},{drive},10,-40,3,7\n"));
        }
    }
    text.push_str("3,1,10,-40,NaN,7\n");
    std::fs::write(&csv, text).unwrap();
    let service = Service::start(&bus, &[]);
    let mut process = replay(
        &bus,
        "drive",
        &["--csv", csv.to_str().unwrap(), "--speed", "max"],
    );
    let status = process.wait(Duration::from_secs(30));
    let stderr = stderr_of(&mut process);
    assert_eq!(status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("drives.csv:11: field \"i_alpha_a\" = \"NaN\""),
        "{stderr}"
    );
    service.wait_for_status("drive", Duration::from_secs(5), "3 frames", |s| {
        s["samples_received"].as_u64() == Some(3)
    });
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn killing_the_service_at_speed_max_shows_the_loss_in_the_replays_counter() {
    let bus = PrivateBus::new();
    let service = Service::start(&bus, &[]);
    let total = 200_000u64;
    let max_frames = total.to_string();
    let args = [
        "--scenario",
        SEED,
        "--speed",
        "max",
        "--loop",
        "--max-frames",
        &max_frames,
    ];
    let mut process = replay(&bus, "drive", &args);
    service.wait_for_status("drive", Duration::from_secs(60), "frames flowing", |s| {
        s["samples_received"].as_u64().unwrap_or(0) > 20_000
    });
    let mut service = service;
    service.process.kill_hard();
    let second = Service::start(&bus, &[]);
    let status = process.wait(Duration::from_secs(120));
    let stderr = stderr_of(&mut process);
    let (taken, lost, unconfirmed) = (
        counter(&stderr, "taken"),
        counter(&stderr, "lost"),
        counter(&stderr, "unconfirmed"),
    );
    eprintln!("killed at --speed max: taken {taken}, lost {lost}, unconfirmed {unconfirmed}");
    assert_eq!(taken + lost + unconfirmed, total, "{stderr}");
    assert_eq!(
        unconfirmed, 0,
        "the second service took the last frame: {stderr}"
    );
    assert!(lost > 0, "a killed service holds frames: {stderr}");
    assert_eq!(status.code(), Some(5), "frames lost: exit 5\n{stderr}");
    // What the second service received is all the replay counts as taken after the kill.
    let received = second.status("drive")["samples_received"].as_u64().unwrap();
    assert!(received > 0 && received <= taken, "{received} of {taken}");
}
