//! Robustness matrix of issue 9: healthy bogies (and a C_say step to 40 %) on plants unlike the
//! filter, one factor at a time from the validated cell (white track of 0.1 m/s, sensor noise
//! as configured, conicity 0.15, 45.3 m/s). The filter is always `DamperMonitorConfig::default()`
//! (it assumes the nominal vehicle at 45.3 m/s and the configured noise); each cell changes the
//! plant only. Per cell, over the seeds: false `damper_degraded` events per hour (healthy runs;
//! `railmon_damper::DamperAlarm`), share of time after 30 s with both RBPF means within 5 % of
//! the truth, 90 % interval coverage of each damper after 30 s, the share of time the filter
//! reports `model_mismatch`, and for the fault runs (a C_say step to 40 % at 30 s; a C_sy ramp
//! to 60 % over 30-50 s) the detection delay (from the step; for the ramp, from when the truth
//! crosses the alarm's `degraded_below_ratio`) and the error 10 s after the step / the ramp's end.
//! False `damper_degraded` events of the fault runs (the damper without a fault, or before the
//! fault) count with the healthy runs' hours. `off_nominal_starts` runs dampers far from
//! nominal from t = 0 (every pair of 0.5x, 1x, 1.5x): both means within 5 % at 30 s?
//!
//! `cargo test --release -p railmon-damper --test robustness -- --ignored --nocapture` runs the
//! issue's matrix (600 s per run, 3 seeds, N = 1000: hours on two cores; not in CI). Smaller runs by environment:
//! `ROBUST_DURATION_S=60 ROBUST_SEEDS=2 ROBUST_PARTICLES=200 ROBUST_CELLS=speed,noise`
//! (`ROBUST_CELLS`: names or prefixes of cells, `ROBUST_FAULT=1` adds the fault runs,
//! `ROBUST_NOISE_SCALE=0` runs the filter without its noise estimate, as before issue 9 item 2;
//! `ROBUST_FIRST_SEED=2` starts at the third seed (9002) to add one to a table;
//! `ROBUST_JUMP=0|1` sets `rbpf.jump_search.enabled`,
//! `ROBUST_JUMP_HAZARD` its `hazard_per_s`, `ROBUST_JUMP_ODDS` its `materialise_odds`,
//! `ROBUST_JUMP_HOLD` its `resume_hold_time_constants`;
//! `ROBUST_FILTER_SEED` sets `rbpf.seed` (the same data, other particles: the filter's own
//! Monte Carlo spread);
//! `ROBUST_VERBOSE=1` prints each false alarm; `ROBUST_MATCHED_NOISE=1` gives the filter each cell's true sensor noise: the reference
//! the noise estimate is judged against).

use std::sync::Arc;
use std::time::Instant;

use railmon_damper::{
    BogieSimulator, DamperAlarm, DamperEventKind, DamperFault, DamperId, DamperMonitor,
    DamperMonitorConfig, DamperScenario, Dampers, ErriLevel, FaultKind, Rbpf, SpeedProfile,
    TrackSpec,
};

fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
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
/// delay and its error (for [`FaultTally::add`]).
fn run(
    scenario: &DamperScenario,
    config: &DamperMonitorConfig,
    table: &Arc<railmon_damper::gain_table::GainTable>,
    fault: Option<&FaultRun>,
    t: &mut Tally,
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
                    if std::env::var_os("ROBUST_VERBOSE").is_some() {
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
            t.covered[k] += usize::from(
                posts[k].q05_ns_per_m <= truths[k] && truths[k] <= posts[k].q95_ns_per_m,
            );
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

#[test]
#[ignore = "the robustness matrix: minutes to hours, see the header"]
fn robustness_matrix() {
    let duration_s: f64 = env_or("ROBUST_DURATION_S", 600.0);
    let seeds: u64 = env_or("ROBUST_SEEDS", 3);
    let first_seed: u64 = env_or("ROBUST_FIRST_SEED", 0);
    let particles: usize = env_or("ROBUST_PARTICLES", 1000);
    let fault: bool = env_or("ROBUST_FAULT", 0u8) == 1;
    let only: Vec<String> = std::env::var("ROBUST_CELLS")
        .map(|v| v.split(',').map(str::to_owned).collect())
        .unwrap_or_default();
    let mut config = DamperMonitorConfig::default();
    config.rbpf.particles = particles;
    config.rbpf.noise_scale.enabled = env_or("ROBUST_NOISE_SCALE", 1u8) == 1;
    config.rbpf.seed = env_or("ROBUST_FILTER_SEED", config.rbpf.seed);
    let js = &mut config.rbpf.jump_search;
    js.enabled = env_or("ROBUST_JUMP", u8::from(js.enabled)) == 1;
    js.hazard_per_s = env_or("ROBUST_JUMP_HAZARD", js.hazard_per_s);
    js.materialise_odds = env_or("ROBUST_JUMP_ODDS", js.materialise_odds);
    js.resume_hold_time_constants = env_or("ROBUST_JUMP_HOLD", js.resume_hold_time_constants);
    let matched: bool = env_or("ROBUST_MATCHED_NOISE", 0u8) == 1;
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
    for cell in cells() {
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
            run(&s, &config, &table, None, &mut t);
            if fault {
                let step = run(&s, &config, &table, Some(&FaultRun::csay_step()), &mut t);
                t.step.add(step);
                let ramp = FaultRun::csy_ramp(config.alarm.degraded_below_ratio);
                let ramp = run(&s, &config, &table, Some(&ramp), &mut t);
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

/// Issue 9: dampers far from nominal from t = 0 (each of C_sy, C_say at 0.5x, 1x, 1.5x of
/// nominal, every pair but nominal-nominal), on the validated cell: both RBPF means within 5 %
/// of the truth at 30 s? Prints a row per pair and seed (`ROBUST_SEEDS`, 3; `ROBUST_PARTICLES`).
/// `cargo test --release -p railmon-damper --test robustness off_nominal -- --ignored --nocapture`
#[test]
#[ignore = "minutes: see the header"]
fn off_nominal_starts() {
    let seeds: u64 = env_or("ROBUST_SEEDS", 3);
    let mut config = DamperMonitorConfig::default();
    config.rbpf.particles = env_or("ROBUST_PARTICLES", 1000);
    let table = Rbpf::gain_table(&config.filter_model(), &config.rbpf, &config.speed).unwrap();
    println!("| C_sy / nominal | C_say / nominal | seed | C_sy error at 30 s | C_say error at 30 s | both within 5 % |");
    println!("|---|---|---|---|---|---|");
    let mut within = 0;
    let mut runs = 0;
    for csy in [0.5, 1.0, 1.5] {
        for csay in [0.5, 1.0, 1.5] {
            if (csy, csay) == (1.0, 1.0) {
                continue;
            }
            for seed in 0..seeds {
                let mut s = DamperScenario::from_toml_str(BASE).unwrap();
                s.duration_s = 30.0;
                s.seed = 9100 + seed;
                let nominal = Dampers::NOMINAL;
                s.dampers = Dampers {
                    csy_ns_per_m: csy * nominal.csy_ns_per_m,
                    csay_ns_per_m: csay * nominal.csay_ns_per_m,
                };
                let mut monitor =
                    DamperMonitor::for_bogie(&config, 1, Some(table.clone())).unwrap();
                let mut sim = BogieSimulator::new(&s).unwrap();
                let mut last = None;
                while let Some((sample, truth)) = sim.step() {
                    let e = *monitor.step(sample).unwrap();
                    last = Some([
                        e.csy.mean_ns_per_m / truth.dampers.csy_ns_per_m - 1.0,
                        e.csay.mean_ns_per_m / truth.dampers.csay_ns_per_m - 1.0,
                    ]);
                }
                let [ey, eay] = last.unwrap();
                let ok = ey.abs() <= 0.05 && eay.abs() <= 0.05;
                within += usize::from(ok);
                runs += 1;
                println!(
                    "| {csy} | {csay} | {seed} | {:+.1} % | {:+.1} % | {} |",
                    100.0 * ey,
                    100.0 * eay,
                    if ok { "yes" } else { "**no**" }
                );
            }
        }
    }
    println!("both within 5 % at 30 s: {within} of {runs} runs");
}
