//! The sample stream the fuel benches share.

use railmon_fuel::{
    FuelMonitor, FuelMonitorConfig, Interval, RailcarScenario, RailcarSimulator, VehicleSample,
};

/// A deterministic, varied stream of plausible samples (no RNG needed for a timing run).
pub fn sample(t: usize) -> VehicleSample {
    let x = t as f64;
    let speed = 15.0 + 10.0 * (x / 37.0).sin();
    let pedal = (30.0 + 25.0 * (x / 11.0).sin()).max(0.0);
    VehicleSample {
        time_s: x,
        fuel_cm3_s: Some((0.3 + 0.02 * pedal + 0.1 * (x / 3.0).cos()).max(0.0)),
        speed_m_s: Some(speed),
        pedal_pct: Some(pedal),
        engine_torque_nm: Some(2.0 * pedal),
        engine_speed_rpm: Some(800.0 + 90.0 * speed),
        gradient_permille: None,
        gear: Some(1 + (speed / 6.0) as i32),
    }
}

/// The shipped railcar route (`config/scenarios/fuel-railcar.toml`, 7228 samples), simulated.
#[allow(dead_code)] // not every bench reads it
pub fn railcar_route() -> Vec<VehicleSample> {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../config/scenarios/fuel-railcar.toml"
    );
    let text = std::fs::read_to_string(path).expect("the shipped railcar scenario");
    let scenario = RailcarScenario::from_toml_str(&text).expect("a valid scenario");
    let mut simulator = RailcarSimulator::new(&scenario).expect("a valid scenario");
    std::iter::from_fn(|| simulator.step().map(|(sample, _)| sample)).collect()
}

/// A monitor in `setting` (the paper's for the bench item; `FuelMonitorConfig::default()`
/// is what the service runs) with `m_c` components, past its initial samples of `sample`, and
/// the index of the next sample.
pub fn initialised_monitor(
    setting: FuelMonitorConfig,
    m_c: usize,
    sample: impl Fn(usize) -> VehicleSample,
) -> (FuelMonitor, usize) {
    let config = FuelMonitorConfig {
        components: m_c,
        ..setting
    };
    let mut monitor = FuelMonitor::new(&config).expect("valid config");
    let mut t = 0;
    while monitor.mixture().is_none() {
        monitor.update(&sample(t)).expect("valid sample");
        t += 1;
    }
    (monitor, t)
}

/// Every interval the last estimate offers (virtual sensor, 1-step forecast, each forecast
/// step): what a published view or `railmon analyze fuel` asks for after a step.
pub fn every_interval(monitor: &FuelMonitor) -> (Interval, Interval, Vec<Interval>) {
    let m = monitor.estimate().mixture.as_ref().expect("initialised");
    (
        m.virtual_sensor_interval_cm3_s(),
        m.one_step_interval_cm3_s(),
        m.forecast_interval_cm3_s(),
    )
}
