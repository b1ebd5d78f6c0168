//! How the RBPF finds a `C_say` step to 40 % at 30 s at each speed (issue 9; the default
//! monitor, N = 1000, plant seed 9000 of the robustness matrix, `damper-seed` at a constant
//! speed): per speed the alarm's delay and, every second after the step, the posterior mean and
//! 95 % quantile of `C_say` (ratios to nominal), the effective sample size, the resamplings and
//! the jump search's materialised hypotheses since the step, and its largest log-odds. The
//! default speeds are those of the information table of `damper/tests/speed.rs`
//! (`the_information_about_the_anti_yaw_damper_grows_with_speed`). About a minute in release:
//!
//! ```text
//! cargo run --release -p railmon-damper --example finding_the_step
//! cargo run --release -p railmon-damper --example finding_the_step -- --seed 9001 --jump off --speeds 10,15
//! ```

use std::process::ExitCode;

use railmon_damper::{
    BogieSimulator, DamperAlarm, DamperEventKind, DamperFault, DamperId, DamperMonitor,
    DamperMonitorConfig, DamperScenario, FaultKind, Rbpf, SpeedProfile, DEFAULT_SPEED_M_S,
};

mod flags;
use flags::{on_off, parsed};

const SEED_SCENARIO: &str = include_str!("../../config/scenarios/damper-seed.toml");

/// The default `--speeds` (m/s).
const SPEEDS_M_S: [f64; 5] = [10.0, 15.0, 20.0, 30.0, DEFAULT_SPEED_M_S];

struct Args {
    seed: u64,
    speeds: Vec<f64>,
    config: DamperMonitorConfig,
}

fn usage() -> String {
    let d = DamperMonitorConfig::default();
    let js = d.rbpf.jump_search;
    let speeds: Vec<String> = SPEEDS_M_S.iter().map(f64::to_string).collect();
    format!(
        "usage: finding_the_step [FLAGS]\n\
         \n\
         --seed N             plant seed (default 9000)\n\
         --speeds A,B         constant speeds to run, m/s (default {speeds})\n\
         --particles N        rbpf.particles (default {particles})\n\
         --jump on|off        rbpf.jump_search.enabled (default {jump})\n\
         --jump-hazard X      rbpf.jump_search.hazard_per_s (default {hazard})\n\
         --jump-odds X        rbpf.jump_search.materialise_odds (default {odds})\n\
         --help               this text",
        speeds = speeds.join(","),
        particles = d.rbpf.particles,
        jump = if js.enabled { "on" } else { "off" },
        hazard = js.hazard_per_s,
        odds = js.materialise_odds,
    )
}

fn parse_args() -> Result<Args, String> {
    let mut args = Args {
        seed: 9000,
        speeds: SPEEDS_M_S.to_vec(),
        config: DamperMonitorConfig::default(),
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or(format!("{flag} needs a value"));
        let js = &mut args.config.rbpf.jump_search;
        match flag.as_str() {
            "--help" | "-h" => {
                println!("{}", usage());
                std::process::exit(0);
            }
            "--seed" => args.seed = parsed(&flag, &value()?)?,
            "--speeds" => {
                args.speeds = value()?
                    .split(',')
                    .map(|v| parsed(&flag, v))
                    .collect::<Result<_, _>>()?
            }
            "--particles" => args.config.rbpf.particles = parsed(&flag, &value()?)?,
            "--jump" => js.enabled = on_off(&flag, &value()?)?,
            "--jump-hazard" => js.hazard_per_s = parsed(&flag, &value()?)?,
            "--jump-odds" => js.materialise_odds = parsed(&flag, &value()?)?,
            other => return Err(format!("unknown flag {other}")),
        }
    }
    if let Some(v) = args.speeds.iter().find(|v| !(**v > 0.0 && v.is_finite())) {
        return Err(format!("--speeds: {v} is not a positive speed"));
    }
    args.config.validate().map_err(|e| e.to_string())?;
    Ok(args)
}

fn main() -> ExitCode {
    let Args {
        seed,
        ref speeds,
        config,
    } = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("finding_the_step: {e} (--help lists the flags)");
            return ExitCode::from(2);
        }
    };
    let table = Rbpf::gain_table(&config.filter_model(), &config.rbpf, &config.speed).unwrap();
    for &v in speeds {
        let mut s = DamperScenario::from_toml_str(SEED_SCENARIO).unwrap();
        s.duration_s = 45.0;
        s.speed = Some(SpeedProfile {
            profile_m_s: vec![[0.0, v]],
        });
        s.seed = seed;
        s.faults = vec![DamperFault {
            damper: DamperId::Csay,
            kind: FaultKind::Step,
            at_s: 30.0,
            end_s: None,
            ratio: 0.4,
        }];
        let mut m = DamperMonitor::for_bogie(&config, 1, Some(table.clone())).unwrap();
        let mut alarms = DamperAlarm::pair(&config.alarm, &config.filter_model(), [false; 2]);
        let mut sim = BogieSimulator::new(&s).unwrap();
        let mut resamples_at_step = 0;
        let mut jumps_at_step = 0;
        let mut rows = vec![];
        let mut detected = None;
        while let Some((y, truth)) = sim.step() {
            let e = *m.step(y).unwrap();
            let t = truth.time_s;
            for ev in alarms.iter_mut().filter_map(|a| a.update(&e)) {
                if ev.kind == DamperEventKind::DamperDegraded && ev.damper == DamperId::Csay {
                    detected.get_or_insert(t - 30.0);
                }
            }
            let ms = (t * 1e3).round() as i64;
            if ms == 30_000 {
                resamples_at_step = m.rbpf().resample_count();
                jumps_at_step = m.rbpf().jump_count();
            }
            if ms >= 29_000 && ms % 1000 == 0 {
                let nominal = config.nominal.csay_ns_per_m;
                rows.push(format!(
                    "{:.0}: {:.3} / {:.3} / {:.0} / {} / {} / {:.1}",
                    t - 30.0,
                    e.csay.mean_ns_per_m / nominal,
                    e.csay.q95_ns_per_m / nominal,
                    e.effective_sample_size,
                    m.rbpf().resample_count() as i64 - resamples_at_step as i64,
                    m.rbpf().jump_count() as i64 - jumps_at_step as i64,
                    m.rbpf().jump_max_ln_odds(),
                ));
            }
        }
        println!(
            "{v:.1} m/s: detected {} s after the step; seconds after the step: mean / q95 / ESS / resamplings since / jumps since / max ln odds; jumps before the step {}",
            detected.map_or("never".into(), |d| format!("{d:.2}")),
            jumps_at_step,
        );
        for r in rows {
            println!("  {r}");
        }
    }
    ExitCode::SUCCESS
}
