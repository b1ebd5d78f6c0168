//! The Grafana dashboard (`dashboards/railmon.json`) against a real Prometheus scraping two
//! real services (two vehicle ids, every stream fed by a looping replay): every panel's query,
//! with the dashboard's variables set as Grafana would, returns data, and no two series of a
//! panel share a legend (a fleet Prometheus doubled 34 of 47 queries of the old dashboard).
//! Also checked: the dashboard provisions as a file (no `${DS_...}` import placeholder), every
//! panel uses the `datasource` variable, every unit is one Grafana knows, and the variables'
//! queries find both vehicles and their drives and bogies.
//!
//! Needs `prometheus` (`scripts/install-test-deps`).

use std::collections::BTreeSet;
use std::time::{Duration, Instant};

use railmon_system_tests::monitoring::{wait_for, Prometheus};
use railmon_system_tests::{start_replay, workspace_root, PrivateBus, Process, Service};
use serde_json::Value;

const VEHICLES: [&str; 2] = ["tram-1", "tram-2"];

/// Units of Grafana's unit picker that the dashboard may use (custom units: `suffix:`).
const GRAFANA_UNITS: [&str; 12] = [
    "none",
    "s",
    "h",
    "cps",
    "percentunit",
    "torqueNm",
    "rotrads",
    "litre",
    "litreh",
    "velocityms",
    "bytes",
    "short",
];

fn dashboard() -> Value {
    let text = std::fs::read_to_string(workspace_root().join("dashboards/railmon.json")).unwrap();
    assert!(
        !text.contains("${DS_"),
        "an import placeholder breaks file provisioning"
    );
    serde_json::from_str(&text).unwrap()
}

/// Every (panel title, expression, legend format) of the dashboard.
fn queries(dashboard: &Value) -> Vec<(String, String, String)> {
    let mut out = Vec::new();
    for panel in dashboard["panels"].as_array().unwrap() {
        let title = panel["title"].as_str().unwrap_or_default();
        if panel["type"] == "row" {
            continue;
        }
        assert_eq!(panel["datasource"]["uid"], "${datasource}", "{title}");
        let unit = panel["fieldConfig"]["defaults"]["unit"]
            .as_str()
            .unwrap_or("none");
        assert!(
            GRAFANA_UNITS.contains(&unit) || unit.starts_with("suffix:"),
            "{title}: unit {unit}"
        );
        for target in panel["targets"].as_array().unwrap() {
            assert_eq!(target["datasource"]["uid"], "${datasource}", "{title}");
            out.push((
                title.to_string(),
                target["expr"].as_str().unwrap().to_string(),
                target["legendFormat"]
                    .as_str()
                    .unwrap_or_default()
                    .to_string(),
            ));
        }
    }
    out
}

/// The expression as Grafana sends it for `vehicle` (all drives and bogies; the rate interval
/// and range fit the test's 250 ms scrapes and short run).
fn substitute(expr: &str, vehicle: &str, drive: &str, bogie: &str) -> String {
    expr.replace("$__rate_interval", "3s")
        .replace("$__range", "1m")
        .replace("$vehicle", vehicle)
        .replace("$drive", drive)
        .replace("$bogie", bogie)
}

/// `{{label}}` of `legend` filled from a series' labels (an empty legend: all labels).
fn legend_of(legend: &str, metric: &Value) -> String {
    if legend.is_empty() {
        return metric.to_string();
    }
    let mut out = legend.to_string();
    if let Some(labels) = metric.as_object() {
        for (k, v) in labels {
            out = out.replace(&format!("{{{{{k}}}}}"), v.as_str().unwrap_or_default());
        }
    }
    out
}

fn start_vehicle(bus: &PrivateBus, vehicle: &str) -> (Service, Vec<Process>) {
    let service = Service::start(
        bus,
        &[
            ("RAILMON_IDENTITY__VEHICLE_ID", vehicle),
            ("RAILMON_BOGIE__ENABLED", "true"),
            ("RAILMON_VEHICLE__ENABLED", "true"),
            ("RAILMON_BOGIE__ESTIMATOR__RBPF__PARTICLES", "100"),
            ("RAILMON_BOGIE__ESTIMATOR__TRACK_VELOCITY_STD_M_S", "0.1"),
        ],
    );
    let replays = vec![
        start_replay(
            bus,
            "drive",
            &[
                "--scenario",
                "config/scenarios/adhesion-seed.toml",
                "--loop",
            ],
        ),
        start_replay(
            bus,
            "bogie",
            &[
                "--scenario",
                "config/scenarios/damper-fault.toml",
                "--bogies",
                "2",
                // 4x real time: the damper trend needs two operating minutes (its panels).
                "--speed",
                "4",
                "--loop",
            ],
        ),
        start_replay(
            bus,
            "vehicle",
            &[
                "--scenario",
                "config/scenarios/fuel-cycles.toml",
                "--speed",
                "100",
                "--loop",
            ],
        ),
    ];
    (service, replays)
}

#[test]
fn every_panel_returns_one_series_per_legend_for_one_of_two_vehicles() {
    let dashboard = dashboard();
    let queries = queries(&dashboard);
    assert!(queries.len() > 30, "{}", queries.len());

    let buses = [PrivateBus::new(), PrivateBus::new()];
    let fleet: Vec<(Service, Vec<Process>)> = buses
        .iter()
        .zip(VEHICLES)
        .map(|(bus, vehicle)| start_vehicle(bus, vehicle))
        .collect();
    let targets: Vec<&str> = fleet.iter().map(|(s, _)| s.addr.as_str()).collect();
    let prometheus = Prometheus::start(&Prometheus::fast_config("railmon", &targets));
    wait_for("both services scraped", Duration::from_secs(30), || {
        prometheus.value("count(up{job=\"railmon\"} == 1)") == Some(2.0)
    });

    // The variables: both vehicles; vehicle 1's drives and bogies.
    let label_values = |label: &str, matcher: &str| -> BTreeSet<String> {
        let path = format!(
            "/api/v1/label/{label}/values?match[]={}",
            railmon_system_tests::monitoring::encode(matcher)
        );
        let (_, body) = railmon_system_tests::http_get(&prometheus.addr, &path);
        let json: Value = serde_json::from_str(&body).unwrap_or(Value::Null);
        json["data"]
            .as_array()
            .map(|a| {
                a.iter()
                    .filter_map(|v| v.as_str().map(String::from))
                    .collect()
            })
            .unwrap_or_default()
    };
    wait_for("the variables' values", Duration::from_secs(30), || {
        label_values("vehicle_id", "railmon_build_info").len() == 2
            && label_values(
                "drive",
                "railmon_drive_slip_seconds_total{vehicle_id=\"tram-1\"}",
            )
            .len()
                == 3
            && label_values(
                "bogie",
                "railmon_bogie_damper_events_total{vehicle_id=\"tram-1\"}",
            )
            .len()
                == 2
    });

    // Every query with data, for all drives and bogies and for one of each, or the list of
    // those without, after at most 90 s (the fuel mixture initialises after 150 samples).
    let selections = [(".*", ".*"), ("2", "1")];
    let mut missing = Vec::new();
    let start = Instant::now();
    loop {
        missing.clear();
        for (title, expr, _) in &queries {
            for (drive, bogie) in selections {
                let query = substitute(expr, VEHICLES[0], drive, bogie);
                if prometheus.query(&query).is_empty() {
                    missing.push(format!("{title}: {query}"));
                }
            }
        }
        if missing.is_empty() || start.elapsed() > Duration::from_secs(90) {
            break;
        }
        std::thread::sleep(Duration::from_millis(500));
    }
    assert!(
        missing.is_empty(),
        "queries without data:\n{}",
        missing.join("\n")
    );

    for (title, expr, legend) in &queries {
        let query = substitute(expr, VEHICLES[0], ".*", ".*");
        let result = prometheus.query(&query);
        let mut legends = BTreeSet::new();
        for series in &result {
            let metric = &series["metric"];
            if let Some(vehicle) = metric["vehicle_id"].as_str() {
                assert_eq!(vehicle, VEHICLES[0], "{title}: {query}");
            }
            assert!(
                legends.insert(legend_of(legend, metric)),
                "{title}: two series with the legend {:?}: {query}\n{result:#?}",
                legend_of(legend, metric)
            );
        }
    }
    drop(fleet);
}
