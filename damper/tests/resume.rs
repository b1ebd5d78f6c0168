//! A monitor resumed from its saved state (issue 12 item 4) goes on exactly as the one that
//! saved it: after a restart its estimates are inside the pre-restart 90 % interval from the
//! first sample on, where a monitor started from its prior (what a restart gave before) is not
//! within 1 s.

use std::sync::Arc;

use railmon_damper::gain_table::GainTable;
use railmon_damper::{
    BogieSample, BogieSimulator, DamperMonitor, DamperMonitorConfig, DamperScenario, Rbpf,
};

/// The scenario's monitor configuration at 200 particles, its gain table, and the samples of
/// `duration_s` of the scenario: what both tests run a saving and a resumed monitor on.
fn setup(
    mut scenario: DamperScenario,
    duration_s: f64,
) -> (DamperMonitorConfig, Arc<GainTable>, Vec<BogieSample>) {
    scenario.duration_s = duration_s;
    let mut config = scenario.monitor_config();
    config.rbpf.particles = 200;
    let table = Rbpf::gain_table(&config.filter_model(), &config.rbpf, &config.speed).unwrap();
    let mut sim = BogieSimulator::new(&scenario).unwrap();
    let mut samples = vec![];
    while let Some((s, _)) = sim.step() {
        samples.push(*s);
    }
    (config, table, samples)
}

#[test]
fn a_resumed_monitor_goes_on_exactly_and_inside_the_pre_restart_interval() {
    let text = include_str!("../../config/scenarios/damper-seed.toml");
    let scenario = DamperScenario::from_toml_str(text).unwrap();
    let (config, table, samples) = setup(scenario, 21.0);
    let (before, after) = samples.split_at(20_000);
    let mut running = DamperMonitor::for_bogie(&config, 1, Some(table.clone())).unwrap();
    for s in before {
        running.step(s).unwrap();
    }
    let pre = *running.estimate();
    // Through bytes, as the service's snapshot file carries it.
    let bytes = bincode::serialize(&running.state()).unwrap();
    let state = bincode::deserialize(&bytes).unwrap();
    let mut resumed = DamperMonitor::resume(&config, Some(table.clone()), state).unwrap();
    // The measured mass is the last sample's, not state: the resumed monitor reports it from
    // its first sample on; the estimate itself is the same to the bit.
    let mut pre_without_mass = pre;
    pre_without_mass.measured_half_body_mass_kg = None;
    assert_eq!(*resumed.estimate(), pre_without_mass);
    let inside = |e: &railmon_damper::DamperEstimate| {
        [(e.csy, pre.csy), (e.csay, pre.csay)]
            .iter()
            .all(|(now, was)| was.covers(now.mean_ns_per_m))
    };
    let mut fresh = DamperMonitor::for_bogie(&config, 1, Some(table.clone())).unwrap();
    for s in after {
        let a = *running.step(s).unwrap();
        let b = *resumed.step(s).unwrap();
        assert_eq!(a, b);
        assert!(inside(&b), "{b:?} outside {pre:?}");
        fresh.step(s).unwrap();
    }
    // What a restart gave before: 1 s after it, the prior's estimate is outside.
    assert!(!inside(fresh.estimate()), "{:?}", fresh.estimate());
    // A state of another particle count is refused.
    let mut other = config;
    other.rbpf.particles = 100;
    assert!(DamperMonitor::resume(&other, None, running.state()).is_err());
}

/// A monitor saved while it holds its publication through a burst (`railmon_damper::burst`:
/// held-out sampler draw 5105, `C_sy` stepping to 0.26 x at 57 s at 46 m/s) resumes holding
/// the same posteriors, and goes on exactly as the one that saved it through the release.
#[test]
fn a_monitor_saved_during_a_burst_hold_resumes_it_exactly() {
    let scenario = railmon_damper::sampler::draw(5105, 120.0).scenario;
    let (config, table, samples) = setup(scenario, 60.0);
    let mut running = DamperMonitor::for_bogie(&config, 1, Some(table.clone())).unwrap();
    let mut at = None;
    for (k, s) in samples.iter().enumerate() {
        if running.step(s).unwrap().held_through_burst {
            at = Some(k + 1);
            break;
        }
    }
    let at = at.expect("the step's burst is held");
    let bytes = bincode::serialize(&running.state()).unwrap();
    let state = bincode::deserialize(&bytes).unwrap();
    let mut resumed = DamperMonitor::resume(&config, Some(table.clone()), state).unwrap();
    assert!(resumed.estimate().held_through_burst);
    assert_eq!(resumed.estimate().csay, running.estimate().csay);
    let mut released = false;
    for s in &samples[at..] {
        let a = *running.step(s).unwrap();
        let b = *resumed.step(s).unwrap();
        assert_eq!(a, b);
        released |= !a.held_through_burst;
    }
    assert!(released, "the hold ends within the run");
}
