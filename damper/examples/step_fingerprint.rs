//! A fingerprint of every published number of seeded monitor runs, so that a change meant to
//! make the step cheaper can be shown to leave the outputs bit for bit as they were (issue
//! 28): each step's `DamperEstimate` (RBPF posterior, EKF, consistency, noise, pause) is
//! hashed through its `Debug` text (which prints every `f64` exactly: it round-trips), with
//! the filter's log-evidence, effective sample size and resamplings.
//!
//! Three runs, each at N = `--particles` (default 1000) for `--duration-s` (default 40 s):
//! `damper-speed-profile` (a start from rest: pauses, settling, speed nodes), the same with
//! the body mass withheld (the particles carry their own mass), `damper-fault` (a step of
//! `C_say` at 30 s: the jump search's hypotheses become particles).
//!
//! ```text
//! cargo run --release -p railmon-damper --example step_fingerprint -- [--particles N] [--duration-s S]
//! ```
//! Run it before and after a change: the printed hashes must be equal.

use std::collections::hash_map::DefaultHasher;
use std::hash::{Hash, Hasher};

use railmon_damper::{BogieSample, BogieSimulator, DamperMonitor, DamperScenario};

mod flags;
use flags::parsed;

const PROFILE: &str = include_str!("../../config/scenarios/damper-speed-profile.toml");
const FAULT: &str = include_str!("../../config/scenarios/damper-fault.toml");

fn run(text: &str, withhold_mass: bool, particles: usize, duration_s: f64) -> (u64, usize) {
    let mut scenario = DamperScenario::from_toml_str(text).expect("scenario");
    scenario.duration_s = duration_s;
    let mut config = scenario.monitor_config();
    config.rbpf.particles = particles;
    let mut monitor = DamperMonitor::for_bogie(&config, 1, None).expect("monitor");
    let mut sim = BogieSimulator::new(&scenario).expect("simulator");
    let mut hasher = DefaultHasher::new();
    let mut steps = 0;
    while let Some((sample, _)) = sim.step() {
        let sample = BogieSample {
            half_body_mass_kg: if withhold_mass {
                None
            } else {
                sample.half_body_mass_kg
            },
            ..*sample
        };
        let estimate = *monitor.step(&sample).expect("step");
        let f = monitor.rbpf();
        format!(
            "{estimate:?} {:?} {:?} {}",
            f.log_evidence(),
            f.effective_sample_size(),
            f.resample_count()
        )
        .hash(&mut hasher);
        steps += 1;
    }
    (hasher.finish(), steps)
}

fn main() -> Result<(), String> {
    let (mut particles, mut duration_s) = (1000, 40.0);
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or(format!("{flag} needs a value"));
        match flag.as_str() {
            "--particles" => particles = parsed(&flag, &value()?)?,
            "--duration-s" => duration_s = parsed(&flag, &value()?)?,
            other => return Err(format!("unknown flag {other}")),
        }
    }
    for (name, text, withhold) in [
        ("damper-speed-profile", PROFILE, false),
        ("damper-speed-profile:no-mass", PROFILE, true),
        ("damper-fault", FAULT, false),
    ] {
        let (hash, steps) = run(text, withhold, particles, duration_s);
        println!("{name:>30} {steps:>7} steps  {hash:016x}");
    }
    Ok(())
}
