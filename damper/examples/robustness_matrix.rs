//! Robustness matrix of issue 9: healthy bogies (and a C_say step to 40 %) on plants unlike the
//! filter, one factor at a time from the validated cell (white track of 0.1 m/s, sensor noise
//! as configured, conicity 0.15, 45.3 m/s). The filter is `DamperMonitorConfig::default()` but
//! for what the flags change (it assumes the nominal vehicle at 45.3 m/s and the configured
//! noise); each cell changes the plant only. Per cell, over the seeds: false `damper_degraded` events per hour (healthy runs;
//! `railmon_damper::DamperAlarm`), share of time after 30 s with both RBPF means within 5 % of
//! the truth, 90 % interval coverage of each damper after 30 s, the share of time the filter
//! reports `model_mismatch`, and for the fault runs (a C_say step to 40 % at 30 s; a C_sy ramp
//! to 60 % over 30-50 s) the detection delay (from the step; for the ramp, from when the truth
//! crosses the alarm's `degraded_below_ratio`) and the error 10 s after the step / the ramp's end.
//! False `damper_degraded` events of the fault runs (the damper without a fault, or before the
//! fault) count with the healthy runs' hours. The accuracy and coverage columns count the
//! healthy runs' time after 30 s only: runs of 30 s or less leave them at 0.
//!
//! ```text
//! cargo run --release -p railmon-damper --example robustness_matrix   # the issue's matrix: hours
//! cargo run --release -p railmon-damper --example robustness_matrix -- \
//!     --duration-s 60 --seeds 2 --particles 200 --cells speed,noise --fault --verbose
//! ```
//! With no flags it runs the issue's matrix (every cell, 600 s per run, 3 seeds, N = 1000: hours
//! on two cores). `--help` lists the flags; `--cells` takes names or prefixes of cells
//! (`--cells "speed profile"`), `--first-seed 2` starts at the third plant seed (9002) to add one
//! to a table, `--noise-scale off` runs the filter without its noise estimate (as before issue 9
//! item 2), `--filter-seed` sets `rbpf.seed` (the same data, other particles: the filter's own
//! Monte Carlo spread), `--matched-noise` gives the filter each cell's true sensor noise (the
//! reference the noise estimate is judged against). Dampers far from nominal from t = 0: the
//! `off_nominal_starts` example.

use std::process::ExitCode;
use std::sync::Arc;
use std::time::Instant;

use railmon_damper::{
    BogieSimulator, DamperAlarm, DamperEventKind, DamperFault, DamperId, DamperMonitor,
    DamperMonitorConfig, DamperScenario, ErriLevel, FaultKind, Rbpf, SpeedProfile, TrackSpec,
};

mod flags;
use flags::{on_off, parsed};

/// What the flags set: the filter's configuration and the matrix's extent.
struct Args {
    duration_s: f64,
    seeds: u64,
    first_seed: u64,
    /// Names or prefixes of the cells to run (empty: all).
    cells: Vec<String>,
    fault: bool,
    matched_noise: bool,
    verbose: bool,
    /// `DamperMonitorConfig::default()` with the flags' changes.
    config: DamperMonitorConfig,
}

fn usage() -> String {
    let d = DamperMonitorConfig::default();
    let js = d.rbpf.jump_search;
    let on_off = |b: bool| if b { "on" } else { "off" };
    let names: Vec<String> = cells().into_iter().map(|c| c.name).collect();
    format!(
        "usage: robustness_matrix [FLAGS]   (no flags: the issue's matrix, hours)\n\
         \n\
         --duration-s S        seconds per healthy run (default 600)\n\
         --seeds N             plant seeds per cell, N >= 1 (default 3)\n\
         --first-seed K        start at plant seed 9000 + K (default 0)\n\
         --particles N         rbpf.particles (default {particles})\n\
         --cells A,B           only the cells whose names start with A or B (default: all)\n\
         --fault               add a C_say step run and a C_sy ramp run per seed\n\
         --noise-scale on|off  rbpf.noise_scale.enabled, the noise estimate (default {noise})\n\
         --filter-seed N       rbpf.seed, the filter's own random numbers (default {seed})\n\
         --jump on|off         rbpf.jump_search.enabled (default {jump})\n\
         --jump-hazard X       rbpf.jump_search.hazard_per_s (default {hazard})\n\
         --jump-odds X         rbpf.jump_search.materialise_odds (default {odds})\n\
         --jump-hold X         rbpf.jump_search.resume_hold_time_constants (default {hold})\n\
         --matched-noise       give the filter each cell's true sensor noise\n\
         --verbose             print each false damper_degraded event\n\
         --help                this text\n\
         \n\
         cells: {cells}",
        particles = d.rbpf.particles,
        noise = on_off(d.rbpf.noise_scale.enabled),
        seed = d.rbpf.seed,
        jump = on_off(js.enabled),
        hazard = js.hazard_per_s,
        odds = js.materialise_odds,
        hold = js.resume_hold_time_constants,
        cells = names.join(", "),
    )
}

fn parse_args() -> Result<Args, String> {
    let mut args = Args {
        duration_s: 600.0,
        seeds: 3,
        first_seed: 0,
        cells: vec![],
        fault: false,
        matched_noise: false,
        verbose: false,
        config: DamperMonitorConfig::default(),
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or(format!("{flag} needs a value"));
        let c = &mut args.config.rbpf;
        match flag.as_str() {
            "--help" | "-h" => {
                println!("{}", usage());
                std::process::exit(0);
            }
            "--duration-s" => args.duration_s = parsed(&flag, &value()?)?,
            "--seeds" => args.seeds = parsed(&flag, &value()?)?,
            "--first-seed" => args.first_seed = parsed(&flag, &value()?)?,
            "--particles" => c.particles = parsed(&flag, &value()?)?,
            "--cells" => args.cells = value()?.split(',').map(str::to_owned).collect(),
            "--noise-scale" => c.noise_scale.enabled = on_off(&flag, &value()?)?,
            "--filter-seed" => c.seed = parsed(&flag, &value()?)?,
            "--jump" => c.jump_search.enabled = on_off(&flag, &value()?)?,
            "--jump-hazard" => c.jump_search.hazard_per_s = parsed(&flag, &value()?)?,
            "--jump-odds" => c.jump_search.materialise_odds = parsed(&flag, &value()?)?,
            "--jump-hold" => c.jump_search.resume_hold_time_constants = parsed(&flag, &value()?)?,
            "--fault" => args.fault = true,
            "--matched-noise" => args.matched_noise = true,
            "--verbose" => args.verbose = true,
            other => return Err(format!("unknown flag {other}")),
        }
    }
    Ok(args)
}

const BASE: &str = "name = \"robust\"\nseed = 1\nduration_s = 60.0\n[track]\nkind = \"white\"\nvelocity_std_m_s = 0.1\n";

/// The profile of `config/scenarios/damper-speed-profile.toml` (from rest; 20, 45, 30, 55 m/s;
/// a stop; 30 m/s), repeated every 300 s over `duration_s`.
fn repeated_speed_profile(duration_s: f64) -> SpeedProfile {
    let file = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../config/scenarios/damper-speed-profile.toml"
    );
    let scenario = DamperScenario::from_toml_str(&std::fs::read_to_string(file).unwrap()).unwrap();
    let one = scenario
        .speed
        .expect("the scenario has a [speed] profile")
        .profile_m_s;
    const PERIOD_S: f64 = 300.0;
    assert!(one.last().unwrap()[0] < PERIOD_S);
    let periods = (duration_s / PERIOD_S).ceil().max(1.0) as usize;
    SpeedProfile {
        profile_m_s: (0..periods)
            .flat_map(|k| one.iter().map(move |[t, v]| [t + k as f64 * PERIOD_S, *v]))
            .collect(),
    }
}

/// One cell: a name and how it changes the plant.
struct Cell {
    name: String,
    apply: Box<dyn Fn(&mut DamperScenario)>,
}

fn cells() -> Vec<Cell> {
    let mut cells: Vec<Cell> = vec![Cell {
        name: "base".into(),
        apply: Box::new(|_| {}),
    }];
    for v in [10.0, 30.0, 55.0, 70.0] {
        cells.push(Cell {
            name: format!("speed {v} m/s"),
            apply: Box::new(move |s| s.vehicle.speed_m_s = v),
        });
    }
    cells.push(Cell {
        name: "speed profile with stops".into(),
        apply: Box::new(|s| s.speed = Some(repeated_speed_profile(s.duration_s))),
    });
    for k in [0.5, 1.5, 2.0, 3.0] {
        cells.push(Cell {
            name: format!("noise {k}x"),
            apply: Box::new(move |s| {
                s.sensors.accel_std_m_s2 *= k;
                s.sensors.gyro_std_rad_s *= k;
            }),
        });
    }
    for c in [0.1, 0.25] {
        cells.push(Cell {
            name: format!("conicity {c}"),
            apply: Box::new(move |s| s.vehicle.conicity = c),
        });
    }
    for (name, level) in [("low", ErriLevel::Low), ("high", ErriLevel::High)] {
        cells.push(Cell {
            name: format!("track erri {name}"),
            apply: Box::new(move |s| s.track = TrackSpec::Erri { level }),
        });
    }
    cells
}

/// A fault run: the fault, when its effect should be found, and when its error is read.
struct FaultRun {
    fault: DamperFault,
    /// From here a `damper_degraded` of `fault.damper` is a detection (earlier: a false alarm).
    starts_s: f64,
    /// The delay is counted from here: the step, or where the ramp's truth crosses the alarm's
    /// `degraded_below_ratio`.
    crosses_s: f64,
    /// The posterior mean is compared with the truth here.
    error_at_s: f64,
    duration_s: f64,
}

impl FaultRun {
    /// C_say steps to 40 % at 30 s (read 10 s after).
    fn csay_step() -> Self {
        FaultRun {
            fault: DamperFault {
                damper: DamperId::Csay,
                kind: FaultKind::Step,
                at_s: 30.0,
                end_s: None,
                ratio: 0.4,
            },
            starts_s: 30.0,
            crosses_s: 30.0,
            error_at_s: 40.0,
            duration_s: 60.0,
        }
    }

    /// C_sy ramps from nominal to 60 % over 30-50 s (read 10 s after the ramp's end).
    fn csy_ramp(degraded_below_ratio: f64) -> Self {
        let (at, end, ratio) = (30.0, 50.0, 0.6);
        FaultRun {
            fault: DamperFault {
                damper: DamperId::Csy,
                kind: FaultKind::Ramp,
                at_s: at,
                end_s: Some(end),
                ratio,
            },
            starts_s: at,
            crosses_s: at + (end - at) * (1.0 - degraded_below_ratio) / (1.0 - ratio),
            error_at_s: end + 10.0,
            duration_s: 75.0,
        }
    }
}

/// What the fault runs of one kind found.
#[derive(Default)]
struct FaultTally {
    delays: Vec<Option<f64>>,
    errors: Vec<f64>,
}

impl FaultTally {
    fn add(&mut self, (delay, error): (Option<f64>, Option<f64>)) {
        self.delays.push(delay);
        self.errors.extend(error);
    }

    fn delays(&self) -> String {
        let d: Vec<String> = self
            .delays
            .iter()
            .map(|d| d.map_or("missed".into(), |d| format!("{d:.2}")))
            .collect();
        d.join(", ")
    }

    fn errors(&self) -> String {
        let e: Vec<String> = self
            .errors
            .iter()
            .map(|e| format!("{:+.1} %", 100.0 * e))
            .collect();
        e.join(", ")
    }
}

#[derive(Default)]
struct Tally {
    runs: usize,
    hours: f64,
    false_degraded: usize,
    judged: usize,
    within: usize,
    covered: [usize; 2],
    mismatch: usize,
    nis_sum: f64,
    step: FaultTally,
    ramp: FaultTally,
    /// The estimated noise std ratio (accelerometer 1, gyro) at the end of each healthy run.
    noise_ratio_end: Vec<[f64; 2]>,
    /// When the plant's output stopped being finite, per run where it did.
    diverged_at_s: Vec<f64>,
    /// Jump hypotheses that became particles in the healthy runs (`rbpf.jump_search`).
    healthy_jumps: u64,
}

fn sample_is_finite(s: &railmon_damper::BogieSample) -> bool {
    [
        s.wheelset1_accel_m_s2,
        s.wheelset2_accel_m_s2,
        s.bogie_accel_m_s2,
        s.bogie_yaw_rate_rad_s,
        s.body_accel_m_s2,
    ]
    .iter()
    .all(|v| v.is_finite())
}

/// Runs `scenario` (healthy when `fault` is `None`; else with its fault): alarms and, after
/// 30 s of a healthy run, the accuracy and coverage counts. A fault run gives its detection
/// delay and its error (for [`FaultTally::add`]). `verbose`: prints each false alarm.
fn run(
    scenario: &DamperScenario,
    config: &DamperMonitorConfig,
    table: &Arc<railmon_damper::gain_table::GainTable>,
    fault: Option<&FaultRun>,
    t: &mut Tally,
    verbose: bool,
) -> (Option<f64>, Option<f64>) {
    let config = *config;
    let mut monitor = DamperMonitor::for_bogie(&config, 1, Some(table.clone())).unwrap();
    let mut alarms = DamperAlarm::pair(&config.alarm, &config.filter_model(), [false; 2]);
    let mut scenario = scenario.clone();
    let spec = fault;
    if let Some(f) = spec {
        scenario.duration_s = f.duration_s;
        scenario.faults = vec![f.fault];
    }
    let mut sim = BogieSimulator::new(&scenario).unwrap();
    let mut detected = None;
    let mut error = None;
    let mut noise_ratio = [f64::NAN; 2];
    while let Some((sample, truth)) = sim.step() {
        // Above its critical speed the linear plant grows without bound: the monitor refuses
        // its first infinite sample, and the run ends there (counted, with its time).
        let e = match monitor.step(sample) {
            Ok(e) => *e,
            Err(_) if !sample_is_finite(sample) => {
                t.diverged_at_s.push(truth.time_s);
                break;
            }
            Err(e) => panic!("{e}"),
        };
        noise_ratio = [e.noise_std_ratio[0], e.noise_std_ratio[3]];
        let time = truth.time_s;
        for event in alarms.iter_mut().filter_map(|a| a.update(&e)) {
            if event.kind != DamperEventKind::DamperDegraded {
                continue;
            }
            match spec {
                Some(f) if event.damper == f.fault.damper && time >= f.starts_s => {
                    detected.get_or_insert(time - f.crosses_s);
                }
                _ => {
                    t.false_degraded += 1;
                    if verbose {
                        println!(
                            "  false {} at {time:.3} s (seed {}, {}): health {:.3}, speed {:.1} m/s, paused {:?}",
                            event.damper.name(),
                            scenario.seed,
                            spec.map_or("healthy", |_| "fault run"),
                            event.health_ratio,
                            sample.speed_m_s,
                            e.paused,
                        );
                    }
                }
            }
        }
        let truths = [truth.dampers.csy_ns_per_m, truth.dampers.csay_ns_per_m];
        let posts = [e.csy, e.csay];
        if let Some(f) = spec {
            if (time - f.error_at_s).abs() < 0.5e-3 {
                let k = f.fault.damper.index();
                error = Some(posts[k].mean_ns_per_m / truths[k] - 1.0);
            }
            continue;
        }
        if time <= 30.0 || !(time * 1e3).round().rem_euclid(10.0).eq(&0.0) {
            continue;
        }
        // Every 10 ms after 30 s.
        t.judged += 1;
        t.within += usize::from(
            posts
                .iter()
                .zip(truths)
                .all(|(p, tr)| (p.mean_ns_per_m / tr - 1.0).abs() <= 0.05),
        );
        for k in 0..2 {
            t.covered[k] += usize::from(posts[k].covers(truths[k]));
        }
        t.mismatch += usize::from(e.model_mismatch);
        t.nis_sum += e.nis_window_mean.unwrap_or(0.0);
    }
    if spec.is_none() {
        t.healthy_jumps += monitor.rbpf().jump_count();
    }
    t.hours += scenario.duration_s / 3600.0;
    if spec.is_none() {
        t.runs += 1;
        t.noise_ratio_end.push(noise_ratio);
    }
    (detected, error)
}

fn main() -> ExitCode {
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("robustness_matrix: {e} (--help lists the flags)");
            return ExitCode::from(2);
        }
    };
    let all = cells();
    let unknown: Vec<&String> = args
        .cells
        .iter()
        .filter(|o| !all.iter().any(|c| c.name.starts_with(o.as_str())))
        .collect();
    let problem = if !(args.duration_s > 0.0 && args.duration_s.is_finite()) {
        Some(format!(
            "--duration-s {}: a positive number",
            args.duration_s
        ))
    } else if args.seeds == 0 {
        Some("--seeds 0: at least one".into())
    } else if let Some(o) = unknown.first() {
        Some(format!("--cells: no cell starts with {o:?}"))
    } else {
        args.config.validate().err().map(|e| e.to_string())
    };
    if let Some(p) = problem {
        eprintln!("robustness_matrix: {p} (--help lists the flags)");
        return ExitCode::from(2);
    }
    matrix(&args, all);
    ExitCode::SUCCESS
}

fn matrix(args: &Args, cells: Vec<Cell>) {
    let Args {
        duration_s,
        seeds,
        first_seed,
        fault,
        matched_noise: matched,
        verbose,
        config,
        ..
    } = *args;
    let particles = config.rbpf.particles;
    let only = &args.cells;
    let table = Rbpf::gain_table(&config.filter_model(), &config.rbpf, &config.speed).unwrap();
    println!(
        "robustness: {duration_s} s per run, {seeds} seeds, N = {particles}{}, noise estimate {}{}",
        if fault {
            ", with C_say step and C_sy ramp runs"
        } else {
            ""
        },
        if config.rbpf.noise_scale.enabled {
            "on"
        } else {
            "off"
        },
        if matched {
            ", filter given the true noise"
        } else {
            ""
        },
    );
    println!(
        "| cell | false degraded / h | both means within 5 % | csy covered | csay covered | model_mismatch | mean NIS / 5 | C_say step: delay s | error 10 s after | C_sy ramp: delay s after crossing | error 10 s after its end | noise std ratio at end (accel 1, gyro) | jumps materialised / healthy h |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for cell in cells {
        if !only.is_empty() && !only.iter().any(|o| cell.name.starts_with(o.as_str())) {
            continue;
        }
        let started = Instant::now();
        let mut t = Tally::default();
        for seed in first_seed..first_seed + seeds {
            let mut s = DamperScenario::from_toml_str(BASE).unwrap();
            s.duration_s = duration_s;
            s.seed = 9000 + seed;
            (cell.apply)(&mut s);
            let (config, table) = if matched {
                let mut c = config;
                c.sensors = s.sensors;
                (
                    c,
                    Rbpf::gain_table(&c.filter_model(), &c.rbpf, &c.speed).unwrap(),
                )
            } else {
                (config, table.clone())
            };
            run(&s, &config, &table, None, &mut t, verbose);
            if fault {
                let step = FaultRun::csay_step();
                let step = run(&s, &config, &table, Some(&step), &mut t, verbose);
                t.step.add(step);
                let ramp = FaultRun::csy_ramp(config.alarm.degraded_below_ratio);
                let ramp = run(&s, &config, &table, Some(&ramp), &mut t, verbose);
                t.ramp.add(ramp);
            }
        }
        let pct = |n: usize| 100.0 * n as f64 / t.judged.max(1) as f64;
        let ratios: Vec<String> = t
            .noise_ratio_end
            .iter()
            .map(|r| format!("{:.2} / {:.2}", r[0], r[1]))
            .collect();
        let or_dash = |text: String| if fault { text } else { "-".into() };
        let diverged: Vec<String> = t.diverged_at_s.iter().map(|d| format!("{d:.1}")).collect();
        let name = match diverged.is_empty() {
            true => cell.name.clone(),
            false => format!(
                "{} (plant diverged at {} s)",
                cell.name,
                diverged.join(", ")
            ),
        };
        println!(
            "| {} | {:.1} | {:.1} % | {:.1} % | {:.1} % | {:.1} % | {:.2} | {} | {} | {} | {} | {} | {:.1} | ({:.0} s)",
            name,
            t.false_degraded as f64 / t.hours,
            pct(t.within),
            pct(t.covered[0]),
            pct(t.covered[1]),
            pct(t.mismatch),
            t.nis_sum / t.judged.max(1) as f64 / 5.0,
            or_dash(t.step.delays()),
            or_dash(t.step.errors()),
            or_dash(t.ramp.delays()),
            or_dash(t.ramp.errors()),
            ratios.join(", "),
            t.healthy_jumps as f64 / (t.runs.max(1) as f64 * duration_s / 3600.0),
            started.elapsed().as_secs_f64(),
        );
    }
}
