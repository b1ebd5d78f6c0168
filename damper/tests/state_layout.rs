//! The serialised layout of a bogie's saved state, pinned under its format version: a change
//! of anything `DamperMonitorState` holds fails here until
//! `DamperMonitorState::STATE_FORMAT_VERSION` is raised (then `RAILMON_UPDATE_GOLDEN=1`
//! rewrites `tests/data/golden/state-layout-damper.txt`).

use railmon_damper::{BogieSimulator, DamperMonitor, DamperMonitorState, DamperScenario};

/// The state of a monitor run `steps` samples into a scenario (N = 50: the layout does not
/// depend on the particle count), with the EKF baseline (off by default) so that its state is
/// traced too.
fn state_after(scenario_toml: &str, steps: usize) -> DamperMonitorState {
    let scenario = DamperScenario::from_toml_str(scenario_toml).unwrap();
    let mut config = scenario.monitor_config();
    config.rbpf.particles = 50;
    config.ekf.enabled = true;
    let mut monitor = DamperMonitor::for_bogie(&config, 1, None).unwrap();
    let mut simulator = BogieSimulator::new(&scenario).unwrap();
    for _ in 0..steps {
        let (sample, _) = simulator.step().expect("enough samples in the scenario");
        monitor.step(sample).unwrap();
    }
    monitor.state()
}

/// A monitor learning at speed, and one paused at the speed profile's start (from rest). Not
/// seen: the bank of `rbpf.propagation = "exact"` (the reference, ~100x too slow for 1 kHz),
/// whose 17-element arrays serde-reflection 0.6 fails to trace ("incompatible formats").
#[test]
fn state_layout_golden_is_pinned_under_the_format_version() {
    let states = [
        state_after(
            include_str!("../../config/scenarios/damper-seed.toml"),
            3_000,
        ),
        state_after(
            include_str!("../../config/scenarios/damper-speed-profile.toml"),
            500,
        ),
    ];
    railmon_golden::check_state_layout(
        "state-layout-damper.txt",
        DamperMonitorState::STATE_FORMAT_VERSION,
        &states,
        &[],
    );
}
