//! A real Prometheus scrapes a real `railmon serve`: the exposition format parses, passes
//! `promtool check metrics`, and the numbers Prometheus stores are the numbers the HTTP API
//! reports.
//!
//! Needs the `prometheus` server and `promtool` on PATH (or `$PROMETHEUS`, `$PROMTOOL`);
//! `scripts/install-test-deps` installs them (Debian package), and `.ci/run` runs that first.

use std::time::Duration;

use railmon_system_tests::monitoring::{promtool, wait_for, Prometheus};
use railmon_system_tests::{start_replay, PrivateBus, Service};

const SEED: &str = "config/scenarios/adhesion-seed.toml";

#[test]
fn prometheus_scrapes_the_numbers_the_api_reports() {
    let bus = PrivateBus::new();
    let service = Service::start(&bus, &[]);
    // Before any frame: no estimate has a series, the stream metrics do.
    let (_, before) = service.get("/metrics");
    assert!(
        !before.contains("railmon_drive_slip_probability_ratio{"),
        "an estimate before the first frame:\n{before}"
    );
    assert!(before.contains("railmon_stream_fresh{"), "{before}");
    let mut replay = start_replay(&bus, "drive", &["--scenario", SEED, "--speed", "max"]);
    assert!(
        replay.wait(Duration::from_secs(60)).success(),
        "sensors-replay failed"
    );

    // Prometheus' own linter on a real scrape (naming, units, help, types).
    let (_, scrape) = service.get("/metrics");
    let (clean, lint) = promtool(&["check", "metrics"], &scrape);
    assert!(clean, "promtool check metrics:\n{lint}");

    let prometheus = Prometheus::start(&Prometheus::fast_config("railmon", &[&service.addr]));
    // The target is up: Prometheus parsed our exposition format.
    wait_for(
        "Prometheus scraping railmon",
        Duration::from_secs(30),
        || prometheus.value("up{job=\"railmon\"}") == Some(1.0),
    );

    let status = service.status("drive");
    let received = status["samples_received"].as_f64().unwrap();
    wait_for(
        "the sample count in Prometheus",
        Duration::from_secs(10),
        || {
            prometheus.value("railmon_stream_samples_received_total{stream=\"drive\"}")
                == Some(received)
        },
    );
    let drives = service.get_json("/api/v1/drives");
    for d in drives["drives"].as_array().unwrap() {
        let query = format!(
            "railmon_drive_slip_probability_ratio{{drive=\"{}\"}}",
            d["id"]
        );
        assert_eq!(
            prometheus.value(&query),
            d["slip_probability"].as_f64(),
            "{query}"
        );
    }
    // Histograms arrive whole: a quantile over the estimator step time is computable.
    let p99 = prometheus.value(
        "histogram_quantile(0.99, sum by (le) (railmon_estimator_step_duration_seconds_bucket{stream=\"drive\"}))",
    );
    assert!(
        p99.is_some_and(|v| v > 0.0 && v < 1.0),
        "p99 step time: {p99:?}"
    );
    // The standard process metrics and the build.
    assert!(prometheus
        .value("process_resident_memory_bytes")
        .is_some_and(|b| b > 1e6));
    assert_eq!(prometheus.value("railmon_build_info"), Some(1.0));
}
