//! The vehicle pipeline without the bus: the service's numbers are the library's numbers,
//! regime changes become events, bad frames are rejected by reason and change nothing.

mod common;

use common::vehicle::{fuel_cycles, vehicle_config, vehicle_header, VehicleHarness};
use railmon_bus::VehicleFrame;
use railmon_fuel::{
    CategoricalConfig, ComponentName, FuelMonitor, FuelMonitorConfig, VehicleSample,
};
use railmon_service::ingest::Pipeline;
use railmon_service::vehicle::IntervalView;

#[test]
fn pipeline_reproduces_the_library_and_reports_regime_changes() {
    let config = vehicle_config();
    let mut reference = FuelMonitor::new(&config.estimator).unwrap();
    let mut harness = VehicleHarness::new(config.clone());
    let (mut changes, mut squared, mut n) = (0u64, 0.0, 0u64);
    for _ in 0..2000 {
        let sample = harness.advance().unwrap();
        let want = reference.update(&sample).unwrap().clone();
        if let Some(m) = &want.mixture {
            changes += u64::from(m.regime_change.is_some());
            let e = want.fuel_cm3_s - m.one_step_forecast_cm3_s;
            (squared, n) = (squared + e * e, n + 1);
        }
        if !harness.step.is_multiple_of(97) && harness.step != 2000 {
            continue;
        }
        let view = harness.view();
        assert_eq!(view.samples, want.samples);
        assert_eq!(view.fuel_rate_cm3_s, Some(want.fuel_cm3_s));
        assert_eq!(view.cumulative_fuel_cm3, want.cumulative_fuel_cm3);
        assert_eq!(
            view.initialising,
            want.mixture.is_none() && harness.step <= 150
        );
        match &want.mixture {
            None => assert!(view.regime.is_none() && view.forecast_cm3_s.is_empty()),
            Some(m) => {
                assert_eq!(view.virtual_sensor_cm3_s, Some(m.virtual_sensor_cm3_s));
                assert_eq!(
                    view.one_step_forecast_cm3_s,
                    Some(m.one_step_forecast_cm3_s)
                );
                assert_eq!(view.zero_step_cm3_s, Some(m.zero_step_cm3_s));
                assert_eq!(view.forecast_cm3_s, m.forecast_cm3_s);
                assert_eq!(view.forecast_cm3_s.len(), 10);
                assert_eq!(view.regime, Some(m.regime));
                assert_eq!(view.most_probable_regime, Some(m.active_regime));
                assert_eq!(view.regime_probabilities, m.regime_probabilities);
                let total: f64 = view.regime_probabilities.iter().sum();
                assert!((total - 1.0).abs() < 1e-9, "{total}");
                // Names and intervals (issue 14 items 3 and 5) are the library's.
                let names: Vec<String> = m.regime_names.iter().map(|n| n.to_string()).collect();
                assert_eq!(view.regime_names, names);
                assert_eq!(view.regime_name, Some(m.regime_name.to_string()));
                assert_eq!(
                    view.most_probable_regime_name,
                    Some(names[m.active_regime].clone())
                );
                assert_eq!(
                    view.virtual_sensor_interval_cm3_s,
                    IntervalView::of(m.virtual_sensor_interval_cm3_s())
                );
                assert_eq!(
                    view.one_step_interval_cm3_s,
                    IntervalView::of(m.one_step_interval_cm3_s())
                );
                assert_eq!(view.forecast_interval_cm3_s.len(), 10);
                for (i, (f, want)) in view
                    .forecast_interval_cm3_s
                    .iter()
                    .zip(&m.forecast_interval_cm3_s())
                    .enumerate()
                {
                    assert_eq!(Some(*f), IntervalView::of(*want));
                    let mean = m.forecast_cm3_s[i];
                    assert!(
                        f.lower_cm3_s <= mean && mean <= f.upper_cm3_s,
                        "{f:?} {mean}"
                    );
                }
                // Inside its interval; on its lower end when both were projected onto 0.
                let v = view.virtual_sensor_interval_cm3_s.unwrap();
                let vs = m.virtual_sensor_cm3_s;
                let inside = v.lower_cm3_s < vs && vs < v.upper_cm3_s;
                assert!(inside || (vs == 0.0 && v.lower_cm3_s == 0.0), "{v:?} {vs}");
            }
        }
    }
    let view = harness.view();
    assert_eq!(view.regime_changes, changes);
    assert!(changes > 0, "2000 s of city driving change regime");
    let rmse = view.forecast_rmse_cm3_s.unwrap();
    assert!((rmse - (squared / n as f64).sqrt()).abs() < 1e-12, "{rmse}");
    let events = common::stored_events(&harness.shared.store);
    assert_eq!(events.len() as u64, changes);
    for pair in events.windows(2) {
        assert_eq!(
            pair[1].detail["from_regime"], pair[0].detail["to_regime"],
            "{pair:?}"
        );
        assert!(pair[1].time_s > pair[0].time_s && pair[1].id == pair[0].id + 1);
    }
    // Names are unique per component: every change is a change of name.
    for e in &events {
        for key in ["from_name", "to_name"] {
            let name = e.detail[key].as_str().unwrap();
            assert!(ComponentName::parse(name).is_some(), "{key} = {name}");
        }
        assert_ne!(e.detail["from_name"], e.detail["to_name"], "{e:?}");
    }
    // One history point per second of stream time.
    let history = harness.shared.history.collect(|_| true);
    assert_eq!(history.len(), 2000);
    assert_eq!(history[1999].fuel_rate_cm3_s, view.fuel_rate_cm3_s.unwrap());
}

/// Offers `bad`, expects rejection `reason`, and checks that the estimate is unchanged and that
/// the next good samples give exactly what an untouched estimator gives.
fn rejected_without_effect(config: FuelMonitorConfig, bad: VehicleSample, reason: &str) {
    let vehicle = railmon_service::config::VehicleConfig {
        estimator: config.clone(),
        ..vehicle_config()
    };
    let mut reference = FuelMonitor::new(&config).unwrap();
    let mut harness = VehicleHarness::new(vehicle);
    for _ in 0..300 {
        reference.update(&harness.advance().unwrap()).unwrap();
    }
    let before = harness.view();
    let rejection = harness.offer(&bad).unwrap_err();
    assert_eq!(rejection.reason, reason, "{}", rejection.message);
    assert_eq!(harness.view(), before);
    for _ in 0..20 {
        let want = reference
            .update(&harness.advance().unwrap())
            .unwrap()
            .clone();
        let got = harness.view();
        let m = want.mixture.unwrap();
        assert_eq!(got.virtual_sensor_cm3_s, Some(m.virtual_sensor_cm3_s));
        assert_eq!(got.regime_probabilities, m.regime_probabilities);
    }
}

fn next_sample() -> VehicleSample {
    fuel_cycles()[300]
}

#[test]
fn nan_fuel_is_rejected_at_the_frame_check_and_changes_nothing() {
    let bad = VehicleSample {
        fuel_cm3_s: Some(f64::NAN),
        ..next_sample()
    };
    rejected_without_effect(FuelMonitorConfig::default(), bad, "not_finite");
}

#[test]
fn a_gear_in_no_configured_group_is_rejected_and_changes_nothing() {
    let config = FuelMonitorConfig {
        categorical: Some(CategoricalConfig::default()),
        ..FuelMonitorConfig::default()
    };
    let bad = VehicleSample {
        gear: Some(9),
        ..next_sample()
    };
    rejected_without_effect(config, bad, "unknown_category");
}

#[test]
fn a_missing_or_implausible_channel_is_rejected_and_changes_nothing() {
    let missing = VehicleSample {
        speed_m_s: None,
        ..next_sample()
    };
    rejected_without_effect(FuelMonitorConfig::default(), missing, "missing_channel");
    let implausible = VehicleSample {
        fuel_cm3_s: Some(1e6),
        ..next_sample()
    };
    rejected_without_effect(FuelMonitorConfig::default(), implausible, "out_of_range");
    let late = VehicleSample {
        time_s: 3.0,
        ..next_sample()
    };
    rejected_without_effect(FuelMonitorConfig::default(), late, "time_not_increasing");
}

/// A speed 13 m/s above the last accepted one a second later: inside the road car's range,
/// beyond its 12 m/s^2. Counted as `acceleration_out_of_range`; the next good sample is
/// judged against the last accepted one and the estimates go on as if nothing had come.
#[test]
fn an_implausible_acceleration_is_rejected_and_changes_nothing() {
    let previous = fuel_cycles()[299].speed_m_s.unwrap();
    let jump = VehicleSample {
        speed_m_s: Some(previous + 13.0),
        ..next_sample()
    };
    assert!(jump.speed_m_s.unwrap() < 70.0);
    rejected_without_effect(
        FuelMonitorConfig::default(),
        jump,
        "acceleration_out_of_range",
    );
}

#[test]
fn unknown_channel_bits_are_rejected_at_the_frame_check() {
    let harness = VehicleHarness::new(vehicle_config());
    let mut frame = VehicleFrame::from_sample(&next_sample());
    frame.present |= 1 << 7;
    let rejection = harness
        .pipeline
        .check(&vehicle_header(0, 0.0), &frame)
        .unwrap_err();
    assert_eq!(rejection.reason, "unknown_channels");
}

#[test]
fn a_new_source_restarts_the_estimator_and_stream_time_continues() {
    let mut harness = VehicleHarness::new(vehicle_config());
    for _ in 0..200 {
        harness.advance();
    }
    let first = harness.view();
    assert_eq!(first.time_s, Some(199.0));
    assert!(!first.initialising);
    harness.pipeline.restart();
    let sample = VehicleSample {
        time_s: 0.0,
        ..fuel_cycles()[0]
    };
    harness.offer(&sample).unwrap();
    let second = harness.view();
    assert_eq!((second.samples, second.initialising), (1, true));
    assert_eq!(second.time_s, Some(200.0), "one step after the last frame");
    assert_eq!(second.run_time_s, Some(0.0));
    assert_eq!(second.regime_changes, 0);
}

/// A restart resumes the saved mixture: the following samples give exactly the estimates of
/// the pipeline that never stopped (no second initialisation of 150+ samples).
#[test]
fn a_saved_state_resumes_the_mixture_exactly() {
    let mut running = VehicleHarness::new(vehicle_config());
    for _ in 0..1500 {
        running.advance();
    }
    running.view();
    let state = running.pipeline.save_state().expect("a monitor to save");
    let mut resumed = VehicleHarness::new(vehicle_config());
    resumed.pipeline.resume_state(&state).unwrap();
    resumed.step = running.step;
    for _ in 0..200 {
        running.advance();
        resumed.advance();
    }
    let (a, b) = (running.view(), resumed.view());
    assert!(!b.initialising, "resumed estimates at once");
    assert_eq!(a.virtual_sensor_cm3_s, b.virtual_sensor_cm3_s);
    assert_eq!(a.forecast_cm3_s, b.forecast_cm3_s);
    assert_eq!(a.regime_probabilities, b.regime_probabilities);
    assert_eq!(a.time_s, b.time_s, "stream time goes on");
}
