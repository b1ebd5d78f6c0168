//! The railcar estimator on generated lines (issue 25 item 2): per line the named-regime
//! accuracy (overall and per label), the virtual sensor against the single regression (RMSE and
//! Diebold-Mariano statistic of the squared-error difference), the coverage of the 90 %
//! intervals, then the distribution over the lines, the named regime's published probability
//! against being right (reliability bins and Brier score, all lines) and the worst lines with
//! their seeds.
//!
//!   cargo run --release -p railmon-fuel --example route_matrix -- --lines 30 --first-seed 100 --split held-out
//!   cargo run --release -p railmon-fuel --example route_matrix -- --seed 101 --write line-101.toml
//!   cargo run --release -p railmon-fuel --example route_matrix -- --scenario config/scenarios/fuel-railcar.toml
//!
//! `--split tuning|held-out|all` takes the first `--lines` seeds from `--first-seed` on that fall
//! in the split (`railmon_fuel::Split::of`: even seeds tune, odd are held out). `--monitor FILE`
//! runs the estimator settings of FILE (a `[monitor]` table, `preset = ...` allowed) instead of
//! the `railcar` preset; the estimator is told each line's speed-sensor noise
//! (`speed_noise_m_s`, the kinematic filter) unless `--ignore-sensor-noise`. `--write` dumps the line as a scenario file for `railmon analyze fuel
//! --scenario`. Scores are computed as `railmon analyze fuel` computes them (`analyze/src/fuel/
//! evaluate.rs`), on the seconds after both estimators initialised; a refused sample is counted
//! and skipped by both (as the service does).

use std::collections::VecDeque;
use std::process::ExitCode;

use railmon_fuel::railcar::RAILCAR_REGIMES;
use railmon_fuel::{
    generated_line, scenario_toml, FuelMonitor, FuelMonitorConfig, Interval, RailcarScenario,
    RailcarSimulator, RegimeName, Split,
};

struct Args {
    lines: usize,
    first_seed: u64,
    split: Option<Split>,
    seed: Option<u64>,
    write: Option<String>,
    monitor: Option<String>,
    ignore_sensor_noise: bool,
    scenario: Option<String>,
}

fn parse_args() -> Result<Args, String> {
    let mut args = Args {
        lines: 30,
        first_seed: 100,
        split: Some(Split::HeldOut),
        seed: None,
        write: None,
        monitor: None,
        ignore_sensor_noise: false,
        scenario: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or(format!("{flag} needs a value"));
        match flag.as_str() {
            "--lines" => args.lines = value()?.parse().map_err(|e| format!("--lines: {e}"))?,
            "--first-seed" => {
                args.first_seed = value()?.parse().map_err(|e| format!("--first-seed: {e}"))?
            }
            "--split" => {
                args.split = match value()?.as_str() {
                    "all" => None,
                    s => Some(Split::parse(s).ok_or(format!("--split {s}: tuning|held-out|all"))?),
                }
            }
            "--seed" => args.seed = Some(value()?.parse().map_err(|e| format!("--seed: {e}"))?),
            "--write" => args.write = Some(value()?),
            "--monitor" => args.monitor = Some(value()?),
            "--ignore-sensor-noise" => args.ignore_sensor_noise = true,
            "--scenario" => args.scenario = Some(value()?),
            other => return Err(format!("unknown flag {other}")),
        }
    }
    if args.write.is_some() && args.seed.is_none() {
        return Err("--write needs --seed".into());
    }
    Ok(args)
}

fn read_monitor(path: &str) -> Result<FuelMonitorConfig, String> {
    #[derive(serde::Deserialize)]
    struct File {
        #[serde(deserialize_with = "railmon_settings::deserialize_with_preset")]
        monitor: FuelMonitorConfig,
    }
    let text = std::fs::read_to_string(path).map_err(|e| format!("{path}: {e}"))?;
    let file: File = toml::from_str(&text).map_err(|e| format!("{path}: {e}"))?;
    file.monitor
        .validate()
        .map_err(|e| format!("{path}: {e}"))?;
    Ok(file.monitor)
}

/// One line's scores.
struct LineScore {
    seed: u64,
    km: f64,
    stations: usize,
    seconds: usize,
    refused: usize,
    speed_noise: f64,
    /// Right and total per label (`RAILCAR_REGIMES` order).
    per_label: [(usize, usize); 5],
    /// Seconds per label (rows, `RAILCAR_REGIMES` order) and name (columns, `RegimeName::ALL`).
    confusion: [[usize; 6]; 5],
    rmse_mixture: f64,
    rmse_single: f64,
    dm: f64,
    coverage_virtual: f64,
    /// Lowest and highest coverage over the virtual sensor and every forecast horizon.
    coverage_range: (f64, f64),
    /// The published probability of the named regime (its components' sum): per bin of
    /// [`RELIABILITY_BINS`], seconds right and seconds; and the sum of its squared error
    /// against being right (Brier).
    reliability: [(usize, usize); 5],
    brier_sum: f64,
    soft_right: usize,
}

/// Lower ends of the reliability bins of the named regime's probability.
const RELIABILITY_BINS: [f64; 5] = [0.0, 0.5, 0.7, 0.9, 0.99];

impl LineScore {
    fn named(&self) -> f64 {
        let right: usize = self.per_label.iter().map(|p| p.0).sum();
        let n: usize = self.per_label.iter().map(|p| p.1).sum();
        right as f64 / n.max(1) as f64
    }

    fn label(&self, l: usize) -> Option<f64> {
        let (right, n) = self.per_label[l];
        (n > 0).then(|| right as f64 / n as f64)
    }

    /// The lowest per-label share (labels with at least 30 s).
    fn worst_label(&self) -> (usize, f64) {
        (0..5)
            .filter(|&l| self.per_label[l].1 >= 30)
            .map(|l| (l, self.label(l).unwrap_or(1.0)))
            .fold((0, 1.0), |a, b| if b.1 < a.1 { b } else { a })
    }
}

/// The Diebold-Mariano statistic of loss differences of estimates of the current sample (no
/// overlap: the plain standard error), as `diebold_mariano(d, 0)` in `analyze`.
fn diebold_mariano(d: &[f64]) -> f64 {
    let n = d.len() as f64;
    if d.len() < 2 {
        return f64::NAN;
    }
    if d.iter().all(|x| *x == 0.0) {
        return 0.0;
    }
    let mean = d.iter().sum::<f64>() / n;
    let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
    mean / (var / n).sqrt()
}

#[derive(Default, Clone, Copy)]
struct Cover {
    inside: usize,
    n: usize,
}

impl Cover {
    fn add(&mut self, i: &Interval, y: f64) {
        self.inside += usize::from(i.contains(y));
        self.n += 1;
    }
    fn share(&self) -> f64 {
        self.inside as f64 / self.n.max(1) as f64
    }
}

/// The line of `seed` analysed with `config`, told the line's speed-sensor noise unless
/// `ignore_sensor_noise` (then `config`'s own `speed_noise_m_s`, 0 in the preset: no filter).
fn line(seed: u64, config: &FuelMonitorConfig, ignore_sensor_noise: bool) -> RailcarScenario {
    let mut scenario = generated_line(seed);
    scenario.monitor = FuelMonitorConfig {
        speed_noise_m_s: match ignore_sensor_noise {
            true => config.speed_noise_m_s,
            false => scenario.railcar.speed_noise_m_s,
        },
        ..config.clone()
    };
    scenario
}

fn score_line(scenario: &RailcarScenario) -> Result<LineScore, String> {
    let (seed, config) = (scenario.seed, &scenario.monitor);
    let mut sim = RailcarSimulator::new(scenario).map_err(|e| e.to_string())?;
    let mut mixture = FuelMonitor::new(config).map_err(|e| e.to_string())?;
    let mut single = FuelMonitor::new(&config.single_regression()).map_err(|e| e.to_string())?;
    let labels: Vec<RegimeName> = RAILCAR_REGIMES
        .iter()
        .map(|l| RegimeName::parse(l).expect("railcar labels are regime names"))
        .collect();
    let horizon = config.forecast_horizon_steps;
    let mut paths: VecDeque<Vec<Interval>> = VecDeque::with_capacity(horizon + 1);
    let mut cover = vec![Cover::default(); horizon + 1];
    let mut per_label = [(0usize, 0usize); 5];
    let mut confusion = [[0usize; 6]; 5];
    let mut reliability = [(0usize, 0usize); 5];
    let mut brier_sum = 0.0;
    let mut soft_right = 0usize;
    let (mut sq_mix, mut sq_single, mut d) = (0.0, 0.0, Vec::new());
    let (mut seconds, mut refused) = (0, 0);
    while let Some((sample, truth)) = sim.step() {
        seconds += 1;
        let a = match mixture.update(&sample) {
            Ok(e) => e.mixture.clone(),
            Err(_) => {
                refused += 1;
                continue;
            }
        };
        let b = single
            .update(&sample)
            .map_err(|e| {
                format!("seed {seed}: the single regression refused what the mixture took: {e}")
            })?
            .mixture
            .clone();
        let (Some(a), Some(b)) = (a, b) else { continue };
        let y = sample.fuel_cm3_s.unwrap_or(f64::NAN);
        for (age, path) in paths.iter().enumerate() {
            cover[age + 1].add(&path[age], y);
        }
        cover[0].add(&a.virtual_sensor_interval_cm3_s(), y);
        paths.push_front(a.forecast_interval_cm3_s());
        paths.truncate(horizon);
        let (e_mix, e_single) = (a.virtual_sensor_cm3_s - y, b.virtual_sensor_cm3_s - y);
        sq_mix += e_mix * e_mix;
        sq_single += e_single * e_single;
        d.push(e_mix * e_mix - e_single * e_single);
        let name = a.regime_names[a.active_regime].regime;
        let right = name == labels[truth.regime];
        let slot = &mut per_label[truth.regime];
        slot.0 += usize::from(right);
        slot.1 += 1;
        let p_named: f64 = a
            .regime_names
            .iter()
            .zip(&a.regime_probabilities)
            .filter(|(n, _)| n.regime == name)
            .map(|(_, p)| p)
            .sum();
        let bin = RELIABILITY_BINS
            .iter()
            .rposition(|&lo| p_named >= lo)
            .unwrap_or(0);
        reliability[bin].0 += usize::from(right);
        reliability[bin].1 += 1;
        brier_sum += (p_named - f64::from(u8::from(right))).powi(2);
        let mut by_regime = [0.0; 6];
        for (n, p) in a.regime_names.iter().zip(&a.regime_probabilities) {
            by_regime[RegimeName::ALL
                .iter()
                .position(|&r| r == n.regime)
                .unwrap_or(5)] += p;
        }
        let soft = (0..6).fold(0, |b, i| if by_regime[i] > by_regime[b] { i } else { b });
        soft_right += usize::from(RegimeName::ALL.get(soft) == Some(&labels[truth.regime]));
        let column = RegimeName::ALL.iter().position(|&n| n == name).unwrap_or(5);
        confusion[truth.regime][column] += 1;
    }
    let n = d.len().max(1) as f64;
    let shares: Vec<f64> = cover.iter().filter(|c| c.n > 0).map(Cover::share).collect();
    Ok(LineScore {
        seed,
        km: scenario.sections.iter().map(|s| s.length_m).sum::<f64>() / 1000.0,
        stations: 1 + scenario.sections.iter().filter(|s| s.stop_s > 0.0).count(),
        seconds,
        refused,
        speed_noise: scenario.railcar.speed_noise_m_s,
        per_label,
        confusion,
        rmse_mixture: (sq_mix / n).sqrt(),
        rmse_single: (sq_single / n).sqrt(),
        dm: diebold_mariano(&d),
        coverage_virtual: cover[0].share(),
        coverage_range: (
            shares.iter().copied().fold(f64::INFINITY, f64::min),
            shares.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        ),
        reliability,
        brier_sum,
        soft_right,
    })
}

fn percent(x: Option<f64>) -> String {
    x.map_or("-".into(), |x| format!("{:.1}", 100.0 * x))
}

fn quantiles(mut v: Vec<f64>) -> String {
    v.retain(|x| x.is_finite());
    if v.is_empty() {
        return "-".into();
    }
    v.sort_by(f64::total_cmp);
    let q = |p: f64| v[((v.len() - 1) as f64 * p).round() as usize];
    format!(
        "min {:.1} / median {:.1} / max {:.1}",
        100.0 * q(0.0),
        100.0 * q(0.5),
        100.0 * q(1.0)
    )
}

fn main() -> ExitCode {
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("route_matrix: {e}");
            return ExitCode::from(2);
        }
    };
    let config = match args.monitor.as_deref().map(read_monitor) {
        None => FuelMonitorConfig::railcar(),
        Some(Ok(c)) => c,
        Some(Err(e)) => {
            eprintln!("route_matrix: {e}");
            return ExitCode::from(2);
        }
    };
    if let (Some(seed), Some(path)) = (args.seed, &args.write) {
        let line = line(seed, &config, args.ignore_sensor_noise);
        let text = match scenario_toml(&line) {
            Ok(t) => t,
            Err(e) => {
                eprintln!("route_matrix: {e}");
                return ExitCode::FAILURE;
            }
        };
        let header = format!(
            "# Generated line, seed {seed} ({} split): `cargo run --release -p railmon-fuel \
             --example route_matrix -- --seed {seed} --write FILE`.\n",
            Split::of(seed).name()
        );
        if let Err(e) = std::fs::write(path, header + &text) {
            eprintln!("route_matrix: {path}: {e}");
            return ExitCode::FAILURE;
        }
        return ExitCode::SUCCESS;
    }
    // A route file (the shipped `config/scenarios/fuel-railcar*.toml`), scored as a line.
    let scenario = match args.scenario.as_deref().map(|path| {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{path}: {e}"))?;
        let mut s = RailcarScenario::from_toml_str(&text).map_err(|e| format!("{path}: {e}"))?;
        if args.monitor.is_some() {
            s.monitor = config.clone();
        }
        Ok::<_, String>(s)
    }) {
        None => None,
        Some(Ok(s)) => Some(s),
        Some(Err(e)) => {
            eprintln!("route_matrix: {e}");
            return ExitCode::from(2);
        }
    };
    let seeds: Vec<u64> = match (args.seed, &scenario) {
        (_, Some(s)) => vec![s.seed],
        (Some(s), None) => vec![s],
        (None, None) => (args.first_seed..)
            .filter(|&s| args.split.is_none_or(|split| Split::of(s) == split))
            .take(args.lines)
            .collect(),
    };
    println!(
        "seed,split,km,stations,s,refused,speed_noise_m_s,named_pct,idle,accelerating,cruising,\
         coasting,braking,vs_rmse_mixture,vs_rmse_single,dm_vs_single,coverage_90_vs,\
         coverage_90_min,coverage_90_max"
    );
    let mut scores = Vec::new();
    for seed in seeds {
        let scored = match &scenario {
            Some(s) => score_line(s),
            None => score_line(&line(seed, &config, args.ignore_sensor_noise)),
        };
        let s = match scored {
            Ok(s) => s,
            Err(e) => {
                eprintln!("route_matrix: seed {seed}: {e}");
                return ExitCode::FAILURE;
            }
        };
        println!(
            "{},{},{:.1},{},{},{},{:.2},{},{},{},{},{},{},{:.3},{:.3},{:.2},{:.3},{:.3},{:.3}",
            s.seed,
            Split::of(s.seed).name(),
            s.km,
            s.stations,
            s.seconds,
            s.refused,
            s.speed_noise,
            percent(Some(s.named())),
            percent(s.label(0)),
            percent(s.label(1)),
            percent(s.label(2)),
            percent(s.label(3)),
            percent(s.label(4)),
            s.rmse_mixture,
            s.rmse_single,
            s.dm,
            s.coverage_virtual,
            s.coverage_range.0,
            s.coverage_range.1,
        );
        scores.push(s);
    }
    println!("\n{} lines", scores.len());
    println!(
        "named regime, %: {}",
        quantiles(scores.iter().map(LineScore::named).collect())
    );
    for (l, name) in RAILCAR_REGIMES.iter().enumerate() {
        println!(
            "  {name}, %: {}",
            quantiles(scores.iter().filter_map(|s| s.label(l)).collect())
        );
    }
    println!("seconds by label (rows) and name (columns), all lines:");
    println!(
        "  label \\ name, {}",
        RegimeName::ALL.map(RegimeName::as_str).join(", ")
    );
    for (l, label) in RAILCAR_REGIMES.iter().enumerate() {
        let row: Vec<String> = (0..6)
            .map(|c| {
                scores
                    .iter()
                    .map(|s| s.confusion[l][c])
                    .sum::<usize>()
                    .to_string()
            })
            .collect();
        println!("  {label}, {}", row.join(", "));
    }
    // Is the named regime's published probability what it is worth?
    let seconds: usize = scores
        .iter()
        .map(|s| s.reliability.iter().map(|r| r.1).sum::<usize>())
        .sum();
    let brier: f64 = scores.iter().map(|s| s.brier_sum).sum::<f64>() / seconds.max(1) as f64;
    println!(
        "named regime's published probability against being right (all lines), Brier {brier:.4}:"
    );
    println!(
        "  (the regime of the highest published probability right: {:.1} %)",
        100.0 * scores.iter().map(|s| s.soft_right).sum::<usize>() as f64 / seconds.max(1) as f64
    );
    for (b, lo) in RELIABILITY_BINS.iter().enumerate() {
        let (right, n) = scores.iter().fold((0, 0), |acc, s| {
            (acc.0 + s.reliability[b].0, acc.1 + s.reliability[b].1)
        });
        let hi = RELIABILITY_BINS.get(b + 1).copied().unwrap_or(1.0);
        println!(
            "  p in [{lo:.2}, {hi:.2}{}: {n} s, right {}",
            if b + 1 == RELIABILITY_BINS.len() {
                "]"
            } else {
                ")"
            },
            percent((n > 0).then(|| right as f64 / n as f64))
        );
    }
    let better = scores.iter().filter(|s| s.dm < -1.645).count();
    let worse = scores.iter().filter(|s| s.dm > 1.645).count();
    println!(
        "virtual sensor vs single regression: significantly better on {better}, significantly \
         worse on {worse} of {} lines (DM beyond -/+1.645)",
        scores.len()
    );
    let cov_lo = scores
        .iter()
        .map(|s| s.coverage_range.0)
        .fold(f64::INFINITY, f64::min);
    let cov_hi = scores
        .iter()
        .map(|s| s.coverage_range.1)
        .fold(f64::NEG_INFINITY, f64::max);
    let outside = scores
        .iter()
        .filter(|s| s.coverage_range.0 < 0.85 || s.coverage_range.1 > 0.95)
        .count();
    println!(
        "coverage_90 (virtual sensor and every horizon): {cov_lo:.3}..{cov_hi:.3}, lines with \
         one outside [0.85, 0.95]: {outside}"
    );
    println!(
        "refused samples: {} on {} lines",
        scores.iter().map(|s| s.refused).sum::<usize>(),
        scores.iter().filter(|s| s.refused > 0).count()
    );
    scores.sort_by(|a, b| a.named().total_cmp(&b.named()));
    println!("worst lines (named regime), each reproducible with --seed N [--write FILE.toml]:");
    for s in scores.iter().take(3) {
        let (l, share) = s.worst_label();
        println!(
            "  seed {}: named {:.1} %, weakest label {} {:.1} %, {:.1} km, {} stations, speed \
             noise {:.2} m/s, DM {:.2}",
            s.seed,
            100.0 * s.named(),
            RAILCAR_REGIMES[l],
            100.0 * share,
            s.km,
            s.stations,
            s.speed_noise,
            s.dm
        );
    }
    ExitCode::SUCCESS
}
