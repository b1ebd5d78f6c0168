//! Criterion benches of the slip pipeline:
//! - `ekf_step_per_drive`: one EKF step (predict + Joseph update) of one drive;
//! - `adhesion/{method}/N`: one step of each adhesion method for N = 3, 8, 32 drives;
//! - `pipeline/seed_scenario`: the whole offline run of `adhesion-seed.toml` (EKFs plus every
//!   method) on pre-simulated samples; the throughput is in drive-steps per second.
//!
//! Run: `CARGO_TARGET_DIR=... cargo bench -p railmon-slip --bench slip`.

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use railmon_bench_support::measure;
use railmon_slip::ekf::{ekf_step, DriveFilter};
use railmon_slip::model::{DriveMatrix, DriveState};
use railmon_slip::{
    AdhesionConfig, AdhesionEstimator, AdhesionMethod, AdhesionScenario, DriveSample,
    DriveSimulator, EkfBank, MultiMethodPipeline, SlipMonitorConfig,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const SEED: &str = include_str!("../../config/scenarios/adhesion-seed.toml");

fn seed_frames() -> (AdhesionScenario, Vec<Vec<DriveSample>>) {
    let scenario = AdhesionScenario::from_toml_str(SEED).expect("seed scenario");
    let mut sim = DriveSimulator::new(&scenario).expect("simulator");
    let mut frames = Vec::with_capacity(scenario.n_steps());
    while let Some((samples, _)) = sim.step() {
        frames.push(samples.to_vec());
    }
    (scenario, frames)
}

fn bench_ekf(c: &mut Criterion) {
    let (scenario, frames) = seed_frames();
    let config = scenario.monitor_config();
    let model = config.model().expect("model");
    // A converged filter state to step from.
    let mut bank = EkfBank::new(model, &config.ekf, 3).expect("bank");
    for f in &frames[..2000] {
        bank.step(f).expect("step");
    }
    let filter: DriveFilter = bank.filters()[0];
    let q = DriveMatrix::from_diagonal(&DriveState::from(config.ekf.process_noise_diag));
    let r = nalgebra::Matrix2::identity() * config.ekf.measurement_noise_a2;
    let sample = frames[2000][0];
    c.bench_function("ekf_step_per_drive", |b| {
        b.iter(|| {
            ekf_step(
                black_box(&model),
                &q,
                &r,
                black_box(&filter),
                black_box(&sample),
            )
        })
    });
}

fn bench_estimators(c: &mut Criterion) {
    let mut group = c.benchmark_group("adhesion");
    let config = AdhesionConfig::default();
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    for n in [3usize, 8, 32] {
        // 64 frames of healthy drives around 20 N m with one dropped drive, cycled.
        let frames: Vec<Vec<f64>> = (0..64)
            .map(|i| {
                (0..n)
                    .map(|k| {
                        if k == i % n {
                            0.5
                        } else {
                            20.0 + 0.2 * (rng.random::<f64>() - 0.5)
                        }
                    })
                    .collect()
            })
            .collect();
        for method in AdhesionMethod::ALL {
            let mut estimator = AdhesionEstimator::new(method, &config, n).expect("estimator");
            let mut i = 0;
            group.bench_with_input(BenchmarkId::new(method.name(), n), &n, |b, _| {
                b.iter(|| {
                    i = (i + 1) % frames.len();
                    black_box(
                        estimator
                            .estimate(black_box(&frames[i]))
                            .expect("estimate")
                            .global_torque_nm,
                    )
                })
            });
        }
    }
    group.finish();
}

/// One offline run of the whole pipeline (EKFs plus every method) over `frames`.
fn run_pipeline(config: &SlipMonitorConfig, n_drives: usize, frames: &[Vec<DriveSample>]) -> f64 {
    let mut pipe = MultiMethodPipeline::new(config, n_drives).expect("pipeline");
    for f in frames {
        pipe.step(f).expect("step");
    }
    black_box(pipe.torque_nm()[0])
}

fn bench_pipeline(c: &mut Criterion) {
    let (scenario, frames) = seed_frames();
    let config = scenario.monitor_config();
    let mut group = c.benchmark_group("pipeline");
    group.sample_size(10);
    group.throughput(Throughput::Elements(
        (frames.len() * scenario.n_drives()) as u64,
    ));
    group.bench_function("seed_scenario_all_methods", |b| {
        b.iter(|| run_pipeline(&config, scenario.n_drives(), &frames))
    });
    group.finish();
}

/// Prints the pipeline's throughput per second of this thread's CPU time (five runs of the seed
/// scenario): on a shared machine the wall-clock times above include waiting for a core.
fn bench_pipeline_cpu_time(_: &mut Criterion) {
    let (scenario, frames) = seed_frames();
    let config = scenario.monitor_config();
    let runs = 5;
    let time = measure(|| {
        for _ in 0..runs {
            run_pipeline(&config, scenario.n_drives(), &frames);
        }
    });
    let drive_steps = (runs * frames.len() * scenario.n_drives()) as f64;
    println!(
        "pipeline/seed_scenario_all_methods (thread CPU time): {:.0} drive-steps/s of CPU, {:.0} drive-steps/s of wall clock",
        drive_steps / time.cpu.as_secs_f64(),
        drive_steps / time.wall.as_secs_f64()
    );
}

fn short() -> Criterion {
    // Two shared cores: keep each measurement short.
    Criterion::default()
        .warm_up_time(Duration::from_millis(300))
        .measurement_time(Duration::from_secs(1))
}

criterion_group! {
    name = benches;
    config = short();
    targets = bench_ekf, bench_estimators, bench_pipeline, bench_pipeline_cpu_time
}
criterion_main!(benches);
