//! Faults at a stop (issue 24 item 4): a damper that fails while the train stands is flagged
//! within 10 s of the train passing `speed.min_m_s` again, and a healthy bogie comes through
//! the same stop without an alarm. Before the settling after a pause was judged on the
//! innovations (a fixed 3 time constants of the slowest mode, 6.2 s) the `C_say` failure
//! below was not flagged by the end of the run, 10.7 s after moving off.

use railmon_damper::{
    BogieSimulator, DamperAlarm, DamperEstimate, DamperEventKind, DamperId, DamperMonitor,
    DamperScenario,
};

/// 11 s at 30 m/s (the alarm's 10 s warm-up), braking to a stop at 13 s, standing 2 s,
/// moving off at 15 s: 5 m/s at 15.33 s, 30 m/s at 17 s; `fault` (TOML) added.
fn scenario(fault: &str) -> DamperScenario {
    let text = format!(
        r#"
name = "stop"
seed = 3
duration_s = 26.0
dt_s = 0.001
[speed]
profile_m_s = [[0.0, 30.0], [11.0, 30.0], [13.0, 0.0], [15.0, 0.0], [17.0, 30.0]]
[track]
kind = "white"
velocity_std_m_s = 0.1
[sensors]
accel_std_m_s2 = 0.02
gyro_std_rad_s = 0.004
{fault}
[monitor]
track_velocity_std_m_s = 0.1
"#
    );
    DamperScenario::from_toml_str(&text).unwrap()
}

/// Runs the default monitor (N = 100) on `s`: when the speed first came back to
/// `speed.min_m_s` after the stop, when the filter learnt again after it, and the
/// `damper_degraded` events `(time, damper)`.
fn run(s: &DamperScenario) -> (f64, f64, Vec<(f64, DamperId)>) {
    let (moving_off_s, learning_s, degraded, _) = run_to_end(s, 1);
    (moving_off_s, learning_s, degraded)
}

/// [`run`] with the filter seeded for bogie `bogie`, and the final estimate.
fn run_to_end(s: &DamperScenario, bogie: u32) -> (f64, f64, Vec<(f64, DamperId)>, DamperEstimate) {
    let mut config = s.monitor_config();
    config.rbpf.particles = 100;
    let mut monitor = DamperMonitor::for_bogie(&config, bogie, None).unwrap();
    let mut alarms = DamperAlarm::pair(&config.alarm, &config.filter_model(), [false; 2]);
    let mut sim = BogieSimulator::new(s).unwrap();
    let (mut moving_off_s, mut learning_s) = (None, None);
    let mut stopped = false;
    let mut degraded = vec![];
    while let Some((sample, truth)) = sim.step() {
        let e = *monitor.step(sample).unwrap();
        stopped |= sample.speed_m_s < config.speed.min_m_s;
        if stopped && moving_off_s.is_none() && sample.speed_m_s >= config.speed.min_m_s {
            moving_off_s = Some(truth.time_s);
        }
        if moving_off_s.is_some() && learning_s.is_none() && e.paused.is_none() {
            learning_s = Some(e.time_s);
        }
        for event in alarms.iter_mut().filter_map(|a| a.update(&e)) {
            if event.kind == DamperEventKind::DamperDegraded {
                degraded.push((event.time_s, event.damper));
            }
        }
    }
    let estimate = *monitor.estimate();
    (
        moving_off_s.unwrap(),
        learning_s.unwrap(),
        degraded,
        estimate,
    )
}

#[test]
fn a_damper_failed_at_a_stop_is_flagged_within_10_s_of_moving_off() {
    let s = scenario("[[faults]]\ndamper = \"csay\"\nkind = \"step\"\nat_s = 14.0\nratio = 0.4");
    let (moving_off_s, _, degraded) = run(&s);
    assert!((15.3..15.4).contains(&moving_off_s), "{moving_off_s}");
    assert!(
        degraded.iter().all(|(_, d)| *d == DamperId::Csay),
        "{degraded:?}"
    );
    let flagged_s = degraded.first().map(|(t, _)| *t);
    assert!(
        flagged_s.is_some_and(|t| t > moving_off_s && t - moving_off_s <= 10.0),
        "flagged at {flagged_s:?}, moving off at {moving_off_s} s"
    );
}

#[test]
fn a_healthy_bogie_comes_through_a_stop_without_an_alarm() {
    let (moving_off_s, learning_s, degraded) = run(&scenario(""));
    assert!(degraded.is_empty(), "{degraded:?}");
    // After the stop the states restart at rest and explain the data within the minimum
    // settling (`speed.resume_settle_s`, 1 s): not the 6.2 s cap.
    assert!(
        learning_s - moving_off_s < 1.6,
        "learnt again {:.3} s after moving off",
        learning_s - moving_off_s
    );
}

/// Passengers board at the stop (issue 24 item 1): the body above the bogie goes from the
/// design 13 t to 16.9 t (1.3 x) at 14 s, the train standing.
fn boarding_at_the_stop() -> DamperScenario {
    scenario("[load]\nchanges_kg = [[14.0, 16900.0]]")
}

/// [`boarding_at_the_stop`]: with the mass measured the filter follows it: no alarm, and
/// `C_sy` within 3 % of the truth at the end, 11 s after moving off (filter seeds 1-7:
/// -0.6 .. +1.1 %). Withheld with the design mass kept (`rbpf.unmeasured_mass.enabled =
/// false`) the heavier body's slower sway reads as a weaker `C_sy` (-22.8 % on 27 Nov): more
/// than 3 % off, so the test fails if the input stops mattering.
#[test]
fn a_load_change_at_a_stop_is_followed_when_measured() {
    let mut s = boarding_at_the_stop();
    let mut sim = BogieSimulator::new(&s).unwrap();
    let mut masses = vec![];
    while let Some((y, truth)) = sim.step() {
        assert_eq!(y.half_body_mass_kg, Some(truth.half_body_mass_kg));
        if masses.last() != Some(&y.half_body_mass_kg) {
            assert!(
                masses.is_empty() || y.speed_m_s == 0.0,
                "a change while running"
            );
            masses.push(y.half_body_mass_kg);
        }
    }
    assert_eq!(masses, [Some(13000.0), Some(16900.0)]);
    let truth = s.dampers;
    let (_, _, degraded, e) = run_to_end(&s, 1);
    let error = |e: &DamperEstimate| e.csy.mean_ns_per_m / truth.csy_ns_per_m - 1.0;
    eprintln!(
        "measured: C_sy {:+.2} %, C_say {:+.2} %",
        100.0 * error(&e),
        100.0 * (e.csay.mean_ns_per_m / truth.csay_ns_per_m - 1.0)
    );
    assert!(degraded.is_empty(), "{degraded:?}");
    assert_eq!(e.measured_half_body_mass_kg, Some(16900.0));
    assert!(error(&e).abs() < 0.03, "C_sy measured: {:+.3}", error(&e));
    s.load.measured = false;
    s.monitor.rbpf.unmeasured_mass.enabled = false;
    let (_, _, _, design) = run_to_end(&s, 1);
    eprintln!(
        "withheld, design mass: C_sy {:+.2} %",
        100.0 * error(&design)
    );
    assert!(
        error(&design).abs() > 0.03,
        "C_sy withheld, design mass: {:+.3}",
        error(&design)
    );
}

/// [`boarding_at_the_stop`] with the mass withheld, the particles carrying their own
/// (`rbpf.unmeasured_mass`): found again after the stop by the particles regenerated from
/// the mass prior, `C_sy` within 3 % and no alarm, for every filter seed. **Fails (issue 24
/// item 1, open)**: N = 100, filter seeds (bogies) 1-7, `C_sy` at the end +0.4, -9.8 (a false
/// `C_say` alarm), -29.2 (false `C_sy` and `C_say` alarms), -20.4, +2.7, +0.4, -18.7 % with
/// the states estimated after the stop (`rbpf/resume_init.rs`); before it +1.4, -3.5 (a false
/// alarm), -5.2, -17.8, -2.2, +2.3, -0.9 %. The heavier body and a weaker `C_sy` lie on a
/// ridge of the likelihood, and after the stop the cloud settles on it where its first draws
/// fall. Until 29 Nov only seed 1 was run, in CI, and passed.
#[test]
#[ignore = "issue 24 item 1, open: fails on 4 of 7 filter seeds, about 4 min in release: \
            `cargo test --release -p railmon-damper --test stop -- --ignored --nocapture`"]
fn a_load_change_at_a_stop_is_found_again_when_withheld_for_every_seed() {
    let mut s = boarding_at_the_stop();
    s.load.measured = false;
    let truth = s.dampers.csy_ns_per_m;
    let mut failed = vec![];
    for bogie in 1..=7 {
        let (_, _, degraded, e) = run_to_end(&s, bogie);
        let error = e.csy.mean_ns_per_m / truth - 1.0;
        eprintln!(
            "seed {bogie}: C_sy {:+.2} %, alarms {degraded:?}",
            100.0 * error
        );
        assert_eq!(e.measured_half_body_mass_kg, None);
        if error.abs() >= 0.03 || !degraded.is_empty() {
            failed.push((bogie, error, degraded));
        }
    }
    assert!(failed.is_empty(), "{failed:?}");
}
