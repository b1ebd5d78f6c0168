//! The train-speed reference (issue 23 item 2): with the train's own speed every drive losing
//! adhesion at once is seen (which no comparison between drives can see), healthy drives stay
//! unflagged under the sensor's noise, and without it the estimate says it judged by the group.

use railmon_slip::fixed_lag::FIXED_LAG_STEPS;
use railmon_slip::sampler::{draw_kind, is_held_out, DrawKind};
use railmon_slip::{
    AdhesionMethod, AdhesionScenario, DetectionCounter, DetectionScore, DriveSimulator,
    MultiMethodPipeline, SlipAlarm, SlipEstimate, SlipMonitor, SpeedReference,
};

/// `n` drives at `load_nm` (negative: braking), every one losing `depth` of it on
/// [6000, 6000 + duration) (onsets within `spread` steps), the train speed measured with
/// `noise_m_s` (absent: none).
fn scenario(
    seed: u64,
    n: usize,
    load_nm: f64,
    depth: f64,
    duration: f64,
    spread: f64,
    noise_m_s: Option<f64>,
) -> AdhesionScenario {
    let mut text = format!(
        "name = \"all-at-once\"\nn_drives = {n}\nn_steps = {}\ndt_s = 125e-6\nseed = {seed}\n\
         [plant]\nsubsteps = 2\n[noise]\ncurrent_std_a = 0.015\nvoltage_std_v = 0.05\n\
         load_std_nm = 0.1\n[load]\nlevels_nm = [{load_nm:?}]\nswitch_steps = []\n\
         smoothing_steps = 30.0\n",
        6000.0 + duration + 6000.0
    );
    if let Some(noise) = noise_m_s {
        text += &format!("[train_speed]\nnoise_std_m_s = {noise:?}\n");
    }
    for k in 0..n {
        if depth > 0.0 {
            let start = 6000.0 + (spread * k as f64 / n as f64).round();
            text += &format!(
                "[[events]]\nkind = \"drop\"\ndrive = {}\nstart_step = {start:?}\n\
                 end_step = {:?}\nremaining_fraction = {:?}\n",
                k + 1,
                start + duration,
                1.0 - depth
            );
        }
    }
    AdhesionScenario::from_toml_str(&text).unwrap()
}

/// Runs the monitor (default settings, the plant's geometry) over `s`, with the train speed
/// when the scenario has one; per drive its score and longest run of flagged steps, and the
/// references the estimates reported.
fn run(s: &AdhesionScenario) -> (Vec<DetectionScore>, Vec<usize>, Vec<SpeedReference>) {
    let n = s.n_drives();
    let mut sim = DriveSimulator::new(s).unwrap();
    let mut monitor = SlipMonitor::new(&s.monitor_config(), n).unwrap();
    if let Some(t) = &s.train_speed {
        monitor.set_speed_reference(t.speed_reference()).unwrap();
    }
    let mut counters = vec![DetectionCounter::default(); n];
    let (mut run, mut longest) = (vec![0; n], vec![0; n]);
    let mut references = Vec::new();
    // Behind the fixed lag each estimate is scored on the truth of the step it names.
    let mut truths = Vec::new();
    let mut score = |e: &SlipEstimate, truths: &[Vec<railmon_slip::DriveTruth>]| {
        let step = e.step as usize;
        if !references.contains(&e.reference) {
            references.push(e.reference);
        }
        for k in 0..n {
            let flagged = e.drives[k].slip_probability > 0.5;
            counters[k].push(step, flagged, truths[step][k].slipping);
            run[k] = if flagged { run[k] + 1 } else { 0 };
            longest[k] = longest[k].max(run[k]);
        }
    };
    while let Some((samples, truth, train)) = sim.step_with_train_speed() {
        truths.push(truth.to_vec());
        if let Some(e) = monitor.step_with_train_speed(samples, train).unwrap() {
            score(e, &truths);
        }
    }
    while let Some(e) = monitor.drain().unwrap() {
        score(e, &truths);
    }
    (
        counters.iter().map(DetectionCounter::score).collect(),
        longest,
        references,
    )
}

#[test]
fn all_six_drives_losing_adhesion_at_once_are_flagged_with_a_train_speed() {
    for (seed, load, depth, spread) in [
        (11, 20.0, 0.5, 0.0),
        (12, -15.0, 0.6, 0.0),
        (13, 8.0, 0.4, 40.0),
        (14, -30.0, 0.8, 40.0),
    ] {
        let s = scenario(seed, 6, load, depth, 8000.0, spread, Some(0.2));
        let (scores, _, references) = run(&s);
        // The group while the test warms up and calibrates (0.15 s), then the train speed.
        assert_eq!(
            references,
            [SpeedReference::Group, SpeedReference::TrainSpeed]
        );
        for (k, score) in scores.iter().enumerate() {
            assert!(
                score.f1.unwrap_or(0.0) >= 0.95 && score.missed_events == 0,
                "seed {seed}, load {load}, drive {}: {score:?}",
                k + 1
            );
        }
    }
}

#[test]
fn without_a_train_speed_the_reference_is_the_group_and_the_common_loss_goes_unseen() {
    let s = scenario(11, 6, 20.0, 0.5, 8000.0, 0.0, None);
    let (scores, _, references) = run(&s);
    assert_eq!(references, [SpeedReference::Group]);
    // The blind spot the train speed closes: the group moves together, nothing stands out.
    for (k, score) in scores.iter().enumerate() {
        assert!(
            score.recall.unwrap_or(0.0) < 0.5,
            "drive {}: {score:?}",
            k + 1
        );
    }
}

/// The train speed's noise (0.2 m/s, 3.5 % of the speed per sample) flags no healthy drive,
/// in traction, braking and coasting; nor does the group's blip on seed 23 at 3 N m (7 steps
/// of the adhesion method over the same frames without the train speed), which the train speed,
/// judging alone once calibrated, overrules.
#[test]
fn healthy_drives_under_a_noisy_train_speed_are_not_flagged() {
    for (seed, load) in [(21, 25.0), (22, -25.0), (23, 3.0), (24, 0.2), (25, -3.0)] {
        let s = scenario(seed, 6, load, 0.0, 20_000.0, 0.0, Some(0.2));
        let n = s.n_drives();
        let mut sim = DriveSimulator::new(&s).unwrap();
        let mut with = SlipMonitor::new(&s.monitor_config(), n).unwrap();
        let mut group = SlipMonitor::new(&s.monitor_config(), n).unwrap();
        let (mut added, mut flagged) = (0, 0);
        while let Some((samples, truth, train)) = sim.step_with_train_speed() {
            assert!(train.is_some() && truth.iter().all(|t| !t.slipping));
            // Both publish the same step at the same frame (the fixed lag).
            let g: Option<Vec<bool>> = group
                .step(samples)
                .unwrap()
                .map(|g| g.drives.iter().map(|d| d.slip_probability > 0.5).collect());
            let e = with.step_with_train_speed(samples, train).unwrap();
            let (Some(g), Some(e)) = (g, e) else {
                continue;
            };
            for (d, g) in e.drives.iter().zip(g) {
                let f = d.slip_probability > 0.5;
                flagged += usize::from(f);
                added += usize::from(f && !g);
            }
        }
        assert_eq!((added, flagged), (0, 0), "seed {seed}, load {load}");
    }
}

#[test]
fn a_drive_losing_adhesion_runs_away_from_the_train() {
    for load in [20.0, -20.0] {
        let s = scenario(31, 2, load, 0.5, 4000.0, 0.0, Some(0.0));
        let t = s.train_speed.unwrap();
        let per_m_s = t.gear_ratio * s.plant.motor.pole_pairs / t.wheel_radius_m;
        let mut sim = DriveSimulator::new(&s).unwrap();
        let mut departure = (0.0f64, 0.0f64);
        let mut step = 0;
        while let Some((_, truth)) = sim.step() {
            let rotor = truth[0].speed_rad_s;
            step += 1;
            let train = sim.true_train_speed_m_s().unwrap() * per_m_s;
            let d = (rotor - train) * load.signum();
            if step == 5_900 {
                departure.0 = d;
            }
            if step == 9_900 {
                departure.1 = d;
            }
        }
        // Adhering: within the creep (under 1 % of 200 rad/s); slipping for 0.5 s with half
        // the load gone: p_p 10 N m / J = 1000 rad/s^2 away, less the constant-power fade.
        assert!(departure.0.abs() < 2.0, "{load}: {departure:?}");
        assert!(departure.1 > 100.0, "{load}: {departure:?}");
    }
}

#[test]
fn a_train_speed_out_of_range_is_refused_and_changes_nothing() {
    let s = scenario(41, 3, 10.0, 0.0, 1000.0, 0.0, Some(0.1));
    let mut sim = DriveSimulator::new(&s).unwrap();
    let mut monitor = SlipMonitor::new(&s.monitor_config(), 3).unwrap();
    let (samples, _) = sim.step().unwrap();
    for bad in [-1.0, 100.5, f64::NAN] {
        let e = monitor
            .step_with_train_speed(samples, Some(bad))
            .unwrap_err()
            .to_string();
        assert!(e.contains("train_speed_m_s"), "{e}");
        assert_eq!(monitor.bank().filters()[0].frames, 0);
    }
    // Warming up and calibrating, the group still judges; then the train speed.
    // The first frames publish nothing (the fixed lag).
    assert!(monitor
        .step_with_train_speed(samples, Some(5.75))
        .unwrap()
        .is_none());
    for _ in 1..FIXED_LAG_STEPS {
        let (samples, _, train) = sim.step_with_train_speed().unwrap();
        assert!(monitor
            .step_with_train_speed(samples, train)
            .unwrap()
            .is_none());
    }
    let (samples, _, train) = sim.step_with_train_speed().unwrap();
    let e = monitor
        .step_with_train_speed(samples, train)
        .unwrap()
        .unwrap();
    assert_eq!((e.step, e.reference), (0, SpeedReference::Group));
    // The test judges from 0.15 s (1,200 steps) on: published FIXED_LAG_STEPS frames later.
    for _ in FIXED_LAG_STEPS + 1..1_200 + FIXED_LAG_STEPS {
        let (samples, _, train) = sim.step_with_train_speed().unwrap();
        monitor.step_with_train_speed(samples, train).unwrap();
    }
    let (samples, _) = sim.step().unwrap();
    let e = monitor
        .step_with_train_speed(samples, Some(5.75))
        .unwrap()
        .unwrap();
    assert_eq!(e.reference, SpeedReference::TrainSpeed);
    // Frames without the train speed: the steps published still had it, until the first
    // frame without it comes out of the lag.
    for _ in 0..FIXED_LAG_STEPS {
        let e = monitor.step(samples).unwrap().unwrap();
        assert_eq!(e.reference, SpeedReference::TrainSpeed);
    }
    let e = monitor.step(samples).unwrap().unwrap();
    assert_eq!(e.reference, SpeedReference::Group);
}

/// Draws of the sampler where every drive loses adhesion at once, with a train speed: held-out
/// seeds (`cargo run --release -p railmon-slip --example sample_matrix -- --kind all-at-once
/// --seed N` prints each).
#[test]
fn sampler_draws_of_every_drive_losing_adhesion_at_once_are_flagged() {
    for seed in [1001, 1003, 1005] {
        assert!(is_held_out(seed));
        let d = draw_kind(seed, DrawKind::AllAtOnce);
        assert_eq!(d.slipping.len(), d.scenario.n_drives());
        let (scores, _, _) = run(&d.scenario);
        for (k, score) in scores.iter().enumerate() {
            assert!(
                score.f1.unwrap_or(0.0) >= 0.95,
                "seed {seed}, drive {}: {score:?}",
                k + 1
            );
        }
    }
}

/// Every method of the offline pipeline (`railmon analyze adhesion`) runs its own train-speed
/// test, as a monitor of that method does (the service): the same probabilities, references
/// and alarm events, bit for bit, on every drive losing adhesion at once.
#[test]
fn the_pipeline_judges_each_method_as_its_monitor_does() {
    let s = scenario(15, 3, 20.0, 0.5, 3000.0, 0.0, Some(0.2));
    let n = s.n_drives();
    let reference = s.train_speed.unwrap().speed_reference();
    let mut sim = DriveSimulator::new(&s).unwrap();
    let mut pipe = MultiMethodPipeline::new(&s.monitor_config(), n).unwrap();
    pipe.set_speed_reference(reference).unwrap();
    let mut monitors: Vec<(SlipMonitor, SlipAlarm)> = AdhesionMethod::ALL
        .iter()
        .map(|&method| {
            let config = railmon_slip::SlipMonitorConfig {
                method,
                ..s.monitor_config()
            };
            let mut m = SlipMonitor::new(&config, n).unwrap();
            m.set_speed_reference(reference).unwrap();
            (m, SlipAlarm::new(config.alarm, n).unwrap())
        })
        .collect();
    let (mut events, mut started) = (Vec::new(), 0);
    let frames: Vec<_> =
        std::iter::from_fn(|| sim.step_with_train_speed().map(|(x, _, t)| (x.to_vec(), t)))
            .collect();
    let mut frames = frames.into_iter();
    loop {
        // The frames, then the steps still behind the lag: both paths drain the same way.
        let frame = frames.next();
        let published = match &frame {
            Some((samples, train)) => pipe.step_with_train_speed(samples, *train).unwrap(),
            None => pipe.drain().unwrap(),
        };
        if frame.is_none() && !published {
            break;
        }
        for ((((m, alarm), (_, p)), (_, r)), (_, e)) in monitors
            .iter_mut()
            .zip(pipe.slip_probability())
            .zip(pipe.references())
            .zip(pipe.events())
        {
            let est = match &frame {
                Some((samples, train)) => m.step_with_train_speed(samples, *train).unwrap(),
                None => m.drain().unwrap(),
            };
            assert_eq!(est.is_some(), published);
            let Some(est) = est else { continue };
            assert_eq!(est.step, pipe.step_index());
            let q: Vec<f64> = est.drives.iter().map(|d| d.slip_probability).collect();
            assert_eq!(q, p);
            assert_eq!(est.reference, r);
            events.clear();
            alarm.update(&q, &mut events);
            assert_eq!(events.as_slice(), e);
            started += e.len();
        }
    }
    // Every method flags every drive (3 drives x 5 methods, start and end).
    assert!(started >= 30, "{started}");
}

/// A speed sensor reads a magnitude: however noisy, the simulated train speed is never
/// negative (the service refuses a negative one as implausible, so a replay of our own
/// simulator near standstill would have lost frames).
#[test]
fn the_measured_train_speed_is_never_negative() {
    let s = scenario(3, 2, 20.0, 0.0, 200.0, 0.0, Some(1e3));
    let mut sim = DriveSimulator::new(&s).unwrap();
    let (mut zeros, mut steps) = (0, 0);
    while let Some((_, _, train)) = sim.step_with_train_speed() {
        let v = train.expect("the scenario has a train speed");
        assert!(v.is_finite() && v >= 0.0, "{v}");
        zeros += usize::from(v == 0.0);
        steps += 1;
    }
    // About half the readings of a noise this large would have been negative.
    assert!(zeros > steps / 4, "{zeros} of {steps} at 0");
}
