//! Same data, same answer (issue 8): one drive recording through the three paths gives the same
//! slip events — the service (replayed over the bus, events from the HTTP API), `railmon
//! analyze adhesion --input` on the file, and `railmon analyze adhesion --scenario` that wrote
//! it. 13,000 steps (1.6 s of data) of the seed scenario: drive 1's first two losses; the
//! service publishes the steps its fixed lag holds once the stream has been silent for
//! `stale_after_ms` (the ingest loop's timer), and those are `analyze`'s last rows. And with
//! the train's measured speed (issue 23 item 2): every drive losing adhesion at once
//! (`config/scenarios/adhesion-all-at-once.toml`) is flagged, with the same events on the
//! three paths and `train_speed` as the reference they report.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use railmon_system_tests::{binaries, start_replay, workspace_root, PrivateBus, Service};

const N_STEPS: u64 = 13_000;

/// `(kind, stream_time_s, subject, slip_probability)` of one event.
type Event = (String, f64, String, f64);

fn analyze(args: &[&str], out: &Path) -> Vec<Event> {
    let output = Command::new(&binaries().railmon)
        .args(["analyze", "adhesion", "--no-plots"])
        .args(args)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    assert!(
        output.status.success(),
        "railmon analyze adhesion {args:?}: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    let text = std::fs::read_to_string(out.join("events.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(
        &header[..5],
        ["id", "kind", "stream_time_s", "subject", "detail"]
    );
    lines
        .map(|line| {
            // The detail is quoted JSON with commas: take it from the raw line.
            let (head, rest) = line.split_once(",\"").unwrap();
            let fields: Vec<&str> = head.split(',').collect();
            let detail = rest.rsplit_once("\",").unwrap().0.replace("\"\"", "\"");
            let detail: serde_json::Value = serde_json::from_str(&detail).unwrap();
            (
                fields[1].to_owned(),
                fields[2].parse().unwrap(),
                fields[3].to_owned(),
                detail["slip_probability"].as_f64().unwrap(),
            )
        })
        .collect()
}

fn service_events(service: &Service, expected: usize) -> Vec<Event> {
    let start = Instant::now();
    loop {
        let page = service.get_json("/api/v1/drives/events?limit=1000");
        let events: Vec<Event> = page["events"]
            .as_array()
            .unwrap()
            .iter()
            .map(|e| {
                (
                    e["kind"].as_str().unwrap().to_owned(),
                    e["time_s"].as_f64().unwrap(),
                    e["subject"].as_str().unwrap().to_owned(),
                    e["slip_probability"].as_f64().unwrap(),
                )
            })
            .collect();
        if events.len() >= expected || start.elapsed() > Duration::from_secs(10) {
            return events;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn service_and_both_analyze_paths_raise_the_same_slip_events() {
    let dir: PathBuf =
        std::env::temp_dir().join(format!("railmon-adhesion-paths-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let seed =
        std::fs::read_to_string(workspace_root().join("config/scenarios/adhesion-seed.toml"))
            .unwrap();
    let short = seed.replace("n_steps = 20000", &format!("n_steps = {N_STEPS}"));
    assert_ne!(short, seed);
    let scenario = dir.join("seed-short.toml");
    std::fs::write(&scenario, short).unwrap();

    let from_scenario = analyze(
        &["--scenario", scenario.to_str().unwrap()],
        &dir.join("scenario"),
    );
    let recording = dir.join("scenario/drives.csv");
    let from_input = analyze(
        &["--input", recording.to_str().unwrap()],
        &dir.join("input"),
    );
    // Drive 1 slips on [500, 1500] and [10000, 12000]: two starts and two ends at least.
    assert!(from_scenario.len() >= 4, "{from_scenario:?}");
    assert_eq!(from_input, from_scenario);

    let bus = PrivateBus::new();
    let stale_after = Duration::from_millis(STALE_AFTER_MS);
    let service = Service::start(
        &bus,
        &[("RAILMON_DRIVE__STALE_AFTER_MS", &STALE_AFTER_MS.to_string())],
    );
    let mut replay = start_replay(
        &bus,
        "drive",
        &["--csv", recording.to_str().unwrap(), "--speed", "max"],
    );
    assert!(
        replay.wait(Duration::from_secs(60)).success(),
        "sensors-replay failed"
    );
    service.wait_for_status("drive", Duration::from_secs(20), "every frame", |s| {
        s["estimator_steps"].as_u64() == Some(N_STEPS)
    });
    // The last frame is in: the view names the step `lag_steps` before it until the stream has
    // been silent for `stale_after_ms`, when the ingest loop publishes what the fixed lag holds.
    let every_frame_at = Instant::now();
    let before_silence = service.get_json("/api/v1/drives");
    if every_frame_at.elapsed() < stale_after / 2 {
        let lag = railmon_slip::fixed_lag::FIXED_LAG_STEPS as u64;
        assert_eq!(
            named_step(&before_silence),
            N_STEPS - 1 - lag,
            "before the silence: {before_silence}"
        );
        assert_eq!(
            before_silence["sequence"],
            N_STEPS - 1,
            "the last frame used"
        );
    }
    let after_silence = wait_for_drives_view(&service, N_STEPS - 1, stale_after * 10);
    assert!(
        every_frame_at.elapsed() >= stale_after / 2,
        "the held steps came before the stream fell silent"
    );
    // ... and they are the steps `analyze --input` published at the end of the file.
    let last = last_step_rows(&dir.join("input/estimates.csv"), N_STEPS - 1);
    let drives = after_silence["drives"].as_array().unwrap();
    assert_eq!(drives.len(), last.len());
    for (drive, row) in drives.iter().zip(&last) {
        let service_row = [
            drive["id"].to_string(),
            format!("{:.6}", drive["electrical_speed_rad_s"].as_f64().unwrap()),
            format!("{:.6}", drive["load_torque_nm"].as_f64().unwrap()),
            format!("{:.6}", after_silence["global_torque_nm"].as_f64().unwrap()),
            format!("{:.6}", drive["slip_probability"].as_f64().unwrap()),
        ];
        assert_eq!(
            &service_row[..],
            &row[..],
            "the last step, service vs analyze"
        );
    }
    let from_service = service_events(&service, from_scenario.len());
    assert_eq!(from_service, from_scenario);
    let _ = std::fs::remove_dir_all(&dir);
}

/// The drive stream's silence limit in the test above: long enough that the view before it is
/// read well inside it on a loaded machine.
const STALE_AFTER_MS: u64 = 3_000;

/// The step a drives view names (its estimates' time in the run over the 8 kHz period; the
/// view's `sequence` is the newest frame used, `lag_steps` later).
fn named_step(view: &serde_json::Value) -> u64 {
    (view["run_time_s"].as_f64().unwrap() / DT_S).round() as u64
}

const DT_S: f64 = 125e-6;

/// Polls `/api/v1/drives` until it names `step`; panics after `timeout`.
fn wait_for_drives_view(service: &Service, step: u64, timeout: Duration) -> serde_json::Value {
    let start = Instant::now();
    loop {
        let view = service.get_json("/api/v1/drives");
        if view["run_time_s"].is_f64() && named_step(&view) == step {
            return view;
        }
        assert!(
            start.elapsed() < timeout,
            "the view never named step {step}: {view}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// `[drive, ekf_speed_rad_s, ekf_torque_nm, temporal_global_torque_nm,
/// temporal_slip_probability]` of each drive's row of `step` in `estimates.csv`, whose
/// `published_step` must be the step itself (the last step, drained at the end of the file).
fn last_step_rows(estimates: &Path, step: u64) -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(estimates).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let column = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let columns = [
        "drive",
        "ekf_speed_rad_s",
        "ekf_torque_nm",
        "temporal_global_torque_nm",
        "temporal_slip_probability",
    ]
    .map(column);
    let (step_column, published) = (column("step"), column("published_step"));
    let rows: Vec<Vec<String>> = lines
        .map(|line| line.split(',').collect::<Vec<&str>>())
        .filter(|f| f[step_column] == step.to_string())
        .map(|f| {
            assert_eq!(f[published], step.to_string(), "{f:?}");
            columns.iter().map(|&c| f[c].to_owned()).collect()
        })
        .collect();
    assert!(!rows.is_empty(), "no rows of step {step}");
    rows
}

/// `(method, value)` of one column of `detection.csv` after its quoted `alarm_rule` (the
/// rule's text has commas: counted from the end of the line).
fn detection_column(out: &Path, name: &str) -> Vec<(String, String)> {
    let text = std::fs::read_to_string(out.join("detection.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let from_end = header.len() - header.iter().position(|h| *h == name).unwrap();
    lines
        .map(|line| {
            let fields: Vec<&str> = line.split(',').collect();
            (
                fields[0].to_owned(),
                fields[fields.len() - from_end].to_owned(),
            )
        })
        .collect()
}

#[test]
fn every_drive_losing_adhesion_at_once_is_flagged_the_same_on_every_path_with_a_train_speed() {
    let dir: PathBuf =
        std::env::temp_dir().join(format!("railmon-adhesion-all-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let scenario = workspace_root().join("config/scenarios/adhesion-all-at-once.toml");
    let text = std::fs::read_to_string(&scenario).unwrap();
    assert!(text.contains("\n[train_speed]\n"));
    let n_steps = 14_000;
    let dt_s = 125e-6;

    let from_scenario = analyze(
        &["--scenario", scenario.to_str().unwrap()],
        &dir.join("scenario"),
    );
    let recording = dir.join("scenario/drives.csv");
    let recorded = std::fs::read_to_string(&recording).unwrap();
    assert!(
        recorded
            .lines()
            .next()
            .unwrap()
            .ends_with(",train_speed_m_s"),
        "the recording carries the train speed"
    );
    let from_input = analyze(
        &["--input", recording.to_str().unwrap()],
        &dir.join("input"),
    );
    assert_eq!(from_input, from_scenario);
    // Every drive (all four lose half their load on [6000, 10000)) starts slipping in the
    // loss, and nothing starts before it.
    for drive in 1..=4 {
        let started: Vec<f64> = from_scenario
            .iter()
            .filter(|e| e.0 == "slip_started" && e.2 == drive.to_string())
            .map(|e| e.1)
            .collect();
        assert!(!started.is_empty(), "drive {drive}: {from_scenario:?}");
        assert!(
            started
                .iter()
                .all(|&t| (6000.0 * dt_s..10_000.0 * dt_s).contains(&t)),
            "drive {drive}: {started:?}"
        );
    }
    for out in ["scenario", "input"] {
        for (method, reference) in detection_column(&dir.join(out), "reference") {
            assert_eq!(reference, "train_speed", "{out}, {method}");
        }
    }

    // Without the train speed the same drives are judged by the group, and say so.
    let without = dir.join("without.toml");
    let without_text = text.replace("[train_speed]\nnoise_std_m_s = 0.2\n", "");
    assert!(!without_text.contains("\n[train_speed]\n") && without_text != text);
    std::fs::write(&without, without_text).unwrap();
    analyze(
        &["--scenario", without.to_str().unwrap()],
        &dir.join("without"),
    );
    for (method, reference) in detection_column(&dir.join("without"), "reference") {
        assert_eq!(reference, "group", "{method}");
    }

    // The service, fed by sensors-replay from the scenario (the simulator's train speed on
    // the bus); its --record is the file analyze wrote, train speed column and all.
    let bus = PrivateBus::new();
    let service = Service::start(&bus, &[]);
    let replayed = dir.join("replayed.csv");
    let mut replay = start_replay(
        &bus,
        "drive",
        &[
            "--scenario",
            scenario.to_str().unwrap(),
            "--speed",
            "max",
            "--record",
            replayed.to_str().unwrap(),
        ],
    );
    assert!(
        replay.wait(Duration::from_secs(60)).success(),
        "sensors-replay failed"
    );
    service.wait_for_status("drive", Duration::from_secs(30), "every frame", |s| {
        s["estimator_steps"].as_u64() == Some(n_steps)
    });
    assert!(
        std::fs::read_to_string(&replayed).unwrap() == recorded,
        "sensors-replay --record wrote what analyze --scenario did"
    );
    let from_service = service_events(&service, from_scenario.len());
    assert_eq!(from_service, from_scenario);
    assert_eq!(service.status("drive")["reference"], "train_speed");
    assert_eq!(
        service.get_json("/api/v1/drives")["reference"],
        "train_speed"
    );
    assert_eq!(service.status("drive")["samples_rejected"], 0);
    let _ = std::fs::remove_dir_all(&dir);
}
