//! Estimator steps per second for `m_c` = 3 and 10 components with 5 continuous channels and
//! the gear (the paper's setting), on simulated samples: the step alone and the step with every
//! 90 % interval asked for. Run with
//! `cargo bench -p railmon-fuel --bench mixture`.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use railmon_fuel::{FuelMonitor, FuelMonitorConfig, VehicleSample};

/// A deterministic, varied stream of plausible samples (no RNG needed for a timing run).
fn sample(t: usize) -> VehicleSample {
    let x = t as f64;
    let speed = 15.0 + 10.0 * (x / 37.0).sin();
    let pedal = (30.0 + 25.0 * (x / 11.0).sin()).max(0.0);
    VehicleSample {
        time_s: x,
        fuel_cm3_s: Some((0.3 + 0.02 * pedal + 0.1 * (x / 3.0).cos()).max(0.0)),
        speed_m_s: Some(speed),
        pedal_pct: Some(pedal),
        engine_torque_nm: Some(2.0 * pedal),
        engine_speed_rpm: Some(800.0 + 90.0 * speed),
        gradient_permille: None,
        gear: Some(1 + (speed / 6.0) as i32),
    }
}

fn bench_steps(c: &mut Criterion) {
    let mut group = c.benchmark_group("fuel_monitor_step");
    group.throughput(Throughput::Elements(1));
    for m_c in [3usize, 10] {
        let config = FuelMonitorConfig {
            components: m_c,
            ..FuelMonitorConfig::paper()
        };
        let mut monitor = FuelMonitor::new(&config).expect("valid config");
        let mut t = 0;
        while monitor.mixture().is_none() {
            monitor.update(&sample(t)).expect("valid sample");
            t += 1;
        }
        // The step alone: what the service pays per sample.
        group.bench_with_input(BenchmarkId::new("update", m_c), &m_c, |b, _| {
            b.iter(|| {
                t += 1;
                monitor.update(&sample(t)).expect("valid sample").samples
            })
        });
        // The step and every interval the estimate offers (virtual sensor, 1-step forecast,
        // each forecast step): what a published view or `railmon analyze fuel` pays per sample.
        group.bench_with_input(
            BenchmarkId::new("update_and_intervals", m_c),
            &m_c,
            |b, _| {
                b.iter(|| {
                    t += 1;
                    let e = monitor.update(&sample(t)).expect("valid sample");
                    let m = e.mixture.as_ref().expect("initialised");
                    let forecast = m.forecast_interval_cm3_s();
                    (
                        m.virtual_sensor_interval_cm3_s(),
                        m.one_step_interval_cm3_s(),
                        forecast,
                    )
                })
            },
        );
    }
    group.finish();
}

criterion_group!(benches, bench_steps);
criterion_main!(benches);
