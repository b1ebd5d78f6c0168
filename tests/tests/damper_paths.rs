//! Same data, same damper events on every path: `railmon analyze damper --scenario`, `railmon
//! analyze damper --input` on the recording the scenario run wrote, and `railmon serve` fed that
//! recording by `sensors-replay bogie --csv`. All three apply `railmon_damper::DamperAlarm` to
//! the same estimates (bogie 1, the scenario's seed, 100 particles).

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use railmon_system_tests::{binaries, start_replay, workspace_root, PrivateBus, Service};
use serde_json::Value;

/// 45 s of damper-fault (C_say steps to 40 % at 30 s; at N = 100 the filter takes up to 8 s to
/// find it, then the alarm holds 3 s).
const SECONDS: &str = "45";
const STEPS: u64 = 45_000;

/// One event as every path reports it: kind, subject, stream time, health ratio.
type Event = (String, String, f64, f64);

fn analyze(args: &[&str], out: &Path) -> Vec<Event> {
    let status = Command::new(&binaries().railmon)
        .current_dir(workspace_root())
        .args(["analyze", "damper", "--no-plots", "--particles", "100"])
        .args(args)
        .arg("--out")
        .arg(out)
        .status()
        .expect("running railmon analyze damper");
    assert!(status.success(), "railmon analyze damper {args:?} failed");
    let mut reader = csv::Reader::from_path(out.join("events.csv")).unwrap();
    let header: Vec<String> = reader.headers().unwrap().iter().map(String::from).collect();
    assert_eq!(header, ["id", "kind", "stream_time_s", "subject", "detail"]);
    reader
        .records()
        .map(|r| {
            let r = r.unwrap();
            let detail: Value = serde_json::from_str(&r[4]).unwrap();
            (
                r[1].to_string(),
                r[3].to_string(),
                r[2].parse().unwrap(),
                detail["health_ratio"].as_f64().unwrap(),
            )
        })
        .collect()
}

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "railmon-damper-paths-{}-{name}",
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

#[test]
fn service_and_both_analyze_paths_raise_the_same_damper_events() {
    let scenario_out = temp("scenario");
    let from_scenario = analyze(
        &[
            "--scenario",
            "config/scenarios/damper-fault.toml",
            "--duration-s",
            SECONDS,
        ],
        &scenario_out,
    );
    // The fault is found (so the comparison below compares something), and nothing else.
    assert_eq!(from_scenario.len(), 1, "{from_scenario:?}");
    assert_eq!(
        (from_scenario[0].0.as_str(), from_scenario[0].1.as_str()),
        ("damper_degraded", "1/csay")
    );
    assert!(
        (30.0..45.0).contains(&from_scenario[0].2),
        "{from_scenario:?}"
    );

    // The scenario's monitor differs from the default only in its seed.
    let recording = scenario_out.join("bogie.csv");
    let monitor = temp("monitor.toml");
    std::fs::write(&monitor, "[rbpf]\nseed = 12\n").unwrap();
    let from_input = analyze(
        &[
            "--input",
            recording.to_str().unwrap(),
            "--config",
            monitor.to_str().unwrap(),
        ],
        &temp("input"),
    );
    assert_eq!(from_input, from_scenario);

    let bus = PrivateBus::new();
    let service = Service::start(
        &bus,
        &[
            ("RAILMON_BOGIE__ENABLED", "true"),
            ("RAILMON_DRIVE__ENABLED", "false"),
            ("RAILMON_BOGIE__BOGIES", "[1]"),
            ("RAILMON_BOGIE__ESTIMATOR__RBPF__PARTICLES", "100"),
            ("RAILMON_BOGIE__ESTIMATOR__RBPF__SEED", "12"),
        ],
    );
    let mut replay = start_replay(
        &bus,
        "bogie",
        &["--csv", recording.to_str().unwrap(), "--speed", "max"],
    );
    assert!(replay.wait(Duration::from_secs(300)).success());
    service.wait_for_status("bogie", Duration::from_secs(60), "every frame", |s| {
        s["estimator_steps"].as_u64() == Some(STEPS)
    });
    let events = service.get_json("/api/v1/bogies/events");
    let from_service: Vec<Event> = events["events"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| {
            (
                e["kind"].as_str().unwrap().to_string(),
                e["subject"].as_str().unwrap().to_string(),
                e["time_s"].as_f64().unwrap(),
                e["health_ratio"].as_f64().unwrap(),
            )
        })
        .collect();
    assert_eq!(from_service.len(), from_scenario.len(), "{from_service:?}");
    for (s, a) in from_service.iter().zip(&from_scenario) {
        assert_eq!((&s.0, &s.1, s.3), (&a.0, &a.1, a.3));
        // events.csv writes the time to the microsecond.
        assert!((s.2 - a.2).abs() < 1e-6, "{s:?} {a:?}");
    }
}
