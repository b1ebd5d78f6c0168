//! Faults at a stop (issue 24 item 4): a damper that fails while the train stands is flagged
//! within 10 s of the train passing `speed.min_m_s` again, and a healthy bogie comes through
//! the same stop without an alarm. Before the settling after a pause was judged on the
//! innovations (a fixed 3 time constants of the slowest mode, 6.2 s) the `C_say` failure
//! below was not flagged by the end of the run, 10.7 s after moving off.

use railmon_damper::{
    BogieSimulator, DamperAlarm, DamperEstimate, DamperEventKind, DamperId, DamperMonitor,
    DamperScenario,
};

#[path = "common/shared_gain_table.rs"]
mod shared_gain_table;

/// 11 s at 30 m/s (the alarm's 10 s warm-up), braking to a stop at 13 s, standing 2 s,
/// moving off at 15 s: 5 m/s at 15.33 s, 30 m/s at 17 s; `fault` (TOML) added.
fn scenario(fault: &str) -> DamperScenario {
    let text = format!("{}\n{fault}\n", include_str!("common/stop.toml"));
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
///
/// The gain table is the binary's shared one ([`shared_gain_table`]): every run here brakes to
/// a stop and moves off again through the speed nodes, and with the mass withheld its
/// particles spread over the mass nodes too; solving them afresh for each run (and each seed
/// of the ignored test) took most of this binary's time.
fn run_to_end(s: &DamperScenario, bogie: u32) -> (f64, f64, Vec<(f64, DamperId)>, DamperEstimate) {
    let mut config = s.monitor_config();
    config.rbpf.particles = 100;
    let table = shared_gain_table::for_config(&config);
    let mut monitor = DamperMonitor::for_bogie(&config, bogie, Some(table.clone())).unwrap();
    // The nodes a run reaches solved on every core (the filter mostly waits for them).
    let ahead = shared_gain_table::SolvingAhead::new(table);
    let design_kg = config.vehicle.half_body_mass_kg;
    let mut alarms = DamperAlarm::pair(&config.alarm, &config.filter_model(), [false; 2]);
    let mut sim = BogieSimulator::new(s).unwrap();
    let (mut moving_off_s, mut learning_s) = (None, None);
    let mut stopped = false;
    let mut degraded = vec![];
    while let Some((sample, truth)) = sim.step() {
        let e = *monitor.step(sample).unwrap();
        let masses_kg = sample
            .half_body_mass_kg
            .map(|m| m..=m)
            .or_else(|| monitor.rbpf().particle_mass_span_kg())
            .unwrap_or(design_kg..=design_kg);
        ahead.follow(sample.speed_m_s, masses_kg);
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
/// `C_sy` within 3 % of the truth at the end, 11 s after moving off (filter seed 1 +0.21 %
/// on 29 Nov with the simulated plant's speed held in 0.1 % steps, +0.18 % before; seeds 1-7
/// -0.6 .. +1.1 % on 28 Nov). Withheld with the design mass kept
/// (`rbpf.unmeasured_mass.enabled = false`) the heavier body's slower sway reads as a weaker
/// `C_sy` (-13.5 % on 29 Nov, -15.6 % before the speed was held, -22.8 % on 27 Nov before the
/// states were estimated after a stop): more than 3 % off, so the test fails if the input
/// stops mattering.
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

/// A failed run: the filter seed, the final `C_sy` error and the `damper_degraded` events.
type Failure = (u32, f64, Vec<(f64, DamperId)>);

/// [`boarding_at_the_stop`] with the mass withheld, the particles carrying their own
/// (`rbpf.unmeasured_mass`), filter seed (bogie) `bogie`: `C_sy` within 3 % at the end and no
/// alarm, or why not.
fn withheld_boarding_fails(bogie: u32) -> Option<Failure> {
    let mut s = boarding_at_the_stop();
    s.load.measured = false;
    let (_, _, degraded, e) = run_to_end(&s, bogie);
    let error = e.csy.mean_ns_per_m / s.dampers.csy_ns_per_m - 1.0;
    eprintln!(
        "seed {bogie}: C_sy {:+.2} %, alarms {degraded:?}",
        100.0 * error
    );
    assert_eq!(e.measured_half_body_mass_kg, None);
    (error.abs() >= 0.03 || !degraded.is_empty()).then_some((bogie, error, degraded))
}

/// [`withheld_boarding_fails`] on filter seed 3, the worst of seeds 1-7 before the particles
/// drew their mass again after a stop (`Rbpf::forget_unmeasured_mass`, issue 24 item 1):
/// then `C_sy` -29.2 % with false `C_sy` and `C_say` alarms, the cloud keeping the mass from
/// before the stop; with it +1.6 %, the mass read 17.25 t of 16.9 t. One seed in CI (most of
/// this binary's time: the gain-table nodes its particles' masses reach, solved once); seeds
/// 1-14: the ignored test below.
#[test]
fn a_load_change_at_a_stop_is_found_again_when_withheld() {
    assert_eq!(withheld_boarding_fails(3), None);
}

/// [`withheld_boarding_fails`] for filter seeds (bogies) 1-14, N = 100: found again after the
/// stop because every particle draws its mass again from the prior when the states restart
/// after a pause below the speed range (`Rbpf::forget_unmeasured_mass`). **Fails on main
/// since 28 Nov's published side kept apart**: `C_sy` at the end (30 Nov) +0.69, **+3.67**,
/// +0.41, +2.14, +1.05, +1.11, +0.88, **+3.41**, +1.69, -0.03, +1.68, -0.21, +0.87, +0.03 %,
/// no alarm (before it all 14 within 1.9 %). The cloud reads the body 2.8 % heavy on
/// average (17.37 t of 16.9 t, its 10-90 % a few tenths of a percent wide) although the
/// likelihood over the last 9 s favours the truth by 24 nats over +2 %: it narrows on a heavy
/// mass within 0.2 s of learning again (the log, 30 Nov; `examples/mass_trace.rs`). Before
/// the redraw the cloud kept the mass from before the stop, and the new one came only
/// through the kernel's regenerated particles (1 % a move, at a tenth of the weight) while
/// the heavier body's data were explained by a weaker `C_sy` and the jump hypotheses (at the
/// old mass): seeds 1-7 +0.4, -9.8 (a false `C_say` alarm), -29.2 (false `C_sy` and `C_say`
/// alarms), -20.4, +2.7, +0.4, -18.7 % (29 Nov). Ignored for its time only.
#[test]
#[ignore = "70-85 s in release on 30 Nov, the seeds sharing the gain table (seed 3 alone runs in CI): \
            `cargo test --release -p railmon-damper --test stop -- --ignored --nocapture`"]
fn a_load_change_at_a_stop_is_found_again_when_withheld_for_every_seed() {
    let failed: Vec<_> = (1..=14).filter_map(withheld_boarding_fails).collect();
    assert!(failed.is_empty(), "{failed:?}");
}
