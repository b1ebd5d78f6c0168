//! What each cheaper per-particle filter gives up against the exact one, on the same data.
//!
//! The RBPF's posterior over `theta` is driven by each particle's log-likelihood
//! `ln p(y_1..y_k | theta)`. For the exact filter (matrix exponential, full covariance) and
//! each cheaper variant, on the same 20 s of `damper-seed.toml`, this computes that
//! log-likelihood at the truth and at +-2% (C_sy) / +-5% (C_say), fits a parabola per
//! coefficient and reports: the log-likelihood error at the truth (nats), the shift of the
//! likelihood's mode (% of the coefficient) and its curvature-based standard deviation. A
//! variant is as good as exact when its mode shift is small against that standard deviation.
//!
//! Then it runs the whole RBPF (N = 100, 20 s) exact and steady-state on the same data.
//!
//! Run: `CARGO_TARGET_DIR=... cargo bench -p railmon-damper --bench accuracy [-- --speed-m-s V
//! --csy-ratio R]`.

use std::time::Instant;

use railmon_damper::model::Vector5;
use railmon_damper::{
    BogieSimulator, DamperMonitorConfig, DamperScenario, Dampers, GainGridConfig, KernelSchedule,
    Propagation, Rbpf,
};

const SEED: &str = include_str!("../../config/scenarios/damper-seed.toml");
const DURATION_S: f64 = 20.0;

/// What the flags set: the data's speed and damper (the variants' accuracy at other points).
struct Args {
    speed_m_s: Option<f64>,
    csy_ratio: f64,
}

impl Args {
    fn parse() -> Self {
        let mut args = Args {
            speed_m_s: None,
            csy_ratio: 1.0,
        };
        let mut it = std::env::args().skip(1);
        while let Some(flag) = it.next() {
            let mut value = |what: &str| -> f64 {
                let v = it.next().unwrap_or_default();
                v.parse().unwrap_or_else(|_| {
                    eprintln!("{flag}: expected {what}, got {v:?}\n{USAGE}");
                    std::process::exit(2)
                })
            };
            match flag.as_str() {
                "--speed-m-s" => args.speed_m_s = Some(value("a speed in m/s")),
                "--csy-ratio" => args.csy_ratio = value("a ratio to the nominal C_sy"),
                // cargo bench passes --bench to every bench binary.
                "--bench" => {}
                _ => {
                    eprintln!("unknown flag {flag}\n{USAGE}");
                    std::process::exit(2)
                }
            }
        }
        args
    }
}

const USAGE: &str = "usage: cargo bench -p railmon-damper --bench accuracy -- [FLAGS]

--speed-m-s V   the data's (and filters') speed (default: damper-seed.toml's, 45.3 m/s)
--csy-ratio R   the plant's C_sy at R x nominal (default 1), the likelihood taken about it";

struct Variant {
    name: &'static str,
    propagation: Propagation,
    taylor_truncation: f64,
    grid_points: usize,
}

/// `ln p(y | theta)` of one filter variant: an RBPF whose particles all sit at `theta`
/// (`DamperMonitorConfig::with_known_dampers`).
fn log_likelihood(config: &DamperMonitorConfig, v: &Variant, d: &Dampers, ys: &[Vector5]) -> f64 {
    let mut c = config.with_known_dampers(*d);
    c.rbpf.kernel = KernelSchedule::AtResampling;
    c.rbpf.propagation = v.propagation;
    c.rbpf.taylor_truncation = v.taylor_truncation;
    // The grid is centred on `nominal`: shift it so that theta falls inside a cell, as
    // a particle's parameters do, not on a node.
    c.rbpf.gain_grid = GainGridConfig {
        points_per_axis: v.grid_points,
        min_ratio: 0.1 * 1.037,
        max_ratio: 3.0 * 1.037,
    };
    let mut rbpf = Rbpf::new(&c.filter_model(), &c.rbpf, &c.speed).expect("rbpf");
    for y in ys {
        rbpf.step(y).expect("step");
    }
    rbpf.log_evidence()
}

/// Mode and standard deviation (relative) of a parabola through `(-h, l-), (0, l0), (h, l+)`.
fn parabola(h: f64, lm: f64, l0: f64, lp: f64) -> (f64, f64) {
    let curvature = (lp - 2.0 * l0 + lm) / (h * h);
    let slope = (lp - lm) / (2.0 * h);
    (-slope / curvature, (-1.0 / curvature).sqrt())
}

fn main() {
    let mut scenario = DamperScenario::from_toml_str(SEED).expect("seed scenario");
    scenario.duration_s = DURATION_S;
    let args = Args::parse();
    if let Some(v) = args.speed_m_s {
        scenario.vehicle.speed_m_s = v;
    }
    scenario.dampers.csy_ns_per_m *= args.csy_ratio;
    let config = scenario.monitor_config();
    let mut sim = BogieSimulator::new(&scenario).expect("simulator");
    let mut ys = vec![];
    while let Some((y, _)) = sim.step() {
        ys.push(y.to_vector());
    }
    let variants = [
        Variant {
            name: "exact",
            propagation: Propagation::Exact,
            taylor_truncation: 1e-9,
            grid_points: 33,
        },
        Variant {
            name: "steady, Taylor to 1e-5, grid 33 (default)",
            propagation: Propagation::SteadyState,
            taylor_truncation: 1e-5,
            grid_points: 33,
        },
        Variant {
            name: "steady, Taylor to 1e-9, grid 33",
            propagation: Propagation::SteadyState,
            taylor_truncation: 1e-9,
            grid_points: 33,
        },
        Variant {
            name: "steady, Taylor to 1e-9, grid 65",
            propagation: Propagation::SteadyState,
            taylor_truncation: 1e-9,
            grid_points: 65,
        },
        Variant {
            name: "steady, Taylor to 1e-4, grid 33",
            propagation: Propagation::SteadyState,
            taylor_truncation: 1e-4,
            grid_points: 33,
        },
        Variant {
            name: "steady, Taylor to 1e-3, grid 33",
            propagation: Propagation::SteadyState,
            taylor_truncation: 1e-3,
            grid_points: 33,
        },
        Variant {
            name: "steady, Taylor to 1e-5, grid 9",
            propagation: Propagation::SteadyState,
            taylor_truncation: 1e-5,
            grid_points: 9,
        },
    ];
    let truth = scenario.dampers;
    let steps = [("csy", 0.02), ("csay", 0.05)];
    println!("Log-likelihood of {DURATION_S} s of damper-seed.toml, per-particle filter variants:");
    println!(
        "{:<40} {:>14} {:>14} {:>12} {:>14} {:>12} {:>9}",
        "variant", "lnL(truth)", "C_sy mode %", "C_sy sd %", "C_say mode %", "C_say sd %", "time s"
    );
    let mut reference: Option<f64> = None;
    for v in &variants {
        let start = Instant::now();
        let l0 = log_likelihood(&config, v, &truth, &ys);
        let mut cols = vec![];
        for (k, (_, h)) in steps.iter().enumerate() {
            let at = |f: f64| {
                let mut d = truth;
                if k == 0 {
                    d.csy_ns_per_m *= f;
                } else {
                    d.csay_ns_per_m *= f;
                }
                log_likelihood(&config, v, &d, &ys)
            };
            let (mode, sd) = parabola(*h, at(1.0 - h), l0, at(1.0 + h));
            cols.push((mode * 100.0, sd * 100.0));
        }
        let dl = reference.map_or(0.0, |r| l0 - r);
        if reference.is_none() {
            reference = Some(l0);
        }
        println!(
            "{:<40} {:>14.3} {:>14.3} {:>12.3} {:>14.3} {:>12.3} {:>9.1}",
            v.name,
            if v.propagation == Propagation::Exact {
                l0
            } else {
                dl
            },
            cols[0].0,
            cols[0].1,
            cols[1].0,
            cols[1].1,
            start.elapsed().as_secs_f64()
        );
    }
    println!("(lnL column: exact value, then each variant's difference from it in nats)");

    println!("\nWhole RBPF, N = 100, {DURATION_S} s, same data and seed:");
    for (name, p) in [
        ("exact", Propagation::Exact),
        ("steady_state", Propagation::SteadyState),
    ] {
        let mut c = config;
        c.rbpf.particles = 100;
        c.rbpf.propagation = p;
        let mut rbpf = Rbpf::new(&c.filter_model(), &c.rbpf, &c.speed).expect("rbpf");
        let start = Instant::now();
        for y in &ys {
            rbpf.step(y).expect("step");
        }
        let e = rbpf.estimate();
        println!(
            "{name:>13}: C_sy {:.4} [{:.4}, {:.4}]  C_say {:.4} [{:.4}, {:.4}]  (ratios to truth; {:.1} s)",
            e.csy.health_ratio,
            e.csy.q05_ns_per_m / truth.csy_ns_per_m,
            e.csy.q95_ns_per_m / truth.csy_ns_per_m,
            e.csay.health_ratio,
            e.csay.q05_ns_per_m / truth.csay_ns_per_m,
            e.csay.q95_ns_per_m / truth.csay_ns_per_m,
            start.elapsed().as_secs_f64()
        );
    }
}
