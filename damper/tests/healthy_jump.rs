//! A healthy damper's published health ratio does not fall below the alarm's threshold when
//! the jump search's hypotheses become particles (issue 24 item 2): they are on probation,
//! published only once their posterior mass has been decisive for a slowest time constant
//! (`railmon_damper::rbpf` jump module docs, "Publishing a jump"). The cheap check of the
//! mechanism is the unit test `rbpf::tests::a_jump_is_published_only_once_its_mass_was_decisive_for_a_time_constant`.

use railmon_damper::sampler;
use railmon_damper::{BogieSimulator, DamperMonitor};

/// The lowest published health ratio of each damper after the alarm's warm-up (judged time,
/// as the alarm and `condition_matrix` count it), with its time, on the condition sampler's
/// draw `seed` (runs of at most 120 s) at `particles`; and how many jump hypotheses became
/// particles.
fn lowest_ratios(seed: u64, particles: usize) -> ([(f64, f64); 2], u64) {
    let draw = sampler::draw(seed, 120.0);
    assert!(
        draw.scenario.faults.is_empty(),
        "seed {seed}: a healthy draw"
    );
    let mut config = draw.scenario.monitor_config();
    config.rbpf.particles = particles;
    let mut monitor = DamperMonitor::for_bogie(&config, 1, None).unwrap();
    let mut sim = BogieSimulator::new(&draw.scenario).unwrap();
    let mut lowest = [(f64::INFINITY, 0.0); 2];
    let mut judged_s = 0.0;
    while let Some((sample, _)) = sim.step() {
        let e = *monitor.step(sample).unwrap();
        if e.paused.is_none() && !e.model_mismatch {
            judged_s += config.dt_s;
        }
        if judged_s + 0.5 * config.dt_s < config.alarm.warmup_s {
            continue;
        }
        for (k, post) in [e.csy, e.csay].iter().enumerate() {
            if post.health_ratio < lowest[k].0 {
                lowest[k] = (post.health_ratio, e.time_s);
            }
        }
    }
    (lowest, monitor.rbpf().jump_count())
}

/// The healthy held-out draw of the condition sampler whose published ratio fell lowest
/// without a stop (27 Nov, mass given): seed 5001, 101 s varying 0-32 m/s, conicity 0.227
/// (the filter assumes 0.15), body 1.31 x the design mass (given), noise 1.58 x. Before the
/// probation its published `C_sy` fell to 0.556 x nominal, in two stretches within 2 s of a
/// jump hypothesis becoming particles (31 did); with it the lowest is 0.947. (The worst
/// healthy draw, 5007, with a stop, still falls below: docs/notes/damper-log.md.) 83 s in
/// release on 2 shared cores, too slow for CI in debug:
/// `cargo test --release -p railmon-damper --test healthy_jump -- --ignored --nocapture`
#[test]
#[ignore = "101 s of a sampler draw at N = 1000, about 85 s in release, too slow for CI in \
            debug: cargo test --release -p railmon-damper --test healthy_jump -- --ignored"]
fn a_healthy_draw_off_the_model_publishes_no_ratio_below_the_threshold() {
    let threshold = railmon_damper::DamperMonitorConfig::default()
        .alarm
        .degraded_below_ratio;
    let (lowest, jumps) = lowest_ratios(5001, 500);
    println!("lowest published ratio (ratio, time s) csy / csay: {lowest:?}; {jumps} jumps");
    assert!(jumps > 0, "the search ran");
    for (ratio, time_s) in lowest {
        assert!(ratio >= threshold, "{ratio} at {time_s} s");
    }
}

/// A step of one damper at speed is found without publishing the healthy one below the
/// threshold (`railmon_damper::burst`): held-out draw 5105 (88 s at 46 m/s, `C_sy` to 0.26 x
/// nominal at 57 s, mass given). For 0.35 s after the step no hypothesis explains the data
/// (NIS 10-60) and the jump search adopted hypotheses of both dampers in turn: the healthy
/// `C_say` was published at 0.098 x nominal for 70 ms before the hold. With it the
/// publication is held from 57.05 s until the innovations are back in their band (about
/// 0.6 s), `C_say`'s lowest is above the threshold, and `C_sy` is flagged as before. About
/// 4 s in release, too slow in debug:
/// `cargo test --release -p railmon-damper --test healthy_jump -- --ignored --nocapture`
#[test]
#[ignore = "88 s of a sampler draw, about 4 s in release, too slow for CI in debug: \
            cargo test --release -p railmon-damper --test healthy_jump -- --ignored"]
fn a_step_at_speed_is_found_without_publishing_the_healthy_damper_below_the_threshold() {
    let draw = sampler::draw(5105, 120.0);
    let onset_s = draw
        .fault_onset_s(railmon_damper::DamperId::Csy)
        .expect("a C_sy step");
    assert!(draw.fault_onset_s(railmon_damper::DamperId::Csay).is_none());
    let mut config = draw.scenario.monitor_config();
    config.rbpf.particles = 500;
    let threshold = config.alarm.degraded_below_ratio;
    let mut monitor = DamperMonitor::for_bogie(&config, 1, None).unwrap();
    let mut alarms =
        railmon_damper::DamperAlarm::pair(&config.alarm, &config.filter_model(), [false; 2]);
    let mut sim = BogieSimulator::new(&draw.scenario).unwrap();
    let (mut lowest_csay, mut held_steps, mut flagged_at) = (f64::INFINITY, 0, None);
    while let Some((sample, _)) = sim.step() {
        let e = *monitor.step(sample).unwrap();
        for event in alarms.iter_mut().filter_map(|a| a.update(&e)) {
            if event.kind == railmon_damper::DamperEventKind::DamperDegraded {
                assert_eq!(
                    event.damper,
                    railmon_damper::DamperId::Csy,
                    "at {}",
                    e.time_s
                );
                flagged_at.get_or_insert(e.time_s);
            }
        }
        if e.time_s > onset_s {
            lowest_csay = lowest_csay.min(e.csay.health_ratio);
            held_steps += usize::from(e.held_through_burst);
        }
    }
    println!(
        "C_say lowest {lowest_csay:.3} after the step; held {held_steps} ms; C_sy flagged at \
         {flagged_at:?} s (step at {onset_s} s)"
    );
    assert!(held_steps > 0, "the burst was held");
    assert!(lowest_csay >= threshold, "C_say published at {lowest_csay}");
    let flagged = flagged_at.expect("C_sy flagged");
    assert!(
        flagged - onset_s < 10.0,
        "flagged {:.1} s after",
        flagged - onset_s
    );
}
