//! `schemathesis` (property-based API tests from the OpenAPI document) against the real
//! service with all three streams fed: every generated request, valid or not, gets an answer
//! that the document describes (status, content type, schema), never a server error. Bounded:
//! a fixed seed, a few examples per operation and a time budget (about a minute on 2 shared
//! cores, two runs of at most 60 s).
//!
//! Needs the Python environment of `scripts/install-test-deps` (`target-venv`, or
//! `$RAILMON_TEST_VENV`).

use std::process::Command;
use std::time::Duration;

use railmon_system_tests::{start_replay, workspace_root, PrivateBus, Service};

#[test]
fn schemathesis_finds_no_failure() {
    let venv = std::env::var("RAILMON_TEST_VENV")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|_| workspace_root().join("target-venv"));
    let schemathesis = venv.join("bin/schemathesis");
    assert!(
        schemathesis.exists(),
        "{} missing: run scripts/install-test-deps",
        schemathesis.display()
    );
    let bus = PrivateBus::new();
    let service = Service::start(
        &bus,
        &[
            ("RAILMON_BOGIE__ENABLED", "true"),
            ("RAILMON_VEHICLE__ENABLED", "true"),
            ("RAILMON_BOGIE__ESTIMATOR__RBPF__PARTICLES", "100"),
            ("RAILMON_BOGIE__ESTIMATOR__TRACK_VELOCITY_STD_M_S", "0.1"),
        ],
    );
    // Data in every stream (estimates, history, events), then the replays end.
    for (stream, args) in [
        (
            "drive",
            &[
                "--scenario",
                "config/scenarios/adhesion-seed.toml",
                "--speed",
                "max",
            ][..],
        ),
        (
            "bogie",
            &[
                "--scenario",
                "config/scenarios/damper-fault.toml",
                "--duration-s",
                "35",
                "--speed",
                "max",
            ][..],
        ),
        (
            "vehicle",
            &[
                "--scenario",
                "config/scenarios/fuel-cycles.toml",
                "--speed",
                "max",
            ][..],
        ),
    ] {
        let mut replay = start_replay(&bus, stream, args);
        assert!(
            replay.wait(Duration::from_secs(180)).success(),
            "{stream} replay failed"
        );
    }
    // Every operation with every check; then `/readyz` without `not_a_server_error`: its 503
    // (the replays have ended, the streams are stale) is the documented answer, not a fault.
    for (only, checks) in [
        (["--exclude-path", "/readyz"], ["--checks", "all"]),
        (
            ["--include-path", "/readyz"],
            ["--exclude-checks", "not_a_server_error"],
        ),
    ] {
        // Its own working directory: schemathesis keeps a cache of past failures in
        // `.schemathesis/`, which would make runs depend on earlier ones.
        let report = std::env::temp_dir().join(format!("railmon-schemathesis-{}", bus.prefix));
        std::fs::create_dir_all(&report).unwrap();
        let out = Command::new(&schemathesis)
            .current_dir(&report)
            .args(["run", &format!("http://{}/openapi.json", service.addr)])
            .args(only)
            .args(checks)
            .args(["--max-examples", "15", "--seed", "1"])
            .args(["--phases", "examples,coverage,fuzzing", "--max-time", "60"])
            .args([
                "--generation-database",
                "none",
                "--no-color",
                "--workers",
                "1",
            ])
            .args(["--report-dir", "report"])
            .output()
            .expect("running schemathesis");
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        let _ = std::fs::remove_dir_all(&report);
        assert!(out.status.success(), "schemathesis {only:?}:\n{text}");
        let summary: Vec<&str> = text.lines().rev().take(6).collect();
        println!(
            "{}",
            summary.into_iter().rev().collect::<Vec<_>>().join("\n")
        );
    }
}
