//! The damper fault raises its alert end to end: `sensors-replay bogie` (the `damper-fault`
//! scenario: `C_say` steps to 40 % at 30 s) -> `railmon serve` -> a real Prometheus evaluating
//! the repository's `dashboards/prometheus/alerts.yml` -> a real Alertmanager, whose API then
//! holds `RailmonDamperDegraded` for that damper of that vehicle, and nothing else about dampers.
//! Before the replay (no estimate yet) no damper alert exists.
//!
//! Prometheus scrapes and evaluates every 250 ms so the test takes well under a minute; the
//! rules' own `for` durations apply unchanged. Needs `prometheus` and `prometheus-alertmanager`
//! (`scripts/install-test-deps`).

use std::time::Duration;

use railmon_system_tests::monitoring::{wait_for, Alertmanager, Prometheus};
use railmon_system_tests::{start_replay, PrivateBus, Service};
use serde_json::Value;

const DAMPER_FAULT: &str = "config/scenarios/damper-fault.toml";

fn damper_alerts(alertmanager: &Alertmanager) -> Vec<Value> {
    alertmanager
        .alerts()
        .into_iter()
        .filter(|a| a["labels"]["alertname"] == "RailmonDamperDegraded")
        .collect()
}

#[test]
fn the_damper_fault_fires_its_alert_in_alertmanager() {
    let bus = PrivateBus::new();
    let service = Service::start(
        &bus,
        &[
            ("RAILMON_BOGIE__ENABLED", "true"),
            ("RAILMON_BOGIE__BOGIES", "[1]"),
            ("RAILMON_DRIVE__ENABLED", "false"),
            ("RAILMON_BOGIE__ESTIMATOR__RBPF__PARTICLES", "100"),
            ("RAILMON_BOGIE__ESTIMATOR__TRACK_VELOCITY_STD_M_S", "0.1"),
            ("RAILMON_IDENTITY__VEHICLE_ID", "tram-7"),
        ],
    );
    let alertmanager = Alertmanager::start();
    let config = format!(
        "{}rule_files: ['{{rules}}']\nalerting:\n  alertmanagers:\n    - static_configs:\n        - targets: ['{}']\n",
        Prometheus::fast_config("railmon", &[&service.addr]),
        alertmanager.addr
    );
    let prometheus = Prometheus::start(&config);
    wait_for(
        "Prometheus scraping railmon",
        Duration::from_secs(30),
        || prometheus.value("up{job=\"railmon\"}") == Some(1.0),
    );
    // Rules evaluated on a service without estimates: no damper alert (2 s = 8 evaluations).
    std::thread::sleep(Duration::from_secs(2));
    assert!(
        prometheus
            .query("ALERTS{alertname=\"RailmonDamperDegraded\"}")
            .is_empty(),
        "a damper alert before any estimate"
    );

    let mut replay = start_replay(
        &bus,
        "bogie",
        &[
            "--scenario",
            DAMPER_FAULT,
            "--bogies",
            "1",
            "--duration-s",
            "40",
            "--speed",
            "max",
        ],
    );
    assert!(
        replay.wait(Duration::from_secs(120)).success(),
        "sensors-replay bogie failed"
    );
    let events = service.get_json("/api/v1/bogies/events");
    wait_for(
        "RailmonDamperDegraded in Alertmanager",
        Duration::from_secs(30),
        || !damper_alerts(&alertmanager).is_empty(),
    );
    let alerts = damper_alerts(&alertmanager);
    assert_eq!(alerts.len(), 1, "{alerts:#?}\nevents: {events}");
    let labels = &alerts[0]["labels"];
    assert_eq!(
        (
            &labels["bogie"],
            &labels["damper"],
            &labels["vehicle_id"],
            &labels["severity"]
        ),
        (
            &Value::from("1"),
            &Value::from("csay"),
            &Value::from("tram-7"),
            &Value::from("critical")
        ),
        "{alerts:#?}"
    );
    assert_eq!(alerts[0]["status"]["state"], "active", "{alerts:#?}");
    assert!(
        alerts[0]["annotations"]["summary"]
            .as_str()
            .is_some_and(|s| s.contains("csay") && s.contains("tram-7")),
        "{alerts:#?}"
    );
}
