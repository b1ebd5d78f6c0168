//! The serialised layout of a vehicle's saved state, pinned under its format version: a
//! change of anything `FuelMonitor` holds fails here until `FuelMonitor::STATE_FORMAT_VERSION`
//! is raised (then `RAILMON_UPDATE_GOLDEN=1` rewrites `tests/data/golden/state-layout-fuel.txt`).

use railmon_fuel::{FuelMonitor, RailcarScenario, RailcarSimulator};

/// The monitor of the shipped railcar scenario after `steps` seconds.
fn monitor_after(steps: usize) -> FuelMonitor {
    let text = include_str!("../../config/scenarios/fuel-railcar.toml");
    let scenario = RailcarScenario::from_toml_str(text).expect("the shipped scenario");
    let mut simulator = RailcarSimulator::new(&scenario).unwrap();
    let mut monitor = FuelMonitor::new(&scenario.monitor).unwrap();
    for _ in 0..steps {
        let (sample, _) = simulator.step().expect("enough samples in the scenario");
        monitor.update(&sample).unwrap();
    }
    monitor
}

/// A monitor still collecting its first samples, and one estimating with forecasts.
#[test]
fn state_layout_golden_is_pinned_under_the_format_version() {
    railmon_golden::check_state_layout(
        "state-layout-fuel.txt",
        FuelMonitor::STATE_FORMAT_VERSION,
        &[monitor_after(10), monitor_after(2_000)],
        &[],
    );
}
