//! The vehicle simulator against its own physics and the trace it follows.

use std::collections::BTreeMap;

use railmon_fuel::{
    DriveCycle, DriverStyle, FuelError, FuelMonitorConfig, VehicleParameters, VehicleSample,
    VehicleScenario, VehicleSimulator, VehicleTruth,
};

/// Stand 10 s, accelerate at 1 m/s^2 to 20 m/s, cruise 60 s, brake at 1 m/s^2, stand 10 s.
fn trapezoid() -> DriveCycle {
    let mut v = vec![0.0; 10];
    v.extend((1..=20).map(|k| k as f64));
    v.extend(std::iter::repeat_n(20.0, 60));
    v.extend((0..20).rev().map(|k| k as f64));
    v.extend(std::iter::repeat_n(0.0, 10));
    DriveCycle {
        grade_rad: vec![0.0; v.len()],
        speed_m_s: v,
    }
}

fn scenario(driver: &str, seed: u64) -> VehicleScenario {
    let text = format!(
        "seed = {seed}\ndrive_cycle_dir = \".\"\n\
         [[segment]]\ncycle = \"trapezoid\"\ndriver = \"{driver}\"\nregime = \"a\"\n\
         [[segment]]\ncycle = \"trapezoid\"\ndriver = \"{driver}\"\nregime = \"b\"\nmax_s = 50\n"
    );
    VehicleScenario::from_toml_str(&text).unwrap()
}

fn simulate(driver: &str, seed: u64) -> Vec<(VehicleSample, VehicleTruth)> {
    let cycles = BTreeMap::from([("trapezoid".to_string(), trapezoid())]);
    let mut sim = VehicleSimulator::new(&scenario(driver, seed), &cycles).unwrap();
    assert_eq!(sim.len(), 120 + 50);
    std::iter::from_fn(|| sim.step()).collect()
}

#[test]
fn follows_the_trace_and_labels_the_segments() {
    for driver in ["eco", "sporty"] {
        let run = simulate(driver, 1);
        assert_eq!(run.len(), 170);
        let worst = run
            .iter()
            .map(|(s, t)| (s.speed_m_s.unwrap() - t.target_speed_m_s).abs())
            .fold(0.0, f64::max);
        assert!(worst < 2.5, "{driver}: speed error up to {worst} m/s");
        assert!(
            run[..120].iter().all(|(_, t)| t.regime == 0)
                && run[120..].iter().all(|(_, t)| t.regime == 1)
        );
        let style = if driver == "eco" {
            DriverStyle::Eco
        } else {
            DriverStyle::Sporty
        };
        assert!(run.iter().all(|(_, t)| t.driver == style));
    }
}

#[test]
fn engine_speed_matches_gear_ratio_and_gears_are_in_range() {
    let p = VehicleParameters::default();
    for (s, _) in simulate("sporty", 2) {
        let gear = s.gear.unwrap();
        assert!((0..=6).contains(&gear));
        let v = s.speed_m_s.unwrap();
        let rpm = s.engine_speed_rpm.unwrap();
        if gear >= 1 && v > 3.0 {
            let expected = v / p.wheel_radius_m * 60.0 / std::f64::consts::TAU
                * p.gear_ratios[gear as usize - 1]
                * p.final_drive;
            assert!(
                (rpm - expected.max(p.idle_rpm)).abs() < 1e-6 * expected,
                "gear {gear} v {v}: {rpm} vs {expected}"
            );
        } else {
            assert!(rpm >= p.idle_rpm - 1e-9);
        }
    }
}

#[test]
fn fuel_is_cut_off_on_overrun_and_idles_when_standing() {
    let run = simulate("eco", 3);
    // Braking from 20 m/s (t = 90..110): pedal released, engine above the cut-off speed.
    let braking: Vec<_> = run[92..105]
        .iter()
        .filter(|(s, _)| s.pedal_pct == Some(0.0) && s.speed_m_s.unwrap() > 5.0)
        .collect();
    assert!(braking.len() >= 5, "only {} overrun samples", braking.len());
    assert!(braking
        .iter()
        .all(|(s, t)| s.fuel_cm3_s == Some(0.0) && t.fuel_true_cm3_s == 0.0));
    assert!(
        braking
            .iter()
            .all(|(s, _)| s.engine_torque_nm.unwrap() < 0.0),
        "engine braking"
    );
    // Standing: neutral, idle fuel (about 0.1 cm^3/s for a 2.5 l engine), no torque.
    for (s, t) in &run[2..9] {
        assert_eq!(s.gear, Some(0));
        assert!(
            (0.03..0.3).contains(&t.fuel_true_cm3_s),
            "idle fuel {}",
            t.fuel_true_cm3_s
        );
        assert_eq!(s.engine_torque_nm, Some(0.0));
    }
    // Cruising at 20 m/s: road load ~ 0.009 m g + 0.5 rho CdA v^2 = 141 + 173 N, 6.3 kW at the
    // wheels -> about 0.8 cm^3/s with friction and a 34 % engine.
    let cruise: f64 = run[60..85]
        .iter()
        .map(|(_, t)| t.fuel_true_cm3_s)
        .sum::<f64>()
        / 25.0;
    assert!((0.5..1.2).contains(&cruise), "cruise fuel {cruise}");
}

#[test]
fn sporty_drivers_rev_higher_and_burn_more() {
    let eco = simulate("eco", 4);
    let sporty = simulate("sporty", 4);
    let mean = |run: &[(VehicleSample, VehicleTruth)], f: fn(&VehicleSample) -> f64| {
        run[10..40].iter().map(|(s, _)| f(s)).sum::<f64>() / 30.0
    };
    assert!(
        mean(&sporty, |s| s.engine_speed_rpm.unwrap())
            > mean(&eco, |s| s.engine_speed_rpm.unwrap()) + 300.0
    );
    assert!(mean(&sporty, |s| s.fuel_cm3_s.unwrap()) > mean(&eco, |s| s.fuel_cm3_s.unwrap()));
}

#[test]
fn runs_are_reproducible_per_seed() {
    assert_eq!(simulate("sporty", 7), simulate("sporty", 7));
    assert_ne!(simulate("sporty", 7), simulate("sporty", 8));
}

#[test]
fn bad_scenarios_and_parameters_are_errors() {
    assert!(matches!(
        VehicleScenario::from_toml_str("seed = 1\ndrive_cycle_dir = \".\"\nsegment = []\n"),
        Err(FuelError::InvalidParameter {
            field: "segment",
            ..
        })
    ));
    assert!(matches!(
        VehicleScenario::from_toml_str("seed = 1\n"),
        Err(FuelError::Scenario(_))
    ));
    let mut s = scenario("eco", 1);
    s.vehicle.gear_ratios = vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0];
    assert!(matches!(
        s.validate(),
        Err(FuelError::InvalidParameter {
            field: "vehicle.gear_ratios",
            ..
        })
    ));
    let mut s = scenario("eco", 1);
    s.vehicle.mass_kg = f64::NAN;
    assert!(matches!(
        s.validate(),
        Err(FuelError::InvalidParameter {
            field: "vehicle.mass_kg",
            ..
        })
    ));
    let mut s = scenario("eco", 1);
    s.vehicle.driveline_efficiency = 1.5;
    assert!(matches!(
        s.validate(),
        Err(FuelError::InvalidParameter {
            field: "vehicle.driveline_efficiency",
            ..
        })
    ));
    // A cycle the caller did not supply, or one with a NaN.
    let s = scenario("eco", 1);
    assert!(matches!(
        VehicleSimulator::new(&s, &BTreeMap::new()),
        Err(FuelError::Scenario(_))
    ));
    let mut bad = trapezoid();
    bad.speed_m_s[5] = f64::NAN;
    assert!(matches!(
        VehicleSimulator::new(&s, &BTreeMap::from([("trapezoid".to_string(), bad)])),
        Err(FuelError::Scenario(_))
    ));
}

/// Issue 8: a scenario without `[monitor]` is analysed with the one default; `preset` starts
/// from a named preset and single keys override it; an unknown preset names the known ones.
#[test]
fn a_scenario_monitor_is_the_default_or_a_named_preset_with_overrides() {
    let base = "seed = 1\ndrive_cycle_dir = \".\"\n\
                [[segment]]\ncycle = \"trapezoid\"\ndriver = \"eco\"\nregime = \"a\"\n";
    let monitor = |table: &str| VehicleScenario::from_toml_str(&format!("{base}{table}"));
    assert_eq!(monitor("").unwrap().monitor, FuelMonitorConfig::default());
    let style = monitor("[monitor]\npreset = \"driving_style\"\ncomponents = 3\n").unwrap();
    let mut want = FuelMonitorConfig::driving_style();
    assert_eq!(want.components, 2);
    want.components = 3;
    assert_eq!(style.monitor, want);
    let paper = monitor("[monitor]\npreset = \"paper\"\n").unwrap();
    assert_eq!(paper.monitor, FuelMonitorConfig::paper());
    assert_ne!(paper.monitor, FuelMonitorConfig::default());
    let err = monitor("[monitor]\npreset = \"magic\"\n")
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("magic") && err.contains("paper") && err.contains("driving_style"),
        "{err}"
    );
    let err = monitor("[monitor]\ncomponents = 0\n")
        .unwrap_err()
        .to_string();
    assert!(err.contains("components"), "{err}");
}
