//! Speed of the damper filters (issue 4).
//!
//! - `rbpf_step/steady_state/N`: one RBPF step (17-state predict and update of every particle,
//!   weights, Liu-West move and resampling when due), N = 100, 1000, 10000, from a filter
//!   that has run 3 s of the seed scenario (posterior narrowed, as in service);
//! - `rbpf_step/exact/N`: the same with the exact per-particle filter (matrix exponential and
//!   full covariance per particle and step), N = 10, 100;
//! - `rbpf_estimate/N`: the posterior summary (sorts the particles for the quantiles);
//! - `ekf_step`: one step of the 19-state augmented EKF.
//!
//! After criterion, prints a table of time per step and real-time factor at 1 kHz
//! (`1 ms / time per step`) measured over 3000 further steps, and the cost of the noise-scale
//! estimate (issue 9 item 2): N = 1000 with and without it, interleaved in blocks of 250 steps
//! so that both see the same machine load, as a ratio.
//!
//! Run: `CARGO_TARGET_DIR=... cargo bench -p railmon-damper --bench rbpf`.

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{criterion_group, BenchmarkId, Criterion};
use railmon_damper::model::Vector5;
use railmon_damper::{
    AugmentedEkf, BogieSimulator, DamperMonitorConfig, DamperScenario, Propagation, Rbpf,
};

const SEED: &str = include_str!("../../config/scenarios/damper-seed.toml");
const WARM_UP_STEPS: usize = 3000;

fn samples(n: usize) -> (DamperMonitorConfig, Vec<Vector5>) {
    let mut scenario = DamperScenario::from_toml_str(SEED).expect("seed scenario");
    scenario.duration_s = n as f64 * scenario.dt_s;
    let mut sim = BogieSimulator::new(&scenario).expect("simulator");
    let mut ys = Vec::with_capacity(n);
    while let Some((y, _)) = sim.step() {
        ys.push(y.to_vector());
    }
    (scenario.monitor_config(), ys)
}

fn warmed_up(config: &DamperMonitorConfig, ys: &[Vector5], n: usize, p: Propagation) -> Rbpf {
    let mut c = *config;
    c.rbpf.particles = n;
    c.rbpf.propagation = p;
    let mut rbpf = Rbpf::new(&c).expect("rbpf");
    let warm = if p == Propagation::Exact {
        200
    } else {
        WARM_UP_STEPS
    };
    for y in &ys[..warm] {
        rbpf.step(y).expect("step");
    }
    rbpf
}

fn bench_rbpf(c: &mut Criterion) {
    let (config, ys) = samples(WARM_UP_STEPS + 20_000);
    let mut group = c.benchmark_group("rbpf_step");
    group.measurement_time(Duration::from_secs(5));
    for (p, name, sizes) in [
        (
            Propagation::SteadyState,
            "steady_state",
            &[100, 1000, 10_000][..],
        ),
        (Propagation::Exact, "exact", &[10, 100][..]),
    ] {
        for &n in sizes {
            let mut rbpf = warmed_up(&config, &ys, n, p);
            let mut k = WARM_UP_STEPS;
            group.bench_with_input(BenchmarkId::new(name, n), &n, |b, _| {
                b.iter(|| {
                    k = if k + 1 < ys.len() {
                        k + 1
                    } else {
                        WARM_UP_STEPS
                    };
                    rbpf.step(black_box(&ys[k])).expect("step");
                })
            });
        }
    }
    group.finish();
    let mut group = c.benchmark_group("rbpf_estimate");
    for n in [1000, 10_000] {
        let mut rbpf = warmed_up(&config, &ys, n, Propagation::SteadyState);
        group.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter(|| black_box(rbpf.estimate()))
        });
    }
    group.finish();
    let mut ekf = AugmentedEkf::new(&config).expect("ekf");
    let mut k = 0;
    c.bench_function("ekf_step", |b| {
        b.iter(|| {
            k = (k + 1) % ys.len();
            black_box(ekf.step(&ys[k]).ok());
        })
    });
}

/// Time per step over `steps` steps after the warm-up, and the real-time factor at 1 kHz.
fn real_time_table() {
    let (config, ys) = samples(WARM_UP_STEPS + 3000);
    println!("\nRBPF step, one core, after {WARM_UP_STEPS} warm-up steps:");
    println!(
        "{:>14} {:>7} {:>14} {:>18}",
        "propagation", "N", "us/step", "real-time factor"
    );
    for (p, name, sizes) in [
        (
            Propagation::SteadyState,
            "steady_state",
            &[100, 1000, 10_000][..],
        ),
        (Propagation::Exact, "exact", &[100][..]),
    ] {
        for &n in sizes {
            let mut rbpf = warmed_up(&config, &ys, n, p);
            let steps = if p == Propagation::Exact { 200 } else { 3000 };
            let start = Instant::now();
            for y in &ys[WARM_UP_STEPS..WARM_UP_STEPS + steps] {
                rbpf.step(y).expect("step");
            }
            let us = start.elapsed().as_secs_f64() * 1e6 / steps as f64;
            println!("{name:>14} {n:>7} {us:>14.1} {:>17.2}x", 1000.0 / us);
        }
    }
}

/// The RBPF step at N = 1000 with the noise-scale estimate against the same filter without it
/// (the configured noise taken as exact), alternating blocks on the same data.
fn noise_estimate_cost() {
    const BLOCK: usize = 250;
    const ROUNDS: usize = 12;
    let (config, ys) = samples(WARM_UP_STEPS + BLOCK * ROUNDS);
    let mut fixed = config;
    fixed.rbpf.noise_scale.enabled = false;
    let mut filters = [
        warmed_up(&fixed, &ys, 1000, Propagation::SteadyState),
        warmed_up(&config, &ys, 1000, Propagation::SteadyState),
    ];
    let mut seconds = [0.0; 2];
    for round in 0..ROUNDS {
        let block = &ys[WARM_UP_STEPS + round * BLOCK..WARM_UP_STEPS + (round + 1) * BLOCK];
        // Alternate which goes first.
        for k in [round % 2, 1 - round % 2] {
            let start = Instant::now();
            for y in block {
                filters[k].step(y).expect("step");
            }
            seconds[k] += start.elapsed().as_secs_f64();
        }
    }
    let us = seconds.map(|s| s * 1e6 / (BLOCK * ROUNDS) as f64);
    println!("\nRBPF step, N = 1000, {ROUNDS} x {BLOCK} steps interleaved:");
    println!("  configured noise (no estimate): {:>8.1} us/step", us[0]);
    println!("  noise-scale estimate:           {:>8.1} us/step", us[1]);
    println!("  ratio:                          {:>8.3}", us[1] / us[0]);
}

criterion_group!(benches, bench_rbpf);

fn main() {
    benches();
    Criterion::default().configure_from_args().final_summary();
    real_time_table();
    noise_estimate_cost();
}
