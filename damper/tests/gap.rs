//! Samples missing from the stream (issue 26 item 3): `DamperMonitor::bridge` steps over one or
//! two lost samples, and after a longer gap (the seconds across a restart of the service) holds
//! the posterior while the states settle on the data again, as after a pause.

use railmon_damper::{
    BogieSimulator, DamperAlarm, DamperEventKind, DamperMonitor, DamperScenario, PauseReason,
    MAX_STEPPED_OVER_SAMPLES,
};

/// 24 s of a healthy bogie at 30 m/s.
fn scenario() -> DamperScenario {
    DamperScenario::from_toml_str(
        r#"
name = "gap"
seed = 5
duration_s = 24.0
dt_s = 0.001
[speed]
profile_m_s = [[0.0, 30.0], [24.0, 30.0]]
[track]
kind = "white"
velocity_std_m_s = 0.1
[sensors]
accel_std_m_s2 = 0.02
gyro_std_rad_s = 0.004
[monitor]
track_velocity_std_m_s = 0.1
"#,
    )
    .unwrap()
}

/// Runs the default monitor (N = 100) with the samples from 12 s on for `gap_steps` not given
/// to it (bridged). Returns the `C_sy` posterior mean just before the gap and at the end, the
/// pause reason of the first estimate after the gap, the time it learnt again (s) and the
/// `damper_degraded` events.
fn run(gap_steps: u64) -> (f64, f64, Option<PauseReason>, Option<f64>, usize) {
    let s = scenario();
    let mut config = s.monitor_config();
    config.rbpf.particles = 100;
    let mut monitor = DamperMonitor::for_bogie(&config, 1, None).unwrap();
    let mut alarms = DamperAlarm::pair(&config.alarm, &config.filter_model(), [false; 2]);
    let mut sim = BogieSimulator::new(&s).unwrap();
    let gap = 12_000..12_000 + gap_steps;
    let (mut before, mut after_gap, mut learning_s) = (f64::NAN, None, None);
    let (mut step, mut degraded, mut last) = (0u64, 0, f64::NAN);
    while let Some((sample, _)) = sim.step() {
        step += 1;
        let k = step - 1;
        if gap.contains(&k) {
            continue;
        }
        if k == gap.end && gap_steps > 0 {
            monitor.bridge(gap_steps);
        }
        let e = *monitor.step(sample).unwrap();
        if k + 1 == gap.start {
            before = e.csy.mean_ns_per_m;
        }
        if k == gap.end {
            after_gap = Some(e.paused);
        }
        if k > gap.end && learning_s.is_none() && e.paused.is_none() {
            learning_s = Some(e.time_s);
        }
        degraded += alarms
            .iter_mut()
            .filter_map(|a| a.update(&e))
            .filter(|ev| ev.kind == DamperEventKind::DamperDegraded)
            .count();
        last = e.csy.mean_ns_per_m;
    }
    (before, last, after_gap.flatten(), learning_s, degraded)
}

#[test]
fn a_lost_sample_is_stepped_over_and_a_long_gap_settles_before_learning() {
    // One or two lost samples: no pause.
    let (_, _, paused, _, degraded) = run(MAX_STEPPED_OVER_SAMPLES);
    assert_eq!((paused, degraded), (None, 0));
    // 3 s lost: paused for the gap, learning again within the longest settling (6.2 s),
    // the posterior where it was (within 2 %) and no alarm.
    let (before, after, paused, learning_s, degraded) = run(3_000);
    assert_eq!(paused, Some(PauseReason::Gap));
    let learning_s = learning_s.expect("learns again");
    assert!(
        learning_s > 15.0 && learning_s < 15.0 + 6.3,
        "learning again at {learning_s:.3} s (the gap ended at 15 s)"
    );
    assert!(
        (after / before - 1.0).abs() < 0.02 && degraded == 0,
        "C_sy {before:.0} before the gap, {after:.0} at the end; {degraded} alarms"
    );
}
