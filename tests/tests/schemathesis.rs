//! `schemathesis` (property-based API tests from the OpenAPI document) against the real
//! service with all three streams fed: every generated request, valid or not, gets an answer
//! that the document describes (status, content type, schema), never a server error. Bounded:
//! a fixed seed, a few examples per operation and a time budget (about a minute on 2 shared
//! cores, two runs of at most 60 s).
//!
//! The same fed service checks the document's response examples: every `GET` answer's keys are
//! in its example (`service/assets/api-examples.json`, rewritten from these answers under
//! `RAILMON_UPDATE_GOLDEN=1`).
//!
//! Needs the Python environment of `scripts/install-test-deps` (`target-venv`, or
//! `$RAILMON_TEST_VENV`).

use std::process::Command;
use std::time::Duration;

use railmon_system_tests::{start_replay, workspace_root, PrivateBus, Service};
use serde_json::Value;

/// Items kept of each array in an example: enough to show an element, short enough to read.
const EXAMPLE_ITEMS: usize = 2;

/// `value` with every array cut to [`EXAMPLE_ITEMS`].
fn trimmed(value: Value) -> Value {
    match value {
        Value::Array(items) => items.into_iter().take(EXAMPLE_ITEMS).map(trimmed).collect(),
        Value::Object(map) => map.into_iter().map(|(k, v)| (k, trimmed(v))).collect(),
        other => other,
    }
}

/// Keys of `live` (at any depth; arrays by their first item) missing from `example`.
fn keys_missing(live: &Value, example: &Value, at: &str, missing: &mut Vec<String>) {
    match (live, example) {
        (Value::Object(live), Value::Object(example)) => {
            for (key, value) in live {
                match example.get(key) {
                    Some(other) => keys_missing(value, other, &format!("{at}.{key}"), missing),
                    None => missing.push(format!("{at}.{key}")),
                }
            }
        }
        (Value::Array(live), Value::Array(example)) => {
            if let (Some(live), Some(example)) = (live.first(), example.first()) {
                keys_missing(live, example, &format!("{at}[0]"), missing);
            }
        }
        _ => {}
    }
}

/// Each documented `GET` with a JSON answer, asked with id 1: every key of the answer is in the
/// document's example for that path, so the examples cannot fall behind the server. Under
/// `RAILMON_UPDATE_GOLDEN=1` the answers become the examples (`service/assets/api-examples.json`).
fn examples_hold_every_key_of_the_live_answers(service: &Service) {
    let api = service.get_json("/openapi.json");
    let update = std::env::var_os("RAILMON_UPDATE_GOLDEN").is_some();
    let mut captured = serde_json::Map::new();
    let mut missing = Vec::new();
    for (path, item) in api["paths"].as_object().unwrap() {
        if item["get"]["responses"]["200"]["content"]
            .get("application/json")
            .is_none()
        {
            continue;
        }
        let uri = path.replace("{id}", "1");
        let (status, body) = service.get(&uri);
        // `/readyz` is 503 once the replays have ended (the streams are stale).
        let key = match status {
            200 => path.clone(),
            503 if path == "/readyz" => format!("{path} 503"),
            _ => panic!("GET {uri}: {status} {body}"),
        };
        let answer = trimmed(serde_json::from_str(&body).unwrap());
        let (at, status) = key.split_once(' ').unwrap_or((&key, "200"));
        let example = &item["get"]["responses"][status]["content"]["application/json"]["example"];
        if update {
            captured.insert(key.clone(), answer);
        } else if example.is_null() {
            missing.push(format!("{key}: no example"));
        } else {
            keys_missing(&answer, example, at, &mut missing);
        }
    }
    if update {
        let file = workspace_root().join("service/assets/api-examples.json");
        let text = serde_json::to_string_pretty(&Value::Object(captured)).unwrap() + "\n";
        std::fs::write(&file, text).unwrap();
        println!("wrote {}", file.display());
    }
    assert!(
        missing.is_empty(),
        "keys of live answers missing from the examples (scripts/regen-golden schemathesis \
         rewrites them): {missing:#?}"
    );
}

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
            // The names the document's examples show.
            ("RAILMON_IDENTITY__VEHICLE_ID", "unit-4711"),
            ("RAILMON_IDENTITY__FLEET", "regional-north"),
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
    examples_hold_every_key_of_the_live_answers(&service);
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
