//! The detection matrix of issue 10: every adhesion scenario of `config/scenarios/` through the
//! EKFs and every method, scored per drive against the slip rule. Prints markdown tables (the
//! ones in docs/adhesion.md):
//! - per scenario, method and drive that loses adhesion: precision, recall, F1 of
//!   "probability > 0.5", median delay, and the F1 of the alarm rule (what the service raises);
//! - per scenario and method, over the drives that never lose adhesion: false-alarm steps
//!   (probability > 0.5, and alarm on), the largest of one drive and the share of all steps,
//!   and the alarm's false episodes (`slip_started` on a drive that never slips);
//! - per method over the whole matrix: true losses, alarm starts, false alarm episodes on
//!   slipping and on healthy drives (an episode is false when none of its steps is a true slip).
//!
//! `cargo bench -p railmon-slip --bench matrix [-- [--confirm=N] [--hold=N] NAME]`
//! (NAME: run only scenarios whose file name contains it; `--confirm`, `--hold`: the alarm's
//! `confirm_steps`, `release_hold_steps`). Every method is behind the fixed lag
//! (`railmon_slip::fixed_lag`, as the service and `analyze` run it), scored at the steps its
//! probabilities name. Takes a minute or two in release on one core.

use std::time::Instant;

mod scenarios_dir;
use scenarios_dir::scenario_paths;

use railmon_slip::{
    AdhesionMethod, AdhesionScenario, DetectionCounter, DetectionScore, DriveSimulator,
    MultiMethodPipeline,
};

struct MethodCounters {
    method: String,
    probability: Vec<DetectionCounter>,
    alarm: Vec<DetectionCounter>,
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or("–".to_owned(), |x| format!("{x:.digits$}"))
}

fn main() {
    let filter = std::env::args().skip(1).find(|a| !a.starts_with('-'));
    let mut per_drive = Vec::new();
    let mut healthy = Vec::new();
    // Per method (in `AdhesionMethod::ALL` order): true losses, alarm starts on slipping
    // drives, false alarm episodes on slipping drives, on healthy drives.
    let labels: Vec<String> = AdhesionMethod::ALL.iter().map(|m| m.to_string()).collect();
    let mut episodes = vec![[0usize; 4]; labels.len()];
    for path in scenario_paths(filter.as_deref()) {
        let text = std::fs::read_to_string(&path).expect("scenario file");
        let scenario = AdhesionScenario::from_toml_str(&text)
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let n = scenario.n_drives();
        let mut sim = DriveSimulator::new(&scenario).expect("simulator");
        let mut cfg = scenario.monitor_config();
        // `--confirm=N`, `--hold=N`: the alarm's holds (`[alarm]`), for the sweep in the docs.
        for arg in std::env::args() {
            let number = |s: &str| s.parse().expect("a number of steps");
            if let Some(v) = arg.strip_prefix("--confirm=") {
                cfg.alarm.confirm_steps = number(v);
            } else if let Some(v) = arg.strip_prefix("--hold=") {
                cfg.alarm.release_hold_steps = number(v);
            }
        }
        let mut pipe = MultiMethodPipeline::new(&cfg, n).expect("pipeline");
        let mut counters: Vec<MethodCounters> = labels
            .iter()
            .map(|method| MethodCounters {
                method: method.clone(),
                probability: vec![DetectionCounter::default(); n],
                alarm: vec![DetectionCounter::default(); n],
            })
            .collect();
        // Every method is behind the fixed lag: each published step is scored against the
        // truth of the step it names, the run's last steps drained at its end.
        let mut truths: Vec<Vec<bool>> = Vec::new();
        let score =
            |pipe: &MultiMethodPipeline, truths: &[Vec<bool>], counters: &mut [MethodCounters]| {
                let at = pipe.step_index() as usize;
                for ((c, (_, p)), (_, flags)) in counters
                    .iter_mut()
                    .zip(pipe.method_probability())
                    .zip(pipe.slipping())
                {
                    for k in 0..n {
                        c.probability[k].push(at, p[k] > 0.5, truths[at][k]);
                        c.alarm[k].push(at, flags[k], truths[at][k]);
                    }
                }
            };
        let mut step = 0;
        let mut pipeline_s = 0.0;
        while let Some((samples, truth)) = sim.step() {
            truths.push(truth.iter().map(|t| t.slipping).collect());
            let t0 = Instant::now();
            let published = pipe.step(samples).expect("pipeline step");
            pipeline_s += t0.elapsed().as_secs_f64();
            if published {
                score(&pipe, &truths, &mut counters);
            }
            step += 1;
        }
        while pipe.drain().expect("drain") {
            score(&pipe, &truths, &mut counters);
        }
        let name = scenario.name.clone();
        eprintln!(
            "{name}: {n} drives x {step} steps, pipeline (EKFs + 5 methods) {:.2} M drive-steps/s",
            (n * step) as f64 / pipeline_s / 1e6
        );
        for (c, totals) in counters.iter().zip(&mut episodes) {
            let scores: Vec<(DetectionScore, DetectionScore)> = c
                .probability
                .iter()
                .zip(&c.alarm)
                .map(|(p, a)| (p.score(), a.score()))
                .collect();
            let (mut false_p, mut false_a, mut worst_p, mut worst_a, mut n_healthy) =
                (0, 0, 0, 0, 0);
            let (mut healthy_episodes, mut worst_episodes) = (0, 0);
            for (k, (p, a)) in scores.iter().enumerate() {
                if p.events == 0 {
                    n_healthy += 1;
                    false_p += p.false_pos;
                    false_a += a.false_pos;
                    worst_p = worst_p.max(p.false_pos);
                    worst_a = worst_a.max(a.false_pos);
                    healthy_episodes += a.false_episodes;
                    worst_episodes = worst_episodes.max(a.false_episodes);
                    totals[3] += a.false_episodes;
                    continue;
                }
                totals[0] += a.events;
                totals[1] += a.detection_episodes;
                totals[2] += a.false_episodes;
                per_drive.push(format!(
                    "| {name} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
                    c.method,
                    k + 1,
                    opt(p.precision, 3),
                    opt(p.recall, 3),
                    opt(p.f1, 3),
                    opt(p.median_delay_steps, 0),
                    p.missed_events,
                    opt(a.f1, 3),
                    opt(a.median_delay_steps, 0),
                    a.events,
                    a.detection_episodes,
                    a.false_episodes,
                ));
            }
            if n_healthy > 0 {
                let share = |f: usize| 100.0 * f as f64 / (n_healthy * step) as f64;
                healthy.push(format!(
                    "| {name} | {} | {n_healthy} | {worst_p} | {:.3} % | {worst_a} | {:.3} % | {healthy_episodes} | {worst_episodes} |",
                    c.method,
                    share(false_p),
                    share(false_a),
                ));
            }
        }
    }
    println!("| scenario | method | drive | precision | recall | F1 | median delay | missed events | alarm F1 | alarm delay | losses | alarm starts | false alarm episodes |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for row in &per_drive {
        println!("{row}");
    }
    println!();
    println!("| scenario | method | healthy drives | most false steps (p > 0.5) | share of steps | most false steps (alarm) | share of steps | false alarm episodes | most on one drive |");
    println!("|---|---|---|---|---|---|---|---|---|");
    for row in &healthy {
        println!("{row}");
    }
    println!();
    println!("| method | true losses | alarm starts on slipping drives | starts per loss | false alarm episodes, slipping drives | false alarm episodes, healthy drives |");
    println!("|---|---|---|---|---|---|");
    for (method, [losses, starts, false_slipping, false_healthy]) in labels.iter().zip(&episodes) {
        println!(
            "| {method} | {losses} | {starts} | {:.2} | {false_slipping} | {false_healthy} |",
            *starts as f64 / (*losses).max(1) as f64
        );
    }
}
