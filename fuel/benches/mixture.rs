//! Estimator steps per second for `m_c` = 3 and 10 components with 5 continuous channels and
//! the gear (the paper's setting), on simulated samples: the step alone and the step with every
//! 90 % interval asked for. Run with
//! `cargo bench -p railmon-fuel --bench mixture`.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

mod common;
use common::{every_interval, initialised_monitor, sample};
use railmon_fuel::FuelMonitorConfig;

fn bench_steps(c: &mut Criterion) {
    let mut group = c.benchmark_group("fuel_monitor_step");
    group.throughput(Throughput::Elements(1));
    for m_c in [3usize, 10] {
        let (mut monitor, mut t) = initialised_monitor(FuelMonitorConfig::paper(), m_c, sample);
        // The step alone: what the service pays per sample.
        group.bench_with_input(BenchmarkId::new("update", m_c), &m_c, |b, _| {
            b.iter(|| {
                t += 1;
                monitor.update(&sample(t)).expect("valid sample").samples
            })
        });
        // The step and every interval: what a published view or `railmon analyze fuel` pays.
        group.bench_with_input(
            BenchmarkId::new("update_and_intervals", m_c),
            &m_c,
            |b, _| {
                b.iter(|| {
                    t += 1;
                    monitor.update(&sample(t)).expect("valid sample");
                    every_interval(&monitor)
                })
            },
        );
    }
    group.finish();
}

criterion_group!(benches, bench_steps);
criterion_main!(benches);
