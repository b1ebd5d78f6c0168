//! The RBPF step at N = 1000 (issue 9 item 4: <= 150 us with speed scheduling and the noise
//! estimate), per variant, as ratios measured in one run:
//!
//! - `plain`: the configured speed (45.3 m/s, no `set_speed`), configured noise taken as exact;
//! - `+noise`: the same with the noise-scale estimate (`[monitor.rbpf.noise_scale]`);
//! - `+speed`: data simulated on a speed ramp 28 -> 34 m/s, `set_speed` every sample (the
//!   model and `H` at the exact speed, the gains of the nearest node, the Taylor order the
//!   speed needs), configured noise;
//! - `+speed+noise`: both (the target);
//! - `+speed+noise@10`: the same on a ramp 9 -> 11 m/s (the creep terms ~ 1 / v are stiffer:
//!   a higher Taylor order);
//! - `+speed+noise+jump`: `+speed+noise` with the jump search's sentinels
//!   (`[monitor.rbpf.jump_search]`; the variants above have it off);
//! - `monitor`: `DamperMonitor::step` of the default configuration on the ramp (adds the
//!   consistency check and the posterior summary);
//! - `monitor:+ekf`: the same with the EKF baseline (`ekf.enabled`, off by default since 29 Nov).
//! - `monitor:no-mass`: the same with the samples' body mass withheld, the particles carrying
//!   their own (`[monitor.rbpf.unmeasured_mass]`: a third parameter, per-particle body row and
//!   gains of its mass node);
//! - `monitor:no-mass:design`: withheld, the design mass assumed (`unmeasured_mass.enabled =
//!   false`: the cost of `monitor`).
//! - `plain:taylor-1e-9`, `monitor:taylor-1e-9`: `plain` and `monitor` with the Taylor series
//!   truncated at 1e-9 (`rbpf.taylor_truncation`; the default 1e-5 since 29 Nov).
//!
//! Every filter first runs 3 s of its data (posterior narrowed, as in service; the speed
//! nodes the ramp visits are solved before timing), then all variants run alternately in
//! blocks of 250 samples over the same stretch, so that they see the same machine load; the
//! table gives the thread's CPU time per step (`CLOCK_THREAD_CPUTIME_ID`: on a machine shared
//! with builds the wall time also counts the time the thread waited for a core; caches and
//! the other hyperthread are still shared) and wall time per step, and the ratio of CPU times
//! to the first variant.
//!
//! Run: `cargo bench -p railmon-damper --bench rbpf_variants` (about 40 s); flags after `--`:
//! `--rounds N` (default 12) blocks per variant, `--particles N` (1000), `--only plain,+noise`
//! (only the variants named, e.g. under `perf record`); `--help`; a bad flag exits 2.

use std::process::ExitCode;
use std::time::Instant;

use railmon_bench_support::measure;
use railmon_damper::{
    BogieSample, BogieSimulator, DamperMonitor, DamperMonitorConfig, DamperScenario, Rbpf,
    SpeedProfile,
};

const SEED: &str = include_str!("../../config/scenarios/damper-seed.toml");
const WARM_UP_STEPS: usize = 3000;
const BLOCK: usize = 250;

/// What the flags set (see the module's documentation).
struct Args {
    rounds: usize,
    particles: usize,
    /// The variants to run (empty: all).
    only: Vec<String>,
}

const USAGE: &str = "usage: cargo bench -p railmon-damper --bench rbpf_variants -- [FLAGS]

--rounds N      blocks of 250 samples per variant (default 12)
--particles N   particles (default 1000)
--only A,B      only the variants named (default: all)
--help          this text";

fn parse_args() -> Result<Args, String> {
    let mut a = Args {
        rounds: 12,
        particles: 1000,
        only: vec![],
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or(format!("{flag} needs a value"));
        let number = |v: String| v.parse().map_err(|e| format!("{flag} {v}: {e}"));
        match flag.as_str() {
            "--help" | "-h" => {
                println!("{USAGE}");
                std::process::exit(0);
            }
            // cargo bench passes it to every bench binary.
            "--bench" => {}
            "--rounds" => a.rounds = number(value()?)?,
            "--particles" => a.particles = number(value()?)?,
            "--only" => a.only = value()?.split(',').map(str::to_owned).collect(),
            other => return Err(format!("unknown flag {other}")),
        }
    }
    if a.rounds == 0 || a.particles == 0 {
        return Err("--rounds and --particles: at least 1".into());
    }
    Ok(a)
}

/// `n` samples of the seed scenario, at the configured speed or on `profile`.
fn samples(n: usize, profile: Option<SpeedProfile>) -> (DamperMonitorConfig, Vec<BogieSample>) {
    let mut scenario = DamperScenario::from_toml_str(SEED).expect("seed scenario");
    scenario.duration_s = n as f64 * scenario.dt_s;
    scenario.speed = profile;
    let mut sim = BogieSimulator::new(&scenario).expect("simulator");
    let mut out = Vec::with_capacity(n);
    while let Some((s, _)) = sim.step() {
        out.push(*s);
    }
    (scenario.monitor_config(), out)
}

/// One variant: a filter (or monitor) and its data.
enum Runner {
    Rbpf { filter: Box<Rbpf>, scheduled: bool },
    Monitor(Box<DamperMonitor>),
}

impl Runner {
    fn step(&mut self, s: &BogieSample) {
        match self {
            Runner::Rbpf { filter, scheduled } => {
                if *scheduled {
                    filter.set_speed(s.speed_m_s).expect("speed");
                }
                filter.step(&s.to_vector()).expect("step");
            }
            Runner::Monitor(m) => {
                m.step(s).expect("step");
            }
        }
    }

    fn resamples(&self) -> u64 {
        match self {
            Runner::Rbpf { filter, .. } => filter.resample_count(),
            Runner::Monitor(m) => m.rbpf().resample_count(),
        }
    }
}

fn main() -> ExitCode {
    let Args {
        rounds,
        particles,
        only,
    } = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("rbpf_variants: {e} (--help lists the flags)");
            return ExitCode::from(2);
        }
    };
    let n = WARM_UP_STEPS + BLOCK * rounds;
    let (config, constant) = samples(n, None);
    let ramp = SpeedProfile {
        profile_m_s: vec![[0.0, 28.0], [n as f64 * config.dt_s, 34.0]],
    };
    let (_, ramped) = samples(n, Some(ramp));
    let slow_ramp = SpeedProfile {
        profile_m_s: vec![[0.0, 9.0], [n as f64 * config.dt_s, 11.0]],
    };
    let (_, slow) = samples(n, Some(slow_ramp));
    let no_mass: Vec<BogieSample> = ramped
        .iter()
        .map(|s| BogieSample {
            half_body_mass_kg: None,
            ..*s
        })
        .collect();
    let mut default = config;
    default.rbpf.particles = particles;
    let mut with_noise = default;
    with_noise.rbpf.jump_search.enabled = false;
    let mut with_jump = with_noise;
    with_jump.rbpf.jump_search.enabled = true;
    let mut design_mass = default;
    design_mass.rbpf.unmeasured_mass.enabled = false;
    let mut fixed = with_noise;
    fixed.rbpf.noise_scale.enabled = false;
    let mut fixed_1e9 = fixed;
    fixed_1e9.rbpf.taylor_truncation = 1e-9;
    let mut with_ekf = default;
    with_ekf.ekf.enabled = true;
    let mut default_1e9 = default;
    default_1e9.rbpf.taylor_truncation = 1e-9;
    let start = Instant::now();
    let table =
        Rbpf::gain_table(&config.filter_model(), &config.rbpf, &config.speed).expect("table");
    let first_s = start.elapsed().as_secs_f64();
    // Solve the nodes the ramp visits now: their first use is not what is timed.
    let (lo, hi) = (table.node_of(28.0), table.node_of(34.0));
    let start = Instant::now();
    for node in lo..=hi {
        table.grid_at(node).expect("grid");
    }
    let per_node_s = start.elapsed().as_secs_f64() / (hi - lo + 1) as f64;
    for node in table.node_of(9.0)..=table.node_of(11.0) {
        table.grid_at(node).expect("grid");
    }
    // And the mass nodes the particles of `monitor:no-mass` reach (0.82-1.48 of the design
    // mass, beyond the prior's 0.85-1.4 by the kernel's spread), at the ramp's speeds.
    let design_kg = config.vehicle.half_body_mass_kg;
    for node in lo..=hi {
        for j in -4..=8 {
            let mass_kg = design_kg * railmon_damper::gain_table::MASS_GRID_RATIO.powi(j);
            let node = table.node_at(table.node_speed_m_s(node), mass_kg);
            table.grid_at(node).expect("grid");
        }
    }
    println!(
        "gain table: the configured speed's grid {first_s:.3} s (with the table), then \
         {per_node_s:.3} s per speed node ({} nodes over the speed range: {:.1} s for all)",
        table.n_nodes(),
        per_node_s * table.n_nodes() as f64
    );
    let rbpf = |c: &DamperMonitorConfig, scheduled| Runner::Rbpf {
        filter: Box::new(
            Rbpf::with_gain_table(&c.filter_model(), &c.rbpf, &c.speed, Some(table.clone()))
                .expect("rbpf"),
        ),
        scheduled,
    };
    let monitor = |c: &DamperMonitorConfig| {
        Runner::Monitor(Box::new(
            DamperMonitor::with_gain_table(c, c.rbpf.seed, Some(table.clone())).expect("monitor"),
        ))
    };
    let mut variants: Vec<(&str, Runner, &[BogieSample])> = vec![
        ("plain", rbpf(&fixed, false), &constant),
        ("+noise", rbpf(&with_noise, false), &constant),
        ("+speed", rbpf(&fixed, true), &ramped),
        ("+speed+noise", rbpf(&with_noise, true), &ramped),
        ("+speed+noise@10", rbpf(&with_noise, true), &slow),
        ("+speed+noise+jump", rbpf(&with_jump, true), &ramped),
        ("monitor", monitor(&default), &ramped),
        ("monitor:+ekf", monitor(&with_ekf), &ramped),
        ("monitor:no-mass", monitor(&default), &no_mass),
        ("monitor:no-mass:design", monitor(&design_mass), &no_mass),
        ("plain:taylor-1e-9", rbpf(&fixed_1e9, false), &constant),
        ("monitor:taylor-1e-9", monitor(&default_1e9), &ramped),
    ];
    if let Some(o) = only
        .iter()
        .find(|o| !variants.iter().any(|v| v.0 == o.as_str()))
    {
        let names: Vec<&str> = variants.iter().map(|v| v.0).collect();
        eprintln!(
            "rbpf_variants: --only: no variant {o:?} ({}) (--help lists the flags)",
            names.join(", ")
        );
        return ExitCode::from(2);
    }
    if !only.is_empty() {
        variants.retain(|v| only.iter().any(|o| o == v.0));
    }
    for (_, runner, data) in &mut variants {
        for s in &data[..WARM_UP_STEPS] {
            runner.step(s);
        }
    }
    let resamples_before: Vec<u64> = variants.iter().map(|v| v.1.resamples()).collect();
    let mut seconds = vec![0.0; variants.len()];
    let mut cpu_seconds = vec![0.0; variants.len()];
    for round in 0..rounds {
        let range = WARM_UP_STEPS + round * BLOCK..WARM_UP_STEPS + (round + 1) * BLOCK;
        // Rotate which variant goes first.
        for k in 0..variants.len() {
            let v = (k + round) % variants.len();
            let (_, runner, data) = &mut variants[v];
            let time = measure(|| {
                for s in &data[range.clone()] {
                    runner.step(s);
                }
            });
            cpu_seconds[v] += time.cpu.as_secs_f64();
            seconds[v] += time.wall.as_secs_f64();
        }
    }
    let steps = (BLOCK * rounds) as f64;
    println!("\nRBPF step, N = {particles}, {rounds} x {BLOCK} steps per variant, interleaved:");
    println!(
        "{:>18} {:>12} {:>10} {:>12} {:>10}",
        "variant", "cpu us/step", "/ first", "wall us/step", "resamples"
    );
    for (((name, runner, _), (s, cpu)), r0) in variants
        .iter()
        .zip(seconds.iter().zip(&cpu_seconds))
        .zip(&resamples_before)
    {
        let resamples = runner.resamples() - r0;
        println!(
            "{name:>18} {:>12.1} {:>10.3} {:>12.1} {resamples:>10}",
            cpu * 1e6 / steps,
            cpu / cpu_seconds[0],
            s * 1e6 / steps,
        );
    }
    ExitCode::SUCCESS
}
