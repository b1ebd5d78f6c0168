//! End to end over the bus for the vehicle stream: the real `railmon serve` and
//! `sensors-replay vehicle` processes on a private bus and a free port.

use std::path::Path;
use std::time::Duration;

use railmon_analyze::fuel::samples_from_rows;
use railmon_bus::{BusNode, VehicleFrame};
use railmon_fuel::{FuelMonitor, FuelMonitorConfig, VehicleSample};
use railmon_records::vehicle::read_vehicle_csv;
use railmon_system_tests::{start_replay, PrivateBus, Service};
use serde_json::Value;

const FUEL_CYCLES: &str = "config/scenarios/fuel-cycles.toml";

/// The vehicle stream on, the drive stream off (so `/readyz` is about the vehicle only).
const VEHICLE_ONLY: [(&str, &str); 2] = [
    ("RAILMON_VEHICLE__ENABLED", "true"),
    ("RAILMON_DRIVE__ENABLED", "false"),
];

/// The library's estimate after every sample of `record` (what the service should say).
fn reference(record: &Path) -> (FuelMonitor, u64) {
    let (_, rows) = read_vehicle_csv(record).unwrap();
    let mut monitor = FuelMonitor::new(&FuelMonitorConfig::default()).unwrap();
    let mut changes = 0;
    for sample in samples_from_rows(&rows) {
        let estimate = monitor.update(&sample).unwrap();
        changes += estimate
            .mixture
            .as_ref()
            .map_or(0, |m| u64::from(m.regime_change.is_some()));
    }
    (monitor, changes)
}

fn f64s(value: &Value) -> Vec<f64> {
    value
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect()
}

#[test]
fn fuel_cycles_replay_reaches_the_service_complete_and_equal_to_the_library() {
    let bus = PrivateBus::new();
    // Stale only after 10 min: `/readyz` is checked after the library has re-run the whole
    // recording, which took longer than the default 3 s on a loaded machine (a 503 `stale`).
    // Staleness itself: `killed_replay_makes_readyz_fail_within_a_second_and_a_new_one_recovers`.
    let settings = [
        VEHICLE_ONLY[0],
        VEHICLE_ONLY[1],
        ("RAILMON_VEHICLE__STALE_AFTER_MS", "600000"),
    ];
    let mut service = Service::start(&bus, &settings);
    let record = std::env::temp_dir().join(format!("railmon-e2e-vehicle-{}.csv", bus.prefix));
    let record_arg = record.to_str().unwrap();
    let args = [
        "--scenario",
        FUEL_CYCLES,
        "--speed",
        "max",
        "--record",
        record_arg,
    ];
    let mut replay = start_replay(&bus, "vehicle", &args);
    assert!(
        replay.wait(Duration::from_secs(120)).success(),
        "sensors-replay vehicle failed"
    );
    let (monitor, changes) = reference(&record);
    let n = monitor.estimate().samples;
    assert_eq!(n, 9675, "--record wrote every frame of the scenario");

    let status = service.wait_for_status("vehicle", Duration::from_secs(20), "every frame", |s| {
        s["estimator_steps"].as_u64() == Some(n)
    });
    assert_eq!(status["samples_received"].as_u64(), Some(n), "{status}");
    assert_eq!(status["sequence_gaps"], 0, "{status}");
    assert_eq!(status["samples_rejected"], 0, "{status}");
    assert_eq!(service.get("/readyz").0, 200);

    // The service's estimate is the library's, to the last bit.
    let v = service.get_json("/api/v1/vehicle");
    let want = monitor.estimate();
    let m = want.mixture.as_ref().unwrap();
    assert_eq!(v["samples"].as_u64(), Some(n));
    assert_eq!(v["run_time_s"].as_f64(), Some(want.time_s));
    assert_eq!(v["fuel_rate_cm3_s"].as_f64(), Some(want.fuel_cm3_s));
    assert_eq!(
        v["cumulative_fuel_cm3"].as_f64(),
        Some(want.cumulative_fuel_cm3)
    );
    assert_eq!(
        v["virtual_sensor_cm3_s"].as_f64(),
        Some(m.virtual_sensor_cm3_s)
    );
    assert_eq!(
        v["one_step_forecast_cm3_s"].as_f64(),
        Some(m.one_step_forecast_cm3_s)
    );
    assert_eq!(f64s(&v["forecast_cm3_s"]), m.forecast_cm3_s);
    assert_eq!(f64s(&v["regime_probabilities"]), m.regime_probabilities);
    assert_eq!(v["regime"].as_u64(), Some(m.regime as u64));
    assert_eq!(
        v["most_probable_regime"].as_u64(),
        Some(m.active_regime as u64)
    );
    assert_eq!(v["regime_changes"].as_u64(), Some(changes));
    assert!(changes > 0);
    let events = service.get_json("/api/v1/vehicle/events?limit=1000");
    let events = events["events"].as_array().unwrap();
    assert_eq!(events.len() as u64, changes);
    assert_eq!(events.last().unwrap()["to_regime"], v["regime"]);
    let history = service.get_json("/api/v1/vehicle/history?seconds=60");
    assert_eq!(history["points"].as_array().unwrap().len(), 61);

    // /metrics carries the same numbers, in base units (m^3/s, m^3).
    let measured = "railmon_vehicle_fuel_rate_cubic_meters_per_second{kind=\"measured\"}";
    assert_eq!(service.metric(measured), Some(want.fuel_cm3_s * 1e-6));
    let consumed = "railmon_vehicle_fuel_consumed_cubic_meters{kind=\"measured\"}";
    assert_eq!(
        service.metric(consumed),
        Some(want.cumulative_fuel_cm3 * 1e-6)
    );
    for (i, p) in m.regime_probabilities.iter().enumerate() {
        let series = format!("railmon_vehicle_regime_probability_ratio{{regime=\"{i}\"}}");
        assert_eq!(service.metric(&series), Some(*p), "{series}");
    }
    let received = "railmon_stream_samples_received_total{stream=\"vehicle\"}";
    assert_eq!(service.metric(received), Some(n as f64));

    // Replaying the recording is a new source with the same data: the same final estimate.
    let mut replay = start_replay(&bus, "vehicle", &["--csv", record_arg, "--speed", "max"]);
    assert!(
        replay.wait(Duration::from_secs(120)).success(),
        "CSV replay failed"
    );
    let status =
        service.wait_for_status("vehicle", Duration::from_secs(20), "the recording", |s| {
            s["estimator_steps"].as_u64() == Some(2 * n)
        });
    assert_eq!(status["sources"], 2, "{status}");
    let again = service.get_json("/api/v1/vehicle");
    for field in [
        "virtual_sensor_cm3_s",
        "regime_probabilities",
        "forecast_cm3_s",
        "cumulative_fuel_cm3",
        "regime_changes",
        "run_time_s",
    ] {
        assert_eq!(again[field], v[field], "{field}");
    }
    assert!(again["time_s"].as_f64() > v["time_s"].as_f64());
    let _ = std::fs::remove_file(record);

    let exit = service.process.terminate(Duration::from_secs(10));
    assert!(exit.success(), "railmon serve exited with {exit}");
}

#[test]
fn bad_vehicle_frames_are_rejected_counted_and_leave_the_estimate_alone() {
    let bus = PrivateBus::new();
    let groups = (
        "RAILMON_VEHICLE__ESTIMATOR__CATEGORICAL__GEAR_GROUPS",
        "[[0], [1, 2], [3]]",
    );
    let service = Service::start(&bus, &[VEHICLE_ONLY[0], VEHICLE_ONLY[1], groups]);
    let node = BusNode::create(&bus.config(), "test-publisher").unwrap();
    let mut publisher = node.publisher::<VehicleFrame>().unwrap();
    publisher
        .wait_for_subscriber(Some(Duration::from_secs(20)), &|| false)
        .unwrap();
    let sample = |t: u64| VehicleSample {
        time_s: t as f64,
        fuel_cm3_s: Some(0.5 + 0.1 * (t as f64).sin()),
        speed_m_s: Some(10.0),
        gear: Some(2),
        ..Default::default()
    };
    for t in 0..10 {
        let frame = VehicleFrame::from_sample(&sample(t));
        assert_eq!(publisher.send(&frame, t * 1_000_000_000).unwrap(), 1);
    }
    publisher.notify().unwrap();
    service.wait_for_status("vehicle", Duration::from_secs(5), "10 good frames", |s| {
        s["estimator_steps"] == 10
    });
    let before = service.get_json("/api/v1/vehicle");
    assert_eq!(before["samples"], 10);

    let mut nan = VehicleFrame::from_sample(&sample(10));
    nan.fuel_cm3_s = f64::NAN;
    let unknown_gear = VehicleFrame::from_sample(&VehicleSample {
        gear: Some(5),
        ..sample(11)
    });
    publisher.send(&nan, 10_000_000_000).unwrap();
    publisher.send(&unknown_gear, 11_000_000_000).unwrap();
    publisher.notify().unwrap();

    service.assert_rejections("vehicle", 10, &["not_finite", "unknown_category"]);
    assert_eq!(service.get_json("/api/v1/vehicle"), before);
}

#[test]
fn bad_vehicle_sources_fail_with_the_culprit_named() {
    let replay = |args: &[&str]| {
        let out = std::process::Command::new(&railmon_system_tests::binaries().replay)
            .arg("vehicle")
            .args(args)
            .output()
            .unwrap();
        assert!(!out.status.success(), "{args:?}");
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let stderr = replay(&["--scenario", "no/such/fuel.toml"]);
    assert!(stderr.contains("no/such/fuel.toml"), "{stderr}");
    let csv = std::env::temp_dir().join(format!("railmon-e2e-nan-{}.csv", std::process::id()));
    std::fs::write(&csv, "time_s,fuel_cm3_s,speed_m_s\n0,0.5,1\n1,NaN,1\n").unwrap();
    let stderr = replay(&["--csv", csv.to_str().unwrap()]);
    assert!(
        stderr.contains(":3:") && stderr.contains("fuel_cm3_s") && stderr.contains("NaN"),
        "{stderr}"
    );
    let _ = std::fs::remove_file(csv);
}

/// Issue 14 item 1: a railcar's fuel (idle ~10 to full power ~116 cm^3/s, above the road
/// car's 100 cm^3/s) runs live with `preset = "railcar"`: every frame of the route estimated,
/// none refused, the estimate the library's.
#[test]
fn the_railcar_route_runs_live_with_the_railcar_preset() {
    let bus = PrivateBus::new();
    let env = [
        VEHICLE_ONLY[0],
        VEHICLE_ONLY[1],
        ("RAILMON_VEHICLE__ESTIMATOR__PRESET", "railcar"),
    ];
    let mut service = Service::start(&bus, &env);
    let record = std::env::temp_dir().join(format!("railmon-e2e-railcar-{}.csv", bus.prefix));
    let record_arg = record.to_str().unwrap();
    let args = [
        "--scenario",
        "config/scenarios/fuel-railcar.toml",
        "--speed",
        "max",
        "--record",
        record_arg,
    ];
    let mut replay = start_replay(&bus, "vehicle", &args);
    assert!(replay.wait(Duration::from_secs(120)).success());
    let (_, rows) = read_vehicle_csv(&record).unwrap();
    let max_fuel = rows
        .iter()
        .map(|r| r.sample.fuel_cm3_s.unwrap())
        .fold(0.0, f64::max);
    assert!(max_fuel > 100.0, "{max_fuel}");
    let mut monitor = FuelMonitor::new(&FuelMonitorConfig::railcar()).unwrap();
    for sample in samples_from_rows(&rows) {
        monitor.update(&sample).unwrap();
    }
    let n = rows.len() as u64;
    let status = service.wait_for_status("vehicle", Duration::from_secs(20), "every frame", |s| {
        s["estimator_steps"].as_u64() == Some(n)
    });
    assert_eq!(status["samples_rejected"], 0, "{status}");
    let v = service.get_json("/api/v1/vehicle");
    let m = monitor.estimate().mixture.clone().unwrap();
    assert_eq!(
        v["virtual_sensor_cm3_s"].as_f64(),
        Some(m.virtual_sensor_cm3_s)
    );
    let _ = std::fs::remove_file(record);
    let exit = service.process.terminate(Duration::from_secs(10));
    assert!(exit.success(), "railmon serve exited with {exit}");
}
