//! Why a healthy damper's published ratio dips, on one condition-sampler draw (issue 24 item
//! 2): every 10 ms while a published ratio is below `--show-below` (or within `--from`/`--to`),
//! and at each event (a pause's start or end, a jump hypothesis becoming particles, one
//! adopted, an alarm event), the published ratios, the ratios of the whole cloud (jump
//! hypotheses on probation included), the posterior mass on probation, the weighted mean NIS
//! of the cloud, the lowest NIS among the sentinels, the largest jump log-odds and the
//! resamplings so far. Runs the draw as `condition_matrix` does (mass given).
//!
//! ```text
//! cargo run --release -p railmon-damper --example dip_trace -- --seed 5010 [--duration-s 120]
//!     [--particles 500] [--show-below 0.75] [--from S --to S] [--oracle-conicity]
//!     [--rbpf-seed N]
//! ```
//! `--oracle-conicity`: the filter given the plant's conicity (as `condition_matrix`).
//! `--rbpf-seed`: the filter's own random numbers (`rbpf.seed`, as `condition_matrix`).
//! `--duration-s` as the `condition_matrix` run the draw came from (a draw depends on it).

use railmon_damper::sampler;
use railmon_damper::{BogieSimulator, DamperAlarm, DamperMonitor, DamperMonitorConfig};

mod flags;
mod oracle;
use flags::parsed;

struct Args {
    seed: u64,
    duration_s: f64,
    particles: usize,
    show_below: f64,
    window: (f64, f64),
    oracle_conicity: bool,
    rbpf_seed: u64,
}

fn parse_args() -> Result<Args, String> {
    let mut a = Args {
        seed: 5007,
        // As the condition matrix's documented runs (a draw depends on it).
        duration_s: 120.0,
        particles: 500,
        show_below: 0.75,
        window: (f64::INFINITY, f64::NEG_INFINITY),
        oracle_conicity: false,
        rbpf_seed: 0,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or(format!("{flag} needs a value"));
        match flag.as_str() {
            "--seed" => a.seed = parsed(&flag, &value()?)?,
            "--duration-s" => a.duration_s = parsed(&flag, &value()?)?,
            "--particles" => a.particles = parsed(&flag, &value()?)?,
            "--show-below" => a.show_below = parsed(&flag, &value()?)?,
            "--from" => a.window.0 = parsed(&flag, &value()?)?,
            "--to" => a.window.1 = parsed(&flag, &value()?)?,
            "--oracle-conicity" => a.oracle_conicity = true,
            "--rbpf-seed" => a.rbpf_seed = parsed(&flag, &value()?)?,
            other => return Err(format!("unknown flag {other}")),
        }
    }
    Ok(a)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = parse_args()?;
    let draw = sampler::draw(args.seed, args.duration_s);
    println!("seed {}: {}", args.seed, draw.short());
    let mut config = DamperMonitorConfig::default();
    config.rbpf.particles = args.particles;
    config.rbpf.seed = args.rbpf_seed;
    if args.oracle_conicity {
        config = oracle::with_plant_conicity(&config, &draw);
    }
    let nominal = config.filter_model().nominal;
    let nominal = [nominal.csy_ns_per_m, nominal.csay_ns_per_m];
    let mut monitor = DamperMonitor::for_bogie(&config, 1, None)?;
    let mut alarms = DamperAlarm::pair(&config.alarm, &config.filter_model(), [false; 2]);
    let mut sim = BogieSimulator::new(&draw.scenario)?.with_mass_input(true);
    let (mut paused, mut jumps, mut adoptions) = (None, 0, 0);
    let mut step = 0u64;
    println!(
        "time s | speed | paused | published csy / csay | cloud csy / csay | on probation | NIS cloud / best sentinel | max ln odds | resamples | event"
    );
    while let Some((sample, truth)) = sim.step() {
        step += 1;
        let e = *monitor.step(sample)?;
        let f = monitor.rbpf();
        let mut events = vec![];
        if e.paused != paused {
            events.push(format!("paused {:?}", e.paused));
            paused = e.paused;
        }
        if f.jump_count() > jumps {
            jumps = f.jump_count();
            events.push(format!("jump {jumps}"));
        }
        if f.jump_adoptions() > adoptions {
            adoptions = f.jump_adoptions();
            events.push(format!("ADOPTED {adoptions}"));
        }
        for ev in alarms.iter_mut().filter_map(|a| a.update(&e)) {
            events.push(format!(
                "{} {} (truth {:.0} / {:.0})",
                ev.kind.as_str(),
                ev.damper.name(),
                truth.dampers.csy_ns_per_m,
                truth.dampers.csay_ns_per_m
            ));
        }
        let published = [e.csy.health_ratio, e.csay.health_ratio];
        let t = e.time_s;
        // Every step below the alarm's threshold (a dip shorter than 10 ms shows too).
        let below_alarm = published.iter().any(|r| *r < 0.7);
        let show = !events.is_empty()
            || below_alarm
            || (step.is_multiple_of(10)
                && (published.iter().any(|r| *r < args.show_below)
                    || (args.window.0..=args.window.1).contains(&t)));
        if !show {
            continue;
        }
        let mut cloud = [0.0; 2];
        for i in 0..f.n_particles() {
            let (th, lw, _, _) = f.particle(i);
            for k in 0..2 {
                cloud[k] += lw.exp() * th[k].exp();
            }
        }
        let best_sentinel = f
            .hypothesis_nis()
            .skip(f.n_particles())
            .fold(f64::INFINITY, f64::min);
        println!(
            "{t:8.3} | {:5.1} | {} | {:.3} / {:.3} | {:.3} / {:.3} | {:.3} | {:.1} / {:.1} | {:.1} | {} | {}",
            sample.speed_m_s,
            if e.paused.is_some() { "P" } else { "-" },
            published[0],
            published[1],
            cloud[0] / nominal[0],
            cloud[1] / nominal[1],
            f.jump_probation_mass(),
            f.normalised_innovation_squared(),
            best_sentinel,
            f.jump_max_ln_odds(),
            f.resample_count(),
            events.join("; ")
        );
    }
    Ok(())
}
