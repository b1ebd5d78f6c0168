//! A real Prometheus scrapes a real `railmon serve`: the exposition format parses, and the
//! numbers Prometheus stores are the numbers the HTTP API reports.
//!
//! Needs the `prometheus` server binary on PATH (or in `$PROMETHEUS`);
//! `scripts/install-test-deps` installs it (Debian package), and `.ci/run` runs that first.

use std::net::TcpListener;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use railmon_system_tests::{http_get, start_replay, PrivateBus, Process, Service};
use serde_json::Value;

const SEED: &str = "config/scenarios/adhesion-seed.toml";

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free port")
}

/// Runs `query` against Prometheus' HTTP API; the value of the single result, if there is one.
fn instant_query(prometheus: &str, query: &str) -> Option<f64> {
    let encoded: String = query
        .bytes()
        .map(|b| match b {
            b'a'..=b'z' | b'A'..=b'Z' | b'0'..=b'9' | b'_' | b'-' | b'.' => (b as char).to_string(),
            _ => format!("%{b:02X}"),
        })
        .collect();
    // Prometheus takes a moment to listen after it starts.
    std::net::TcpStream::connect(prometheus).ok()?;
    let (status, body) = http_get(prometheus, &format!("/api/v1/query?query={encoded}"));
    if status != 200 {
        return None;
    }
    let json: Value = serde_json::from_str(&body).ok()?;
    let result = json["data"]["result"].as_array()?;
    if result.len() != 1 {
        return None;
    }
    result[0]["value"][1].as_str()?.parse().ok()
}

fn wait_for(what: &str, timeout: Duration, mut check: impl FnMut() -> bool) {
    let start = Instant::now();
    while !check() {
        assert!(start.elapsed() < timeout, "{what} within {timeout:?}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

#[test]
fn prometheus_scrapes_the_numbers_the_api_reports() {
    let bus = PrivateBus::new();
    let service = Service::start(&bus, &[]);
    let mut replay = start_replay(&bus, "drive", &["--scenario", SEED, "--speed", "max"]);
    assert!(
        replay.wait(Duration::from_secs(60)).success(),
        "sensors-replay failed"
    );

    let dir = std::env::temp_dir().join(format!("railmon-prometheus-{}", bus.prefix));
    std::fs::create_dir_all(&dir).unwrap();
    let config = dir.join("prometheus.yml");
    std::fs::write(
        &config,
        format!(
            "scrape_configs:\n  - job_name: railmon\n    scrape_interval: 250ms\n    \
             scrape_timeout: 200ms\n    static_configs:\n      - targets: ['{}']\n",
            service.addr
        ),
    )
    .unwrap();
    let prometheus_addr = format!("127.0.0.1:{}", free_port());
    let binary = std::env::var("PROMETHEUS").unwrap_or_else(|_| "prometheus".into());
    let child = Command::new(&binary)
        .arg(format!("--config.file={}", config.display()))
        .arg(format!(
            "--storage.tsdb.path={}",
            dir.join("data").display()
        ))
        .arg(format!("--web.listen-address={prometheus_addr}"))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap_or_else(|e| {
            panic!(
                "cannot start `{binary}` ({e}): run scripts/install-test-deps, or set PROMETHEUS"
            )
        });
    let mut prometheus = Process {
        child,
        name: "prometheus".into(),
    };

    // The target is up: Prometheus parsed our exposition format.
    wait_for(
        "Prometheus scraping railmon",
        Duration::from_secs(30),
        || instant_query(&prometheus_addr, "up{job=\"railmon\"}") == Some(1.0),
    );

    let status = service.status("drive");
    let received = status["samples_received"].as_f64().unwrap();
    wait_for(
        "the sample count in Prometheus",
        Duration::from_secs(10),
        || {
            instant_query(
                &prometheus_addr,
                "railmon_stream_samples_received_total{stream=\"drive\"}",
            ) == Some(received)
        },
    );
    let drives = service.get_json("/api/v1/drives");
    for d in drives["drives"].as_array().unwrap() {
        let query = format!(
            "railmon_drive_slip_probability_ratio{{drive=\"{}\"}}",
            d["id"]
        );
        assert_eq!(
            instant_query(&prometheus_addr, &query),
            d["slip_probability"].as_f64(),
            "{query}"
        );
    }
    // Histograms arrive whole: a quantile over the estimator step time is computable.
    let p99 = instant_query(
        &prometheus_addr,
        "histogram_quantile(0.99, sum by (le) (railmon_estimator_step_duration_seconds_bucket{stream=\"drive\"}))",
    );
    assert!(
        p99.is_some_and(|v| v > 0.0 && v < 1.0),
        "p99 step time: {p99:?}"
    );

    prometheus.terminate(Duration::from_secs(10));
    let _ = std::fs::remove_dir_all(&dir);
}
