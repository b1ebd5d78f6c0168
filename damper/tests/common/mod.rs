//! Scenarios shared by several test binaries.

use railmon_damper::*;

/// `damper-seed` (30 m/s, white track) with `C_sy` falling linearly from nominal to 0.4 x over
/// 120 s from 20 s (crossing 0.7 at 80 s), run to 130 s, and its monitor's settings at
/// N = 300: the slow wear of issue 24 item 3.
pub fn csy_ramp_on_seed() -> (DamperScenario, DamperMonitorConfig) {
    let text = include_str!("../../../config/scenarios/damper-seed.toml");
    let mut scenario = DamperScenario::from_toml_str(text).unwrap();
    scenario.duration_s = 130.0;
    scenario.faults = vec![DamperFault {
        damper: DamperId::Csy,
        kind: FaultKind::Ramp,
        at_s: 20.0,
        end_s: Some(140.0),
        ratio: 0.4,
    }];
    let mut config = scenario.monitor_config();
    config.rbpf.particles = 300;
    (scenario, config)
}
