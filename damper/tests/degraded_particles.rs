//! Degraded compute (issue 28 item 3): a filter cut to fewer particles while the host cannot
//! keep up (`Rbpf::set_particles`, down to `MIN_DEGRADED_PARTICLES`) and restored afterwards
//! still gives a valid posterior: run in lockstep with the uncut filter on a wear ramp, its
//! 90 % interval covers the truth >= 85 % of the degraded stretch and its mean stays inside
//! the uncut filter's interval; and a state saved while degraded resumes exactly.

use railmon_damper::*;

mod common;

/// What a cut filter and the full one, run in lockstep on [`common::csy_ramp_on_seed`]
/// (N = 300) with filter seed `seed`, publish every 10 ms from 20 s: the cut one goes to
/// `MIN_DEGRADED_PARTICLES` at 40 s and back to 300 at 100 s.
struct Lockstep {
    /// Truth inside the 90 % interval, per stretch (full N, degraded, restored), of the cut
    /// filter and of the full one.
    cut_coverage: [f64; 3],
    full_coverage: [f64; 3],
    /// Per stretch, the share of the steps where the cut filter's `C_sy` mean lies inside
    /// the full filter's 90 % interval (1 before the cut: they are the same filter).
    mean_inside_full: [f64; 3],
}

fn lockstep(seed: u64) -> Lockstep {
    let (scenario, config) = common::csy_ramp_on_seed();
    let mut cut = DamperMonitor::new(&config, seed).unwrap();
    let mut full = DamperMonitor::new(&config, seed).unwrap();
    let mut sim = BogieSimulator::new(&scenario).unwrap();
    let mut seen = [0usize; 3];
    let (mut cut_covered, mut full_covered, mut inside) = ([0usize; 3], [0usize; 3], [0usize; 3]);
    let mut step = 0usize;
    while let Some((sample, truth)) = sim.step() {
        step += 1;
        if step == 40_000 || step == 100_000 {
            let n = if step == 40_000 {
                MIN_DEGRADED_PARTICLES
            } else {
                300
            };
            cut.set_particles(n).unwrap();
            assert_eq!(cut.particles(), n);
            assert_eq!(cut.rbpf().n_particles(), n);
            let total: f64 = (0..n).map(|i| cut.rbpf().particle(i).1.exp()).sum();
            assert!((total - 1.0).abs() < 1e-9, "weights sum to {total}");
        }
        let c = *cut.step(sample).unwrap();
        let f = *full.step(sample).unwrap();
        assert!(c.csy.mean_ns_per_m.is_finite() && c.csy.mean_ns_per_m > 0.0);
        assert!(c.effective_sample_size <= cut.particles() as f64 + 1e-9);
        if step < 40_000 {
            assert_eq!(c, f, "the two differ before the cut");
        }
        if truth.time_s >= 20.0 && step.is_multiple_of(10) {
            let stretch = match step {
                ..40_000 => 0,
                40_000..100_000 => 1,
                _ => 2,
            };
            let truth_csy = truth.dampers.csy_ns_per_m;
            seen[stretch] += 1;
            cut_covered[stretch] += usize::from(c.csy.covers(truth_csy));
            full_covered[stretch] += usize::from(f.csy.covers(truth_csy));
            inside[stretch] += usize::from(f.csy.covers(c.csy.mean_ns_per_m));
        }
    }
    let share = |counts: [usize; 3]| [0, 1, 2].map(|k| counts[k] as f64 / seen[k] as f64);
    let l = Lockstep {
        cut_coverage: share(cut_covered),
        full_coverage: share(full_covered),
        mean_inside_full: share(inside),
    };
    eprintln!(
        "seed {seed}: coverage (full N, degraded, restored) cut {:.3?}, uncut {:.3?}; \
         cut mean inside the uncut interval {:.3?}",
        l.cut_coverage, l.full_coverage, l.mean_inside_full
    );
    l
}

/// The cut keeps a valid posterior: over the degraded stretch the cut filter's interval
/// covers the ramp >= 85 % of the time (issue 28's bar), and through the degraded and the
/// restored stretches its mean stays inside the uncut filter's interval >= 90 % of the time
/// (the two filters' Monte Carlo error is time-correlated: on filter seed 3 the uncut one
/// covers the degraded stretch 0.807, the cut one 0.907, and the cut mean lies inside the
/// uncut interval 0.942 of it; a cut that moved the mean by one posterior standard deviation
/// would give about 0.74).
/// The restored stretch's coverage is not judged here: the ramp's last 30 s (to 0.45 x
/// nominal) is covered 0.75-0.86 by the uncut filter itself on seeds 1-6, the cut one
/// 0.74-0.87 (issue 24 item 3, docs/damper.md).
fn assert_valid(l: &Lockstep) {
    assert_eq!(l.mean_inside_full[0], 1.0);
    assert!(
        l.cut_coverage[1] >= 0.85,
        "degraded coverage {:.3}",
        l.cut_coverage[1]
    );
    for k in [1, 2] {
        assert!(
            l.mean_inside_full[k] >= 0.90,
            "stretch {k}: the cut mean inside the uncut interval {:.3}",
            l.mean_inside_full[k]
        );
    }
}

/// The configured filter seed (11). Measured (29 Nov): the cut filter covers the degraded
/// stretch 0.919 (uncut 0.913), its mean inside the uncut interval 0.959 of it and 0.997 of the
/// restored stretch.
#[test]
fn a_filter_cut_to_the_floor_and_restored_keeps_a_valid_posterior() {
    let (_, config) = common::csy_ramp_on_seed();
    assert_valid(&lockstep(config.rbpf.seed));
}

/// [`a_filter_cut_to_the_floor_and_restored_keeps_a_valid_posterior`] on filter seeds 1-6
/// (29 Nov: the cut filter's coverage over the degraded stretch 0.887-0.948, the uncut one's
/// 0.807-0.952; the cut mean inside the uncut interval 0.942-0.997 of the degraded stretch,
/// 0.962-0.997 of the restored one).
#[test]
#[ignore = "about 70 s in release: `cargo test --release -p railmon-damper --test \
            degraded_particles -- --ignored --nocapture`"]
fn the_cut_keeps_a_valid_posterior_on_every_seed() {
    for seed in 1..=6 {
        assert_valid(&lockstep(seed));
    }
}

/// A state saved at the floor resumes at its own count in a monitor configured for more, and
/// goes on exactly as the one that saved it; a state of more particles than configured is
/// refused.
#[test]
fn a_state_saved_while_degraded_resumes_exactly() {
    let text = include_str!("../../config/scenarios/damper-seed.toml");
    let mut scenario = DamperScenario::from_toml_str(text).unwrap();
    scenario.duration_s = 3.0;
    let mut config = scenario.monitor_config();
    config.rbpf.particles = 200;
    let mut sim = BogieSimulator::new(&scenario).unwrap();
    let mut samples: Vec<BogieSample> = vec![];
    while let Some((s, _)) = sim.step() {
        samples.push(*s);
    }
    let (before, after) = samples.split_at(2000);
    let mut running = DamperMonitor::for_bogie(&config, 1, None).unwrap();
    for s in &before[..1000] {
        running.step(s).unwrap();
    }
    running.set_particles(MIN_DEGRADED_PARTICLES).unwrap();
    for s in &before[1000..] {
        running.step(s).unwrap();
    }
    let mut resumed = DamperMonitor::resume(&config, None, running.state()).unwrap();
    assert_eq!(resumed.particles(), MIN_DEGRADED_PARTICLES);
    for s in after {
        assert_eq!(running.step(s).unwrap(), resumed.step(s).unwrap());
    }
    let mut fewer = config;
    fewer.rbpf.particles = MIN_DEGRADED_PARTICLES - 1;
    assert!(DamperMonitor::resume(&fewer, None, running.state()).is_err());
}
