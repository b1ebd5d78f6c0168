//! When a monitor pauses and learns again, and its alarms, on one scenario file: each change
//! of `paused` with the time since the speed last rose through `speed.min_m_s`, the jump
//! search's materialisations so far, and every alarm event with the truth.
//!
//! ```text
//! cargo run --release -p railmon-damper --example resume_trace -- \
//!     config/scenarios/damper-speed-profile.toml [PARTICLES]   # 300 s at N = 1000: ~1.5 min
//! ```

use railmon_damper::{BogieSimulator, DamperAlarm, DamperMonitor, DamperScenario};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let path = args
        .next()
        .ok_or("usage: resume_trace SCENARIO.toml [PARTICLES]")?;
    let text = std::fs::read_to_string(&path).map_err(|e| format!("{path}: {e}"))?;
    let scenario = DamperScenario::from_toml_str(&text).map_err(|e| format!("{path}: {e}"))?;
    let mut config = scenario.monitor_config();
    if let Some(p) = args.next() {
        config.rbpf.particles = p.parse().map_err(|e| format!("PARTICLES {p}: {e}"))?;
    }
    let mut monitor = DamperMonitor::for_bogie(&config, 1, None)?;
    let mut alarms = DamperAlarm::pair(&config.alarm, &config.filter_model(), [false; 2]);
    let mut sim = BogieSimulator::new(&scenario)?;
    let (mut paused, mut rose_at_s, mut below) = (None, 0.0, true);
    while let Some((sample, truth)) = sim.step() {
        let e = *monitor.step(sample)?;
        if below && sample.speed_m_s >= config.speed.min_m_s {
            rose_at_s = truth.time_s;
        }
        below = sample.speed_m_s < config.speed.min_m_s;
        if e.paused != paused {
            println!(
                "{:8.3} s  paused {:?} at {:.2} m/s ({:+.3} s after passing {} m/s at {:.3} s), {} jumps",
                e.time_s,
                e.paused,
                sample.speed_m_s,
                e.time_s - rose_at_s,
                config.speed.min_m_s,
                rose_at_s,
                monitor.rbpf().jump_count()
            );
            paused = e.paused;
        }
        for event in alarms.iter_mut().filter_map(|a| a.update(&e)) {
            println!(
                "{:8.3} s  {} {} health {:.3}, truth {:.0} / {:.0} N s/m",
                event.time_s,
                event.kind.as_str(),
                event.damper.name(),
                event.health_ratio,
                truth.dampers.csy_ns_per_m,
                truth.dampers.csay_ns_per_m
            );
        }
    }
    println!("{} jumps in all", monitor.rbpf().jump_count());
    Ok(())
}
