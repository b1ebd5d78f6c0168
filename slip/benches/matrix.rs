//! The detection matrix of issue 10: every adhesion scenario of `config/scenarios/` through the
//! EKFs and every method, scored per drive against the slip rule. Prints markdown tables (the
//! ones in docs/adhesion.md):
//! - per scenario, method and drive that loses adhesion: precision, recall, F1 of
//!   "probability > 0.5", median delay, and the F1 of the alarm rule (what the service raises);
//! - per scenario and method, over the drives that never lose adhesion: false-alarm steps
//!   (probability > 0.5, and alarm on), the largest of one drive and the share of all steps.
//!
//! `cargo bench -p railmon-slip --bench matrix [-- [--jump] NAME]` (NAME: run only scenarios
//! whose file name contains it; `--jump`: every EKF with its load-jump test on). Takes a minute or two in release on one core.

use std::time::Instant;

mod scenarios_dir;
use scenarios_dir::scenario_paths;

use railmon_slip::{
    AdhesionMethod, AdhesionScenario, DetectionCounter, DetectionScore, DriveSimulator,
    MultiMethodPipeline,
};

struct MethodCounters {
    method: AdhesionMethod,
    probability: Vec<DetectionCounter>,
    alarm: Vec<DetectionCounter>,
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or("–".to_owned(), |x| format!("{x:.digits$}"))
}

fn main() {
    let filter = std::env::args().skip(1).find(|a| !a.starts_with('-'));
    let jump = std::env::args().any(|a| a == "--jump");
    let mut per_drive = Vec::new();
    let mut healthy = Vec::new();
    for path in scenario_paths(filter.as_deref()) {
        let text = std::fs::read_to_string(&path).expect("scenario file");
        let scenario = AdhesionScenario::from_toml_str(&text)
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let n = scenario.n_drives();
        let mut sim = DriveSimulator::new(&scenario).expect("simulator");
        let mut cfg = scenario.monitor_config();
        // `--jump`: the same with the load-jump test of the EKFs on (`[ekf.jump]`).
        cfg.ekf.jump.enabled |= jump;
        let mut pipe = MultiMethodPipeline::new(&cfg, n).expect("pipeline");
        let mut counters: Vec<MethodCounters> = AdhesionMethod::ALL
            .iter()
            .map(|&method| MethodCounters {
                method,
                probability: vec![DetectionCounter::default(); n],
                alarm: vec![DetectionCounter::default(); n],
            })
            .collect();
        let mut step = 0;
        let mut pipeline_s = 0.0;
        while let Some((samples, truth)) = sim.step() {
            let t0 = Instant::now();
            pipe.step(samples).expect("pipeline step");
            pipeline_s += t0.elapsed().as_secs_f64();
            for ((c, (_, out)), (_, flags)) in
                counters.iter_mut().zip(pipe.outputs()).zip(pipe.slipping())
            {
                for k in 0..n {
                    c.probability[k].push(step, out.slip_probability[k] > 0.5, truth[k].slipping);
                    c.alarm[k].push(step, flags[k], truth[k].slipping);
                }
            }
            step += 1;
        }
        let name = scenario.name.clone();
        eprintln!(
            "{name}: {n} drives x {step} steps, pipeline (EKFs + 5 methods) {:.2} M drive-steps/s",
            (n * step) as f64 / pipeline_s / 1e6
        );
        for c in &counters {
            let scores: Vec<(DetectionScore, DetectionScore)> = c
                .probability
                .iter()
                .zip(&c.alarm)
                .map(|(p, a)| (p.score(), a.score()))
                .collect();
            let (mut false_p, mut false_a, mut worst_p, mut worst_a, mut n_healthy) =
                (0, 0, 0, 0, 0);
            for (k, (p, a)) in scores.iter().enumerate() {
                if p.events == 0 {
                    n_healthy += 1;
                    false_p += p.false_pos;
                    false_a += a.false_pos;
                    worst_p = worst_p.max(p.false_pos);
                    worst_a = worst_a.max(a.false_pos);
                    continue;
                }
                per_drive.push(format!(
                    "| {name} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
                    c.method,
                    k + 1,
                    opt(p.precision, 3),
                    opt(p.recall, 3),
                    opt(p.f1, 3),
                    opt(p.median_delay_steps, 0),
                    p.missed_events,
                    opt(a.f1, 3),
                    opt(a.median_delay_steps, 0),
                ));
            }
            if n_healthy > 0 {
                let share = |f: usize| 100.0 * f as f64 / (n_healthy * step) as f64;
                healthy.push(format!(
                    "| {name} | {} | {n_healthy} | {worst_p} | {:.3} % | {worst_a} | {:.3} % |",
                    c.method,
                    share(false_p),
                    share(false_a),
                ));
            }
        }
    }
    println!("| scenario | method | drive | precision | recall | F1 | median delay | missed events | alarm F1 | alarm delay |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for row in &per_drive {
        println!("{row}");
    }
    println!();
    println!("| scenario | method | healthy drives | most false steps (p > 0.5) | share of steps | most false steps (alarm) | share of steps |");
    println!("|---|---|---|---|---|---|---|");
    for row in &healthy {
        println!("{row}");
    }
}
