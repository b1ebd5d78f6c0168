//! The serialised layout of a drive's saved state, pinned under its format version: a change
//! of anything `SlipMonitor` holds fails here until `SlipMonitor::STATE_FORMAT_VERSION` is
//! raised (then `RAILMON_UPDATE_GOLDEN=1` rewrites `tests/data/golden/state-layout-slip.txt`).

use railmon_slip::{AdhesionMethod, AdhesionScenario, DriveSimulator, SlipMonitor};

const SEED: &str = include_str!("../../config/scenarios/adhesion-seed.toml");

/// One monitor per adhesion method (each holds its own method's state), stepped through the
/// seed scenario's first loss of adhesion so that every part of the state is filled; the
/// optional settings the state carries set, so that their type is seen.
#[test]
fn state_layout_golden_is_pinned_under_the_format_version() {
    let scenario = AdhesionScenario::from_toml_str(SEED).unwrap();
    let monitors: Vec<SlipMonitor> = AdhesionMethod::ALL
        .iter()
        .enumerate()
        .map(|(i, &method)| {
            let mut config = scenario.monitor_config();
            config.method = method;
            config.adhesion.vb.stop_tolerance = Some(1e-6);
            config.adhesion.vb.loss_wishart_scale = Some(1.0);
            config.adhesion.vmp.stop_tolerance = Some(1e-6);
            let mut monitor = SlipMonitor::new(&config, scenario.n_drives()).unwrap();
            let mut simulator = DriveSimulator::new(&scenario).unwrap();
            for k in 0..4_000 {
                let (samples, _) = simulator.step().expect("4,000 steps in the scenario");
                // Steps with a train speed, so that the train-speed test's state is filled; every
                // other monitor's last steps without, so that both references are seen.
                let train = (k >= 1_500 && (i % 2 == 0 || k < 3_900)).then_some(5.75);
                monitor.step_with_train_speed(samples, train).unwrap();
            }
            monitor
        })
        .collect();
    railmon_golden::check_state_layout(
        "state-layout-slip.txt",
        SlipMonitor::STATE_FORMAT_VERSION,
        &monitors,
        &[],
    );
}
