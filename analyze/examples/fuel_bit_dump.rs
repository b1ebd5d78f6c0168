//! Every output of the fuel monitor, to the bit, on one recording or scenario: for the mixture
//! (the input's settings) and the single regression (the same with one component), per sample
//! the whole estimate (`{:?}` prints each `f64` in its shortest round-trip form, so equal text
//! is equal bits, NaN and infinities included), every 90 % interval and each component's
//! operating point. A change meant to leave the numbers as they are (docs/fuel.md,
//! "Benchmark") is checked by comparing this dump before and after it:
//!
//! `cargo run --release -p railmon-analyze --example fuel_bit_dump -- --input data/anl-camry-2018/61811011.csv > before.txt`
//! (or `--scenario config/scenarios/fuel-railcar.toml`), then `cmp before.txt after.txt`.

use std::io::Write;
use std::path::PathBuf;

use railmon_analyze::fuel::{load_recording, simulate_scenario, FuelInput};
use railmon_fuel::FuelMonitor;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let input: FuelInput = match args.as_slice() {
        [flag, path] if flag == "--input" => load_recording(&PathBuf::from(path))?,
        [flag, path] if flag == "--scenario" => simulate_scenario(&PathBuf::from(path))?.0,
        _ => return Err("usage: fuel_bit_dump (--input CSV | --scenario TOML)".into()),
    };
    let out = std::io::stdout();
    let mut out = std::io::BufWriter::new(out.lock());
    for (label, config) in [
        ("mixture", input.config.clone()),
        ("single", input.config.single_regression()),
    ] {
        let mut monitor = FuelMonitor::new(&config)?;
        for sample in &input.samples {
            let estimate = monitor.update(sample)?.clone();
            writeln!(out, "{label} {estimate:?}")?;
            if let Some(m) = &estimate.mixture {
                writeln!(
                    out,
                    "{label} intervals {:?} {:?} {:?}",
                    m.virtual_sensor_interval_cm3_s(),
                    m.one_step_interval_cm3_s(),
                    m.forecast_interval_cm3_s()
                )?;
                writeln!(out, "{label} points {:?}", monitor.operating_points())?;
            }
        }
    }
    out.flush()?;
    Ok(())
}
