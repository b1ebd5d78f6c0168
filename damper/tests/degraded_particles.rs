//! Degraded compute (issue 28 item 3): a filter cut to fewer particles while the host cannot
//! keep up (`Rbpf::set_particles`, down to `MIN_DEGRADED_PARTICLES`) and restored afterwards
//! still gives a valid posterior: run in lockstep with the uncut filter on a wear ramp, its
//! 90 % interval covers the truth >= 85 % of the degraded stretch and its mean stays inside
//! the uncut filter's interval; and a state saved while degraded resumes exactly.

use railmon_damper::*;

mod common;

/// What a cut filter and the full one, run in lockstep on [`common::csy_ramp_on_seed`]
/// (N = 300), publish every 10 ms from 20 s: the cut one goes to `MIN_DEGRADED_PARTICLES` at
/// 40 s and back to 300 at 100 s. Counts per stretch (full N, degraded, restored), summed over
/// the filter seeds run.
#[derive(Default)]
struct Lockstep {
    seen: [usize; 3],
    /// Truth inside the 90 % interval of the cut filter, and of the full one.
    cut_covered: [usize; 3],
    full_covered: [usize; 3],
    /// The cut filter's `C_sy` mean inside the full filter's 90 % interval (every step
    /// before the cut: they are the same filter).
    mean_inside_full: [usize; 3],
}

impl Lockstep {
    fn share(&self, counts: [usize; 3]) -> [f64; 3] {
        [0, 1, 2].map(|k| counts[k] as f64 / self.seen[k] as f64)
    }

    fn print(&self, what: &str) {
        eprintln!(
            "{what}: coverage (full N, degraded, restored) cut {:.3?}, uncut {:.3?}; \
             cut mean inside the uncut interval {:.3?}",
            self.share(self.cut_covered),
            self.share(self.full_covered),
            self.share(self.mean_inside_full)
        );
    }

    /// Runs filter seed `seed`: its counts.
    fn of_seed(seed: u64) -> Lockstep {
        let (scenario, config) = common::csy_ramp_on_seed();
        let mut cut = DamperMonitor::new(&config, seed).unwrap();
        let mut full = DamperMonitor::new(&config, seed).unwrap();
        let mut sim = BogieSimulator::new(&scenario).unwrap();
        let mut this = Lockstep::default();
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
                this.seen[stretch] += 1;
                this.cut_covered[stretch] += usize::from(c.csy.covers(truth_csy));
                this.full_covered[stretch] += usize::from(f.csy.covers(truth_csy));
                this.mean_inside_full[stretch] += usize::from(f.csy.covers(c.csy.mean_ns_per_m));
            }
        }
        this.print(&format!("seed {seed}"));
        this
    }

    /// The counts of filter seeds `seeds`, summed. The seeds run at once, a thread each: each
    /// is a long single-threaded run, and one after the other they left the second core idle
    /// for most of this binary's time. Each seed's run is its own, and the sums are of
    /// integers: the same totals in any order.
    fn over_seeds(seeds: &[u64]) -> Lockstep {
        let runs: Vec<Lockstep> = std::thread::scope(|s| {
            let threads: Vec<_> = seeds
                .iter()
                .map(|&seed| s.spawn(move || Lockstep::of_seed(seed)))
                .collect();
            threads
                .into_iter()
                .map(|t| t.join().unwrap_or_else(|e| std::panic::resume_unwind(e)))
                .collect()
        });
        let mut sum = Lockstep::default();
        for run in runs {
            for k in 0..3 {
                sum.seen[k] += run.seen[k];
                sum.cut_covered[k] += run.cut_covered[k];
                sum.full_covered[k] += run.full_covered[k];
                sum.mean_inside_full[k] += run.mean_inside_full[k];
            }
        }
        sum
    }

    /// The cut keeps a valid posterior, over the seeds run: over the degraded stretch the
    /// cut filter's interval covers the ramp >= 85 % of the time (issue 28's bar), and
    /// through the degraded and the restored stretches its mean lies inside the uncut
    /// filter's interval >= 90 % of the time (a cut that moved the mean by one posterior
    /// standard deviation would give about 0.74).
    ///
    /// Judged over seeds, not per seed: one 60 s stretch of a ramp is one correlated path,
    /// and its coverage swings with the path alone. The uncut filter's own degraded-stretch
    /// coverage on filter seeds 1-6 and 11 was 0.807-0.952, the cut one's 0.820-0.948, at
    /// the Taylor truncation 1e-9 and 1e-5 (29 Nov; the difference of the two -0.12 ..
    /// +0.10, mean -0.005). The restored stretch's coverage is not judged: the ramp's last
    /// 30 s (to 0.45 x nominal) is covered 0.70-0.87 by the uncut filter itself (issue 24
    /// item 3, docs/damper.md).
    fn assert_valid(&self) {
        self.print("over the seeds");
        let inside = self.share(self.mean_inside_full);
        assert_eq!(inside[0], 1.0);
        let coverage = self.share(self.cut_covered)[1];
        assert!(coverage >= 0.85, "degraded coverage {coverage:.3}");
        for k in [1, 2] {
            assert!(
                inside[k] >= 0.90,
                "stretch {k}: the cut mean inside the uncut interval {:.3}",
                inside[k]
            );
        }
    }
}

/// The configured filter seed (11) and seeds 1 and 2. Measured (29 Nov, default truncation
/// 1e-5): degraded coverage 0.820, 0.887, 0.923 (uncut 0.936, 0.889, 0.905), the cut mean
/// inside the uncut interval 0.967-0.988 of the degraded stretch, 0.951-0.987 of the restored
/// one.
#[test]
fn a_filter_cut_to_the_floor_and_restored_keeps_a_valid_posterior() {
    let (_, config) = common::csy_ramp_on_seed();
    Lockstep::over_seeds(&[config.rbpf.seed, 1, 2]).assert_valid();
}

/// [`a_filter_cut_to_the_floor_and_restored_keeps_a_valid_posterior`] over filter seeds 1-12.
/// Measured (29 Nov, truncation 1e-5): coverage of the degraded stretch cut 0.899, uncut
/// 0.897 (per seed cut 0.820-0.940, uncut 0.809-0.936); of the restored stretch cut 0.836,
/// uncut 0.808; the cut mean inside the uncut interval 0.977 and 0.963 of the two stretches.
#[test]
#[ignore = "about 2.5 min in release: `cargo test --release -p railmon-damper --test \
            degraded_particles -- --ignored --nocapture`"]
fn the_cut_keeps_a_valid_posterior_over_twelve_seeds() {
    let seeds: Vec<u64> = (1..=12).collect();
    Lockstep::over_seeds(&seeds).assert_valid();
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
