//! Metrics without gaps (issue 29 item 2): `railmon serve` -> an onboard Prometheus in agent
//! mode (the repository's `dashboards/prometheus/agent.yml`) -> remote write -> a ground
//! Prometheus with the receiver (`dashboards/prometheus/ground.yml`, the rules of `alerts.yml`)
//! -> Alertmanager. The ground is stopped for `OUTAGE` (its data kept) while the agent keeps
//! scraping into its WAL, then started again: every scrape of the outage must reach the ground,
//! and a rule of alerts.yml must fire there naming the vehicle.
//!
//! The two config files are used as they are, with only what a test must change replaced
//! (addresses, the rule file's path, intervals shortened to 1 s, the agent's `max_backoff` to
//! 2 s so the test does not wait up to 30 s after the restart); each replaced text must be in
//! the file exactly once. Needs `prometheus` 2.42 and `prometheus-alertmanager`
//! (`scripts/install-test-deps`). Prints the outage and what arrived (docs/fleet.md, "Metrics").

use std::time::{Duration, SystemTime, UNIX_EPOCH};

use railmon_system_tests::monitoring::{wait_for, Alertmanager, Prometheus, PrometheusMode};
use railmon_system_tests::{http_get, workspace_root, PrivateBus, Service};
use serde_json::Value;

const VEHICLE: &str = "unit-7";
const FLEET: &str = "north";
const SCRAPE_INTERVAL_S: f64 = 1.0;
/// The ground's down time: long against the scrape interval and the agent's backoff.
const OUTAGE: Duration = Duration::from_secs(25);

fn now_s() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_secs_f64()
}

/// The repository's `dashboards/prometheus/<file>` with each `(from, to)` replaced; `from` must
/// occur exactly once (a changed file fails here rather than testing something else).
fn config_file(file: &str, replacements: &[(&str, &str)]) -> String {
    let path = workspace_root().join("dashboards/prometheus").join(file);
    let mut text = std::fs::read_to_string(&path).unwrap();
    for (from, to) in replacements {
        assert_eq!(
            text.matches(from).count(),
            1,
            "{}: `{from}` should occur once",
            path.display()
        );
        text = text.replace(from, to);
    }
    text
}

/// The sum of the samples of metric `name` in a text exposition (0 if it has none).
fn metric_sum(text: &str, name: &str) -> f64 {
    text.lines()
        .filter(|l| {
            l.strip_prefix(name)
                .is_some_and(|rest| rest.starts_with('{') || rest.starts_with(' '))
        })
        .filter_map(|l| l.rsplit(' ').next()?.parse::<f64>().ok())
        .sum()
}

/// The sample times (Unix seconds) of the one series `selector` selects on the ground in the
/// `window_s` seconds up to `at_s`.
fn sample_times(ground: &Prometheus, selector: &str, window_s: f64, at_s: f64) -> Vec<f64> {
    let result = ground.query_at(&format!("{selector}[{}s]", window_s.ceil()), at_s);
    assert_eq!(result.len(), 1, "{selector}: one series, got {result:?}");
    result[0]["values"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v[0].as_f64().unwrap())
        .collect()
}

#[test]
fn the_ground_gets_every_scrape_of_an_outage_from_the_agent_wal() {
    let bus = PrivateBus::new();
    // No replay: the streams stay stale, which RailmonStreamStale reports (the ground's alert).
    let service = Service::start(
        &bus,
        &[
            ("RAILMON_IDENTITY__VEHICLE_ID", VEHICLE),
            ("RAILMON_IDENTITY__FLEET", FLEET),
        ],
    );
    let alertmanager = Alertmanager::start();
    let alertmanager_target = format!("targets: [\"{}\"]", alertmanager.addr);
    let mut ground = Prometheus::start_as(
        PrometheusMode::Receiver,
        &config_file(
            "ground.yml",
            &[
                ("/etc/railmon/alerts.yml", "{rules}"),
                ("targets: [\"alertmanager:9093\"]", &alertmanager_target),
                ("evaluation_interval: 5s", "evaluation_interval: 1s"),
            ],
        ),
        &[],
    );
    let scrape_target = format!("targets: [\"{}\"]", service.addr);
    let write_url = format!("url: http://{}/api/v1/write", ground.addr);
    let agent = Prometheus::start_as(
        PrometheusMode::Agent,
        &config_file(
            "agent.yml",
            &[
                ("targets: [\"127.0.0.1:8787\"]", &scrape_target),
                ("url: http://prometheus:9090/api/v1/write", &write_url),
                ("scrape_interval: 5s", "scrape_interval: 1s"),
                ("scrape_timeout: 4s", "scrape_timeout: 900ms"),
                ("batch_send_deadline: 5s", "batch_send_deadline: 1s"),
                ("max_backoff: 30s", "max_backoff: 2s"),
            ],
        ),
        &[("RAILMON_VEHICLE_ID", VEHICLE), ("RAILMON_FLEET", FLEET)],
    );
    let start_s = now_s();

    // The ground has the vehicle's series: railmon's own labels, and the agent's external
    // labels on `up` (which the service does not export).
    let up = format!("up{{job=\"railmon\",vehicle_id=\"{VEHICLE}\",fleet=\"{FLEET}\"}}");
    wait_for(
        "`up` of the vehicle on the ground",
        Duration::from_secs(60),
        || ground.value(&up) == Some(1.0),
    );
    let build_info = format!("railmon_build_info{{vehicle_id=\"{VEHICLE}\",fleet=\"{FLEET}\"}}");
    wait_for(
        "railmon_build_info on the ground",
        Duration::from_secs(10),
        || ground.value(&build_info) == Some(1.0),
    );
    let per_scrape = ground
        .value(&format!(
            "scrape_samples_scraped{{vehicle_id=\"{VEHICLE}\"}}"
        ))
        .expect("scrape_samples_scraped on the ground");
    std::thread::sleep(Duration::from_secs(5));

    // The outage: the ground is down, the agent keeps scraping into its WAL.
    let stop_s = now_s();
    ground.stop();
    std::thread::sleep(OUTAGE);
    let restart_s = now_s();
    ground.start_again();

    // Caught up when the newest sample on the ground is from after the restart (each series
    // is sent in order, so everything before it has arrived).
    let newest = format!("timestamp({build_info})");
    wait_for("the backlog on the ground", Duration::from_secs(60), || {
        ground.value(&newest).is_some_and(|t| t > restart_s + 2.0)
    });
    let caught_up_s = now_s();

    // Every scrape of the outage is on the ground: per series, no two consecutive samples
    // further apart than two scrape intervals from 5 s before the stop to after the restart.
    let window_s = restart_s + 2.0 - (stop_s - 5.0);
    let mut in_outage = Vec::new();
    for selector in [
        up.clone(),
        build_info.clone(),
        format!("process_resident_memory_bytes{{vehicle_id=\"{VEHICLE}\"}}"),
    ] {
        let times = sample_times(&ground, &selector, window_s, restart_s + 2.0);
        let largest_gap_s = times
            .windows(2)
            .map(|w| w[1] - w[0])
            .fold(0.0_f64, f64::max);
        let during = times
            .iter()
            .filter(|&&t| t > stop_s && t <= restart_s)
            .count();
        println!(
            "{selector}: {} samples in {window_s:.1} s, {during} of them during the outage, \
             largest gap {largest_gap_s:.3} s",
            times.len()
        );
        assert!(
            largest_gap_s <= 2.0 * SCRAPE_INTERVAL_S,
            "{selector}: a gap of {largest_gap_s} s on the ground"
        );
        in_outage.push(during);
    }
    let outage_s = restart_s - stop_s;
    let scrapes = (outage_s / SCRAPE_INTERVAL_S).floor() as usize;
    for during in &in_outage {
        assert!(
            during + 2 >= scrapes,
            "{during} samples of a series during the {outage_s:.1} s outage, {scrapes} scrapes"
        );
    }

    // All series: the samples of the outage on the ground against the series per scrape
    // times the scrapes (`up` samples) of the outage (raw samples: `count_over_time` over
    // several metrics would drop their names and collide).
    let all = ground.query_at(
        &format!(
            "{{vehicle_id=\"{VEHICLE}\",__name__!~\"ALERTS.*\"}}[{}s]",
            outage_s.ceil()
        ),
        restart_s,
    );
    let count = |series: &Value| series["values"].as_array().map_or(0, Vec::len) as f64;
    let recovered: f64 = all.iter().map(count).sum();
    let ups: f64 = all
        .iter()
        .filter(|s| s["metric"]["__name__"] == "up")
        .map(count)
        .sum();
    // `up` and the four other series the scrape itself makes, besides the scraped ones.
    let expected = (per_scrape + 5.0) * ups;
    println!(
        "outage {outage_s:.1} s (ground stopped {stop_s:.3}, started {restart_s:.3}), caught up \
         {:.1} s after the start; {recovered} samples of the vehicle over the outage window on \
         the ground = {ups} scrapes x {} series (expected {expected})",
        caught_up_s - restart_s,
        per_scrape + 5.0
    );
    assert!(
        recovered >= 0.99 * expected,
        "{recovered} samples of the outage on the ground, {expected} scraped"
    );

    // The agent's side: nothing dropped, what it retried.
    let (status, metrics) = http_get(&agent.addr, "/metrics");
    assert_eq!(status, 200);
    let failed = metric_sum(&metrics, "prometheus_remote_storage_samples_failed_total");
    println!(
        "agent: samples sent {}, retried {}, failed {failed}, pending {}; WAL {} bytes after \
         {:.0} s at {per_scrape} samples per scrape",
        metric_sum(&metrics, "prometheus_remote_storage_samples_total"),
        metric_sum(&metrics, "prometheus_remote_storage_samples_retried_total"),
        metric_sum(&metrics, "prometheus_remote_storage_samples_pending"),
        agent.disk_bytes("agent/wal"),
        now_s() - start_s,
    );
    assert_eq!(failed, 0.0, "samples the ground refused");

    // The ground evaluates the vehicle rules on pushed series: the stale streams of a service
    // without sensors fire RailmonStreamStale (for: 30s) for this vehicle, into Alertmanager.
    let stale = format!(
        "ALERTS{{alertname=\"RailmonStreamStale\",alertstate=\"firing\",vehicle_id=\"{VEHICLE}\"}}"
    );
    wait_for(
        "RailmonStreamStale firing on the ground",
        Duration::from_secs(60),
        || !ground.query(&stale).is_empty(),
    );
    wait_for(
        "RailmonStreamStale of the vehicle in Alertmanager",
        Duration::from_secs(30),
        || {
            alertmanager.alerts().iter().any(|a| {
                a["labels"]["alertname"] == "RailmonStreamStale"
                    && a["labels"]["vehicle_id"] == VEHICLE
                    && a["labels"]["fleet"] == FLEET
            })
        },
    );
    println!(
        "RailmonStreamStale in Alertmanager {:.1} s after the ground's restart",
        now_s() - restart_s
    );
}
