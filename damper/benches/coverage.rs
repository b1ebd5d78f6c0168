//! Calibration of the RBPF over many realisations (issue 4), and its bias on a spectral track.
//!
//! **seed study**: `damper-seed.toml` (nominal dampers, white track) re-run with many simulator
//! seeds, each with its own filter seed. At 10, 30, 45 and 60 s, per damper and filter variant:
//! the empirical coverage of the 90% interval (5%/95% quantiles) with its binomial standard
//! error, the mean and standard deviation of the relative error `mean / truth - 1`, the mean
//! interval width relative to the truth, and the fraction of seeds with both means within 3%
//! at 30 s.
//!
//! Beside each run, the **ideal** posterior: the exact likelihood of the same data (the
//! per-parameter steady-state Kalman filter, shown equal to the exact filter in
//! `benches/accuracy.rs`) on a 3 x 3 stencil in `(ln C_sy, ln C_say)` about the truth, a
//! quadratic through it (Laplace approximation) times the RBPF's log-normal prior. Its 90%
//! interval is what a perfect, infinite-N static-parameter filter would report; its coverage is
//! 90% up to the sampling error when the filter model is the plant's, and the spread of
//! `RBPF mean - ideal mean` is the error the particle filter adds to the data's own. The
//! stencil is evaluated at two step sizes (the second half the first): the difference checks
//! that the likelihood is quadratic over it.
//!
//! **spectral study**: `damper-spectral.toml` (ERRI low) and `damper-spectral-high.toml` over
//! several seeds; the filters keep the white track model. RBPF, EKF and the white model's
//! likelihood mode (the "ideal" under the wrong model, i.e. the bias that more particles
//! cannot remove).
//!
//! Flags after `--` (all optional; `--help` lists them, a bad one exits 2):
//! - `--study seed|spectral|all` (default `all`);
//! - `--seeds N` (default 40) and `--spectral-seeds N` (default 10, per level);
//! - `--first-seed S` (default 1000): seed `i` runs the simulator with `S + i` and the filter
//!   with `S + 500_000 + i`;
//! - `--duration-s S` (default 60);
//! - `--variants A,B` (default `default`): filter variants run on the same data, see
//!   [`VARIANTS`]; empty (`--variants ""`): the ideal only;
//! - `--ideal-floors A,B`: process-noise floors (std per step): the ideal also under filter
//!   models with these floors (default: none);
//! - `--ekf on|off` (default on): run the EKF baseline too;
//! - `--threads N` (default 2, at most 2): seeds run in parallel;
//! - `--csv FILE`: a file to write every estimate to (`group,sim_seed,method,time_s,damper,
//!   mean_ratio,q05_ratio,q95_ratio`, ratios to the truth).
//!
//! Run: `CARGO_TARGET_DIR=... cargo bench -p railmon-damper --bench coverage`
//! (a short run: `... --bench coverage -- --study seed --seeds 4 --duration-s 10`).

use std::collections::BTreeMap;
use std::io::Write;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use nalgebra::{Matrix2, Vector2};
use railmon_damper::expm::discretize;
use railmon_damper::gain_table::GainTable;
use railmon_damper::kalman::{steady_state, SteadyState};
use railmon_damper::model::{BogieModel, Matrix17, Matrix5x17, Vector17, Vector5};
use railmon_damper::{
    AugmentedEkf, BogieSimulator, DamperMonitorConfig, DamperScenario, Dampers, KernelSchedule,
    Rbpf, RbpfConfig,
};

#[path = "../examples/flags/mod.rs"]
mod flags;
use flags::{on_off, parsed};

const SEED_SCENARIO: &str = include_str!("../../config/scenarios/damper-seed.toml");
const SPECTRAL_LOW: &str = include_str!("../../config/scenarios/damper-spectral.toml");
const SPECTRAL_HIGH: &str = include_str!("../../config/scenarios/damper-spectral-high.toml");

const CHECKPOINTS_S: [f64; 4] = [10.0, 30.0, 45.0, 60.0];
/// The 95% quantile of the standard normal: the 90% interval is `+- Z90` standard deviations.
const Z90: f64 = 1.644_853_626_951_472_2;
const DAMPERS: [&str; 2] = ["csy", "csay"];
/// Stencil steps in `ln C` (C_sy, C_say): about the likelihood's standard deviation at 10 s.
const STENCIL_LN_STEP: [f64; 2] = [0.004, 0.015];

/// Filter variants (name, what it changes, the change).
type Variant = (&'static str, &'static str, fn(&mut RbpfConfig));
const VARIANTS: &[Variant] = &[
    ("default", "the scenario's monitor settings", |_| {}),
    ("no_diffusion", "ln_diffusion_per_sqrt_s = 0", |c| {
        c.ln_diffusion_per_sqrt_s = 0.0
    }),
    ("no_regeneration", "regeneration_fraction = 0", |c| {
        c.regeneration_fraction = 0.0
    }),
    (
        "static",
        "no diffusion, no regeneration, no jump search (the paper's static parameters)",
        |c| {
            c.ln_diffusion_per_sqrt_s = 0.0;
            c.regeneration_fraction = 0.0;
            c.jump_search.enabled = false;
        },
    ),
    (
        "every_step",
        "Liu-West move every step (the paper's schedule; no jump search)",
        |c| {
            c.kernel = KernelSchedule::EveryStep;
            c.jump_search.enabled = false;
        },
    ),
    ("n4000", "N = 4000", |c| c.particles = 4000),
    ("static_n4000", "static and N = 4000", |c| {
        c.ln_diffusion_per_sqrt_s = 0.0;
        c.regeneration_fraction = 0.0;
        c.jump_search.enabled = false;
        c.particles = 4000;
    }),
];

/// What the flags set (see the module's documentation).
struct Args {
    study: String,
    seeds: u64,
    spectral_seeds: u64,
    first_seed: u64,
    duration_s: f64,
    threads: usize,
    variants: String,
    floors: String,
    ekf: bool,
    csv: Option<String>,
}

const USAGE: &str = "usage: cargo bench -p railmon-damper --bench coverage -- [FLAGS]

--study seed|spectral|all  which study (default all)
--seeds N                  seed-study runs (default 40)
--spectral-seeds N         spectral-study runs per level (default 10)
--first-seed S             simulator seeds from S, filter seeds from S + 500000 (default 1000)
--duration-s S             seconds per run (default 60)
--variants A,B             filter variants (default default; empty: the ideal only)
--ideal-floors A,B         the ideal also with these process-noise floors (default none)
--ekf on|off               run the EKF baseline too (default on)
--threads N                seeds in parallel, 1-2 (default 2)
--csv FILE                 write every estimate to FILE
--help                     this text";

fn parse_args() -> Result<Args, String> {
    let mut a = Args {
        study: "all".into(),
        seeds: 40,
        spectral_seeds: 10,
        first_seed: 1000,
        duration_s: 60.0,
        threads: 2,
        variants: "default".into(),
        floors: String::new(),
        ekf: true,
        csv: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or(format!("{flag} needs a value"));
        match flag.as_str() {
            "--help" | "-h" => {
                println!("{USAGE}");
                std::process::exit(0);
            }
            // cargo bench passes it to every bench binary.
            "--bench" => {}
            "--study" => {
                a.study = value()?;
                if !["seed", "spectral", "all"].contains(&a.study.as_str()) {
                    return Err(format!("--study {}: seed, spectral or all", a.study));
                }
            }
            "--seeds" => a.seeds = parsed(&flag, &value()?)?,
            "--spectral-seeds" => a.spectral_seeds = parsed(&flag, &value()?)?,
            "--first-seed" => a.first_seed = parsed(&flag, &value()?)?,
            "--duration-s" => a.duration_s = parsed(&flag, &value()?)?,
            "--threads" => a.threads = parsed(&flag, &value()?)?,
            "--variants" => a.variants = value()?,
            "--ideal-floors" => a.floors = value()?,
            "--ekf" => a.ekf = on_off(&flag, &value()?)?,
            "--csv" => a.csv = Some(value()?),
            other => return Err(format!("unknown flag {other}")),
        }
    }
    if !(a.duration_s > 0.0 && a.duration_s.is_finite()) {
        return Err(format!("--duration-s {}: a positive number", a.duration_s));
    }
    if !(1..=2).contains(&a.threads) {
        return Err(format!("--threads {}: 1 or 2", a.threads));
    }
    for name in a
        .variants
        .split(',')
        .map(str::trim)
        .filter(|n| !n.is_empty())
    {
        if !VARIANTS.iter().any(|v| v.0 == name) {
            let names: Vec<&str> = VARIANTS.iter().map(|v| v.0).collect();
            return Err(format!(
                "--variants: no variant {name:?} ({})",
                names.join(", ")
            ));
        }
    }
    for floor in a.floors.split(',').map(str::trim).filter(|f| !f.is_empty()) {
        parsed::<f64>("--ideal-floors", floor)?;
    }
    Ok(a)
}

/// One estimate of one damper at one checkpoint, as ratios to the truth.
#[derive(Debug, Clone, Copy)]
struct Estimate {
    mean: f64,
    lo: f64,
    hi: f64,
}

impl Estimate {
    fn error(&self) -> f64 {
        self.mean - 1.0
    }
    fn covers(&self) -> bool {
        self.lo <= 1.0 && 1.0 <= self.hi
    }
    /// The error in `ln C` over the standard deviation the interval implies
    /// (`ln(q95 / q05) / (2 Z90)`): standard normal across seeds when calibrated.
    fn z(&self) -> f64 {
        self.mean.ln() * 2.0 * Z90 / (self.hi / self.lo).ln()
    }
}

/// What one seed gives: per method, checkpoint and damper.
#[derive(Debug, Clone)]
struct SeedResult {
    group: String,
    seed: u64,
    /// `(method, checkpoint index)` -> per damper.
    estimates: BTreeMap<(String, usize), [Estimate; 2]>,
}

/// The exact likelihood of the data at the stencil `ln theta_truth + (i h_0, j h_1)`,
/// `i, j in {-1, 0, 1}`, for two step sizes: steady-state Kalman filters of fixed parameters.
#[derive(Debug, Clone)]
struct Stencil {
    /// Per filter: `Phi_f`, the steady state, its stencil position.
    filters: Vec<(Matrix17, SteadyState)>,
    h: Matrix5x17,
    /// Prior of `ln C`: mean offset from the truth and standard deviation.
    prior_offset: [f64; 2],
    prior_std: f64,
}

const SCALES: [f64; 2] = [1.0, 0.5];

impl Stencil {
    fn new(config: &DamperMonitorConfig, truth: &Dampers) -> Self {
        let model = BogieModel::new(&config.vehicle, config.drift_leak_per_s).expect("model");
        let noise = config.noise();
        let h = model.h_matrix();
        let g = model.g_matrix();
        let mut filters = vec![];
        for scale in SCALES {
            for i in -1..=1 {
                for j in -1..=1 {
                    let ln = truth.ln();
                    let d = Dampers::from_ln([
                        ln[0] + scale * i as f64 * STENCIL_LN_STEP[0],
                        ln[1] + scale * j as f64 * STENCIL_LN_STEP[1],
                    ]);
                    let disc = discretize(&model.a_matrix(&d), &g, config.dt_s).expect("disc");
                    let ss = steady_state(&disc, &h, &noise).expect("riccati");
                    filters.push((disc.phi, ss));
                }
            }
        }
        let prior_centre = Dampers {
            csy_ns_per_m: config.nominal.csy_ns_per_m * config.rbpf.prior_ratio,
            csay_ns_per_m: config.nominal.csay_ns_per_m * config.rbpf.prior_ratio,
        }
        .ln();
        let ln = truth.ln();
        Stencil {
            filters,
            h,
            prior_offset: [prior_centre[0] - ln[0], prior_centre[1] - ln[1]],
            prior_std: config.rbpf.prior_ln_std,
        }
    }

    fn start(&self) -> StencilRun {
        StencilRun {
            x: vec![Vector17::zeros(); self.filters.len()],
            ll: vec![0.0; self.filters.len()],
        }
    }

    /// Laplace approximation of the posterior of `ln theta - ln theta_truth` from the stencil
    /// of scale `s` (index into [`SCALES`]): mode and covariance.
    fn posterior(&self, run: &StencilRun, s: usize) -> Option<(Vector2<f64>, Matrix2<f64>)> {
        let f = |i: usize, j: usize| run.ll[s * 9 + i * 3 + j];
        let h = [
            SCALES[s] * STENCIL_LN_STEP[0],
            SCALES[s] * STENCIL_LN_STEP[1],
        ];
        let mut grad = Vector2::new(
            (f(2, 1) - f(0, 1)) / (2.0 * h[0]),
            (f(1, 2) - f(1, 0)) / (2.0 * h[1]),
        );
        let h00 = (f(2, 1) - 2.0 * f(1, 1) + f(0, 1)) / (h[0] * h[0]);
        let h11 = (f(1, 2) - 2.0 * f(1, 1) + f(1, 0)) / (h[1] * h[1]);
        let h01 = (f(2, 2) - f(2, 0) - f(0, 2) + f(0, 0)) / (4.0 * h[0] * h[1]);
        let mut precision = -Matrix2::new(h00, h01, h01, h11);
        if self.prior_std > 0.0 {
            let p = self.prior_std.powi(-2);
            precision += Matrix2::identity() * p;
            grad += Vector2::new(self.prior_offset[0], self.prior_offset[1]) * p;
        }
        let cov = precision.cholesky()?.inverse();
        Some((cov * grad, cov))
    }

    /// The log-normal marginal of damper `k`: mean, 5% and 95% quantiles as ratios to the truth.
    fn estimate(mode: &Vector2<f64>, cov: &Matrix2<f64>, k: usize) -> Estimate {
        let sd = cov[(k, k)].sqrt();
        Estimate {
            mean: (mode[k] + 0.5 * cov[(k, k)]).exp(),
            lo: (mode[k] - Z90 * sd).exp(),
            hi: (mode[k] + Z90 * sd).exp(),
        }
    }
}

#[derive(Debug, Clone)]
struct StencilRun {
    x: Vec<Vector17>,
    ll: Vec<f64>,
}

impl StencilRun {
    fn step(&mut self, stencil: &Stencil, y: &Vector5) {
        for ((x, ll), (phi, ss)) in self.x.iter_mut().zip(&mut self.ll).zip(&stencil.filters) {
            let pred = phi * *x;
            let e = y - stencil.h * pred;
            *ll += ss.log_likelihood(&e);
            *x = pred + ss.gain * e;
        }
    }
}

/// A study: scenario texts (one group each) and how many seeds.
struct Job {
    group: String,
    scenario: DamperScenario,
    seed_index: u64,
}

struct Shared {
    variants: Vec<(&'static str, DamperMonitorConfig, Arc<GainTable>)>,
    /// The exact likelihood under the monitor's model ("ideal"), and under models with
    /// other process-noise floors.
    stencils: Vec<(String, Stencil)>,
    /// The monitor settings (the EKF's).
    config: DamperMonitorConfig,
    ekf: bool,
    first_seed: u64,
}

fn run_job(job: &Job, shared: &Shared) -> SeedResult {
    let sim_seed = shared.first_seed + job.seed_index;
    let filter_seed = shared.first_seed + 500_000 + job.seed_index;
    let mut scenario = job.scenario.clone();
    scenario.seed = sim_seed;
    let mut sim = BogieSimulator::new(&scenario).expect("simulator");
    let mut filters: Vec<(&str, Rbpf)> = shared
        .variants
        .iter()
        .map(|(name, cfg, table)| {
            let mut c = *cfg;
            c.rbpf.seed = filter_seed;
            (
                *name,
                Rbpf::with_gain_table(&c.filter_model(), &c.rbpf, &c.speed, Some(table.clone()))
                    .expect("rbpf"),
            )
        })
        .collect();
    let mut ekf = shared.ekf.then(|| {
        AugmentedEkf::new(&shared.config.filter_model(), &shared.config.ekf).expect("ekf")
    });
    let mut stencil_runs: Vec<StencilRun> =
        shared.stencils.iter().map(|(_, s)| s.start()).collect();
    let checkpoints: Vec<(usize, usize)> = CHECKPOINTS_S
        .iter()
        .enumerate()
        .filter(|(_, t)| **t <= scenario.duration_s + 1e-9)
        .map(|(c, t)| (c, (t / scenario.dt_s).round() as usize))
        .collect();
    let mut estimates = BTreeMap::new();
    let mut k = 0;
    while let Some((sample, truth)) = sim.step() {
        let y = sample.to_vector();
        let truth = truth.dampers;
        k += 1;
        for (_, f) in filters.iter_mut() {
            f.step(&y).expect("rbpf step");
        }
        let ekf_estimate = ekf.as_mut().map(|e| e.step(&y));
        if matches!(ekf_estimate, Some(Err(_))) {
            ekf = None;
        }
        for (run, (_, s)) in stencil_runs.iter_mut().zip(&shared.stencils) {
            run.step(s, &y);
        }
        let Some(&(c, _)) = checkpoints.iter().find(|(_, at)| *at == k) else {
            continue;
        };
        let truths = [truth.csy_ns_per_m, truth.csay_ns_per_m];
        for (name, f) in filters.iter_mut() {
            let e = f.estimate();
            let per = [e.csy, e.csay].map(|p| (p.mean_ns_per_m, p.q05_ns_per_m, p.q95_ns_per_m));
            let est = std::array::from_fn(|d| Estimate {
                mean: per[d].0 / truths[d],
                lo: per[d].1 / truths[d],
                hi: per[d].2 / truths[d],
            });
            estimates.insert((name.to_string(), c), est);
        }
        if let Some(Ok(e)) = ekf_estimate {
            let m = [e.dampers.csy_ns_per_m, e.dampers.csay_ns_per_m];
            let est = std::array::from_fn(|d| Estimate {
                mean: m[d] / truths[d],
                lo: (m[d] - Z90 * e.std_ns_per_m[d]) / truths[d],
                hi: (m[d] + Z90 * e.std_ns_per_m[d]) / truths[d],
            });
            estimates.insert(("ekf".to_string(), c), est);
        }
        // The stencil sits about the initial truth (no faults in these scenarios).
        for (run, (name, stencil)) in stencil_runs.iter().zip(&shared.stencils) {
            for (s, suffix) in [(0, ""), (1, "_half_step")] {
                if let Some((mode, cov)) = stencil.posterior(run, s) {
                    let est = std::array::from_fn(|d| Stencil::estimate(&mode, &cov, d));
                    estimates.insert((format!("{name}{suffix}"), c), est);
                }
            }
        }
    }
    SeedResult {
        group: job.group.clone(),
        seed: sim_seed,
        estimates,
    }
}

fn mean_sd(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    (m, var.sqrt())
}

fn pct(x: f64) -> String {
    format!("{:+.2}%", 100.0 * x)
}

/// Per group: the coverage table of every method.
fn report(group: &str, results: &[&SeedResult], duration_s: f64, methods: &[String]) {
    let n = results.len();
    println!("\n## {group}: {n} seeds, {duration_s} s\n");
    println!(
        "| method | damper | t (s) | coverage of 90% | mean error | sd error | mean width | sd z | sd(mean - ideal mean) |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for method in methods {
        for (d, dname) in DAMPERS.iter().enumerate() {
            for (c, t) in CHECKPOINTS_S.iter().enumerate() {
                let pairs: Vec<(Estimate, Option<Estimate>)> = results
                    .iter()
                    .filter_map(|r| {
                        let e = r.estimates.get(&(method.clone(), c))?[d];
                        let ideal = r.estimates.get(&("ideal".to_string(), c)).map(|i| i[d]);
                        Some((e, ideal))
                    })
                    .collect();
                if pairs.is_empty() {
                    continue;
                }
                let m = pairs.len() as f64;
                let p = pairs.iter().filter(|(e, _)| e.covers()).count() as f64 / m;
                let se = (p * (1.0 - p) / m).sqrt();
                let (err_mean, err_sd) =
                    mean_sd(&pairs.iter().map(|(e, _)| e.error()).collect::<Vec<_>>());
                let width = pairs.iter().map(|(e, _)| e.hi - e.lo).sum::<f64>() / m;
                let z_sd = mean_sd(&pairs.iter().map(|(e, _)| e.z()).collect::<Vec<_>>()).1;
                let diffs: Vec<f64> = pairs
                    .iter()
                    .filter_map(|(e, i)| i.map(|i| e.mean - i.mean))
                    .collect();
                let dev = if diffs.len() > 1 {
                    format!("{:.2}%", 100.0 * mean_sd(&diffs).1)
                } else {
                    String::new()
                };
                let missing = if pairs.len() < n {
                    format!(" (of {})", pairs.len())
                } else {
                    String::new()
                };
                println!(
                    "| {method}{missing} | {dname} | {t:.0} | {:.1}% +- {:.1}% | {} | {:.2}% | {:.2}% | {z_sd:.2} | {dev} |",
                    100.0 * p,
                    100.0 * se,
                    pct(err_mean),
                    100.0 * err_sd,
                    100.0 * width,
                );
            }
        }
    }
    let c30 = CHECKPOINTS_S.iter().position(|t| *t == 30.0).expect("30 s");
    for method in methods {
        let both: Vec<bool> = results
            .iter()
            .filter_map(|r| r.estimates.get(&(method.clone(), c30)))
            .map(|e| e.iter().all(|d| d.error().abs() < 0.03))
            .collect();
        if !both.is_empty() {
            let k = both.iter().filter(|b| **b).count();
            println!(
                "{method}: both means within 3% at 30 s in {k} of {} seeds",
                both.len()
            );
        }
    }
    // Is the likelihood quadratic over the stencil? Compare the two step sizes.
    let mut worst = [0.0f64; 2];
    for r in results {
        for c in 0..CHECKPOINTS_S.len() {
            if let (Some(a), Some(b)) = (
                r.estimates.get(&("ideal".to_string(), c)),
                r.estimates.get(&("ideal_half_step".to_string(), c)),
            ) {
                for d in 0..2 {
                    let sd = (a[d].hi.ln() - a[d].lo.ln()) / (2.0 * Z90);
                    worst[0] = worst[0].max((a[d].mean.ln() - b[d].mean.ln()).abs() / sd);
                    let sd_b = (b[d].hi.ln() - b[d].lo.ln()) / (2.0 * Z90);
                    worst[1] = worst[1].max((sd_b / sd - 1.0).abs());
                }
            }
        }
    }
    println!(
        "ideal, stencil step vs half step: means differ by at most {:.3} sd, sds by at most {:.2}%",
        worst[0],
        100.0 * worst[1]
    );
}

fn write_csv(path: &str, results: &[SeedResult]) -> Result<(), csv::Error> {
    let mut w = csv::Writer::from_path(path)?;
    w.write_record([
        "group",
        "sim_seed",
        "method",
        "time_s",
        "damper",
        "mean_ratio",
        "q05_ratio",
        "q95_ratio",
    ])?;
    for r in results {
        for ((method, c), est) in &r.estimates {
            for (d, e) in est.iter().enumerate() {
                w.write_record([
                    r.group.clone(),
                    r.seed.to_string(),
                    method.clone(),
                    CHECKPOINTS_S[*c].to_string(),
                    DAMPERS[d].to_string(),
                    e.mean.to_string(),
                    e.lo.to_string(),
                    e.hi.to_string(),
                ])?;
            }
        }
    }
    w.flush()?;
    Ok(())
}

fn main() -> std::process::ExitCode {
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("coverage: {e} (--help lists the flags)");
            return std::process::ExitCode::from(2);
        }
    };
    let Args {
        study,
        seeds,
        spectral_seeds,
        first_seed,
        duration_s,
        threads,
        variants: variant_names,
        floors,
        ekf,
        csv,
    } = args;

    let base = DamperScenario::from_toml_str(SEED_SCENARIO).expect("damper-seed.toml");
    let config = base.monitor_config();
    let mut variants = vec![];
    for name in variant_names
        .split(',')
        .map(str::trim)
        .filter(|n| !n.is_empty())
    {
        let (vname, what, apply) = VARIANTS
            .iter()
            .find(|v| v.0 == name)
            .unwrap_or_else(|| panic!("unknown variant {name:?}"));
        let mut c = config;
        apply(&mut c.rbpf);
        let table = Rbpf::gain_table(&c.filter_model(), &c.rbpf, &c.speed).expect("gain table");
        println!("variant {vname}: {what}");
        variants.push((*vname, c, table));
    }
    let mut stencils = vec![("ideal".to_string(), Stencil::new(&config, &base.dampers))];
    for floor in floors.split(',').map(str::trim).filter(|f| !f.is_empty()) {
        let mut c = config;
        c.process_noise_floor_std_per_step = floor.parse().expect("checked by parse_args");
        stencils.push((
            format!("ideal_floor_{floor}"),
            Stencil::new(&c, &base.dampers),
        ));
    }
    let shared = Shared {
        stencils,
        variants,
        config,
        ekf,
        first_seed,
    };

    let mut jobs = vec![];
    let mut groups: Vec<String> = vec![];
    let mut add = |group: &str, text: &str, n: u64| {
        let mut s = DamperScenario::from_toml_str(text).expect("scenario");
        s.duration_s = duration_s;
        // The filters' settings are the seed scenario's (the same in all the files, but for
        // the filter seed, which is set per run).
        let mut monitor = s.monitor_config();
        monitor.rbpf.seed = config.rbpf.seed;
        assert_eq!(monitor, config, "{group}: monitor settings differ");
        assert!(
            s.faults.is_empty(),
            "{group}: the stencil assumes constant truth"
        );
        groups.push(group.to_string());
        for i in 0..n {
            jobs.push(Job {
                group: group.to_string(),
                scenario: s.clone(),
                seed_index: i,
            });
        }
    };
    if study == "seed" || study == "all" {
        add("damper-seed (white track)", SEED_SCENARIO, seeds);
    }
    if study == "spectral" || study == "all" {
        add("damper-spectral (ERRI low)", SPECTRAL_LOW, spectral_seeds);
        add(
            "damper-spectral-high (ERRI high)",
            SPECTRAL_HIGH,
            spectral_seeds,
        );
    }
    println!(
        "{} runs of {duration_s} s on {threads} thread(s); simulator seeds from {first_seed}, filter seeds from {}",
        jobs.len(),
        first_seed + 500_000
    );

    let next = AtomicUsize::new(0);
    let results = Mutex::new(Vec::<SeedResult>::new());
    let start = Instant::now();
    std::thread::scope(|scope| {
        for _ in 0..threads {
            scope.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some(job) = jobs.get(i) else { break };
                let t0 = Instant::now();
                let r = run_job(job, &shared);
                let last = CHECKPOINTS_S.iter().rposition(|t| *t <= duration_s + 1e-9);
                let mut line = format!("{} seed {}:", r.group, r.seed);
                let names = shared.variants.iter().map(|v| v.0);
                let ideals = shared.stencils.iter().map(|s| s.0.as_str());
                for m in names.chain(ideals).chain(["ekf"]) {
                    if let Some(e) = last.and_then(|c| r.estimates.get(&(m.to_string(), c))) {
                        line += &format!(
                            " {m} csy {} csay {}{}",
                            pct(e[0].error()),
                            pct(e[1].error()),
                            if e[0].covers() && e[1].covers() {
                                ""
                            } else {
                                " (miss)"
                            }
                        );
                    }
                }
                let mut out = std::io::stdout().lock();
                writeln!(out, "{line} ({:.1} s)", t0.elapsed().as_secs_f64()).ok();
                drop(out);
                results.lock().expect("results").push(r);
            });
        }
    });
    let results = results.into_inner().expect("results");
    println!(
        "\n{} runs in {:.0} s",
        results.len(),
        start.elapsed().as_secs_f64()
    );
    let mut methods: Vec<String> = shared.variants.iter().map(|v| v.0.to_string()).collect();
    methods.extend(shared.stencils.iter().map(|s| s.0.clone()));
    methods.push("ekf".to_string());
    if let Some(path) = csv {
        write_csv(&path, &results).unwrap_or_else(|e| panic!("{path}: {e}"));
        println!("estimates written to {path}");
    }
    for group in &groups {
        let rs: Vec<&SeedResult> = results.iter().filter(|r| &r.group == group).collect();
        report(group, &rs, duration_s, &methods);
    }
    std::process::ExitCode::SUCCESS
}
