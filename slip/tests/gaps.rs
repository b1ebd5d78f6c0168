//! Frames lost before they reach the monitor (a sample lost at the source, the seconds across a
//! restart of the service): `SlipMonitor::bridge` carries the estimator over the missing
//! periods. Tiny gaps are predicted through, longer ones relock the EKFs from the back-EMF.
//! On the condition sampler's draws, with a gap of each length placed in the run, the healthy
//! drives are flagged no more than without the gap, the losses after it are still found and
//! every EKF's speed is back on the truth 10 ms after.

use railmon_slip::ekf::MAX_PREDICTED_GAP_S;
use railmon_slip::sampler::{draw_kind, DrawKind};
use railmon_slip::{DetectionCounter, DetectionScore, DriveSimulator, SlipMonitor};

/// What a run with a gap gave.
struct GapRun {
    /// Per drive, its flags (p > 0.5) scored against the truth.
    scores: Vec<DetectionScore>,
    /// The largest relative speed error of a healthy drive from 10 to 50 ms after the gap's
    /// end (NaN when the run ends before).
    speed_error: f64,
    /// The drives that lose adhesion in the draw.
    slipping: Vec<usize>,
}

/// Runs draw `seed` of `kind` with the frames of steps `gap_at .. gap_at + gap_steps` not
/// given to the monitor (bridged instead when `bridge`).
fn run_with_gap(
    kind: DrawKind,
    seed: u64,
    gap_at: usize,
    gap_steps: usize,
    bridge: bool,
) -> GapRun {
    let d = draw_kind(seed, kind);
    let n = d.scenario.n_drives();
    let dt_s = d.scenario.monitor_config().dt_s;
    let gap_end = gap_at + gap_steps;
    // From 10 ms to 50 ms after the gap: the relocked EKFs have their speed from the back-EMF.
    let check = gap_end + (0.01 / dt_s).round() as usize..=gap_end + (0.05 / dt_s).round() as usize;
    let mut sim = DriveSimulator::new(&d.scenario).unwrap();
    let mut monitor = SlipMonitor::new(&d.scenario.monitor_config(), n).unwrap();
    let mut counters = vec![DetectionCounter::default(); n];
    let mut speed_error = f64::NAN;
    // Behind the fixed lag an estimate names its frame: the frames' steps and truths.
    let mut frames: Vec<(usize, Vec<railmon_slip::DriveTruth>)> = Vec::new();
    let mut step = 0;
    let mut published: Vec<railmon_slip::SlipEstimate> = Vec::new();
    while let Some((samples, truth)) = sim.step() {
        step += 1;
        let step = step - 1;
        if (gap_at..gap_end).contains(&step) {
            continue;
        }
        if step == gap_end && bridge {
            monitor
                .bridge(gap_steps as u64, &mut |e| published.push(e.clone()))
                .unwrap();
        }
        frames.push((step, truth.to_vec()));
        if let Some(e) = monitor.step(samples).unwrap() {
            published.push(e.clone());
        }
    }
    while let Some(e) = monitor.drain().unwrap() {
        published.push(e.clone());
    }
    assert_eq!(
        published.len(),
        frames.len(),
        "every frame's step is published"
    );
    for estimate in &published {
        let (step, truth) = &frames[estimate.step as usize];
        let step = *step;
        for (k, (drive, truth)) in estimate.drives.iter().zip(truth).enumerate() {
            counters[k].push(step, drive.slip_probability > 0.5, truth.slipping);
            if check.contains(&step) && !truth.slipping {
                let e = (drive.speed_rad_s - truth.speed_rad_s).abs()
                    / truth.speed_rad_s.abs().max(10.0);
                speed_error = e.max(if speed_error.is_nan() { e } else { speed_error });
            }
        }
    }
    GapRun {
        scores: counters.iter().map(DetectionCounter::score).collect(),
        speed_error,
        slipping: d.slipping,
    }
}

/// A gap of `gap_steps` at step 600 (the EKFs locked, the adhesion method warm) of draw
/// `seed`, ending 800 steps or more before the first loss (within the warm-up after a relock,
/// 400 steps, no drive is judged), bridged, against the same draw without the gap: each
/// healthy drive flagged on at most 50 steps more, never longer in a row than 50 steps or
/// than without the gap; each slipping drive found (recall at least half of that without the
/// gap); each healthy drive's speed, 10 to 50 ms after the gap, within 1 % (of the truth) of
/// its error at the same steps without the gap (the draws' plants differ from the monitor's
/// model: on some its speed is a few % off).
fn bridged_gap_holds(seed: u64, gap_steps: usize) {
    const GAP_AT: usize = 600;
    let kind = DrawKind::Ordinary;
    let base = run_with_gap(kind, seed, GAP_AT, 0, true);
    // The gapless run's speed error over the steps checked in the run with the gap.
    let base_speed_error = run_with_gap(kind, seed, GAP_AT + gap_steps, 0, true).speed_error;
    let run = run_with_gap(kind, seed, GAP_AT, gap_steps, true);
    let at = format!("seed {seed}, gap of {gap_steps} steps at {GAP_AT}");
    for (k, (s, sb)) in run.scores.iter().zip(&base.scores).enumerate() {
        if run.slipping.contains(&k) {
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
                s.false_pos <= sb.false_pos + 50
                    && s.longest_episode_steps <= sb.longest_episode_steps.max(50),
                "{at}: healthy drive {} flagged on {} steps ({} without the gap), {} in a row",
                k + 1,
                s.false_pos,
                sb.false_pos,
                s.longest_episode_steps
            );
        }
    }
    assert!(
        run.speed_error <= base_speed_error + 0.01,
        "{at}: speed {:.2} % off 10-50 ms after ({:.2} % without the gap)",
        100.0 * run.speed_error,
        100.0 * base_speed_error
    );
}

#[test]
fn gaps_of_every_length_are_bridged_without_a_false_alarm() {
    // dt = 125 us: one sample and the longest predicted gap (0.5 ms), then 5 ms and 0.15 s
    // (relocked), in traction and braking, few drives and many.
    let longest_predicted = (MAX_PREDICTED_GAP_S / 125e-6).round() as usize;
    for seed in [1201, 1205, 1207, 1221, 1231, 1245] {
        for gap_steps in [1, longest_predicted, 40, 1200] {
            bridged_gap_holds(seed, gap_steps);
        }
    }
    // Seconds across a restart of the service, in a long draw (coasting).
    bridged_gap_holds(1239, 16000);
}

#[test]
fn a_long_gap_stepped_over_without_bridging_leaves_the_speed_wrong() {
    // What the service did before bridging (issue 26 item 3; the resumed service once showed
    // two drives at -171 rad/s and a slip alarm): after 2 s the rotor angle is anywhere, and
    // the EKFs stepped on from their old state lose the speed, some turning backwards.
    let kind = DrawKind::TrainSpeed;
    let unbridged = run_with_gap(kind, 1239, 1000, 16000, false).speed_error;
    let bridged = run_with_gap(kind, 1239, 1000, 16000, true).speed_error;
    assert!(
        bridged < 0.02 && unbridged > 5.0 * bridged.max(0.01),
        "speed error 10-50 ms after a 2 s gap: {:.2} % bridged, {:.2} % not",
        100.0 * bridged,
        100.0 * unbridged
    );
}
