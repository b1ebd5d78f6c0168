//! The condition sampler's matrix (issue 23 item 3): draws scenarios from the operating
//! envelope (`railmon_slip::sampler`), runs the EKFs and one adhesion method over each, and
//! prints the distribution over the draws and the worst draws, each reproducible from its seed:
//! - per slipping drive: F1 of "probability > 0.5" and the F1 a detector at the information
//!   bound reaches (`railmon_slip::bound`, `gamma` 1000 steps); a drive is *above the bound*
//!   when that F1 is at least 0.95 (its loss is long and deep enough for the target);
//! - per draw: the largest share of false-alarm steps (p > 0.5) on one healthy drive, the
//!   longest run of them, and whether the slipping drives are the flagged ones (every slipping
//!   drive above the bound flagged on at least half its loss, no healthy drive on more than
//!   0.1 % of its steps).
//!
//! ```text
//! cargo run --release -p railmon-slip --example sample_matrix -- [--draws 200] [--first-seed 1000]
//!     [--split held-out|tuning|all] [--method temporal] [--worst 10] [--list]
//!     [--kind ordinary|train-speed|all-at-once] [--lag-study]
//! cargo run --release -p railmon-slip --example sample_matrix -- --seed N [--write FILE.toml]
//!     [--kind ...]
//! ```
//! `--kind train-speed` runs the same draws with a measured train speed (the drives then
//! torque-controlled, running away when they lose adhesion), `--kind all-at-once` draws where
//! every drive loses adhesion at once with a train speed (`railmon_slip::sampler::DrawKind`);
//! in those every slipping drive is scored against the F1 target, not only those above the
//! torque information bound (the train speed is information the bound does not count).
//! `--split` keeps the seeds of one side of the split (held-out: odd seeds, tuning: even) from
//! `--first-seed` on until `--draws` are run; `--list` prints one row per draw; `--seed` runs
//! one draw and prints its drives; `--write` also writes it as a scenario file for
//! `railmon analyze adhesion --scenario`. `--lag-study` also scores the method published a
//! fixed lag late (`railmon_slip::fixed_lag`) and the views it was chosen among: a causal EMA,
//! centred means, edges back-dated or on the truth's (docs/adhesion.md, "Fixed-lag
//! publication").

use railmon_slip::bound::{
    excess_over_slip_rule_nm, f1_bound, losses_at_bound, LoadChangeInformation,
};
use railmon_slip::fixed_lag::{CentredMean, FixedLagEstimator};
use railmon_slip::model::DriveState;
use railmon_slip::sampler::{draw_kind, is_held_out, Draw, DrawKind};
use railmon_slip::{
    AdhesionEstimator, AdhesionMethod, DetectionCounter, DriveModel, DriveSimulator,
    MultiMethodPipeline,
};

/// The bars of issue 23.
const F1_TARGET: f64 = 0.95;
const FALSE_SHARE_MAX_PCT: f64 = 0.1;
const RUN_MAX_STEPS: usize = 50;

struct Args {
    draws: usize,
    first_seed: u64,
    split: Split,
    method: Option<AdhesionMethod>,
    worst: usize,
    list: bool,
    seed: Option<u64>,
    write: Option<String>,
    kind: DrawKind,
    lag_study: bool,
}

#[derive(Clone, Copy, PartialEq)]
enum Split {
    HeldOut,
    Tuning,
    All,
}

fn usage() -> ! {
    eprintln!(
        "usage: sample_matrix [--draws N] [--first-seed S] [--split held-out|tuning|all] \
         [--method NAME] [--worst N] [--list] | --seed N [--write FILE.toml] [--method NAME]; \
         [--kind ordinary|train-speed|all-at-once] [--lag-study]"
    );
    std::process::exit(2);
}

fn parse_args() -> Args {
    let mut a = Args {
        draws: 200,
        first_seed: 1000,
        split: Split::HeldOut,
        method: None,
        worst: 10,
        list: false,
        seed: None,
        write: None,
        kind: DrawKind::Ordinary,
        lag_study: false,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().unwrap_or_else(|| usage());
        match flag.as_str() {
            "--draws" => a.draws = value().parse().unwrap_or_else(|_| usage()),
            "--first-seed" => a.first_seed = value().parse().unwrap_or_else(|_| usage()),
            "--split" => {
                a.split = match value().as_str() {
                    "held-out" => Split::HeldOut,
                    "tuning" => Split::Tuning,
                    "all" => Split::All,
                    _ => usage(),
                }
            }
            "--method" => a.method = Some(value().parse().unwrap_or_else(|_| usage())),
            "--worst" => a.worst = value().parse().unwrap_or_else(|_| usage()),
            "--list" => a.list = true,
            "--seed" => a.seed = Some(value().parse().unwrap_or_else(|_| usage())),
            "--write" => a.write = Some(value()),
            "--kind" => a.kind = value().parse().unwrap_or_else(|_| usage()),
            "--lag-study" => a.lag_study = true,
            _ => usage(),
        }
    }
    a
}

/// One slipping drive's figures.
struct Slipping {
    drive: usize,
    f1: f64,
    recall: f64,
    alarm_f1: f64,
    bound_f1: f64,
    /// The bound of the slip rule's question: the information in the loss's excess over the
    /// rule's tolerance (below).
    bound_f1_rule: f64,
    /// Whether the loss is deeper than the EKF resolves: `|depth| >= max(0.1 |T|, 0.5 N m,
    /// 3 s) + 2 s`, `s` the rms error of the drive's torque estimate while it adhered.
    resolvable: bool,
    median_delay: Option<f64>,
    /// The deepest loss: (departure, healthy load) at its deepest step, N m; the rms error of
    /// the drive's torque estimate while it adhered (for `--seed`'s table).
    depth: (f64, f64),
    rms_nm: f64,
}

/// One draw's figures.
struct Outcome {
    draw: Draw,
    slipping: Vec<Slipping>,
    /// Per healthy drive: (drive, false steps p > 0.5, longest run, false alarm steps, first
    /// step of the longest run).
    healthy: Vec<(usize, usize, usize, usize, usize)>,
    /// Drives whose drawn loss the slip rule never flags (scored neither way).
    sub_rule: usize,
    steps: usize,
    lag: Option<(LagScores, Vec<Vec<f64>>)>,
}

impl Outcome {
    fn worst_false_pct(&self) -> f64 {
        self.healthy
            .iter()
            .map(|h| 100.0 * h.1 as f64 / self.steps as f64)
            .fold(0.0, f64::max)
    }
    fn longest_run(&self) -> usize {
        self.healthy.iter().map(|h| h.2).max().unwrap_or(0)
    }
    fn above_bound(&self) -> impl Iterator<Item = &Slipping> {
        self.slipping.iter().filter(|s| s.bound_f1 >= F1_TARGET)
    }
    fn above_bound_resolvable(&self) -> impl Iterator<Item = &Slipping> {
        self.above_bound().filter(|s| s.resolvable)
    }
    /// The slipping drives held to the F1 target: those above the bound, or with every drive
    /// losing adhesion at once (a train speed), every one.
    fn targets(&self) -> impl Iterator<Item = &Slipping> {
        let all = self.draw.kind == DrawKind::AllAtOnce;
        self.slipping
            .iter()
            .filter(move |s| all || s.bound_f1 >= F1_TARGET)
    }
    fn right_drives_flagged(&self) -> bool {
        self.targets().all(|s| s.recall >= 0.5) && self.worst_false_pct() <= FALSE_SHARE_MAX_PCT
    }
    /// The same with the slipping drives above the slip rule's bound as the targets.
    fn right_drives_flagged_by_rule(&self) -> bool {
        let all = self.draw.kind == DrawKind::AllAtOnce;
        self.slipping
            .iter()
            .filter(|s| all || s.bound_f1_rule >= F1_TARGET)
            .all(|s| s.recall >= 0.5)
            && self.worst_false_pct() <= FALSE_SHARE_MAX_PCT
    }
    /// How far the draw is from the bars, 1 at a bar: the largest of the healthy drives'
    /// false share over 0.1 %, their longest run over 50 steps and the F1 shortfall of a
    /// slipping drive above the bound over 0.05.
    fn badness(&self) -> f64 {
        let shortfall = self
            .targets()
            .map(|s| (1.0 - s.f1) / (1.0 - F1_TARGET))
            .fold(0.0, f64::max);
        (self.worst_false_pct() / FALSE_SHARE_MAX_PCT)
            .max(self.longest_run() as f64 / RUN_MAX_STEPS as f64)
            .max(shortfall)
    }
    fn many_at_once(&self) -> bool {
        let d = &self.draw;
        2 * d.slipping.len() >= d.scenario.n_drives()
            && d.onsets != railmon_slip::sampler::Onsets::Staggered
    }
    fn summary(&self) -> String {
        let d = &self.draw;
        let f1s: Vec<String> = self
            .slipping
            .iter()
            .map(|s| {
                let mark = match (s.bound_f1 >= F1_TARGET, s.resolvable) {
                    (true, true) => "",
                    (true, false) => "~",
                    (false, _) => "*",
                };
                format!("{}:{:.3}{mark}", s.drive + 1, s.f1)
            })
            .collect();
        format!(
            "| {} | {} | {} of {} | {} | {} | {:.2} | {:.3} | {} | {} | {} |",
            d.seed,
            d.regime.name(),
            d.slipping.len(),
            d.scenario.n_drives(),
            d.onsets.name(),
            d.scenario.n_steps(),
            d.noise_factor,
            self.worst_false_pct(),
            self.longest_run(),
            if self.right_drives_flagged() {
                "yes"
            } else {
                "no"
            },
            f1s.join(" "),
        )
    }
}

fn run(draw: Draw, method: Option<AdhesionMethod>, lag_study: bool) -> Outcome {
    let scenario = &draw.scenario;
    let n = scenario.n_drives();
    let mut cfg = scenario.monitor_config();
    if let Some(m) = method {
        cfg.method = m;
    }
    let mut pipe = MultiMethodPipeline::with_methods(&cfg, n, &[cfg.method]).expect("pipeline");
    if let Some(t) = &scenario.train_speed {
        pipe.set_speed_reference(t.speed_reference())
            .expect("speed reference");
    }
    let mut sim = DriveSimulator::new(scenario).expect("simulator");
    let model = DriveModel::new(scenario.plant.motor, scenario.dt_s()).expect("model");
    let noise = scenario.noise;
    let mut info: Vec<Option<LoadChangeInformation>> = (0..n)
        .map(|k| {
            draw.slipping.contains(&k).then(|| {
                LoadChangeInformation::new(
                    model,
                    noise.current_std_a,
                    noise.voltage_std_v,
                    noise.load_std_nm,
                )
            })
        })
        .collect();
    let mut probability = vec![DetectionCounter::default(); n];
    let mut alarm = vec![DetectionCounter::default(); n];
    let mut truth_flags = vec![Vec::new(); n];
    // Per drive, the sum of squares and count of its torque estimate's error while it adheres
    // before its first loss (from step 1000, the EKFs locked): its resolution.
    let mut adhering_error = vec![(0.0, 0usize); n];
    let (mut run_now, mut run_max) = (vec![0usize; n], vec![0usize; n]);
    let mut run_start = vec![0usize; n];
    let mut lag = lag_study.then(|| LagRunner::new(&cfg, n));
    // The pipeline publishes each step `FIXED_LAG_STEPS` frames later (the fixed lag on every
    // path): its probabilities and alarms are scored against the truth of the step they name
    // (`step_index`), kept here until then, and the last steps are drained at the end.
    let mut truth_by_step: Vec<Vec<bool>> = Vec::new();
    let mut score_published = |pipe: &MultiMethodPipeline, truth_by_step: &[Vec<bool>]| {
        let named = pipe.step_index() as usize;
        let (_, probability_now) = pipe.slip_probability().next().expect("one method");
        let (_, flags) = pipe.slipping().next().expect("one method");
        for k in 0..n {
            let flagged = probability_now[k] > 0.5;
            let truth = truth_by_step[named][k];
            probability[k].push(named, flagged, truth);
            alarm[k].push(named, flags[k], truth);
            run_now[k] = if flagged { run_now[k] + 1 } else { 0 };
            if run_now[k] > run_max[k] {
                run_max[k] = run_now[k];
                run_start[k] = named + 1 - run_now[k];
            }
        }
    };
    let mut step = 0;
    while let Some((samples, truth, train_speed)) = sim.step_with_train_speed() {
        truth_by_step.push(truth.iter().map(|t| t.slipping).collect());
        let published = pipe
            .step_with_train_speed(samples, train_speed)
            .expect("pipeline step");
        if let Some(l) = &mut lag {
            l.push(pipe.torque_nm(), &truth_by_step[step]);
        }
        if published {
            score_published(&pipe, &truth_by_step);
        }
        for k in 0..n {
            if let Some(i) = &mut info[k] {
                let (s, t) = (&samples[k], &truth[k]);
                if step >= 1000 && !truth_flags[k].contains(&true) && !t.slipping {
                    let e = pipe.torque_nm()[k] - t.torque_nm;
                    adhering_error[k].0 += e * e;
                    adhering_error[k].1 += 1;
                }
                i.push(&DriveState::new(
                    s.i_alpha_a,
                    s.i_beta_a,
                    t.speed_rad_s,
                    t.angle_rad,
                    t.torque_nm,
                ));
                truth_flags[k].push(t.slipping);
            }
        }
        step += 1;
    }
    while pipe.drain().expect("drain") {
        score_published(&pipe, &truth_by_step);
    }
    let mut slipping = Vec::new();
    let mut healthy = Vec::new();
    let mut sub_rule = 0;
    for k in 0..n {
        let (p, a) = (probability[k].score(), alarm[k].score());
        match &info[k] {
            Some(i) if p.events > 0 => {
                let departure = |t: usize| {
                    scenario.true_load_nm(k, t as f64).0 - scenario.healthy_load_nm(k, t as f64)
                };
                let losses = losses_at_bound(i, &truth_flags[k], departure);
                let at_bound: Vec<_> = losses.iter().map(|l| l.at_bound[0]).collect();
                // The bound of the slip rule's question (is the loss beyond the tolerance?):
                // that of the loss's excess over the tolerance.
                let excess = |t: usize| {
                    excess_over_slip_rule_nm(departure(t), scenario.healthy_load_nm(k, t as f64))
                };
                let at_rule: Vec<_> = losses_at_bound(i, &truth_flags[k], excess)
                    .iter()
                    .map(|l| l.at_bound[0])
                    .collect();
                let (sum, count) = adhering_error[k];
                let rms = (sum / count.max(1) as f64).sqrt();
                let resolvable = losses.iter().all(|l| {
                    let healthy = scenario.healthy_load_nm(k, l.on as f64).abs();
                    let limit = (0.1 * healthy).max(0.5).max(3.0 * rms);
                    l.depth_nm.abs() >= limit + 2.0 * rms
                });
                slipping.push(Slipping {
                    drive: k,
                    f1: p.f1.unwrap_or(0.0),
                    recall: p.recall.unwrap_or(0.0),
                    alarm_f1: a.f1.unwrap_or(0.0),
                    bound_f1: f1_bound(&at_bound),
                    bound_f1_rule: f1_bound(&at_rule),
                    resolvable,
                    median_delay: p.median_delay_steps,
                    depth: losses
                        .iter()
                        .max_by(|a, b| a.depth_nm.abs().total_cmp(&b.depth_nm.abs()))
                        .map_or((0.0, 0.0), |l| {
                            (l.depth_nm, scenario.healthy_load_nm(k, l.on as f64))
                        }),
                    rms_nm: rms,
                });
            }
            // A drive whose drawn loss stays within the slip rule (coasting, shallow losses
            // of small loads) is neither: its load did change, so a flag is no false alarm.
            Some(_) => sub_rule += 1,
            None => healthy.push((k, p.false_pos, run_max[k], a.false_pos, run_start[k])),
        }
    }
    let lag = lag.map(|l| {
        let ks: Vec<usize> = slipping.iter().map(|s| s.drive).collect();
        let hs: Vec<usize> = healthy.iter().map(|h| h.0).collect();
        lag_scores(&l.finish(), &ks, &hs)
    });
    Outcome {
        draw,
        slipping,
        healthy,
        sub_rule,
        steps: step,
        lag,
    }
}

fn quantiles(mut v: Vec<f64>) -> String {
    if v.is_empty() {
        return "–".to_owned();
    }
    v.sort_by(f64::total_cmp);
    let q = |f: f64| v[((v.len() - 1) as f64 * f).round() as usize];
    format!(
        "min {:.3}, 5 % {:.3}, 25 % {:.3}, median {:.3}, max {:.3}",
        q(0.0),
        q(0.05),
        q(0.25),
        q(0.5),
        q(1.0)
    )
}

const HEADER: &str = "| seed | regime | slipping | onsets | steps | noise x | worst healthy false % | longest healthy run | slipping drives flagged | F1 per slipping drive (* below the bound, ~ not resolved) |\n|---|---|---|---|---|---|---|---|---|---|";

fn main() {
    let args = parse_args();
    if let Some(seed) = args.seed {
        let d = draw_kind(seed, args.kind);
        if let Some(path) = &args.write {
            let text = toml::to_string(&d.scenario).expect("scenario as TOML");
            let header = format!("# {}\n", d.scenario.description);
            std::fs::write(path, header + &text).expect("write the scenario");
            eprintln!("wrote {path}");
        }
        let o = run(d, args.method, args.lag_study);
        println!("{}", o.draw.scenario.description);
        println!("{HEADER}");
        println!("{}", o.summary());
        println!();
        println!("| drive | F1 | recall | alarm F1 | F1 at the bound | at the rule's bound | median delay | deepest loss / healthy load [N m] (x the tolerance) | EKF rms [N m] | resolved |");
        println!("|---|---|---|---|---|---|---|---|---|---|");
        for s in &o.slipping {
            let delay = s.median_delay.map_or("–".to_owned(), |d| format!("{d:.0}"));
            let (dep, load) = s.depth;
            let tol = (railmon_slip::sample::SLIP_RULE_FRACTION * load.abs())
                .max(railmon_slip::sample::SLIP_RULE_FLOOR_NM);
            println!(
                "| {} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {delay} | {dep:.2} / {load:.2} ({:.2}) | {:.2} | {} |",
                s.drive + 1,
                s.f1,
                s.recall,
                s.alarm_f1,
                s.bound_f1,
                s.bound_f1_rule,
                dep.abs() / tol,
                s.rms_nm,
                if s.resolvable { "yes" } else { "no" }
            );
        }
        println!();
        println!("| healthy drive | false steps | longest run (from step) | false alarm steps |");
        println!("|---|---|---|---|");
        for (k, f, r, a, from) in &o.healthy {
            println!("| {} | {f} | {r} ({from}) | {a} |", k + 1);
        }
        return;
    }
    let seeds = (args.first_seed..)
        .filter(|&s| match args.split {
            Split::HeldOut => is_held_out(s),
            Split::Tuning => !is_held_out(s),
            Split::All => true,
        })
        .take(args.draws);
    let mut outcomes = Vec::new();
    for seed in seeds {
        let o = run(draw_kind(seed, args.kind), args.method, args.lag_study);
        if args.list {
            if outcomes.is_empty() {
                println!("{HEADER}");
            }
            println!("{}", o.summary());
        }
        outcomes.push(o);
    }
    let method = args
        .method
        .unwrap_or(railmon_slip::SlipMonitorConfig::default().method);
    let above: Vec<&Slipping> = outcomes.iter().flat_map(|o| o.above_bound()).collect();
    let met = above.iter().filter(|s| s.f1 >= F1_TARGET).count();
    let all_slipping = outcomes.iter().map(|o| o.slipping.len()).sum::<usize>();
    let sub_rule = outcomes.iter().map(|o| o.sub_rule).sum::<usize>();
    let healthy = outcomes.iter().map(|o| o.healthy.len()).sum::<usize>();
    println!(
        "method {method}, {} draws (seeds {}..={}, split {}), {healthy} healthy drives, {sub_rule} drives with a loss the slip rule never flags (not scored), {} slipping drives, {} above the bound",
        outcomes.len(),
        outcomes.first().map_or(0, |o| o.draw.seed),
        outcomes.last().map_or(0, |o| o.draw.seed),
        match args.split {
            Split::HeldOut => "held-out",
            Split::Tuning => "tuning",
            Split::All => "all",
        },
        all_slipping,
        above.len()
    );
    println!();
    println!("| figure | value |");
    println!("|---|---|");
    if args.kind != DrawKind::Ordinary {
        let targets: Vec<&Slipping> = outcomes.iter().flat_map(|o| o.targets()).collect();
        let hit = targets.iter().filter(|s| s.f1 >= F1_TARGET).count();
        println!(
            "| draws {}: slipping drives held to the target with F1 >= 0.95 | {hit} of {} ({:.1} %) |",
            args.kind.name(),
            targets.len(),
            100.0 * hit as f64 / targets.len().max(1) as f64
        );
        println!(
            "| F1 of slipping drives held to the target | {} |",
            quantiles(targets.iter().map(|s| s.f1).collect())
        );
        let worst = outcomes
            .iter()
            .flat_map(|o| o.targets().map(move |s| (o.draw.seed, s.drive, s.f1)))
            .min_by(|a, b| a.2.total_cmp(&b.2));
        if let Some((seed, drive, f1)) = worst {
            println!(
                "| worst slipping drive | seed {seed}, drive {}: F1 {f1:.3} |",
                drive + 1
            );
        }
    }
    println!(
        "| slipping drives above the bound with F1 >= 0.95 | {met} of {} ({:.1} %) |",
        above.len(),
        100.0 * met as f64 / above.len().max(1) as f64
    );
    // The same share by kind of draw, and for losses well above the bound.
    let share = |name: &str, keep: &dyn Fn(&Outcome, &Slipping) -> bool| {
        let (mut n, mut hit) = (0, 0);
        for o in &outcomes {
            for s in o.above_bound().filter(|s| keep(o, s)) {
                n += 1;
                hit += usize::from(s.f1 >= F1_TARGET);
            }
        }
        println!(
            "| {name}: F1 >= 0.95 | {hit} of {n} ({:.1} %) |",
            100.0 * hit as f64 / n.max(1) as f64
        );
    };
    share("half or more at once (within 5 ms)", &|o, _| {
        o.many_at_once()
    });
    share("fewer than half, or staggered", &|o, _| !o.many_at_once());
    for regime in ["traction", "braking", "coasting"] {
        share(regime, &|o, _| o.draw.regime.name() == regime);
    }
    share("F1 at the bound >= 0.99", &|_, s| s.bound_f1 >= 0.99);
    share(
        "above the bound of the slip rule (the loss's excess over the tolerance)",
        &|_, s| s.bound_f1_rule >= F1_TARGET,
    );
    share("deeper than the EKF resolves", &|_, s| s.resolvable);
    share(
        "deeper than the EKF resolves, half or more at once",
        &|o, s| s.resolvable && o.many_at_once(),
    );
    println!(
        "| F1 of slipping drives above the bound and resolved | {} |",
        quantiles(
            outcomes
                .iter()
                .flat_map(|o| o.above_bound_resolvable())
                .map(|s| s.f1)
                .collect()
        )
    );
    println!(
        "| F1 of slipping drives above the bound | {} |",
        quantiles(above.iter().map(|s| s.f1).collect())
    );
    println!(
        "| alarm F1 of slipping drives above the bound | {} |",
        quantiles(above.iter().map(|s| s.alarm_f1).collect())
    );
    let over = |f: &dyn Fn(&Outcome) -> bool| outcomes.iter().filter(|o| f(o)).count();
    println!(
        "| worst healthy false-alarm share per draw [%] | {} |",
        quantiles(outcomes.iter().map(Outcome::worst_false_pct).collect())
    );
    println!(
        "| draws with a healthy drive over 0.1 % | {} |",
        over(&|o| o.worst_false_pct() > FALSE_SHARE_MAX_PCT)
    );
    println!(
        "| longest healthy run per draw [steps] | {} |",
        quantiles(outcomes.iter().map(|o| o.longest_run() as f64).collect())
    );
    println!(
        "| draws with a healthy run over 50 steps | {} |",
        over(&|o| o.longest_run() > RUN_MAX_STEPS)
    );
    println!(
        "| draws with healthy alarm steps | {} |",
        over(&|o| o.healthy.iter().any(|h| h.3 > 0))
    );
    let many: Vec<&Outcome> = outcomes.iter().filter(|o| o.many_at_once()).collect();
    println!(
        "| half or more at once (within 5 ms): slipping drives are the flagged ones | {} of {} draws |",
        many.iter().filter(|o| o.right_drives_flagged()).count(),
        many.len()
    );
    println!(
        "| half or more at once: those above the slip rule's bound are the flagged ones | {} of {} draws |",
        many.iter().filter(|o| o.right_drives_flagged_by_rule()).count(),
        many.len()
    );
    println!(
        "| every draw: slipping drives are the flagged ones | {} of {} draws |",
        over(&|o| o.right_drives_flagged()),
        outcomes.len()
    );
    if args.lag_study {
        print_lag_study(&outcomes);
    }
    println!();
    let mut ranked: Vec<&Outcome> = outcomes.iter().collect();
    ranked.sort_by(|a, b| b.badness().total_cmp(&a.badness()));
    println!("Worst {} draws (badness: 1 at a bar)", args.worst);
    println!();
    println!("{HEADER}");
    for o in ranked.iter().take(args.worst) {
        println!("{} badness {:.2}", o.summary(), o.badness());
    }
}

// Fixed-lag study (issue 23 item 1, eighth round): what a slip probability published L steps
// late could gain. Per drive the flags "p > 0.5" of the shipped method on the raw torque
// estimates, on a causal EMA (alpha 1/32, sixth round) and on a centred boxcar of the same
// white-noise variance (63 steps, published 31 late), each scored as it is and with its
// episodes' edges moved: back by a fixed number of steps (realisable with that look-ahead) or
// onto the truth's (an oracle).

/// Half-widths of the centred boxcars: 2 H + 1 = 63 steps has the variance of an EMA of
/// `alpha` 1/32 on white noise (`alpha / (2 - alpha)` = 1/63).
const BOX_HALVES: [usize; 2] = [31, 47];
const EMA_ALPHA: f64 = 1.0 / 32.0;

/// Edge moves: (name, back-date of onsets, back-date of releases); `None` = the oracle.
const EDGES: [(&str, Option<(usize, usize)>); 14] = [
    ("as is", Some((0, 0))),
    ("-8/0", Some((8, 0))),
    ("-16/0", Some((16, 0))),
    ("-24/0", Some((24, 0))),
    ("-32/0", Some((32, 0))),
    ("-16/-8", Some((16, 8))),
    ("-24/-8", Some((24, 8))),
    ("-24/-16", Some((24, 16))),
    ("-32/-16", Some((32, 16))),
    ("-24/-24", Some((24, 24))),
    ("-24/-32", Some((24, 32))),
    ("-24/-48", Some((24, 48))),
    ("-32/-48", Some((32, 48))),
    ("oracle", None),
];

fn runs(flags: &[bool]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut start = None;
    for (t, &f) in flags.iter().enumerate() {
        match (start, f) {
            (None, true) => start = Some(t),
            (Some(a), false) => {
                out.push((a, t));
                start = None;
            }
            _ => {}
        }
    }
    if let Some(a) = start {
        out.push((a, flags.len()));
    }
    out
}

/// Every episode `[a, b)` becomes `[a - on, b - off)` (dropped when empty).
fn back_date(flags: &[bool], on: usize, off: usize) -> Vec<bool> {
    let mut out = vec![false; flags.len()];
    for (a, b) in runs(flags) {
        let (a, b) = (a.saturating_sub(on), b.saturating_sub(off));
        for f in out.iter_mut().take(b).skip(a) {
            *f = true;
        }
    }
    out
}

/// Every episode that overlaps a true loss becomes the true losses it overlaps.
fn oracle(flags: &[bool], truth: &[bool]) -> Vec<bool> {
    let mut out = vec![false; flags.len()];
    let true_runs = runs(truth);
    for (a, b) in runs(flags) {
        let hit: Vec<_> = true_runs.iter().filter(|r| r.0 < b && a < r.1).collect();
        if hit.is_empty() {
            for f in &mut out[a..b] {
                *f = true;
            }
        }
        for r in hit {
            for f in &mut out[r.0..r.1] {
                *f = true;
            }
        }
    }
    out
}

/// (F1, false steps, longest run of flags outside a loss).
fn score_flags(flags: &[bool], truth: &[bool]) -> (f64, usize, usize, Option<f64>) {
    let mut c = DetectionCounter::default();
    let (mut run, mut longest) = (0, 0);
    for (t, (&f, &tr)) in flags.iter().zip(truth).enumerate() {
        c.push(t, f, tr);
        run = if f && !tr { run + 1 } else { 0 };
        longest = longest.max(run);
    }
    let s = c.score();
    (
        s.f1.unwrap_or(0.0),
        s.false_pos,
        longest,
        s.median_delay_steps,
    )
}

/// Median steps from each true loss's end to the end of the detected episode over it.
fn release_delays(flags: &[bool], truth: &[bool]) -> Vec<f64> {
    let det = runs(flags);
    runs(truth)
        .into_iter()
        .filter_map(|(_, e)| {
            det.iter()
                .find(|d| d.0 < e && e <= d.1)
                .or_else(|| det.iter().rev().find(|d| d.1 <= e && d.1 + 200 > e))
                .map(|d| d.1 as f64 - e as f64)
        })
        .collect()
}

/// A centred mean of `2 half + 1` steps of the torque estimates and the method on it: its
/// flag for step `t` is known at `t + half`.
struct Centred {
    half: usize,
    mean: CentredMean,
    est: AdhesionEstimator,
    flags: Vec<Vec<bool>>,
}

impl Centred {
    fn new(cfg: &railmon_slip::SlipMonitorConfig, n: usize, half: usize) -> Self {
        Centred {
            half,
            mean: CentredMean::new(half, n),
            est: AdhesionEstimator::new(cfg.method, &cfg.adhesion, n).expect("estimator"),
            flags: vec![Vec::new(); n],
        }
    }

    fn push(&mut self, x: &[f64]) {
        // The first mean is step 0's (the window cut at the start), given at step `half`.
        if let Some(m) = self.mean.push(x) {
            let p = &self.est.estimate(m).expect("centred").slip_probability;
            for (f, &pk) in self.flags.iter_mut().zip(p) {
                f.push(pk > 0.5);
            }
        }
    }

    /// The last `half` steps' means, over the steps there are after them.
    fn drain(&mut self) {
        while let Some(m) = self.mean.drain() {
            let p = &self.est.estimate(m).expect("centred").slip_probability;
            for (f, &pk) in self.flags.iter_mut().zip(p) {
                f.push(pk > 0.5);
            }
        }
    }
}

/// Per-drive flags of the views.
struct LagViews {
    views: Vec<(String, Vec<Vec<bool>>)>,
    truth: Vec<Vec<bool>>,
}

struct LagRunner {
    /// The method on the raw torque estimates, causal (as shipped before the fixed lag).
    raw_est: AdhesionEstimator,
    ema_est: AdhesionEstimator,
    ema_x: Vec<f64>,
    raw: Vec<Vec<bool>>,
    ema: Vec<Vec<bool>>,
    centred: Vec<Centred>,
    /// The library's stage (`railmon_slip::fixed_lag`), its flags dated back by its lag.
    stage: FixedLagEstimator,
    stage_flags: Vec<Vec<bool>>,
    truth: Vec<Vec<bool>>,
}

impl LagRunner {
    fn new(cfg: &railmon_slip::SlipMonitorConfig, n: usize) -> Self {
        LagRunner {
            raw_est: AdhesionEstimator::new(cfg.method, &cfg.adhesion, n).expect("estimator"),
            ema_est: AdhesionEstimator::new(cfg.method, &cfg.adhesion, n).expect("estimator"),
            ema_x: Vec::new(),
            raw: vec![Vec::new(); n],
            ema: vec![Vec::new(); n],
            centred: BOX_HALVES
                .iter()
                .map(|&h| Centred::new(cfg, n, h))
                .collect(),
            stage: FixedLagEstimator::new(
                AdhesionEstimator::new(cfg.method, &cfg.adhesion, n).expect("estimator"),
            ),
            stage_flags: vec![Vec::new(); n],
            truth: vec![Vec::new(); n],
        }
    }

    fn push(&mut self, x: &[f64], truth: &[bool]) {
        let n = x.len();
        let p_raw = self
            .raw_est
            .estimate(x)
            .expect("raw")
            .slip_probability
            .clone();
        if self.ema_x.is_empty() {
            self.ema_x = x.to_vec();
        }
        for (e, &xk) in self.ema_x.iter_mut().zip(x) {
            *e += EMA_ALPHA * (xk - *e);
        }
        let p = &self
            .ema_est
            .estimate(&self.ema_x)
            .expect("ema")
            .slip_probability;
        for k in 0..n {
            self.raw[k].push(p_raw[k] > 0.5);
            self.ema[k].push(p[k] > 0.5);
            self.truth[k].push(truth[k]);
        }
        for c in &mut self.centred {
            c.push(x);
        }
        // The stage's first output (at step FIXED_LAG_STEPS) is step 0's.
        if let Some(p) = self.stage.estimate(x).expect("stage") {
            for (f, &pk) in self.stage_flags.iter_mut().zip(p) {
                f.push(pk > 0.5);
            }
        }
    }

    fn finish(mut self) -> LagViews {
        for c in &mut self.centred {
            c.drain();
        }
        while let Some((p, _)) = self.stage.drain().expect("stage drain") {
            for (f, &pk) in self.stage_flags.iter_mut().zip(p) {
                f.push(pk > 0.5);
            }
        }
        let len = self.raw.first().map_or(0, Vec::len);
        let mut views = vec![
            ("raw".to_owned(), self.raw),
            ("ema 1/32".to_owned(), self.ema),
        ];
        for c in self.centred {
            assert!(
                c.flags.iter().all(|f| f.len() == len),
                "every step has its flag"
            );
            views.push((format!("centred {}", 2 * c.half + 1), c.flags));
        }
        let stage = self.stage_flags;
        assert!(
            stage.iter().all(|f| f.len() == len),
            "every step has its flag"
        );
        views.push(("library stage".to_owned(), stage));
        LagViews {
            views,
            truth: self.truth,
        }
    }
}

/// Per variant (view x edge move): per slipping drive its F1, per healthy drive (false
/// steps, longest run).
type LagScores = Vec<(String, Vec<f64>, Vec<(usize, usize)>, Vec<Option<f64>>)>;

fn lag_scores(v: &LagViews, slipping: &[usize], healthy: &[usize]) -> (LagScores, Vec<Vec<f64>>) {
    let mut out = Vec::new();
    for (view, flags) in &v.views {
        for (edge, mv) in EDGES {
            let moved = |k: usize| match mv {
                Some((on, off)) => back_date(&flags[k], on, off),
                None => oracle(&flags[k], &v.truth[k]),
            };
            let sc: Vec<_> = slipping
                .iter()
                .map(|&k| score_flags(&moved(k), &v.truth[k]))
                .collect();
            let f1s = sc.iter().map(|s| s.0).collect();
            let delays = sc.iter().map(|s| s.3).collect();
            let h = healthy
                .iter()
                .map(|&k| {
                    let s = score_flags(&moved(k), &v.truth[k]);
                    (s.1, s.2)
                })
                .collect();
            out.push((format!("{view}, {edge}"), f1s, h, delays));
        }
    }
    let rel = v
        .views
        .iter()
        .map(|(_, flags)| {
            slipping
                .iter()
                .flat_map(|&k| release_delays(&flags[k], &v.truth[k]))
                .collect()
        })
        .collect();
    (out, rel)
}

fn print_lag_study(outcomes: &[Outcome]) {
    let Some((first, _)) = outcomes.iter().find_map(|o| o.lag.as_ref()) else {
        return;
    };
    println!();
    println!("Fixed-lag study (F1 >= 0.95 of the slipping drives above the bound; resolved / not; draws with a healthy drive over 0.1 %; draws with a healthy run over 50 steps)");
    println!();
    println!("| view, edges back-dated (onset/release) | F1 >= 0.95 | resolved | not resolved | false draws | long-run draws | worst healthy false % (seed) | longest healthy run |");
    println!("|---|---|---|---|---|---|---|---|");
    for (v, (name, _, _, _)) in first.iter().enumerate() {
        let (mut n, mut met, mut met_r, mut n_r, mut fd, mut rd) = (0, 0, 0, 0, 0, 0);
        let (mut worst_all, mut worst_seed, mut longest) = (0.0, 0, 0);
        for o in outcomes {
            let Some((scores, _)) = &o.lag else { continue };
            let (_, f1s, h, _) = &scores[v];
            for (s, &f1) in o.slipping.iter().zip(f1s) {
                if s.bound_f1 >= F1_TARGET {
                    n += 1;
                    met += usize::from(f1 >= F1_TARGET);
                    if s.resolvable {
                        n_r += 1;
                        met_r += usize::from(f1 >= F1_TARGET);
                    }
                }
            }
            let worst = h
                .iter()
                .map(|x| 100.0 * x.0 as f64 / o.steps as f64)
                .fold(0.0, f64::max);
            fd += usize::from(worst > FALSE_SHARE_MAX_PCT);
            if worst > worst_all {
                (worst_all, worst_seed) = (worst, o.draw.seed);
            }
            longest = longest.max(h.iter().map(|x| x.1).max().unwrap_or(0));
            rd += usize::from(h.iter().any(|x| x.1 > RUN_MAX_STEPS));
        }
        println!(
            "| {name} | {met} of {n} ({:.1} %) | {met_r} of {n_r} | {} of {} | {fd} | {rd} | {worst_all:.3} ({worst_seed}) | {longest} |",
            100.0 * met as f64 / n.max(1) as f64,
            met - met_r,
            n - n_r
        );
    }
    println!();
    println!("| view | onset delay [steps], per drive median, above the bound | release delay [steps], truth's end to the episode's end |");
    println!("|---|---|---|");
    for (v, (name, _, _, _)) in first
        .iter()
        .enumerate()
        .filter(|(_, x)| x.0.ends_with("as is"))
    {
        let i = v / EDGES.len();
        let rel: Vec<f64> = outcomes
            .iter()
            .filter_map(|o| o.lag.as_ref())
            .flat_map(|l| l.1[i].clone())
            .collect();
        let on: Vec<f64> = outcomes
            .iter()
            .filter_map(|o| o.lag.as_ref().map(|l| (o, l)))
            .flat_map(|(o, l)| {
                o.slipping
                    .iter()
                    .zip(&l.0[v].3)
                    .filter(|(s, _)| s.bound_f1 >= F1_TARGET)
                    .filter_map(|(_, d)| *d)
            })
            .collect();
        println!("| {name} | {} | {} |", quantiles(on), quantiles(rel));
    }
}
