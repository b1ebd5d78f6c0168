//! The monitor on vehicle samples: validation, bad input, long runs, output consistency.

use railmon_fuel::ChannelRanges;
use railmon_fuel::{
    CategoricalConfig, Channel, FuelError, FuelMonitor, FuelMonitorConfig, RailcarScenario,
    RailcarSimulator, VehicleSample,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A plausible drive: speed oscillating, fuel following load, gear from speed.
fn sample(t: usize, rng: &mut ChaCha8Rng) -> VehicleSample {
    let x = t as f64;
    let speed = (12.0 + 10.0 * (x / 40.0).sin()).max(0.0);
    let accel = 10.0 / 40.0 * (x / 40.0).cos();
    let pedal = (20.0 + 40.0 * accel + rng.random_range(-2.0..2.0)).clamp(0.0, 100.0);
    let fuel = if accel < -0.15 {
        0.0
    } else {
        0.3 + 0.03 * pedal + 0.01 * speed + rng.random_range(-0.05..0.05)
    };
    VehicleSample {
        time_s: x,
        fuel_cm3_s: Some(fuel),
        speed_m_s: Some(speed),
        pedal_pct: Some(pedal),
        engine_torque_nm: Some(3.0 * pedal + rng.random_range(-1.0..1.0)),
        engine_speed_rpm: Some(900.0 + 80.0 * speed),
        gradient_permille: None,
        gear: Some(((speed / 4.0) as i32).clamp(1, 6)),
    }
}

fn run(config: &FuelMonitorConfig, n: usize, seed: u64) -> (FuelMonitor, Vec<VehicleSample>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let samples: Vec<VehicleSample> = (0..n).map(|t| sample(t, &mut rng)).collect();
    let mut monitor = FuelMonitor::new(config).unwrap();
    for s in &samples {
        monitor.update(s).unwrap();
    }
    (monitor, samples)
}

macro_rules! rejects {
    ($name:ident, $field:literal, |$c:ident| $change:expr) => {
        #[test]
        fn $name() {
            let mut $c = FuelMonitorConfig::paper();
            $change;
            match FuelMonitor::new(&$c) {
                Err(FuelError::InvalidParameter { field, .. }) => assert_eq!(field, $field),
                other => panic!(
                    "expected {} to be rejected, got {:?}",
                    $field,
                    other.map(|_| ())
                ),
            }
        }
    };
}

rejects!(rejects_channels_without_fuel, "channels", |c| c.channels =
    vec![Channel::Speed]);
rejects!(rejects_duplicate_channels, "channels", |c| c.channels =
    vec![Channel::Fuel, Channel::Fuel]);
rejects!(rejects_one_gear_group, "categorical.gear_groups", |c| c
    .categorical =
    Some(CategoricalConfig {
        gear_groups: vec![vec![1]],
        ..Default::default()
    }));
rejects!(rejects_gear_in_two_groups, "categorical.gear_groups", |c| {
    c.categorical = Some(CategoricalConfig {
        gear_groups: vec![vec![1, 2], vec![2]],
        ..Default::default()
    })
});
rejects!(rejects_zero_components, "components", |c| c.components = 0);
rejects!(rejects_an_empty_range, "ranges", |c| c.ranges.fuel_cm3_s =
    [5.0, 5.0]);
rejects!(rejects_a_nan_range, "ranges", |c| c
    .ranges
    .gradient_permille[1] =
    f64::NAN);
rejects!(rejects_a_gap_below_the_period, "max_gap_s", |c| c
    .max_gap_s =
    0.5);
rejects!(rejects_long_regression_memory, "regression_memory", |c| c
    .regression_memory =
    11);
rejects!(rejects_unsorted_speed_bins, "speed_bins_m_s", |c| c
    .speed_bins_m_s =
    vec![5.0, 1.0]);
rejects!(rejects_nan_fuel_bins, "fuel_bins_cm3_s", |c| c
    .fuel_bins_cm3_s =
    vec![f64::NAN]);
rejects!(
    rejects_unsorted_acceleration_bins,
    "acceleration_bins_m_s2",
    |c| c.acceleration_bins_m_s2 = vec![0.3, -0.3]
);
rejects!(rejects_zero_switching_memory, "switching_memory", |c| c
    .switching_memory =
    0);
rejects!(rejects_huge_switching_memory, "switching_memory", |c| c
    .switching_memory =
    20);
rejects!(rejects_too_few_init_samples, "init_samples", |c| c
    .init_samples =
    2);
rejects!(rejects_too_many_init_iterations, "init_iterations", |c| c
    .init_iterations =
    5000);
rejects!(rejects_zero_init_weight, "init_weight", |c| c.init_weight =
    0.0);
rejects!(rejects_forgetting_above_one, "forgetting", |c| c
    .forgetting =
    1.01);
rejects!(
    rejects_negative_prior_information,
    "prior_information",
    |c| c.prior_information = -1.0
);
rejects!(rejects_zero_prior_kappa, "prior_kappa", |c| c.prior_kappa =
    0.0);
rejects!(rejects_zero_dirichlet_prior, "dirichlet_prior", |c| c
    .dirichlet_prior =
    0.0);
rejects!(
    rejects_infinite_switching_stay,
    "switching_prior_stay",
    |c| c.switching_prior_stay = f64::INFINITY
);
rejects!(rejects_zero_switching_move, "switching_prior_move", |c| c
    .switching_prior_move =
    0.0);
rejects!(rejects_zero_noise_floor, "min_noise_variance", |c| c
    .min_noise_variance =
    0.0);
rejects!(rejects_zero_horizon, "forecast_horizon_steps", |c| c
    .forecast_horizon_steps =
    0);
rejects!(
    rejects_zero_regime_confirmation,
    "regime_confirm_samples",
    |c| c.regime_confirm_samples = 0
);
rejects!(rejects_zero_sample_period, "sample_period_s", |c| c
    .sample_period_s =
    0.0);

rejects!(
    rejects_a_pointer_level_that_is_no_channel,
    "pointer_levels",
    |c| c.pointer_levels = vec!["acceleration".into()]
);
rejects!(
    rejects_a_pointer_level_listed_twice,
    "pointer_levels",
    |c| c.pointer_levels = vec!["speed".into(), "speed".into()]
);

rejects!(rejects_standing_without_levels, "pointer_standing", |c| c
    .pointer_standing =
    true);
rejects!(
    rejects_standing_with_one_component,
    "pointer_standing",
    |c| {
        c.pointer_levels = vec!["fuel".into(), "speed".into()];
        c.pointer_standing = true;
        c.components = 1;
    }
);
rejects!(
    rejects_standing_without_a_level_measured_at_standstill,
    "pointer_levels",
    |c| {
        c.pointer_levels = vec!["speed".into()];
        c.pointer_standing = true;
    }
);

/// With `pointer_standing`, standstill is a regime given: every standing sample is component
/// 0's (pointer 1) and no moving one is (pointer 0), component 0 is named idle by its share of
/// standing samples (1) and the others have none. Without the option there is no share.
#[test]
fn standstill_is_the_standing_components_and_only_its() {
    // Every fifth sample stands (speed 0) between moving ones, a 12 m/s change in a second that
    // the acceleration bound refuses: opened here so that the test counts standing samples.
    let config = FuelMonitorConfig {
        components: 3,
        pointer_levels: vec!["fuel".into(), "speed".into()],
        pointer_level_min_variance: 3e-2,
        pointer_standing: true,
        ranges: ChannelRanges {
            acceleration_m_s2: [-100.0, 100.0],
            ..FuelMonitorConfig::paper().ranges
        },
        ..FuelMonitorConfig::paper()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let samples: Vec<VehicleSample> = (0..1800)
        .map(|t| {
            let s = sample(t, &mut rng);
            match t % 5 {
                0 => VehicleSample {
                    speed_m_s: Some(0.0),
                    ..s
                },
                _ => s,
            }
        })
        .collect();
    let mut monitor = FuelMonitor::new(&config).unwrap();
    let mut checked = 0;
    for s in &samples {
        let e = monitor.update(s).unwrap();
        if let Some(m) = &e.mixture {
            let standing = s.speed_m_s == Some(0.0);
            assert_eq!(
                m.regime_probabilities[0],
                f64::from(u8::from(standing)),
                "{s:?}"
            );
            checked += 1;
        }
    }
    assert!(checked > 1000, "{checked}");
    let shares: Vec<_> = (monitor.operating_points().iter())
        .map(|p| p.standing_share)
        .collect();
    assert_eq!(shares, vec![Some(1.0), Some(0.0), Some(0.0)]);
    let names = monitor.regime_names();
    assert_eq!(names[0].regime, railmon_fuel::RegimeName::Idle);
    assert!(names[1..]
        .iter()
        .all(|n| n.regime != railmon_fuel::RegimeName::Idle));
    let without = FuelMonitorConfig {
        pointer_standing: false,
        ..config
    };
    let mut monitor = FuelMonitor::new(&without).unwrap();
    for s in &samples {
        monitor.update(s).unwrap();
    }
    assert_eq!(monitor.operating_points()[0].standing_share, None);
}

#[test]
fn pointer_levels_index_y_as_the_monitor_lays_it_out() {
    // y = [fuel, speed, gradient, acceleration, power_demand, speed_squared] (fuel first, then
    // the other measured channels in order, then the derived ones).
    let c = FuelMonitorConfig {
        channels: vec![Channel::Speed, Channel::Fuel, Channel::Gradient],
        pointer_levels: vec!["acceleration".into(), "speed".into(), "fuel".into()],
        ..FuelMonitorConfig::railcar()
    };
    assert_eq!(c.pointer_level_indices().unwrap(), vec![3, 1, 0]);
}

#[test]
fn config_errors_name_field_and_value() {
    let c = FuelMonitorConfig {
        forgetting: 1.5,
        ..Default::default()
    };
    let msg = c.validate().unwrap_err().to_string();
    assert!(msg.contains("forgetting") && msg.contains("1.5"), "{msg}");
    assert!(FuelMonitorConfig::default().validate().is_ok());
    assert!(FuelMonitorConfig::paper().validate().is_ok());
    // An acceleration range must contain 0 (a vehicle keeping its speed).
    let mut c = FuelMonitorConfig::railcar();
    c.ranges.acceleration_m_s2 = [0.5, 2.0];
    let msg = c.validate().unwrap_err().to_string();
    assert!(msg.contains("acceleration_m_s2 = [0.5, 2]"), "{msg}");
}

#[test]
fn config_parses_from_toml_and_rejects_unknown_fields() {
    let c: FuelMonitorConfig =
        toml::from_str("components = 4\nchannels = [\"fuel\", \"engine_speed\"]").unwrap();
    assert_eq!(c.components, 4);
    assert_eq!(c.channels, vec![Channel::Fuel, Channel::EngineSpeed]);
    assert!(toml::from_str::<FuelMonitorConfig>("component = 4").is_err());
}

/// A locomotive-scale drive: notch 0-8, fuel 5-200 cm^3/s (a ~3 MW engine from idle to full
/// power), speed up to 33 m/s, gradient +-10 per mille.
fn locomotive_sample(t: usize, time_scale: f64) -> VehicleSample {
    let x = t as f64;
    let notch = (4.0 + 4.0 * (x / 90.0).sin()).round() as i32;
    VehicleSample {
        time_s: x * time_scale,
        fuel_cm3_s: Some(5.0 + 195.0 * f64::from(notch) / 8.0 + (x / 7.0).sin()),
        speed_m_s: Some(17.0 + 16.0 * (x / 300.0).sin()),
        gradient_permille: Some(10.0 * (x / 500.0).cos()),
        gear: Some(notch),
        ..Default::default()
    }
}

#[test]
fn a_locomotive_profile_runs_with_the_railcar_ranges_and_is_refused_with_a_cars() {
    let mut railcar = FuelMonitor::new(&FuelMonitorConfig::railcar()).unwrap();
    let mut max_fuel: f64 = 0.0;
    for t in 0..600 {
        let s = locomotive_sample(t, 1.0);
        max_fuel = max_fuel.max(s.fuel_cm3_s.unwrap());
        let e = railcar.update(&s).unwrap();
        assert_eq!(e.samples, t as u64 + 1);
    }
    assert!(max_fuel > 190.0, "the profile reaches {max_fuel}");
    let e = railcar.estimate().mixture.clone().unwrap();
    assert!(e.virtual_sensor_cm3_s.is_finite() && e.forecast_cm3_s.iter().all(|f| f.is_finite()));
    // The road car's ranges refuse it, naming the channel, the value and the range.
    let car = FuelMonitorConfig {
        channels: vec![Channel::Fuel, Channel::Speed, Channel::Gradient],
        ..FuelMonitorConfig::default()
    };
    let mut monitor = FuelMonitor::new(&car).unwrap();
    let refused = (0..600)
        .filter(|&t| monitor.update(&locomotive_sample(t, 1.0)).is_err())
        .count();
    assert!(refused > 100, "{refused} refused");
    let err = FuelMonitor::new(&car)
        .unwrap()
        .update(&locomotive_sample(780, 1.0))
        .unwrap_err();
    let msg = err.to_string();
    assert!(msg.contains("`fuel`") && msg.contains("[-1, 100]"), "{msg}");
}

#[test]
fn time_stamps_in_milliseconds_are_refused_after_the_first_sample() {
    let mut monitor = FuelMonitor::new(&FuelMonitorConfig::railcar()).unwrap();
    monitor.update(&locomotive_sample(0, 1000.0)).unwrap();
    for t in 1..5 {
        let err = monitor.update(&locomotive_sample(t, 1000.0)).unwrap_err();
        assert!(
            matches!(err, FuelError::SamplePeriod { step_s, .. } if step_s == 1000.0 * t as f64)
        );
        assert!(err.to_string().contains("ms?"), "{err}");
    }
    assert_eq!(monitor.estimate().samples, 1);
    // A gap of whole periods within `max_gap_s` is bridged (a lost frame).
    monitor.update(&locomotive_sample(3, 1.0)).unwrap();
}

/// A railcar's speed in km/h (the locomotive profile departing from standing at 0.6 m/s^2,
/// i.e. 2.16 "m/s^2") is refused by the acceleration bound while its speed is still far inside
/// the range, nothing of it reaches the statistics, and the same monitor takes the m/s data
/// that follow: the reference is the last accepted sample.
#[test]
fn a_railcar_speed_in_km_h_is_refused_by_its_acceleration_and_changes_nothing() {
    let departure = |t: usize, factor: f64| VehicleSample {
        speed_m_s: Some((0.6 * t as f64).min(30.0) * factor),
        ..locomotive_sample(t, 1.0)
    };
    let config = FuelMonitorConfig::railcar();
    // Sees only the samples the other one accepts: t = 3..9 never arrive (a gap).
    let mut clean = FuelMonitor::new(&config).unwrap();
    let mut faulty = FuelMonitor::new(&config).unwrap();
    for t in 0..3 {
        clean.update(&departure(t, 1.0)).unwrap();
        faulty.update(&departure(t, 1.0)).unwrap();
    }
    for t in 3..10 {
        let err = faulty.update(&departure(t, 3.6)).unwrap_err();
        // Judged against t = 2 (1.2 m/s), over t - 2 seconds.
        let want = (0.6 * 3.6 * t as f64 - 1.2) / (t - 2) as f64;
        match err {
            FuelError::AccelerationOutOfRange {
                acceleration_m_s2,
                previous_speed_m_s,
                step_s,
                ..
            } => {
                assert!((acceleration_m_s2 - want).abs() < 1e-9, "{err}");
                assert_eq!((previous_speed_m_s, step_s), (1.2, (t - 2) as f64));
            }
            other => panic!("{other}"),
        }
    }
    assert_eq!(faulty.estimate().samples, 3);
    // The good data after the refused run: 0.6 m/s^2 on average since t = 2, accepted, and
    // the same estimates as without the refused samples, to the bit.
    for t in 10..200 {
        let a = clean.update(&departure(t, 1.0)).unwrap().clone();
        let b = faulty.update(&departure(t, 1.0)).unwrap().clone();
        assert_eq!(a, b, "diverged at {t}");
    }
    assert!(faulty.estimate().mixture.is_some());
}

#[test]
fn bad_samples_are_errors_and_leave_the_state_untouched() {
    let config = FuelMonitorConfig::paper();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let samples: Vec<VehicleSample> = (0..450).map(|t| sample(t, &mut rng)).collect();
    let mut clean = FuelMonitor::new(&config).unwrap();
    let mut faulty = FuelMonitor::new(&config).unwrap();
    for (t, s) in samples.iter().enumerate() {
        if t % 50 == 7 {
            let mut bad = *s;
            match (t / 50) % 9 {
                0 => bad.fuel_cm3_s = Some(f64::NAN),
                1 => bad.engine_torque_nm = Some(f64::INFINITY),
                2 => bad.pedal_pct = None,
                3 => bad.gear = Some(9),
                4 => bad.gear = None,
                5 => bad.time_s += 0.5,
                // 320 km/h read as m/s: above the road car's 70 m/s.
                6 => bad.speed_m_s = Some(320.0),
                // 13 m/s faster than a second ago (inside the range): 13 m/s^2, beyond a
                // road car's 12.
                7 => bad.speed_m_s = Some(samples[t - 1].speed_m_s.unwrap() + 13.0),
                _ => bad.time_s = -1.0,
            }
            let err = faulty.update(&bad).unwrap_err();
            match (t / 50) % 9 {
                0 => assert!(matches!(
                    err,
                    FuelError::NonFinite {
                        channel: Channel::Fuel,
                        ..
                    }
                )),
                1 => assert!(matches!(
                    err,
                    FuelError::NonFinite {
                        channel: Channel::EngineTorque,
                        ..
                    }
                )),
                2 => assert!(matches!(
                    err,
                    FuelError::MissingChannel {
                        channel: Channel::Pedal,
                        ..
                    }
                )),
                3 => assert!(matches!(err, FuelError::UnknownCategory { gear: 9, .. })),
                4 => assert!(matches!(err, FuelError::MissingGear { .. })),
                5 => assert!(matches!(err, FuelError::SamplePeriod { .. }), "{err}"),
                6 => assert!(matches!(
                    err,
                    FuelError::OutOfRange {
                        channel: Channel::Speed,
                        max: 70.0,
                        ..
                    }
                )),
                7 => assert!(
                    matches!(err, FuelError::AccelerationOutOfRange { max: 12.0, .. }),
                    "{err}"
                ),
                _ => assert!(matches!(err, FuelError::TimeNotIncreasing { .. })),
            }
        }
        let a = clean.update(s).unwrap().clone();
        let b = faulty.update(s).unwrap().clone();
        assert_eq!(a, b, "state diverged after a rejected sample at step {t}");
    }
    assert!(clean.estimate().mixture.is_some());
}

#[test]
fn a_gear_category_never_seen_keeps_a_finite_prior_probability() {
    // Only gears 1..3 for 300 s, then gear 6 (category 4 of the paper's grouping) appears for
    // the first time: it has only its Dirichlet prior, so the step is finite, the weights still
    // sum to one, and the category's counts grow by exactly the weights (sum 1, eq. 12).
    let config = FuelMonitorConfig::paper();
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let mut monitor = FuelMonitor::new(&config).unwrap();
    for t in 0..300 {
        let mut s = sample(t, &mut rng);
        s.gear = Some(s.gear.unwrap().min(3));
        monitor.update(&s).unwrap();
    }
    let added = |monitor: &FuelMonitor| -> f64 {
        let tables = monitor.mixture().unwrap().categorical();
        tables
            .iter()
            .map(|t| {
                (0..t.rows())
                    .map(|q| t.count(q, 4) - config.dirichlet_prior)
                    .sum::<f64>()
            })
            .sum()
    };
    assert!(added(&monitor).abs() < 1e-12);
    let mut s = sample(300, &mut rng);
    s.gear = Some(6);
    let e = monitor.update(&s).unwrap();
    let m = e.mixture.as_ref().unwrap();
    assert!(m.regime_probabilities.iter().all(|p| p.is_finite()));
    assert!((m.regime_probabilities.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    assert!(m.virtual_sensor_cm3_s.is_finite() && m.one_step_forecast_cm3_s.is_finite());
    assert!((added(&monitor) - 1.0).abs() < 1e-12);
}

#[test]
fn monitor_outputs_stay_finite_over_extreme_samples() {
    // Extreme but plausible inputs: values jumping between the ends of each channel's
    // plausible range, long constant runs (zero variance) and exact zeros, gear and fuel
    // levels changing at random. Default config (forgetting on) and 3 components. (The 10^6-step
    // version on the mixture itself is in tests/mixture.rs.)
    // The speed jumps from end to end of its range in a second, which the acceleration bound
    // refuses: opened here so that these extremes reach the statistics.
    let ranges = ChannelRanges {
        acceleration_m_s2: [-100.0, 100.0],
        ..ChannelRanges::default()
    };
    let config = FuelMonitorConfig {
        categorical: Some(CategoricalConfig::default()),
        forecast_horizon_steps: 1,
        ranges,
        ..Default::default()
    };
    let mut monitor = FuelMonitor::new(&config).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    let pick = |rng: &mut ChaCha8Rng, ch: Channel, mode: u32| {
        let [lo, hi] = config.ranges.of(ch);
        match mode {
            0 => lo,
            1 => hi,
            2 => 0.0,
            _ => rng.random_range(lo..=hi),
        }
    };
    let mut mode = 0;
    for t in 0..100_000usize {
        if t % 1000 == 0 {
            mode = rng.random_range(0..5u32);
        }
        let m = if mode == 4 {
            rng.random_range(0..4u32)
        } else {
            mode
        };
        let s = VehicleSample {
            time_s: t as f64,
            fuel_cm3_s: Some(pick(&mut rng, Channel::Fuel, m)),
            speed_m_s: Some(pick(&mut rng, Channel::Speed, m)),
            gear: Some(rng.random_range(-1..=6)),
            ..Default::default()
        };
        let e = monitor.update(&s).unwrap();
        if let Some(m) = &e.mixture {
            let sum: f64 = m.regime_probabilities.iter().sum();
            assert!((sum - 1.0).abs() < 1e-9, "step {t}: weights sum to {sum}");
            assert!(
                m.regime_probabilities
                    .iter()
                    .all(|p| p.is_finite() && *p >= 0.0),
                "step {t}"
            );
            assert!(
                m.one_step_forecast_cm3_s.is_finite() && m.virtual_sensor_cm3_s.is_finite(),
                "step {t}"
            );
        }
    }
}

#[test]
fn horizon_one_forecast_is_the_next_one_step_forecast() {
    let (mut monitor, _) = run(&FuelMonitorConfig::paper(), 300, 3);
    let path = monitor
        .estimate()
        .mixture
        .as_ref()
        .unwrap()
        .forecast_cm3_s
        .clone();
    assert_eq!(path.len(), 10);
    let mut rng = ChaCha8Rng::seed_from_u64(77);
    let next = monitor.update(&sample(300, &mut rng)).unwrap();
    assert_eq!(
        next.mixture.as_ref().unwrap().one_step_forecast_cm3_s,
        path[0]
    );
}

#[test]
fn fuel_only_virtual_sensor_is_the_one_step_forecast() {
    // Without the blend (which moves the forecast, not the virtual sensor) and without the
    // channels derived from the speed.
    let config = FuelMonitorConfig {
        channels: vec![Channel::Fuel],
        derived_channels: Vec::new(),
        forecast_blend: false,
        ..Default::default()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let mut monitor = FuelMonitor::new(&config).unwrap();
    let mut checked = 0;
    for t in 0..400 {
        let e = monitor.update(&sample(t, &mut rng)).unwrap();
        if let Some(m) = &e.mixture {
            assert!((m.virtual_sensor_cm3_s - m.one_step_forecast_cm3_s).abs() < 1e-9);
            checked += 1;
        }
    }
    assert_eq!(checked, 250);
}

#[test]
fn cumulative_fuel_integrates_the_measured_rate() {
    let (monitor, samples) = run(&FuelMonitorConfig::default(), 200, 8);
    let expected: f64 = samples.iter().map(|s| s.fuel_cm3_s.unwrap()).sum();
    assert!((monitor.estimate().cumulative_fuel_cm3 - expected).abs() < 1e-9);
    assert_eq!(monitor.estimate().samples, 200);
}

#[test]
fn paper_setting_separates_fuel_cut_off_from_driving() {
    // On the synthetic drive the cut-off (fuel exactly 0 while decelerating) is a regime of its
    // own: the mixture's virtual sensor beats a single regression there.
    let config = FuelMonitorConfig::paper();
    let (mut mix, mut one) = (
        FuelMonitor::new(&config).unwrap(),
        FuelMonitor::new(&config.single_regression()).unwrap(),
    );
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let (mut se_mix, mut se_one) = (0.0, 0.0);
    for t in 0..2000 {
        let s = sample(t, &mut rng);
        let truth = s.fuel_cm3_s.unwrap();
        let a = mix.update(&s).unwrap().mixture.clone();
        let b = one.update(&s).unwrap().mixture.clone();
        if let (Some(a), Some(b)) = (a, b) {
            se_mix += (a.virtual_sensor_cm3_s - truth).powi(2);
            se_one += (b.virtual_sensor_cm3_s - truth).powi(2);
        }
    }
    assert!(se_mix < 0.8 * se_one, "mixture {se_mix} vs single {se_one}");
}

/// Runs the synthetic drive from t = 160 to 1000 and checks every estimate's reported regime
/// and change flag against the rule written out here: the reported regime follows the active
/// (most probable) one once that has been active for `confirm` samples in a row. Returns the
/// changes of the active and of the reported regime.
fn check_regime_confirmation(confirm: usize) -> (usize, usize) {
    let config = FuelMonitorConfig {
        regime_confirm_samples: confirm,
        ..FuelMonitorConfig::paper()
    };
    let (mut monitor, _) = run(&config, 160, 12);
    let mut rng = ChaCha8Rng::seed_from_u64(13);
    let first = monitor.estimate().mixture.clone().unwrap();
    let (mut reported, mut active) = (first.regime, first.active_regime);
    let mut streak = 1;
    let (mut active_changes, mut reported_changes) = (0, 0);
    for t in 160..1000 {
        let e = monitor
            .update(&sample(t, &mut rng))
            .unwrap()
            .mixture
            .clone()
            .unwrap();
        if e.active_regime == active {
            streak += 1;
        } else {
            (active, streak) = (e.active_regime, 1);
            active_changes += 1;
        }
        let expected = if streak >= confirm { active } else { reported };
        assert_eq!(e.regime, expected, "t = {t}");
        let change = (expected != reported).then_some((reported, expected));
        assert_eq!(
            e.regime_change.map(|c| (c.from_regime, c.to_regime)),
            change,
            "t = {t}"
        );
        if let Some(c) = e.regime_change {
            assert_eq!(c.probability, e.regime_probabilities[c.to_regime]);
        }
        reported_changes += usize::from(change.is_some());
        reported = expected;
    }
    (active_changes, reported_changes)
}

#[test]
fn regime_changes_are_flagged_once_per_confirmed_change() {
    // Unconfirmed (1 sample): the reported regime is the pointer estimate itself.
    let (active, reported) = check_regime_confirmation(1);
    assert!(active > 0, "the synthetic drive switches regime");
    assert_eq!(reported, active);
    // Confirmed over 5 samples: fewer changes, each still flagged once.
    let (active, reported) = check_regime_confirmation(5);
    assert!(reported > 0 && reported < active, "{reported} of {active}");
}

/// Issue 14 item 3: a component's operating point is the mean of the data it absorbed. With
/// one component and no forgetting every sample has weight 1, so the operating point is the
/// plain mean of fuel, speed and the derived acceleration over the samples the statistics hold
/// (all but the first `regression_memory`, which only fill the regressor).
#[test]
fn the_operating_point_of_one_component_is_the_mean_of_its_data() {
    let config = FuelMonitorConfig {
        components: 1,
        forgetting: 1.0,
        ..FuelMonitorConfig::default()
    };
    let n = 400;
    let (monitor, samples) = run(&config, n, 21);
    let used = &samples[config.regression_memory..];
    let mean = |f: &dyn Fn(usize) -> f64| {
        (config.regression_memory..n).map(f).sum::<f64>() / used.len() as f64
    };
    let fuel = mean(&|t| samples[t].fuel_cm3_s.unwrap());
    let speed = mean(&|t| samples[t].speed_m_s.unwrap());
    let acceleration = mean(&|t| samples[t].speed_m_s.unwrap() - samples[t - 1].speed_m_s.unwrap());
    let points = monitor.operating_points();
    assert_eq!(points.len(), 1);
    let p = points[0];
    assert!((p.samples - used.len() as f64).abs() < 1e-6, "{p:?}");
    assert!(
        (p.fuel_cm3_s - fuel).abs() < 1e-9 * fuel.abs().max(1.0),
        "{p:?} {fuel}"
    );
    assert!(
        (p.speed_m_s.unwrap() - speed).abs() < 1e-9 * speed.max(1.0),
        "{p:?}"
    );
    assert!(
        (p.acceleration_m_s2.unwrap() - acceleration).abs() < 1e-9,
        "{p:?}"
    );
    // The paper's setting has no acceleration channel: the speed now minus a lag ago.
    let paper = FuelMonitorConfig {
        components: 1,
        ..FuelMonitorConfig::paper()
    };
    let (monitor, samples) = run(&paper, n, 21);
    let mean_change = (1..n)
        .map(|t| samples[t].speed_m_s.unwrap() - samples[t - 1].speed_m_s.unwrap())
        .sum::<f64>()
        / (n - 1) as f64;
    let a = monitor.operating_points()[0].acceleration_m_s2.unwrap();
    assert!((a - mean_change).abs() < 1e-9, "{a} {mean_change}");
}

/// Names are a function of the statistics: a monitor restored from its serialised state (as
/// the service's snapshot does) names its components as the running one, now and after more
/// samples; and every estimate's names are the monitor's.
#[test]
fn regime_names_survive_a_restore_and_follow_the_statistics() {
    let (mut running, _) = run(&FuelMonitorConfig::default(), 600, 31);
    let saved = serde_json::to_string(&running).unwrap();
    let mut restored: FuelMonitor = serde_json::from_str(&saved).unwrap();
    assert_eq!(restored.regime_names(), running.regime_names());
    assert_eq!(restored.operating_points(), running.operating_points());
    let mut rng = ChaCha8Rng::seed_from_u64(32);
    for t in 600..900 {
        let s = sample(t, &mut rng);
        let a = running.update(&s).unwrap().mixture.clone().unwrap();
        let b = restored.update(&s).unwrap().mixture.clone().unwrap();
        assert_eq!(a, b, "t = {t}");
        assert_eq!(a.regime_names, running.regime_names());
        assert_eq!(a.regime_name, a.regime_names[a.regime]);
        if let Some(c) = a.regime_change {
            assert_eq!(
                (c.from_name, c.to_name),
                (a.regime_names[c.from_regime], a.regime_names[c.to_regime])
            );
        }
    }
}

/// The estimate keeps the predictive terms and computes the intervals when asked: the 1-step
/// predictive is the first step of the previous estimate's forecast predictive (same terms,
/// same interval to the bit), each interval holds 90 % of its mixture (the CDF at its ends is
/// 0.05 and 0.95, or beyond where an end was projected onto the fuel's range), and an estimate that went through serde gives the same intervals (the
/// service's snapshot and an offline re-read see what the live path saw).
#[test]
fn intervals_asked_for_later_are_the_quantiles_of_the_kept_terms() {
    let config = FuelMonitorConfig::default();
    assert!(config.forecast_blend, "the blend pools two mixtures' terms");
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let mut monitor = FuelMonitor::new(&config).unwrap();
    let mut previous: Option<railmon_fuel::MixtureEstimate> = None;
    let mut checked = 0;
    for t in 0..400 {
        let e = monitor.update(&sample(t, &mut rng)).unwrap().clone();
        let Some(m) = e.mixture else { continue };
        match &previous {
            Some(p) => {
                assert_eq!(m.one_step_predictive, p.forecast_predictive[0]);
                let (now, then) = (m.one_step_interval_cm3_s(), p.forecast_interval_cm3_s()[0]);
                assert_eq!(now.lower.to_bits(), then.lower.to_bits());
                assert_eq!(now.upper.to_bits(), then.upper.to_bits());
            }
            // The forecast made when the initial samples were complete.
            None => assert!(m.one_step_interval_cm3_s().lower.is_finite()),
        }
        let mut asked = vec![(
            &m.virtual_sensor_predictive,
            m.virtual_sensor_interval_cm3_s(),
        )];
        asked.extend(
            m.forecast_predictive
                .iter()
                .zip(m.forecast_interval_cm3_s()),
        );
        // An end inside the fuel's range is the quantile; one on its edge was projected there
        // (the quantile lay beyond it).
        let [min, max] = m.fuel_range_cm3_s;
        for (terms, interval) in asked {
            let cdf = |x: f64| terms.iter().map(|s| s.weight * s.cdf(x)).sum::<f64>();
            let (lower, upper) = (cdf(interval.lower), cdf(interval.upper));
            let what = format!("t {t}: {interval:?}, CDF {lower} .. {upper}");
            match interval.lower > min {
                true => assert!((lower - 0.05).abs() < 1e-6, "{what}"),
                false => assert!(lower >= 0.05 - 1e-6, "{what}"),
            }
            match interval.upper < max {
                true => assert!((upper - 0.95).abs() < 1e-6, "{what}"),
                false => assert!(upper <= 0.95 + 1e-6, "{what}"),
            }
        }
        let reread: railmon_fuel::MixtureEstimate =
            serde_json::from_str(&serde_json::to_string(&m).unwrap()).unwrap();
        assert_eq!(
            reread.forecast_interval_cm3_s(),
            m.forecast_interval_cm3_s()
        );
        assert_eq!(
            reread.virtual_sensor_interval_cm3_s(),
            m.virtual_sensor_interval_cm3_s()
        );
        previous = Some(m);
        checked += 1;
    }
    assert!(checked > 200, "{checked}");
}

/// What the step keeps between samples outside the snapshot (the forecast's first predictions
/// and work space, the switching probabilities, the spare statistics) changes no number: a
/// monitor restored from its serialised state, which starts without them, gives the running
/// one's estimates and intervals to the bit (`{:?}` prints each `f64` exactly), with the
/// paper's gear and five lagged channels and with the default's blend and forgetting.
#[test]
fn a_restored_monitor_continues_to_the_bit() {
    for (config, seed) in [
        (FuelMonitorConfig::paper(), 41),
        (FuelMonitorConfig::default(), 42),
    ] {
        let (mut running, _) = run(&config, 400, seed);
        let mut restored: FuelMonitor =
            serde_json::from_str(&serde_json::to_string(&running).unwrap()).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(seed + 100);
        for t in 400..600 {
            let s = sample(t, &mut rng);
            let a = running.update(&s).unwrap().clone();
            let b = restored.update(&s).unwrap().clone();
            assert_eq!(format!("{a:?}"), format!("{b:?}"), "t = {t}");
            let m = a.mixture.as_ref().unwrap();
            let n = b.mixture.as_ref().unwrap();
            assert_eq!(
                format!("{:?}", m.forecast_interval_cm3_s()),
                format!("{:?}", n.forecast_interval_cm3_s())
            );
        }
    }
}

/// Every published fuel value (0-step, virtual sensor, each forecast step, every interval end)
/// lies in the fuel's range with its lower end at 0, and the integrated virtual fuel never
/// falls. The case that found it: the shipped railcar route with a light train (150 t, a
/// condition the preset was not set on), where a component that had just become active took
/// the virtual sensor to -95.75 cm^3/s at t = 244 s before the projection (docs/fuel.md, "Fuel
/// estimates in the fuel's range").
#[test]
fn every_published_fuel_value_is_in_the_fuel_range() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../config/scenarios/fuel-railcar.toml"
    );
    let mut scenario = RailcarScenario::from_toml_str(&std::fs::read_to_string(path).unwrap())
        .expect("the shipped scenario");
    scenario.railcar.mass_t = 150.0;
    let mut simulator = RailcarSimulator::new(&scenario).unwrap();
    let mut monitor = FuelMonitor::new(&scenario.monitor).unwrap();
    let [_, max] = scenario.monitor.ranges.fuel_cm3_s;
    let in_range = |what: &str, t: f64, v: f64| {
        assert!((0.0..=max).contains(&v), "{what} at t = {t}: {v}");
    };
    let mut cumulative = 0.0;
    let mut estimated = 0;
    for _ in 0..400 {
        let (sample, _) = simulator.step().unwrap();
        let e = monitor.update(&sample).unwrap();
        let Some(m) = &e.mixture else { continue };
        let t = sample.time_s;
        in_range("0-step", t, m.zero_step_cm3_s);
        in_range("virtual sensor", t, m.virtual_sensor_cm3_s);
        m.forecast_cm3_s
            .iter()
            .for_each(|&f| in_range("forecast", t, f));
        let ends = std::iter::once(m.virtual_sensor_interval_cm3_s())
            .chain(m.forecast_interval_cm3_s())
            .flat_map(|i| [i.lower, i.upper]);
        ends.for_each(|v| in_range("interval end", t, v));
        assert!(m.cumulative_virtual_fuel_cm3 >= cumulative, "t = {t}");
        cumulative = m.cumulative_virtual_fuel_cm3;
        estimated += 1;
    }
    assert!(estimated > 200, "{estimated}");
}
