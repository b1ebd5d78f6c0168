//! The damper's condition matrix (issue 24 item 5): scenarios drawn from the whole operating
//! envelope by `railmon_damper::sampler` (speed profiles with stops, track, sensor noise,
//! conicity, body mass, faults), each run through `DamperMonitor` + `DamperAlarm` with the
//! filter's defaults (it assumes the design vehicle: only the plant varies), given the
//! plant's body mass as the measured load (`BogieSample::half_body_mass_kg`; `--withhold-mass`:
//! not given, the filter assumes the design mass). The quick check stays `robustness_matrix`
//! (one factor at a time).
//!
//! Per draw one row: the conditions; false `damper_degraded` events (on a damper whose fault
//! has not started); the lowest published health ratio (posterior mean / nominal) of each
//! damper while it is healthy, after the alarm's warm-up (`!` when below the alarm's
//! `degraded_below_ratio`), and how long and in how many stretches it was below (how many
//! began within 2 s of a jump hypothesis becoming particles); the jump hypotheses that became
//! particles while both dampers were healthy (`Rbpf::jump_count`), how many were adopted
//! into the published posterior (`Rbpf::jump_adoptions`) and how many moved a published
//! ratio down by more than 0.05 within 2 s; after 30 s, every 10 ms: the share of time with both means within
//! 5 % of the truth, the 90 % interval's coverage of each damper, the share of time the
//! filter reports `model_mismatch`, and the mean error `mean / truth - 1` of each damper; per
//! faulty damper the detection delay, from the first sample with the truth below the alarm's
//! threshold while the speed is in the filter's range (a fault at a stop: from moving off
//! again). Then the totals, the figures by body mass, and the worst draws by each criterion
//! with the command that reproduces each.
//!
//! ```text
//! cargo run --release -p railmon-damper --example condition_matrix -- \
//!     --draws 40 --first-seed 5000 --split held-out --particles 500 --duration-s 120
//! ```
//! Even seeds are tuning draws, odd seeds held out: tune on `--split tune`, report on
//! `--split held-out`. A draw depends on its seed and on `--duration-s` (the longest run: a
//! draw lasts 0.5-1 times it, its events placed within), so a row is reproduced by
//! `--first-seed S --draws 1 --split all` with the same `--duration-s` and `--particles`.

use std::process::ExitCode;
use std::sync::Arc;
use std::time::Instant;

use railmon_damper::gain_table::GainTable;
use railmon_damper::sampler::{self, Draw, FaultShape};
use railmon_damper::{
    BogieSimulator, DamperAlarm, DamperEventKind, DamperId, DamperMonitor, DamperMonitorConfig,
    Rbpf,
};

mod draws;
mod flags;
mod oracle;
use draws::Split;
use flags::{on_off, parsed};

/// Accuracy, coverage and mismatch are counted from here (s), as in `robustness_matrix`.
const JUDGE_FROM_S: f64 = 30.0;
/// "Within" means both posterior means within this of the truth.
const WITHIN: f64 = 0.05;
/// A jump hypothesis that became particles "moved" a healthy damper's published ratio when
/// it fell by more than this within `JUMP_WINDOW_S` after it (of nominal).
const JUMP_MOVE: f64 = 0.05;
/// How long after a materialisation its effect on the published ratio is looked for (s).
const JUMP_WINDOW_S: f64 = 2.0;

struct Args {
    draws: usize,
    first_seed: u64,
    split: Split,
    duration_s: f64,
    worst: usize,
    verbose: bool,
    /// Only draws of this fault shape (`--shape`).
    shape: Option<FaultShape>,
    /// Only draws with a stop (`--with-stops`).
    with_stops: bool,
    withhold_mass: bool,
    /// The filter is given the plant's own conicity (`--oracle-conicity`).
    oracle_conicity: bool,
    config: DamperMonitorConfig,
}

fn usage() -> String {
    format!(
        "usage: condition_matrix [FLAGS]\n\
         \n\
         --draws N          draws to run, N >= 1 (default 40)\n\
         --first-seed S     the first seed considered (default 5000)\n\
         --split all|tune|held-out  which seeds from S on: all, even (tune), odd (held-out;\n\
         \u{20}                  default)\n\
         --particles N      rbpf.particles (default {particles})\n\
         --duration-s S     the longest run, s >= {min} (default {max}): a draw lasts 0.5-1\n\
         \u{20}                  times it\n\
         --worst K          the worst K draws by each criterion (default 3)\n\
         --shape S          only draws whose fault is S: healthy, step, ramp or at-stop (a\n\
         \u{20}                  step while standing); the seeds of the split are skipped\n\
         \u{20}                  until N such draws\n\
         --with-stops       only draws whose speed profile has a stop\n\
         --verbose          print each damper_degraded event\n\
         --withhold-mass    the samples carry no body mass (the particles carry their own,\n\
         \u{20}                  rbpf.unmeasured_mass)\n\
         --design-mass      without a measured mass assume the design one\n\
         \u{20}                  (rbpf.unmeasured_mass.enabled = false)\n\
         --oracle-conicity  the filter's vehicle takes each draw's plant conicity (an upper\n\
         \u{20}                  bound: the conicity is not measured onboard), its speed range\n\
         \u{20}                  ending at the draw's top speed; gain grids solved per draw\n\
         --rbpf-seed N      rbpf.seed (default 0): the filter's own random numbers, to tell\n\
         \u{20}                  a figure from the run-to-run spread\n\
         --jump on|off      rbpf.jump_search.enabled (default on)\n\
         --min-speed-m-s V  speed.min_m_s: the filter pauses below it (default {min_speed})\n\
         --resume-settle-s S  speed.resume_settle_s, the least settling after a pause\n\
         \u{20}                  (default {settle})\n\
         --help             this text",
        particles = DamperMonitorConfig::default().rbpf.particles,
        min_speed = DamperMonitorConfig::default().speed.min_m_s,
        settle = DamperMonitorConfig::default().speed.resume_settle_s,
        min = sampler::MIN_MAX_DURATION_S,
        max = sampler::MAX_DURATION_S,
    )
}

fn parse_args() -> Result<Args, String> {
    let mut args = Args {
        draws: 40,
        first_seed: 5000,
        split: Split::HeldOut,
        duration_s: sampler::MAX_DURATION_S,
        worst: 3,
        verbose: false,
        shape: None,
        with_stops: false,
        withhold_mass: false,
        oracle_conicity: false,
        config: DamperMonitorConfig::default(),
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or(format!("{flag} needs a value"));
        match flag.as_str() {
            "--help" | "-h" => {
                println!("{}", usage());
                std::process::exit(0);
            }
            "--draws" => args.draws = parsed(&flag, &value()?)?,
            "--first-seed" => args.first_seed = parsed(&flag, &value()?)?,
            "--split" => args.split = value()?.parse()?,
            "--particles" => args.config.rbpf.particles = parsed(&flag, &value()?)?,
            "--duration-s" => args.duration_s = parsed(&flag, &value()?)?,
            "--worst" => args.worst = parsed(&flag, &value()?)?,
            "--verbose" => args.verbose = true,
            "--shape" => {
                args.shape = Some(match value()?.as_str() {
                    "healthy" => FaultShape::None,
                    "step" => FaultShape::Step,
                    "ramp" => FaultShape::Ramp,
                    "at-stop" => FaultShape::AtStop,
                    other => {
                        return Err(format!("--shape {other}: healthy, step, ramp or at-stop"))
                    }
                })
            }
            "--with-stops" => args.with_stops = true,
            "--withhold-mass" => args.withhold_mass = true,
            "--design-mass" => args.config.rbpf.unmeasured_mass.enabled = false,
            "--oracle-conicity" => args.oracle_conicity = true,
            "--rbpf-seed" => args.config.rbpf.seed = parsed(&flag, &value()?)?,
            "--jump" => args.config.rbpf.jump_search.enabled = on_off(&flag, &value()?)?,
            "--min-speed-m-s" => args.config.speed.min_m_s = parsed(&flag, &value()?)?,
            "--resume-settle-s" => args.config.speed.resume_settle_s = parsed(&flag, &value()?)?,
            other => return Err(format!("unknown flag {other}")),
        }
    }
    if args.draws == 0 {
        return Err("--draws 0: at least one".into());
    }
    if !(args.duration_s >= sampler::MIN_MAX_DURATION_S && args.duration_s.is_finite()) {
        return Err(format!(
            "--duration-s {}: at least {}",
            args.duration_s,
            sampler::MIN_MAX_DURATION_S
        ));
    }
    args.config.validate().map_err(|e| e.to_string())?;
    Ok(args)
}

/// A faulty damper's detection.
struct Detection {
    damper: DamperId,
    /// Where the delay counts from (`Draw::detectable_from_s`); `None`: not reached in the run.
    from_s: Option<f64>,
    /// The first `damper_degraded` of the damper after its fault started.
    at_s: Option<f64>,
    /// Faults at a stop: the delay the data allow ([`DataBound`]), `None` inside when the
    /// evidence never became decisive in the run; `None`: not a fault at a stop.
    data_bound_s: Option<Option<f64>>,
}

impl Detection {
    fn delay_s(&self) -> Option<f64> {
        Some(self.at_s? - self.from_s?)
    }

    fn missed(&self) -> bool {
        self.from_s.is_some() && self.at_s.is_none()
    }

    fn text(&self) -> String {
        let what = match (self.from_s, self.at_s) {
            (Some(_), Some(_)) => format!("{:+.1} s", self.delay_s().unwrap_or(0.0)),
            (Some(_), None) => "MISSED".to_owned(),
            (None, Some(at)) => format!("at {at:.1} s, before the crossing"),
            (None, None) => "not reached".to_owned(),
        };
        let bound = match self.data_bound_s {
            Some(Some(b)) => format!(" (data {b:.1} s)"),
            Some(None) => " (data: never decisive)".to_owned(),
            None => String::new(),
        };
        format!("{} {what}{bound}", self.damper.name())
    }
}

/// One draw's figures.
struct Outcome {
    draw: Draw,
    false_degraded: usize,
    /// The lowest health ratio of each damper while healthy, after the alarm's warm-up.
    healthy_min_ratio: [Option<f64>; 2],
    /// Time a healthy damper's published ratio spent below the alarm's threshold, after the
    /// warm-up (s, both dampers summed), and in how many stretches.
    below_s: f64,
    below_stretches: usize,
    /// Of those stretches, how many began within `JUMP_WINDOW_S` of a materialisation.
    below_after_jump: usize,
    /// Jump hypotheses that became particles (`Rbpf::jump_count`) while both dampers were
    /// healthy, and how many of them moved a healthy published ratio down by `JUMP_MOVE`.
    healthy_jumps: usize,
    moving_jumps: usize,
    /// Jump hypotheses adopted into the published posterior (`Rbpf::jump_adoptions`) while
    /// both dampers were healthy.
    healthy_adoptions: usize,
    judged: usize,
    within: usize,
    covered: [usize; 2],
    mismatch: usize,
    error_sum: [f64; 2],
    detections: Vec<Detection>,
    diverged_at_s: Option<f64>,
    /// The filter's posterior mean body mass at the end over the design's, when the particles
    /// carried it (`Rbpf::estimated_half_body_mass_kg`).
    mass_estimate_ratio: Option<f64>,
    seconds: f64,
}

impl Outcome {
    fn share(&self, n: usize) -> f64 {
        n as f64 / self.judged.max(1) as f64
    }

    fn within_share(&self) -> f64 {
        self.share(self.within)
    }

    fn coverage(&self) -> f64 {
        self.share(self.covered[0].min(self.covered[1]))
    }

    fn mismatch_share(&self) -> f64 {
        self.share(self.mismatch)
    }

    fn mean_error(&self, k: usize) -> f64 {
        self.error_sum[k] / self.judged.max(1) as f64
    }

    fn lowest_healthy(&self) -> f64 {
        self.healthy_min_ratio
            .iter()
            .flatten()
            .copied()
            .fold(f64::INFINITY, f64::min)
    }

    fn missed(&self) -> bool {
        self.detections.iter().any(Detection::missed)
    }

    /// The longest detection delay; a miss counts as infinite.
    fn worst_delay(&self) -> Option<f64> {
        self.detections
            .iter()
            .filter(|d| d.from_s.is_some())
            .map(|d| d.delay_s().unwrap_or(f64::INFINITY))
            .reduce(f64::max)
    }

    fn row(&self, threshold: f64) -> String {
        let ratio = |r: Option<f64>| match r {
            Some(r) if r < threshold => format!("{r:.3}!"),
            Some(r) => format!("{r:.3}"),
            None => "-".to_owned(),
        };
        let pct = |x: f64| format!("{:.1}", 100.0 * x);
        let detections: Vec<String> = self.detections.iter().map(Detection::text).collect();
        format!(
            "| {} | {}{}{} | {} | {} / {} | {:.2} s, {} ({} after a jump) | {} / {} / {} | {} | {} / {} | {} | {:+.1} / {:+.1} | {} | {:.0} |",
            self.draw.seed,
            self.draw.short(),
            self.mass_estimate_ratio
                .map_or(String::new(), |m| format!(", mass read {m:.2}")),
            self.diverged_at_s
                .map_or(String::new(), |t| format!(" (plant diverged at {t:.1} s)")),
            self.false_degraded,
            ratio(self.healthy_min_ratio[0]),
            ratio(self.healthy_min_ratio[1]),
            self.below_s,
            self.below_stretches,
            self.below_after_jump,
            self.healthy_jumps,
            self.healthy_adoptions,
            self.moving_jumps,
            pct(self.within_share()),
            pct(self.share(self.covered[0])),
            pct(self.share(self.covered[1])),
            pct(self.mismatch_share()),
            100.0 * self.mean_error(0),
            100.0 * self.mean_error(1),
            if detections.is_empty() {
                "-".to_owned()
            } else {
                detections.join(", ")
            },
            self.seconds,
        )
    }
}

const HEADER: &str = "| seed | conditions | false degraded | lowest healthy ratio csy / csay | healthy below threshold: time, stretches | healthy jumps / adopted / moving the mean | both within 5 % [%] | 90 % coverage csy / csay [%] | model_mismatch [%] | mean error csy / csay [%] | detection delay | wall s |\n|---|---|---|---|---|---|---|---|---|---|---|---|";

/// The delay the data allow a fault at a stop (issue 24 item 4: flagged within 10 s of
/// passing the minimum speed), per failed damper: two filters of known dampers beside the
/// monitor, with that damper failed and with it healthy (the other as the plant has it; the
/// monitor's model, mass given, its settling after the pause;
/// `DamperMonitorConfig::with_known_dampers`: their log-evidence is the exact Kalman
/// log-likelihood), and the log-likelihood ratio of failed over healthy from the crossing on.
/// A posterior that puts 95 % on the failure needs that ratio to pass `ln 19 - ln(lambda T)`,
/// `lambda T` the prior odds of a failure during the stop (the jump search's hazard over the
/// stop's length); the alarm then holds `alarm.hold_s`. An ideal observer's delay that knows
/// the failed value, not a strict bound: a filter whose evidence runs ahead of its
/// expectation can be earlier.
struct DataBound {
    damper: DamperId,
    monitors: [DamperMonitor; 2],
    needed_nats: f64,
    at_crossing: Option<f64>,
    delay_s: Option<f64>,
    hold_s: f64,
}

impl DataBound {
    /// One per damper failed during a stop.
    fn of_draw(draw: &Draw, config: &DamperMonitorConfig, table: &Arc<GainTable>) -> Vec<Self> {
        let s = &draw.scenario;
        let failed = railmon_damper::faults::dampers_at(&s.dampers, &s.faults, s.duration_s);
        let fixed = |dampers: railmon_damper::Dampers| {
            let c = config.with_known_dampers(dampers);
            DamperMonitor::with_gain_table(&c, 1, Some(table.clone())).ok()
        };
        s.faults
            .iter()
            .filter_map(|fault| {
                let stop_s = draw
                    .stops
                    .iter()
                    .find(|(from, to)| (*from..=*to).contains(&fault.at_s))
                    .map(|(from, to)| to - from)?;
                let mut healthy = failed;
                match fault.damper {
                    DamperId::Csy => healthy.csy_ns_per_m = s.dampers.csy_ns_per_m,
                    DamperId::Csay => healthy.csay_ns_per_m = s.dampers.csay_ns_per_m,
                }
                let hazard = config.rbpf.jump_search.hazard_per_s;
                Some(DataBound {
                    damper: fault.damper,
                    monitors: [fixed(healthy)?, fixed(failed)?],
                    needed_nats: 19f64.ln() - (hazard * stop_s).ln(),
                    at_crossing: None,
                    delay_s: None,
                    hold_s: config.alarm.hold_s,
                })
            })
            .collect()
    }

    fn step(
        &mut self,
        sample: &railmon_damper::BogieSample,
        time_s: f64,
        detections: &[Detection],
        config: &DamperMonitorConfig,
    ) {
        for m in &mut self.monitors {
            // A failure of the plant's model at an edge of the envelope stops the bound only.
            if m.step(sample).is_err() {
                return;
            }
        }
        let llr = self.monitors[1].rbpf().log_evidence() - self.monitors[0].rbpf().log_evidence();
        let Some(from_s) = detections
            .iter()
            .find(|d| d.damper == self.damper)
            .and_then(|d| d.from_s)
        else {
            return;
        };
        if time_s + 0.5 * config.dt_s < from_s || self.delay_s.is_some() {
            return;
        }
        let base = *self.at_crossing.get_or_insert(llr);
        if llr - base >= self.needed_nats {
            self.delay_s = Some(time_s - from_s + self.hold_s);
        }
    }
}

/// Issue 24 item 4: a fault at a stop flagged within this long of passing the minimum speed.
const AT_STOP_BAR_S: f64 = 10.0;

fn run(
    draw: Draw,
    config: &DamperMonitorConfig,
    table: &Arc<GainTable>,
    verbose: bool,
    withhold_mass: bool,
) -> Outcome {
    let started = Instant::now();
    let threshold = config.alarm.degraded_below_ratio;
    let mut monitor = DamperMonitor::for_bogie(config, 1, Some(table.clone())).unwrap();
    let mut alarms = DamperAlarm::pair(&config.alarm, &config.filter_model(), [false; 2]);
    let mut sim = BogieSimulator::new(&draw.scenario)
        .unwrap()
        .with_mass_input(!withhold_mass);
    let nominal = config.filter_model().nominal;
    let nominal = [nominal.csy_ns_per_m, nominal.csay_ns_per_m];
    let initial = draw.scenario.dampers;
    let initial = [initial.csy_ns_per_m, initial.csay_ns_per_m];
    let onset = DamperId::ALL.map(|d| draw.fault_onset_s(d));
    let mut detections: Vec<Detection> = DamperId::ALL
        .iter()
        .filter(|d| onset[d.index()].is_some())
        .map(|&damper| Detection {
            damper,
            from_s: draw.detectable_from_s(damper, threshold, &config.speed),
            at_s: None,
            data_bound_s: None,
        })
        .collect();
    let mut bounds = if draw.fault_shape == FaultShape::AtStop {
        DataBound::of_draw(&draw, config, table)
    } else {
        vec![]
    };
    let mut o = Outcome {
        draw: draw.clone(),
        false_degraded: 0,
        healthy_min_ratio: [None; 2],
        below_s: 0.0,
        below_stretches: 0,
        below_after_jump: 0,
        healthy_jumps: 0,
        moving_jumps: 0,
        healthy_adoptions: 0,
        judged: 0,
        within: 0,
        covered: [0; 2],
        mismatch: 0,
        error_sum: [0.0; 2],
        detections: vec![],
        diverged_at_s: None,
        mass_estimate_ratio: None,
        seconds: 0.0,
    };
    // Judged time as the alarm counts it (not paused, no mismatch), for its warm-up.
    let mut judged_s = 0.0;
    let mut step = 0usize;
    // Jump instrumentation: the materialisations seen, each (time, healthy ratios before it,
    // the lowest since) until its window closes; whether each damper is below threshold.
    let mut jumps_seen = 0u64;
    let mut adoptions_seen = 0u64;
    let mut open_jumps: Vec<(f64, [f64; 2], [f64; 2])> = vec![];
    let mut last_jump_s = f64::NEG_INFINITY;
    let mut below = [false; 2];
    let mut ratios_before = [1.0; 2];
    while let Some((sample, truth)) = sim.step() {
        step += 1;
        let e = match monitor.step(sample) {
            Ok(e) => *e,
            // Above the critical speed the linear plant grows without bound (the sampler
            // keeps below it: this would be its defect).
            Err(_) => {
                o.diverged_at_s = Some(truth.time_s);
                break;
            }
        };
        let time = e.time_s;
        for b in &mut bounds {
            b.step(sample, time, &detections, config);
        }
        if e.paused.is_none() && !e.model_mismatch {
            judged_s += config.dt_s;
        }
        let truths = [truth.dampers.csy_ns_per_m, truth.dampers.csay_ns_per_m];
        let posts = [e.csy, e.csay];
        let healthy = [0, 1].map(|k| truths[k] == initial[k]);
        for event in alarms.iter_mut().filter_map(|a| a.update(&e)) {
            if event.kind != DamperEventKind::DamperDegraded {
                continue;
            }
            let k = event.damper.index();
            let faulty = onset[k].is_some_and(|at| truth.time_s - config.dt_s >= at - 1e-9);
            if faulty {
                if let Some(d) = detections.iter_mut().find(|d| d.damper == event.damper) {
                    d.at_s.get_or_insert(time);
                }
            } else {
                o.false_degraded += 1;
            }
            if verbose {
                eprintln!(
                    "  seed {}: {} degraded at {time:.2} s ({}), health {:.3}, speed {:.1} m/s",
                    draw.seed,
                    event.damper.name(),
                    if faulty { "detection" } else { "FALSE" },
                    event.health_ratio,
                    sample.speed_m_s,
                );
            }
        }
        let ratios = [0, 1].map(|k| posts[k].mean_ns_per_m / nominal[k]);
        let jumps = monitor.rbpf().jump_count();
        let adoptions = monitor.rbpf().jump_adoptions();
        if adoptions > adoptions_seen {
            adoptions_seen = adoptions;
            o.healthy_adoptions += usize::from(healthy[0] && healthy[1]);
        }
        if jumps > jumps_seen {
            jumps_seen = jumps;
            last_jump_s = time;
            if healthy[0] && healthy[1] {
                o.healthy_jumps += 1;
                open_jumps.push((time, ratios_before, ratios));
            }
        }
        open_jumps.retain_mut(|(at, before, lowest)| {
            for k in 0..2 {
                lowest[k] = lowest[k].min(ratios[k]);
            }
            let open = time - *at < JUMP_WINDOW_S;
            if !open && (0..2).any(|k| before[k] - lowest[k] > JUMP_MOVE) {
                o.moving_jumps += 1;
            }
            open
        });
        ratios_before = ratios;
        if judged_s + 0.5 * config.dt_s >= config.alarm.warmup_s {
            for k in 0..2 {
                if healthy[k] {
                    let r = ratios[k];
                    let m = o.healthy_min_ratio[k].get_or_insert(r);
                    *m = m.min(r);
                    let now_below = r < threshold;
                    if now_below {
                        o.below_s += config.dt_s;
                        if !below[k] {
                            o.below_stretches += 1;
                            o.below_after_jump += usize::from(time - last_jump_s < JUMP_WINDOW_S);
                        }
                    }
                    below[k] = now_below;
                }
            }
        }
        if time <= JUDGE_FROM_S || !step.is_multiple_of(10) {
            continue;
        }
        o.judged += 1;
        let errors = [0, 1].map(|k| posts[k].mean_ns_per_m / truths[k] - 1.0);
        o.within += usize::from(errors.iter().all(|e| e.abs() <= WITHIN));
        for k in 0..2 {
            o.error_sum[k] += errors[k];
            o.covered[k] += usize::from(posts[k].covers(truths[k]));
        }
        o.mismatch += usize::from(e.model_mismatch);
    }
    o.moving_jumps += open_jumps
        .iter()
        .filter(|(_, before, lowest)| (0..2).any(|k| before[k] - lowest[k] > JUMP_MOVE))
        .count();
    for b in bounds {
        for d in &mut detections {
            if d.damper == b.damper {
                d.data_bound_s = Some(b.delay_s);
            }
        }
    }
    o.detections = detections;
    o.mass_estimate_ratio = monitor
        .rbpf()
        .estimated_half_body_mass_kg()
        .map(|m| m / config.vehicle.half_body_mass_kg);
    o.seconds = started.elapsed().as_secs_f64();
    o
}

fn quantiles(mut v: Vec<f64>) -> String {
    if v.is_empty() {
        return "-".to_owned();
    }
    v.sort_by(f64::total_cmp);
    let q = |f: f64| v[((v.len() - 1) as f64 * f).round() as usize];
    format!(
        "min {:.3}, 10 % {:.3}, median {:.3}, max {:.3}",
        q(0.0),
        q(0.1),
        q(0.5),
        q(1.0)
    )
}

fn main() -> ExitCode {
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("condition_matrix: {e} (--help lists the flags)");
            return ExitCode::from(2);
        }
    };
    let config = args.config;
    let threshold = config.alarm.degraded_below_ratio;
    // Drawing is cheap beside running: the shape and stop filters draw each seed once more.
    let wanted = |d: &Draw| {
        args.shape.is_none_or(|s| d.fault_shape == s) && (!args.with_stops || !d.stops.is_empty())
    };
    let seeds: Vec<u64> = (args.first_seed..)
        .filter(|&s| args.split.admits(s))
        .filter(|&s| wanted(&sampler::draw(s, args.duration_s)))
        .take(args.draws)
        .collect();
    let table = Rbpf::gain_table(&config.filter_model(), &config.rbpf, &config.speed)
        .expect("the default filter's gain table");
    let started = Instant::now();
    let outcomes = draws::run_each(
        &seeds,
        |seed| {
            let draw = sampler::draw(seed, args.duration_s);
            if args.oracle_conicity {
                // The filter's model at the plant's conicity: its own gain grids.
                let config = oracle::with_plant_conicity(&config, &draw);
                let table = Rbpf::gain_table(&config.filter_model(), &config.rbpf, &config.speed)
                    .expect("the oracle filter's gain table");
                run(draw, &config, &table, args.verbose, args.withhold_mass)
            } else {
                run(draw, &config, &table, args.verbose, args.withhold_mass)
            }
        },
        |o| o.seconds,
    );
    report(&args, &outcomes, threshold, started.elapsed().as_secs_f64());
    ExitCode::SUCCESS
}

fn report(args: &Args, outcomes: &[Outcome], threshold: f64, wall_s: f64) {
    let particles = args.config.rbpf.particles;
    println!(
        "condition matrix: {} draws (seeds {}..={}, split {}), runs of at most {} s, N = {particles}, filter defaults (design vehicle{}), {wall_s:.0} s wall",
        outcomes.len(),
        outcomes.first().map_or(0, |o| o.draw.seed),
        outcomes.last().map_or(0, |o| o.draw.seed),
        args.split.name(),
        args.duration_s,
        if args.oracle_conicity {
            "; oracle: the plant's conicity"
        } else {
            ""
        },
    );
    println!();
    println!("{HEADER}");
    for o in outcomes {
        println!("{}", o.row(threshold));
    }
    println!();
    let count = |f: &dyn Fn(&Outcome) -> bool| outcomes.iter().filter(|o| f(o)).count();
    let n = outcomes.len();
    let faulty: usize = outcomes.iter().map(|o| o.detections.len()).sum();
    let reached: Vec<&Detection> = outcomes
        .iter()
        .flat_map(|o| &o.detections)
        .filter(|d| d.from_s.is_some())
        .collect();
    let missed = reached.iter().filter(|d| d.at_s.is_none()).count();
    let delays: Vec<f64> = reached.iter().filter_map(|d| d.delay_s()).collect();
    let hours: f64 = outcomes
        .iter()
        .map(|o| o.draw.scenario.duration_s)
        .sum::<f64>()
        / 3600.0;
    println!("| figure | value |");
    println!("|---|---|");
    println!(
        "| draws: healthy / step / ramp / step at a stop | {} / {} / {} / {} |",
        count(&|o| o.draw.fault_shape == FaultShape::None),
        count(&|o| o.draw.fault_shape == FaultShape::Step),
        count(&|o| o.draw.fault_shape == FaultShape::Ramp),
        count(&|o| o.draw.fault_shape == FaultShape::AtStop),
    );
    println!(
        "| draws with a false damper_degraded | {} of {n} ({} events in {hours:.2} h) |",
        count(&|o| o.false_degraded > 0),
        outcomes.iter().map(|o| o.false_degraded).sum::<usize>(),
    );
    println!(
        "| draws with a healthy damper's published ratio below {threshold} | {} of {n} |",
        count(&|o| o.lowest_healthy() < threshold),
    );
    println!(
        "| time a healthy ratio was below {threshold} | {:.2} s in {} stretches ({} within {JUMP_WINDOW_S} s of a jump) |",
        outcomes.iter().map(|o| o.below_s).sum::<f64>(),
        outcomes.iter().map(|o| o.below_stretches).sum::<usize>(),
        outcomes.iter().map(|o| o.below_after_jump).sum::<usize>(),
    );
    println!(
        "| jumps materialised while healthy / adopted (published) / moving a published ratio down by {JUMP_MOVE} within {JUMP_WINDOW_S} s | {} / {} / {} |",
        outcomes.iter().map(|o| o.healthy_jumps).sum::<usize>(),
        outcomes.iter().map(|o| o.healthy_adoptions).sum::<usize>(),
        outcomes.iter().map(|o| o.moving_jumps).sum::<usize>(),
    );
    println!(
        "| lowest healthy ratio per draw | {} |",
        quantiles(
            outcomes
                .iter()
                .map(Outcome::lowest_healthy)
                .filter(|r| r.is_finite())
                .collect()
        )
    );
    println!(
        "| share of time both within 5 % per draw | {} |",
        quantiles(outcomes.iter().map(Outcome::within_share).collect())
    );
    println!(
        "| 90 % coverage per draw (the lower damper) | {} |",
        quantiles(outcomes.iter().map(Outcome::coverage).collect())
    );
    println!(
        "| model_mismatch share per draw | {} |",
        quantiles(outcomes.iter().map(Outcome::mismatch_share).collect())
    );
    println!(
        "| faulty dampers: reached the threshold moving / detected / missed | {faulty}: {} / {} / {missed} |",
        reached.len(),
        delays.len(),
    );
    println!(
        "| draws with a missed fault | {} of {} with a fault |",
        count(&|o| o.missed()),
        count(&|o| !o.detections.is_empty()),
    );
    println!("| detection delay [s] | {} |", quantiles(delays));
    // Faults at a stop against what their data allow (`DataBound`).
    let at_stop: Vec<&Detection> = outcomes
        .iter()
        .filter(|o| o.draw.fault_shape == FaultShape::AtStop)
        .flat_map(|o| &o.detections)
        .filter(|d| d.from_s.is_some())
        .collect();
    if !at_stop.is_empty() {
        let within = |v: Option<f64>| v.is_some_and(|s| s <= AT_STOP_BAR_S);
        println!(
            "| faults at a stop: within {AT_STOP_BAR_S} s of the crossing, flagged / the data allow | {} / {} of {} |",
            at_stop.iter().filter(|d| within(d.delay_s())).count(),
            at_stop.iter().filter(|d| within(d.data_bound_s.flatten())).count(),
            at_stop.len(),
        );
        println!(
            "| faults at a stop: the delay the data allow [s] (`DataBound`, the alarm's hold included) | {} |",
            quantiles(at_stop.iter().filter_map(|d| d.data_bound_s.flatten()).collect())
        );
    }
    println!(
        "| plant diverged | {} |",
        count(&|o| o.diverged_at_s.is_some())
    );
    println!();
    println!(
        "By body mass ({}):",
        if args.withhold_mass && args.config.rbpf.unmeasured_mass.enabled {
            "withheld: the particles carry the mass"
        } else if args.withhold_mass {
            "withheld: the filter assumes the design mass"
        } else {
            "given to the filter as the measured load"
        }
    );
    println!();
    println!("| mass x | draws | false degraded draws | healthy ratio below {threshold} | median both within 5 % [%] | median mean error csy / csay [%] | mean error csy / csay [%] | 90 % coverage csy / csay [%] | both within 5 % [%] | model_mismatch [%] |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for (lo, hi) in [(0.0, 0.95), (0.95, 1.05), (1.05, 1.2), (1.2, 2.0)] {
        let group: Vec<&Outcome> = outcomes
            .iter()
            .filter(|o| (lo..hi).contains(&o.draw.mass_ratio))
            .collect();
        if group.is_empty() {
            continue;
        }
        let median = |f: &dyn Fn(&Outcome) -> f64| {
            let mut v: Vec<f64> = group.iter().map(|o| f(o)).collect();
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        // Pooled over the group's judged samples (each draw weighs by its length).
        let judged: usize = group.iter().map(|o| o.judged).sum::<usize>().max(1);
        let pooled = |f: &dyn Fn(&Outcome) -> f64| {
            100.0 * group.iter().map(|o| f(o)).sum::<f64>() / judged as f64
        };
        println!(
            "| {lo:.2}-{hi:.2} | {} | {} | {} | {:.1} | {:+.1} / {:+.1} | {:+.2} / {:+.2} | {:.1} / {:.1} | {:.1} | {:.1} |",
            group.len(),
            group.iter().filter(|o| o.false_degraded > 0).count(),
            group
                .iter()
                .filter(|o| o.lowest_healthy() < threshold)
                .count(),
            100.0 * median(&|o| o.within_share()),
            100.0 * median(&|o| o.mean_error(0)),
            100.0 * median(&|o| o.mean_error(1)),
            pooled(&|o| o.error_sum[0]),
            pooled(&|o| o.error_sum[1]),
            pooled(&|o| o.covered[0] as f64),
            pooled(&|o| o.covered[1] as f64),
            pooled(&|o| o.within as f64),
            pooled(&|o| o.mismatch as f64),
        );
    }
    println!();
    let command = |seed: u64| {
        format!(
            "cargo run --release -p railmon-damper --example condition_matrix -- --first-seed {seed} --draws 1 --split all --particles {particles} --duration-s {}",
            args.duration_s
        )
    };
    // (criterion, the figure of a draw: larger is worse, None: not ranked).
    type Badness = (&'static str, fn(&Outcome) -> Option<f64>);
    let criteria: [Badness; 6] = [
        ("false damper_degraded events", |o| {
            (o.false_degraded > 0).then_some(o.false_degraded as f64)
        }),
        ("lowest healthy ratio", |o| {
            o.lowest_healthy().is_finite().then(|| -o.lowest_healthy())
        }),
        ("share of time both within 5 %", |o| Some(-o.within_share())),
        ("90 % coverage (the lower damper)", |o| Some(-o.coverage())),
        ("model_mismatch share", |o| Some(o.mismatch_share())),
        ("detection delay (a miss: worst)", |o| o.worst_delay()),
    ];
    println!("Worst draws by each criterion:");
    for (name, badness) in criteria {
        let mut ranked: Vec<(f64, &Outcome)> = outcomes
            .iter()
            .filter_map(|o| badness(o).map(|b| (b, o)))
            .collect();
        ranked.sort_by(|a, b| b.0.total_cmp(&a.0));
        println!();
        println!("{name}:");
        if ranked.is_empty() {
            println!("  none");
        }
        for (_, o) in ranked.iter().take(args.worst) {
            println!("  {}", o.row(threshold));
            println!("    {}", command(o.draw.seed));
        }
    }
}
