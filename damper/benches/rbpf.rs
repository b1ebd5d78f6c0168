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
//! (`1 ms / time per step`) measured over 3000 further steps. The cost of speed scheduling and
//! of the noise-scale estimate: `benches/rbpf_variants.rs`.
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
    let mut rbpf = Rbpf::new(&c.filter_model(), &c.rbpf, &c.speed).expect("rbpf");
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
    let mut ekf = AugmentedEkf::new(&config.filter_model(), &config.ekf).expect("ekf");
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

criterion_group!(benches, bench_rbpf);

fn main() {
    benches();
    Criterion::default().configure_from_args().final_summary();
    real_time_table();
}
