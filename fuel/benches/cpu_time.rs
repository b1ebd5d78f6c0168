//! CPU time of `FuelMonitor::update`, alone and with every interval asked for, at `m_c` = 3
//! and 10 (the samples and settings of `benches/mixture.rs`), from the thread's own CPU clock
//! (`railmon_bench_support`): on the shared 2-core build machine criterion's wall-clock medians
//! rise with the other jobs' load, the time this thread spends on a core much less.
//! Rows `update` and `update_and_intervals` run the paper's setting (the bench item);
//! `update_default` runs `FuelMonitorConfig::default()`, the service's setting (fuel, speed and
//! derived channels, forecasts and virtual sensor blended with the single regression);
//! `update_railcar` runs `FuelMonitorConfig::railcar()` (9 components, every regime given, the pointer weighed by
//! levels with standstill a regime given) on the shipped railcar route, `update_railcar_filtered`
//! the same with the kinematic speed filter (`speed_noise_m_s` = 0.2). Prints a table. Run with `cargo bench -p railmon-fuel --bench cpu_time` (one row: `-- update/3`).

mod common;
use common::{every_interval, initialised_monitor, railcar_route, sample};
use railmon_fuel::{FuelMonitorConfig, VehicleSample};

/// CPU and wall time per step, µs, over `steps` steps after `warm_up` unmeasured ones.
fn measure(
    setting: FuelMonitorConfig,
    m_c: usize,
    with_intervals: bool,
    warm_up: usize,
    steps: usize,
    sample: impl Fn(usize) -> VehicleSample,
) -> (f64, f64) {
    let (mut monitor, mut t) = initialised_monitor(setting, m_c, &sample);
    let mut run = |n: usize| {
        let mut kept = 0.0;
        for _ in 0..n {
            t += 1;
            kept += monitor.update(&sample(t)).expect("valid sample").fuel_cm3_s;
            if with_intervals {
                kept += every_interval(&monitor).0.lower;
            }
        }
        std::hint::black_box(kept);
    };
    run(warm_up);
    let time = railmon_bench_support::measure(|| run(steps));
    let per_step = |ns: f64| ns / steps as f64 / 1e3;
    (
        per_step(time.cpu.as_nanos() as f64),
        per_step(time.wall.as_nanos() as f64),
    )
}

fn main() {
    // `cargo bench` passes `--bench`; any other argument keeps only the rows whose name
    // (`update/3`, `update_and_intervals/10`, ...) equals it.
    let only: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with("--"))
        .collect();
    println!("| row | m_c | CPU µs/step | steps/s (CPU) | wall µs/step |");
    println!("|---|---|---|---|---|");
    let paper_rows = [3usize, 10].into_iter().flat_map(|m_c| {
        [false, true].map(|with_intervals| {
            let row = if with_intervals {
                "update_and_intervals"
            } else {
                "update"
            };
            (row, FuelMonitorConfig::paper(), m_c, with_intervals)
        })
    });
    let default_row = ("update_default", FuelMonitorConfig::default(), 3, false);
    let railcar_row = ("update_railcar", FuelMonitorConfig::railcar(), 9, false);
    // The same with the kinematic filter of a 0.2 m/s speed sensor (issue 25 item 4).
    let filtered_row = (
        "update_railcar_filtered",
        FuelMonitorConfig {
            speed_noise_m_s: 0.2,
            ..FuelMonitorConfig::railcar()
        },
        9,
        false,
    );
    let rows = paper_rows.chain([default_row, railcar_row, filtered_row]);
    for (row, setting, m_c, with_intervals) in rows {
        let steps = match (row, m_c, with_intervals) {
            // The route is 7228 samples long: 150 initial, 500 to warm up, 6000 measured.
            ("update_railcar" | "update_railcar_filtered", _, _) => 6_000,
            (_, 3, false) => 20_000,
            (_, 3, true) | (_, 10, false) => 4_000,
            _ => 1_000,
        };
        if !only.is_empty() && !only.contains(&format!("{row}/{m_c}")) {
            continue;
        }
        let (cpu_us, wall_us) = if row.starts_with("update_railcar") {
            let route = railcar_route();
            measure(setting, m_c, with_intervals, 500, steps, |t| route[t])
        } else {
            measure(setting, m_c, with_intervals, steps / 10, steps, sample)
        };
        println!(
            "| {row} | {m_c} | {cpu_us:.2} | {:.0} | {wall_us:.2} |",
            1e6 / cpu_us
        );
    }
}
