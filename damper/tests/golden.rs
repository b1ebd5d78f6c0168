//! Golden headline numbers of a short seeded run: `damper-fault.toml` (C_say steps to 40 % at
//! 30 s) for 36 s at N = 200, the default monitor with the scenario's seed: the RBPF's mean and
//! 90 % interval of both dampers at 10, 20, 30 and 36 s, and the alarm events. Pinned in
//! `tests/data/golden/damper-fault-short.csv` at a relative tolerance of 1e-9 (the run is
//! deterministic; the tolerance only absorbs the last bits of a different CPU's vector path).
//! Regenerate with `RAILMON_UPDATE_GOLDEN=1 cargo test -p railmon-damper --test golden`.

use railmon_damper::{BogieSimulator, DamperAlarm, DamperMonitor, DamperScenario};

const TOLERANCE: f64 = 1e-9;

/// `(quantity, value)` rows of the run.
fn headline() -> Vec<(String, f64)> {
    let text = include_str!("../../config/scenarios/damper-fault.toml");
    let mut scenario = DamperScenario::from_toml_str(text).unwrap();
    scenario.duration_s = 36.0;
    let mut config = scenario.monitor_config();
    config.rbpf.particles = 200;
    let mut monitor = DamperMonitor::for_bogie(&config, 1, None).unwrap();
    let mut alarms = DamperAlarm::pair(&config.alarm, &config.filter_model(), [false; 2]);
    let mut sim = BogieSimulator::new(&scenario).unwrap();
    let mut rows = vec![];
    while let Some((sample, truth)) = sim.step() {
        let t = truth.time_s;
        let estimate = *monitor.step(sample).unwrap();
        for event in alarms.iter_mut().filter_map(|a| a.update(&estimate)) {
            let name = format!("{}_{}", event.kind.as_str(), event.damper.name());
            rows.push((format!("{name}_time_s"), event.time_s));
            rows.push((format!("{name}_health_ratio"), event.health_ratio));
        }
        let step = (t * 1e3).round() as u64;
        if [10_000, 20_000, 30_000, 36_000].contains(&step) {
            for (name, p) in [("csy", estimate.csy), ("csay", estimate.csay)] {
                for (q, v) in [
                    ("mean", p.mean_ns_per_m),
                    ("q05", p.q05_ns_per_m),
                    ("q95", p.q95_ns_per_m),
                ] {
                    rows.push((format!("{name}_{q}_ns_per_m_at_{}s", step / 1000), v));
                }
            }
        }
    }
    rows
}

#[test]
fn short_fault_run_matches_its_golden_numbers() {
    railmon_golden::check_quantities("damper-fault-short.csv", &headline(), TOLERANCE);
}
