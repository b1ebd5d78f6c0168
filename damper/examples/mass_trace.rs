//! The boarding at a stop of `tests/stop.rs` (body 13 t -> 16.9 t at 14 s while standing;
//! `--boarded-kg` another mass) with the mass withheld, the particles carrying their own
//! (issue 24 item 1): every `--every` s the published `C_sy` error with its 90 % interval,
//! the `C_say` error, the weighted mean and 10/90 % of the particles' body mass, the weighted
//! correlation of `ln m` with `ln C_sy`, the ESS, the resamplings so far and whether paused;
//! and every alarm event.
//!
//! `--given-ratio R`: instead, from the stop on the samples carry `R` times the boarded mass,
//! and the end prints the log evidence the filter gathered over 17-26 s (moving again):
//! runs at several `R` trace the likelihood of the mass the data allow (the peak is the mass
//! the data favour; the drop from it, in nats, how sharply).
//!
//! ```text
//! cargo run --release -p railmon-damper --example mass_trace -- --bogie 3 [--every 0.5]
//!     [--particles 100] [--boarded-kg 16900] [--given-ratio 1.02]
//!     [--from S --to S --fine 0.05]
//! ```

use railmon_damper::{BogieSimulator, DamperAlarm, DamperMonitor, DamperScenario};

mod flags;
use flags::parsed;

/// `tests/stop.rs`'s boarding at the stop to `boarded_kg` (16.9 t there), the mass withheld.
fn scenario(boarded_kg: f64) -> DamperScenario {
    let text = format!(
        "{}\n[load]\nchanges_kg = [[14.0, {boarded_kg:?}]]\nmeasured = false\n",
        include_str!("../tests/common/stop.toml")
    );
    DamperScenario::from_toml_str(&text).unwrap()
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let (mut bogie, mut every_s, mut particles) = (1u32, 0.5f64, 100usize);
    let mut boarded_kg = 16900.0;
    let mut given_ratio: Option<f64> = None;
    let mut window = (f64::INFINITY, f64::NEG_INFINITY, 0.05f64);
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or(format!("{flag} needs a value"));
        match flag.as_str() {
            "--bogie" => bogie = parsed(&flag, &value()?)?,
            "--every" => every_s = parsed(&flag, &value()?)?,
            "--particles" => particles = parsed(&flag, &value()?)?,
            "--boarded-kg" => boarded_kg = parsed(&flag, &value()?)?,
            "--given-ratio" => given_ratio = Some(parsed(&flag, &value()?)?),
            "--from" => window.0 = parsed(&flag, &value()?)?,
            "--to" => window.1 = parsed(&flag, &value()?)?,
            "--fine" => window.2 = parsed(&flag, &value()?)?,
            other => return Err(format!("unknown flag {other}").into()),
        }
    }
    let s = scenario(boarded_kg);
    let mut config = s.monitor_config();
    config.rbpf.particles = particles;
    let mut monitor = DamperMonitor::for_bogie(&config, bogie, None)?;
    let mut alarms = DamperAlarm::pair(&config.alarm, &config.filter_model(), [false; 2]);
    let mut sim = BogieSimulator::new(&s)?;
    let design = monitor.rbpf().design_half_body_mass_kg();
    let mut next_s = 0.0;
    let mut evidence_from_17_s = None;
    while let Some((sample, truth)) = sim.step() {
        let mut sample = *sample;
        if let Some(r) = given_ratio {
            if truth.half_body_mass_kg != design {
                sample.half_body_mass_kg = Some(r * truth.half_body_mass_kg);
            }
        }
        let e = *monitor.step(&sample)?;
        if truth.time_s >= 17.0 && evidence_from_17_s.is_none() {
            evidence_from_17_s = Some(monitor.rbpf().log_evidence());
        }
        for event in alarms.iter_mut().filter_map(|a| a.update(&e)) {
            println!(
                "{:7.3} s  {} {} health {:.3}",
                event.time_s,
                event.kind.as_str(),
                event.damper.name(),
                event.health_ratio
            );
        }
        if truth.time_s + 1e-9 < next_s {
            continue;
        }
        next_s += if (window.0..window.1).contains(&truth.time_s) {
            window.2
        } else {
            every_s
        };
        let f = monitor.rbpf();
        let n = f.n_particles();
        let mut rows: Vec<(f64, f64, f64)> = (0..n)
            .filter_map(|i| {
                let (th, lw, _, _) = f.particle(i);
                f.particle_ln_mass(i).map(|m| (m, th[0], lw.exp()))
            })
            .collect();
        let (mut mm, mut mc, mut vm, mut vc, mut cov) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for &(m, c, w) in &rows {
            mm += w * m;
            mc += w * c;
        }
        for &(m, c, w) in &rows {
            vm += w * (m - mm) * (m - mm);
            vc += w * (c - mc) * (c - mc);
            cov += w * (m - mm) * (c - mc);
        }
        rows.sort_by(|a, b| a.0.total_cmp(&b.0));
        let q = |p: f64| {
            let mut acc = 0.0;
            for &(m, _, w) in &rows {
                acc += w;
                if acc >= p {
                    return design * m.exp();
                }
            }
            f64::NAN
        };
        println!(
            "{:6.2} s {:5.1} m/s  C_sy {:+6.2} % [{:+6.2}, {:+6.2}]  C_say {:+6.2} %  mass {:6.0} [{:6.0}, {:6.0}] kg (truth {:.0})  corr {:+.2}  ESS {:5.1}  res {:4}  jumps {} prob {:.2} lnodds {:.1}  {}",
            truth.time_s,
            sample.speed_m_s,
            100.0 * (e.csy.mean_ns_per_m / truth.dampers.csy_ns_per_m - 1.0),
            100.0 * (e.csy.q05_ns_per_m / truth.dampers.csy_ns_per_m - 1.0),
            100.0 * (e.csy.q95_ns_per_m / truth.dampers.csy_ns_per_m - 1.0),
            100.0 * (e.csay.mean_ns_per_m / truth.dampers.csay_ns_per_m - 1.0),
            design * mm.exp(),
            q(0.1),
            q(0.9),
            truth.half_body_mass_kg,
            cov / (vm * vc).sqrt().max(1e-300),
            e.effective_sample_size,
            f.resample_count(),
            f.jump_count(),
            f.jump_probation_mass(),
            f.jump_max_ln_odds(),
            e.paused.map_or(String::new(), |p| format!("{p:?}")),
        );
    }
    if let (Some(r), Some(from)) = (given_ratio, evidence_from_17_s) {
        println!(
            "mass given at {r} x the boarded: log evidence over 17 s .. end {:.1}",
            monitor.rbpf().log_evidence() - from
        );
    }
    Ok(())
}
