//! Frames lost before they reach the monitor (a sample lost at the source, the seconds across a
//! restart of the service): `SlipMonitor::bridge` carries the estimator over the missing
//! periods. Short gaps are predicted through, longer ones relock the EKFs from the back-EMF.
//! On the condition sampler's draws, with one gap of each length placed in the run, the
//! healthy drives stay unflagged as the sampler's own test requires and every EKF's speed is
//! back on the truth within 50 ms of the gap.

use railmon_slip::ekf::MAX_PREDICTED_GAP_S;
use railmon_slip::sampler::{draw_kind, DrawKind};
use railmon_slip::{DetectionCounter, DriveSimulator, SlipMonitor};

/// Runs draw `seed` with the frames of steps `gap_at .. gap_at + gap_steps` not given to the
/// monitor (bridged instead when `bridge`). Returns, per drive, the flag counters, the longest
/// run of flagged steps, the largest relative speed error of a healthy drive from 10 to 50 ms
/// after the gap, the slipping drives and the steps estimated.
fn run_with_gap(
    kind: DrawKind,
    seed: u64,
    gap_at: usize,
    gap_steps: usize,
    bridge: bool,
) -> (Vec<DetectionCounter>, Vec<usize>, f64, Vec<usize>, usize) {
    let d = draw_kind(seed, kind);
    let n = d.scenario.n_drives();
    let dt_s = d.scenario.monitor_config().dt_s;
    // From 10 ms to 50 ms after the gap: the relocked EKFs have their speed from the back-EMF.
    let check = gap_at + gap_steps + (0.01 / dt_s).round() as usize
        ..=gap_at + gap_steps + (0.05 / dt_s).round() as usize;
    let mut sim = DriveSimulator::new(&d.scenario).unwrap();
    let mut monitor = SlipMonitor::new(&d.scenario.monitor_config(), n).unwrap();
    let mut counters = vec![DetectionCounter::default(); n];
    let (mut run, mut longest) = (vec![0usize; n], vec![0usize; n]);
    // NaN until measured: a run too short to reach the check fails the caller's range check.
    let mut speed_error = f64::NAN;
    let mut step = 0;
    let mut estimated = 0;
    while let Some((samples, truth)) = sim.step() {
        if (gap_at..gap_at + gap_steps).contains(&step) {
            step += 1;
            continue;
        }
        if step == gap_at + gap_steps && bridge {
            monitor.bridge(gap_steps as u64);
        }
        let estimate = monitor.step(samples).unwrap();
        for k in 0..n {
            let flagged = estimate.drives[k].slip_probability > 0.5;
            counters[k].push(step, flagged, truth[k].slipping);
            run[k] = if flagged { run[k] + 1 } else { 0 };
            longest[k] = longest[k].max(run[k]);
            if check.contains(&step) && !truth[k].slipping {
                let e = (estimate.drives[k].speed_rad_s - truth[k].speed_rad_s).abs()
                    / truth[k].speed_rad_s.abs().max(10.0);
                speed_error = if speed_error.is_nan() {
                    e
                } else {
                    speed_error.max(e)
                };
            }
        }
        step += 1;
        estimated += 1;
    }
    (
        counters,
        longest,
        speed_error,
        d.slipping.clone(),
        estimated,
    )
}

/// A gap of `gap_steps` at step 600 (the EKFs locked, the adhesion method warm) of draw
/// `seed`, ending 800 steps or more before the first loss (within the warm-up after a relock,
/// 400 steps, no drive is judged), bridged: the healthy drives flagged on at most 50 steps more
/// than without the gap and never longer in a row than 50 steps or than without it; the
/// slipping drives found (recall at least half of that without the gap); every healthy drive's speed
/// from 10 to 50 ms after the gap within 1 % (of the truth) of its error without the gap (the
/// draws' plants differ from the monitor's model: its speed is a few % off on some).
fn bridged_gap_holds(seed: u64, gap_steps: usize) {
    const GAP_AT: usize = 600;
    let kind = DrawKind::Ordinary;
    let (base, base_longest, _, slipping, _) = run_with_gap(kind, seed, GAP_AT, 0, true);
    // The gapless run's speed error over the same steps as the run with the gap.
    let (.., base_speed_error, _, _) = run_with_gap_measured_at(kind, seed, GAP_AT + gap_steps);
    let (counters, longest, speed_error, _, _) = run_with_gap(kind, seed, GAP_AT, gap_steps, true);
    let at = format!("seed {seed}, gap of {gap_steps} steps at {GAP_AT}");
    for (k, (c, b)) in counters.iter().zip(&base).enumerate() {
        let (s, sb) = (c.score(), b.score());
        if slipping.contains(&k) {
            // Found still: the steps of the gap and of the warm-up after a relock teach the
            // method nothing about each drive's scatter, so a slow ramp soon after is found
            // later than without the gap (seed 1231: F1 0.84 against 0.94).
            let (recall, recall_base) = (s.recall.unwrap_or(0.0), sb.recall.unwrap_or(0.0));
            assert!(
                recall >= 0.5 * recall_base,
                "{at}: slipping drive {} recall {recall:.3}, {recall_base:.3} without the gap",
                k + 1
            );
        } else {
            assert!(
                s.false_pos <= sb.false_pos + 50 && longest[k] <= base_longest[k].max(50),
                "{at}: healthy drive {} flagged on {} steps ({} without the gap), {} in a row",
                k + 1,
                s.false_pos,
                sb.false_pos,
                longest[k]
            );
        }
    }
    assert!(
        speed_error <= base_speed_error + 0.01,
        "{at}: speed {:.2} % off 10-50 ms after ({:.2} % without the gap)",
        100.0 * speed_error,
        100.0 * base_speed_error
    );
}

/// The gapless run, its speed error measured where a gap ending at `gap_end` would have it.
fn run_with_gap_measured_at(
    kind: DrawKind,
    seed: u64,
    gap_end: usize,
) -> (Vec<DetectionCounter>, Vec<usize>, f64, Vec<usize>, usize) {
    run_with_gap(kind, seed, gap_end, 0, true)
}

#[test]
fn gaps_of_every_length_are_bridged_without_a_false_alarm() {
    // dt = 125 us: one sample, 5 ms, the longest predicted gap (50 ms), then 0.15 s
    // (relocked), in traction and braking, few drives and many.
    let longest_predicted = (MAX_PREDICTED_GAP_S / 125e-6).round() as usize;
    for seed in [1201, 1205, 1207, 1221, 1231, 1245] {
        for gap_steps in [1, 40, longest_predicted, 1200] {
            bridged_gap_holds(seed, gap_steps);
        }
    }
    // Seconds across a restart of the service, in a long draw (coasting, then traction).
    bridged_gap_holds(1239, 16000);
}

#[test]
fn a_long_gap_stepped_over_without_bridging_leaves_the_speed_wrong() {
    // What the service did before bridging (issue 26 item 3; the resumed service once showed
    // two drives at -171 rad/s and a slip alarm): after 2 s the rotor angle is anywhere, and
    // the EKFs stepped on from their old state lose the speed, some turning backwards.
    let kind = DrawKind::TrainSpeed;
    let (_, _, unbridged, _, _) = run_with_gap(kind, 1239, 1000, 16000, false);
    let (_, _, bridged, _, _) = run_with_gap(kind, 1239, 1000, 16000, true);
    assert!(
        bridged < 0.02 && unbridged > 5.0 * bridged.max(0.01),
        "speed error 10-50 ms after a 2 s gap: {:.2} % bridged, {:.2} % not",
        100.0 * bridged,
        100.0 * unbridged
    );
}
