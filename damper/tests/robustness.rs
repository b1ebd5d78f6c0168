//! Robustness matrix of issue 9: healthy bogies (and a C_say step to 40 %) on plants unlike the
//! filter, one factor at a time from the validated cell (white track of 0.1 m/s, sensor noise
//! as configured, conicity 0.15, 45.3 m/s). The filter is always `DamperMonitorConfig::default()`
//! (it assumes the nominal vehicle at 45.3 m/s and the configured noise); each cell changes the
//! plant only. Per cell, over the seeds: false `damper_degraded` events per hour (healthy runs;
//! `railmon_damper::DamperAlarm`), share of time after 30 s with both RBPF means within 5 % of
//! the truth, 90 % interval coverage of each damper after 30 s, the share of time the filter
//! reports `model_mismatch`, and for the fault runs the detection delay and the C_say error
//! 10 s after the step.
//!
//! `cargo test --release -p railmon-damper --test robustness -- --ignored --nocapture` runs the
//! issue's matrix (600 s per run, 3 seeds, N = 1000: hours on two cores; not in CI). Smaller runs by environment:
//! `ROBUST_DURATION_S=60 ROBUST_SEEDS=2 ROBUST_PARTICLES=200 ROBUST_CELLS=speed,noise`
//! (`ROBUST_CELLS`: names or prefixes of cells, `ROBUST_FAULT=1` adds the fault runs,
//! `ROBUST_NOISE_SCALE=0` runs the filter without its noise estimate, as before issue 9 item 2;
//! `ROBUST_MATCHED_NOISE=1` gives the filter each cell's true sensor noise: the reference
//! the noise estimate is judged against).

use std::sync::Arc;
use std::time::Instant;

use railmon_damper::{
    BogieSimulator, DamperAlarm, DamperEventKind, DamperFault, DamperId, DamperMonitor,
    DamperMonitorConfig, DamperScenario, ErriLevel, FaultKind, Rbpf, TrackSpec,
};

fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

const BASE: &str = "name = \"robust\"\nseed = 1\nduration_s = 60.0\n[track]\nkind = \"white\"\nvelocity_std_m_s = 0.1\n";

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
    for v in [10.0, 30.0, 70.0] {
        cells.push(Cell {
            name: format!("speed {v} m/s"),
            apply: Box::new(move |s| s.vehicle.speed_m_s = v),
        });
    }
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
    delays: Vec<Option<f64>>,
    errors_10s: Vec<f64>,
    /// The estimated noise std ratio (accelerometer 1, gyro) at the end of each healthy run.
    noise_ratio_end: Vec<[f64; 2]>,
}

fn run(
    scenario: &DamperScenario,
    config: &DamperMonitorConfig,
    table: &Arc<railmon_damper::gain_table::GainTable>,
    fault: bool,
    t: &mut Tally,
) {
    let config = *config;
    let mut monitor = DamperMonitor::for_bogie(&config, 1, Some(table.clone())).unwrap();
    let mut alarms = DamperAlarm::pair(&config, [false; 2]);
    let mut sim = BogieSimulator::new(scenario).unwrap();
    let mut detected = None;
    let fault_at = scenario.faults.first().map(|f| f.at_s);
    let mut noise_ratio = [f64::NAN; 2];
    while let Some((sample, truth)) = sim.step() {
        let e = *monitor.step(sample).unwrap();
        noise_ratio = [e.noise_std_ratio[0], e.noise_std_ratio[3]];
        let time = truth.time_s;
        for event in alarms.iter_mut().filter_map(|a| a.update(&e)) {
            let real = fault_at.is_some_and(|at| time >= at) && event.damper == DamperId::Csay;
            if event.kind == DamperEventKind::DamperDegraded {
                if real {
                    detected.get_or_insert(time - fault_at.unwrap_or(0.0));
                } else {
                    t.false_degraded += 1;
                }
            }
        }
        if fault_at.is_some_and(|at| (time - at - 10.0).abs() < 0.5e-3) {
            t.errors_10s
                .push(e.csay.mean_ns_per_m / truth.dampers.csay_ns_per_m - 1.0);
        }
        if time <= 30.0 || !(time * 1e3).round().rem_euclid(10.0).eq(&0.0) {
            continue;
        }
        // Every 10 ms after 30 s.
        let truths = [truth.dampers.csy_ns_per_m, truth.dampers.csay_ns_per_m];
        let posts = [e.csy, e.csay];
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
    t.runs += 1;
    t.hours += scenario.duration_s / 3600.0;
    if fault {
        t.delays.push(detected);
    } else {
        t.noise_ratio_end.push(noise_ratio);
    }
}

#[test]
#[ignore = "the robustness matrix: minutes to hours, see the header"]
fn robustness_matrix() {
    let duration_s: f64 = env_or("ROBUST_DURATION_S", 600.0);
    let seeds: u64 = env_or("ROBUST_SEEDS", 3);
    let particles: usize = env_or("ROBUST_PARTICLES", 1000);
    let fault: bool = env_or("ROBUST_FAULT", 0u8) == 1;
    let only: Vec<String> = std::env::var("ROBUST_CELLS")
        .map(|v| v.split(',').map(str::to_owned).collect())
        .unwrap_or_default();
    let mut config = DamperMonitorConfig::default();
    config.rbpf.particles = particles;
    config.rbpf.noise_scale.enabled = env_or("ROBUST_NOISE_SCALE", 1u8) == 1;
    let matched: bool = env_or("ROBUST_MATCHED_NOISE", 0u8) == 1;
    let table = Rbpf::gain_table(&config).unwrap();
    println!(
        "robustness: {duration_s} s per run, {seeds} seeds, N = {particles}{}, noise estimate {}{}",
        if fault { ", with C_say step runs" } else { "" },
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
        "| cell | false degraded / h | both means within 5 % | csy covered | csay covered | model_mismatch | mean NIS / 5 | C_say step: detected (delay s) | error 10 s after | noise std ratio at end (accel 1, gyro) |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for cell in cells() {
        if !only.is_empty() && !only.iter().any(|o| cell.name.starts_with(o.as_str())) {
            continue;
        }
        let started = Instant::now();
        let mut t = Tally::default();
        for seed in 0..seeds {
            let mut s = DamperScenario::from_toml_str(BASE).unwrap();
            s.duration_s = duration_s;
            s.seed = 9000 + seed;
            (cell.apply)(&mut s);
            let (config, table) = if matched {
                let mut c = config;
                c.sensors = s.sensors;
                (c, Rbpf::gain_table(&c).unwrap())
            } else {
                (config, table.clone())
            };
            run(&s, &config, &table, false, &mut t);
            if fault {
                let mut f = s.clone();
                f.duration_s = duration_s.clamp(45.0, 60.0);
                f.faults = vec![DamperFault {
                    damper: DamperId::Csay,
                    kind: FaultKind::Step,
                    at_s: 30.0,
                    end_s: None,
                    ratio: 0.4,
                }];
                let mut ft = Tally::default();
                run(&f, &config, &table, true, &mut ft);
                t.delays.extend(ft.delays);
                t.errors_10s.extend(ft.errors_10s);
            }
        }
        let pct = |n: usize| 100.0 * n as f64 / t.judged.max(1) as f64;
        let delays: Vec<String> = t
            .delays
            .iter()
            .map(|d| d.map_or("missed".into(), |d| format!("{d:.2}")))
            .collect();
        let errors: Vec<String> = t
            .errors_10s
            .iter()
            .map(|e| format!("{:+.1} %", 100.0 * e))
            .collect();
        let ratios: Vec<String> = t
            .noise_ratio_end
            .iter()
            .map(|r| format!("{:.2} / {:.2}", r[0], r[1]))
            .collect();
        println!(
            "| {} | {:.1} | {:.1} % | {:.1} % | {:.1} % | {:.1} % | {:.2} | {} | {} | {} | ({:.0} s)",
            cell.name,
            t.false_degraded as f64 / t.hours,
            pct(t.within),
            pct(t.covered[0]),
            pct(t.covered[1]),
            pct(t.mismatch),
            t.nis_sum / t.judged.max(1) as f64 / 5.0,
            if fault { delays.join(", ") } else { "-".into() },
            if fault { errors.join(", ") } else { "-".into() },
            ratios.join(", "),
            started.elapsed().as_secs_f64(),
        );
    }
}
