//! Dampers far from nominal from t = 0 (issue 9): each of C_sy, C_say at 0.5x, 1x, 1.5x of
//! nominal, every pair but nominal-nominal, on the validated cell of the robustness matrix
//! (white track of 0.1 m/s, 45.3 m/s, plant seeds 9100 on; the filter
//! `DamperMonitorConfig::default()`): both RBPF means within 5 % of the truth at 30 s? Prints a
//! row per pair and seed, then the count. Minutes in release:
//!
//! ```text
//! cargo run --release -p railmon-damper --example off_nominal_starts [-- --seeds 3 --particles 1000]
//! ```

use std::process::ExitCode;

use railmon_damper::{
    BogieSimulator, DamperMonitor, DamperMonitorConfig, DamperScenario, Dampers, Rbpf,
};

/// The validated cell of the `robustness_matrix` example.
const BASE: &str = "name = \"robust\"\nseed = 1\nduration_s = 60.0\n[track]\nkind = \"white\"\nvelocity_std_m_s = 0.1\n";

const USAGE: &str = "usage: off_nominal_starts [FLAGS]

--seeds N       plant seeds per pair of dampers, from 9100, N >= 1 (default 3)
--particles N   rbpf.particles (default 1000)
--help          this text";

fn parse_args() -> Result<(u64, DamperMonitorConfig), String> {
    let mut seeds = 3;
    let mut config = DamperMonitorConfig::default();
    config.rbpf.particles = 1000;
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or(format!("{flag} needs a value"));
        match flag.as_str() {
            "--help" | "-h" => {
                println!("{USAGE}");
                std::process::exit(0);
            }
            "--seeds" => seeds = value()?.parse().map_err(|e| format!("--seeds: {e}"))?,
            "--particles" => {
                config.rbpf.particles = value()?.parse().map_err(|e| format!("--particles: {e}"))?
            }
            other => return Err(format!("unknown flag {other}")),
        }
    }
    if seeds == 0 {
        return Err("--seeds 0: at least one".into());
    }
    config.validate().map_err(|e| e.to_string())?;
    Ok((seeds, config))
}

fn main() -> ExitCode {
    let (seeds, config) = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("off_nominal_starts: {e} (--help lists the flags)");
            return ExitCode::from(2);
        }
    };
    let table = Rbpf::gain_table(&config.filter_model(), &config.rbpf, &config.speed).unwrap();
    println!("| C_sy / nominal | C_say / nominal | seed | C_sy error at 30 s | C_say error at 30 s | both within 5 % |");
    println!("|---|---|---|---|---|---|");
    let mut within = 0;
    let mut runs = 0;
    for csy in [0.5, 1.0, 1.5] {
        for csay in [0.5, 1.0, 1.5] {
            if (csy, csay) == (1.0, 1.0) {
                continue;
            }
            for seed in 0..seeds {
                let mut s = DamperScenario::from_toml_str(BASE).unwrap();
                s.duration_s = 30.0;
                s.seed = 9100 + seed;
                let nominal = Dampers::NOMINAL;
                s.dampers = Dampers {
                    csy_ns_per_m: csy * nominal.csy_ns_per_m,
                    csay_ns_per_m: csay * nominal.csay_ns_per_m,
                };
                let mut monitor =
                    DamperMonitor::for_bogie(&config, 1, Some(table.clone())).unwrap();
                let mut sim = BogieSimulator::new(&s).unwrap();
                let mut last = None;
                while let Some((sample, truth)) = sim.step() {
                    let e = *monitor.step(sample).unwrap();
                    last = Some([
                        e.csy.mean_ns_per_m / truth.dampers.csy_ns_per_m - 1.0,
                        e.csay.mean_ns_per_m / truth.dampers.csay_ns_per_m - 1.0,
                    ]);
                }
                let [ey, eay] = last.unwrap();
                let ok = ey.abs() <= 0.05 && eay.abs() <= 0.05;
                within += usize::from(ok);
                runs += 1;
                println!(
                    "| {csy} | {csay} | {seed} | {:+.1} % | {:+.1} % | {} |",
                    100.0 * ey,
                    100.0 * eay,
                    if ok { "yes" } else { "**no**" }
                );
            }
        }
    }
    println!("both within 5 % at 30 s: {within} of {runs} runs");
    ExitCode::SUCCESS
}
