//! The condition sampler (issue 23 item 3): scenarios drawn at random from the operating
//! envelope instead of a hand-written list. [`draw`] turns a seed into an
//! [`AdhesionScenario`] built from the ordinary scenario types, so any draw can be written as
//! TOML (`toml::to_string(&scenario)`) and replayed with `railmon analyze adhesion --scenario`;
//! the same seed always gives the same scenario (one `ChaCha8Rng` seeded from it, which also
//! seeds the simulation's noise).
//!
//! **The envelope** (each draw independent, ranges inclusive):
//! - drives `N` 2-32 (uniform), the load shared unevenly: each drive's scale
//!   `1 + u_i`, `|u_i|` up to a spread drawn in 0-5 %;
//! - regime: traction, braking or coasting (a third each) at a base load of 3-40 N m
//!   (log-uniform; coasting: within +-0.5 N m of 0); 0-2 notches (switches of the common
//!   load to 0.5-1.5 times the base, same sign, smoothed over 0-60 steps);
//! - `k` of the `N` drives lose adhesion (`k` uniform in 1..=N-1, which ones at random), each
//!   once: onsets simultaneous (a third: the same step), together (a third: within 40 steps,
//!   5 ms) or staggered (a third: within 2000 steps); depth 10-90 % of the healthy load
//!   (uniform, the same for the group or drawn per drive); duration 20 steps to 10 s
//!   (log-uniform); a drop (edges smoothed over 0-60 steps) or, one time in four, a ramp of
//!   50-2000 steps;
//! - sensor noise 0.5-2 times that of `adhesion-half` (current 0.015 A, voltage 0.05 V, load
//!   0.1 N m), one factor per draw;
//! - the plant's motor parameters `R_s`, `L_s`, `Psi_pm`, `J` each 0.9-1.1 times the nominal
//!   (the monitor keeps the nominal: a model mismatch), 1-4 plant sub-steps.
//!
//! **Size.** A draw is some 4,000 to 90,000 steps (2,000 to settle, the losses, 1,500 after
//! the last); long draws keep at most [`MAX_DRIVE_STEPS`] drive-steps by having fewer drives,
//! so that 200 draws run in minutes.
//!
//! **Families** ([`DrawKind`], [`draw_kind`]): the envelope above (ordinary, [`draw`]); the
//! same draws with a measured train speed (train-speed: `[train_speed]`, noise 0.05-0.2 m/s,
//! drawn after everything else so the rest of the draw is the ordinary one); and draws where
//! every drive loses adhesion at once with a train speed (all-at-once: traction or braking,
//! simultaneous or within 5 ms, 30-90 % for 0.5-5 s).
//!
//! **Split.** Even seeds are tuning draws, odd seeds held out ([`is_held_out`]): a method is
//! tuned on even seeds and reported on odd ones.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::model::MotorParams;
use crate::monitor::SlipMonitorConfig;
use crate::scenario::{
    AdhesionScenario, ControllerConfig, LoadProfile, NoiseConfig, PlantConfig, SlipEvent,
    TrainSpeedConfig,
};

/// Fewest and most drives of a draw.
pub const DRIVES: (usize, usize) = (2, 32);
/// Shortest and longest loss, steps (20 steps to 10 s at 125 us).
pub const LOSS_STEPS: (f64, f64) = (20.0, 80_000.0);
/// Smallest and largest loss, fraction of the healthy load.
pub const DEPTH: (f64, f64) = (0.1, 0.9);
/// Noise factor range, applied to [`BASE_NOISE`].
pub const NOISE_FACTOR: (f64, f64) = (0.5, 2.0);
/// The noise the factor scales: `adhesion-half`'s.
pub const BASE_NOISE: NoiseConfig = NoiseConfig {
    current_std_a: 0.015,
    voltage_std_v: 0.05,
    load_std_nm: 0.1,
};
/// Base load magnitude range in traction and braking, N m.
pub const LOAD_NM: (f64, f64) = (3.0, 40.0);
/// Steps before the first loss: the EKFs lock on (400) and learn each drive's spread.
pub const SETTLE_STEPS: usize = 2000;
/// Steps after the last loss ends (the EKF's return, a release seen).
pub const TAIL_STEPS: usize = 1500;
/// A draw has at most this many drive-steps (`n_drives * n_steps`); a long draw has fewer
/// drives instead.
pub const MAX_DRIVE_STEPS: usize = 400_000;

/// Noise of the measured train speed in draws with one, m/s (radar, GNSS).
pub const TRAIN_SPEED_NOISE_M_S: (f64, f64) = (0.05, 0.2);
/// Shortest and longest loss of [`DrawKind::AllAtOnce`], steps (0.5 s to 5 s): a loss of
/// every drive the train speed sees only as the rotors run away, at
/// `p_p (T_healthy - T_limit) / J`, so that a short shallow one is over before the slip
/// velocity clears the sensor's noise.
pub const ALL_AT_ONCE_LOSS_STEPS: (f64, f64) = (4_000.0, 40_000.0);
/// Smallest and largest loss of [`DrawKind::AllAtOnce`], fraction of the healthy load.
pub const ALL_AT_ONCE_DEPTH: (f64, f64) = (0.3, 0.9);

/// Which family a draw comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DrawKind {
    /// The envelope of the module's documentation, no train speed (what [`draw`] gives).
    #[default]
    Ordinary,
    /// The same draw with a measured train speed (`[train_speed]`, noise in
    /// [`TRAIN_SPEED_NOISE_M_S`]): the drives are torque-controlled and run away from the
    /// train when they lose adhesion.
    TrainSpeed,
    /// Every drive loses adhesion, simultaneously or within 5 ms, with a train speed: in
    /// traction or braking, depth in [`ALL_AT_ONCE_DEPTH`], duration in
    /// [`ALL_AT_ONCE_LOSS_STEPS`]; the rest of the envelope as ordinary draws.
    AllAtOnce,
}

impl DrawKind {
    pub fn name(self) -> &'static str {
        match self {
            DrawKind::Ordinary => "ordinary",
            DrawKind::TrainSpeed => "train-speed",
            DrawKind::AllAtOnce => "all-at-once",
        }
    }

    pub fn has_train_speed(self) -> bool {
        self != DrawKind::Ordinary
    }
}

impl std::str::FromStr for DrawKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        [
            DrawKind::Ordinary,
            DrawKind::TrainSpeed,
            DrawKind::AllAtOnce,
        ]
        .into_iter()
        .find(|k| k.name() == s)
        .ok_or_else(|| format!("{s}: not ordinary, train-speed or all-at-once"))
    }
}

/// Whether `seed` is held out (odd) or a tuning draw (even).
pub fn is_held_out(seed: u64) -> bool {
    seed % 2 == 1
}

/// The operating regime of a draw.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Regime {
    Traction,
    Braking,
    Coasting,
}

impl Regime {
    pub fn name(self) -> &'static str {
        match self {
            Regime::Traction => "traction",
            Regime::Braking => "braking",
            Regime::Coasting => "coasting",
        }
    }
}

/// How the onsets of a draw's losses are placed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Onsets {
    /// The same step.
    Simultaneous,
    /// Within 40 steps (5 ms).
    Together,
    /// Within 2000 steps.
    Staggered,
}

impl Onsets {
    pub fn name(self) -> &'static str {
        match self {
            Onsets::Simultaneous => "simultaneous",
            Onsets::Together => "together",
            Onsets::Staggered => "staggered",
        }
    }

    fn spread_steps(self) -> f64 {
        match self {
            Onsets::Simultaneous => 0.0,
            Onsets::Together => 40.0,
            Onsets::Staggered => 2000.0,
        }
    }
}

/// A draw: the scenario and what was drawn, for the reports.
#[derive(Debug, Clone, PartialEq)]
pub struct Draw {
    pub seed: u64,
    pub kind: DrawKind,
    pub regime: Regime,
    pub onsets: Onsets,
    /// Drives that lose adhesion (0-based), sorted.
    pub slipping: Vec<usize>,
    pub noise_factor: f64,
    pub scenario: AdhesionScenario,
}

fn uniform(rng: &mut ChaCha8Rng, (lo, hi): (f64, f64)) -> f64 {
    lo + (hi - lo) * rng.random::<f64>()
}

fn log_uniform(rng: &mut ChaCha8Rng, (lo, hi): (f64, f64)) -> f64 {
    (lo.ln() + (hi.ln() - lo.ln()) * rng.random::<f64>()).exp()
}

/// The scenario of `seed` (see the module's documentation for the envelope).
pub fn draw(seed: u64) -> Draw {
    draw_kind(seed, DrawKind::Ordinary)
}

/// The scenario of `seed` from the family `kind`. [`DrawKind::Ordinary`] is [`draw`];
/// [`DrawKind::TrainSpeed`] is the same draw (the same drives, losses and noise) with a train
/// speed added; [`DrawKind::AllAtOnce`] draws its own.
pub fn draw_kind(seed: u64, kind: DrawKind) -> Draw {
    let all = kind == DrawKind::AllAtOnce;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut n = rng.random_range(DRIVES.0..=DRIVES.1);
    let regime = match rng.random_range(0..3) {
        0 => Regime::Traction,
        1 => Regime::Braking,
        // Coasting carries no load to lose: every drive losing adhesion is drawn in traction or
        // braking.
        _ if all => Regime::Traction,
        _ => Regime::Coasting,
    };
    let sign = if regime == Regime::Braking { -1.0 } else { 1.0 };
    let base = match regime {
        Regime::Coasting => uniform(&mut rng, (-0.5, 0.5)),
        _ => sign * log_uniform(&mut rng, LOAD_NM),
    };
    let onsets = match rng.random_range(0..3) {
        0 => Onsets::Simultaneous,
        1 => Onsets::Together,
        _ if all => Onsets::Simultaneous,
        _ => Onsets::Staggered,
    };
    let (loss_steps, depth_range) = if all {
        (ALL_AT_ONCE_LOSS_STEPS, ALL_AT_ONCE_DEPTH)
    } else {
        (LOSS_STEPS, DEPTH)
    };
    let duration = log_uniform(&mut rng, loss_steps).round();
    let per_drive_depth = rng.random_bool(0.5);
    let group_depth = uniform(&mut rng, depth_range);
    let ramp = rng.random_bool(0.25);
    let ramp_steps = uniform(&mut rng, (50.0, 2000.0)).round().min(duration);
    let edge_smoothing = uniform(&mut rng, (0.0, 60.0)).round();
    let first_onset = SETTLE_STEPS as f64 + uniform(&mut rng, (0.0, 2000.0)).round();
    let spread = onsets.spread_steps();
    let n_steps = (first_onset + spread + duration + 4.0 * edge_smoothing) as usize + TAIL_STEPS;
    // Fewer drives rather than more than the budget of drive-steps.
    n = n.min((MAX_DRIVE_STEPS / n_steps).max(DRIVES.0));
    let k = rng.random_range(1..n);
    let k = if all { n } else { k };
    let mut drives: Vec<usize> = (0..n).collect();
    // Partial Fisher-Yates: the first k are the slipping drives.
    for i in 0..k {
        let j = rng.random_range(i..n);
        drives.swap(i, j);
    }
    let mut slipping = drives[..k].to_vec();
    slipping.sort_unstable();

    let events = slipping
        .iter()
        .map(|&d| {
            let start = first_onset + uniform(&mut rng, (0.0, spread)).round();
            let depth = if per_drive_depth {
                uniform(&mut rng, depth_range)
            } else {
                group_depth
            };
            if ramp {
                SlipEvent::Ramp {
                    drive: d + 1,
                    start_step: start,
                    full_step: start + ramp_steps.max(1.0),
                    end_step: start + duration.max(ramp_steps.max(1.0)),
                    remaining_fraction: 1.0 - depth,
                    smoothing_steps: Some(edge_smoothing),
                }
            } else {
                SlipEvent::Drop {
                    drive: d + 1,
                    start_step: start,
                    end_step: start + duration,
                    remaining_fraction: 1.0 - depth,
                    smoothing_steps: Some(edge_smoothing),
                }
            }
        })
        .collect();

    // Notches: 0-2 switches of the common load anywhere in the draw, same sign as the base.
    let notches = rng.random_range(0..=2);
    let mut switch_steps: Vec<f64> = (0..notches)
        .map(|_| uniform(&mut rng, (SETTLE_STEPS as f64, n_steps as f64)).round())
        .collect();
    switch_steps.sort_by(f64::total_cmp);
    let mut levels_nm = vec![base];
    levels_nm.extend((0..notches).map(|_| base * uniform(&mut rng, (0.5, 1.5))));
    let load_smoothing = uniform(&mut rng, (0.0, 60.0)).round();
    let share = uniform(&mut rng, (0.0, 0.05));
    let drive_scale = (0..n)
        .map(|_| 1.0 + uniform(&mut rng, (-share, share)))
        .collect();

    let noise_factor = uniform(&mut rng, NOISE_FACTOR);
    let noise = NoiseConfig {
        current_std_a: BASE_NOISE.current_std_a * noise_factor,
        voltage_std_v: BASE_NOISE.voltage_std_v * noise_factor,
        load_std_nm: BASE_NOISE.load_std_nm * noise_factor,
    };
    let nominal = MotorParams::default();
    let mut off_nominal = |v: f64| v * uniform(&mut rng, (0.9, 1.1));
    let motor = MotorParams {
        r_s_ohm: off_nominal(nominal.r_s_ohm),
        l_s_h: off_nominal(nominal.l_s_h),
        psi_pm_wb: off_nominal(nominal.psi_pm_wb),
        inertia_kg_m2: off_nominal(nominal.inertia_kg_m2),
        ..nominal
    };
    let substeps = rng.random_range(1..=4);
    let simulation_seed = rng.random::<u64>();
    // Drawn last, so that a train-speed draw is its ordinary draw with the speed added.
    let train_speed = kind.has_train_speed().then(|| TrainSpeedConfig {
        noise_std_m_s: uniform(&mut rng, TRAIN_SPEED_NOISE_M_S),
        ..TrainSpeedConfig::default()
    });
    let onset_word = onsets.name();
    let scenario = AdhesionScenario {
        name: match kind {
            DrawKind::Ordinary => format!("adhesion-draw-{seed}"),
            _ => format!("adhesion-draw-{}-{seed}", kind.name()),
        },
        description: format!(
            "condition sampler draw {seed}: {n} drives, {k} losing adhesion ({onset_word}) for {duration} steps, {}, noise x{noise_factor:.2}{}",
            regime.name(),
            train_speed.map_or(String::new(), |t| format!(
                ", train speed measured with {:.3} m/s noise",
                t.noise_std_m_s
            ))
        ),
        n_drives: n,
        n_steps,
        dt_s: 125e-6,
        seed: simulation_seed,
        plant: PlantConfig {
            motor,
            substeps,
            controller: ControllerConfig::default(),
        },
        noise,
        load: LoadProfile {
            levels_nm,
            switch_steps,
            smoothing_steps: load_smoothing,
            drive_scale,
        },
        events,
        train_speed,
        monitor: SlipMonitorConfig::default(),
    };
    Draw {
        seed,
        kind,
        regime,
        onsets,
        slipping,
        noise_factor,
        scenario,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_seed_gives_the_same_scenario_and_seeds_differ() {
        assert_eq!(draw(1001), draw(1001));
        assert_ne!(draw(1001).scenario, draw(1003).scenario);
    }

    #[test]
    fn draws_stay_within_the_envelope_and_validate() {
        let mut seen = (0, 0, 0, 0);
        for seed in 0..300 {
            let d = draw(seed);
            let s = &d.scenario;
            s.validate().unwrap_or_else(|e| panic!("seed {seed}: {e}"));
            let n = s.n_drives();
            assert!((DRIVES.0..=DRIVES.1).contains(&n), "seed {seed}: {n}");
            assert!(n * s.n_steps() <= MAX_DRIVE_STEPS.max(2 * s.n_steps()));
            let k = d.slipping.len();
            assert!((1..n).contains(&k), "seed {seed}: {k} of {n}");
            assert_eq!(s.events.len(), k);
            assert!((NOISE_FACTOR.0..=NOISE_FACTOR.1).contains(&d.noise_factor));
            for e in &s.events {
                let (start, end, rest) = match *e {
                    SlipEvent::Drop {
                        start_step,
                        end_step,
                        remaining_fraction,
                        ..
                    }
                    | SlipEvent::Ramp {
                        start_step,
                        end_step,
                        remaining_fraction,
                        ..
                    } => (start_step, end_step, remaining_fraction),
                    SlipEvent::HalfSine { .. } => panic!("seed {seed}: no half sines drawn"),
                };
                assert!((LOSS_STEPS.0..=LOSS_STEPS.1).contains(&(end - start)));
                assert!((1.0 - DEPTH.1..=1.0 - DEPTH.0).contains(&rest));
                assert!(start >= SETTLE_STEPS as f64);
                assert!(end + TAIL_STEPS as f64 <= s.n_steps() as f64);
            }
            let nominal = MotorParams::default();
            for (v, v0) in [
                (s.plant.motor.r_s_ohm, nominal.r_s_ohm),
                (s.plant.motor.inertia_kg_m2, nominal.inertia_kg_m2),
            ] {
                assert!((0.9..=1.1).contains(&(v / v0)), "seed {seed}");
            }
            let base = s.load.levels_nm[0];
            match d.regime {
                Regime::Traction => assert!(base >= LOAD_NM.0),
                Regime::Braking => assert!(base <= -LOAD_NM.0),
                Regime::Coasting => assert!(base.abs() <= 0.5),
            }
            seen.0 += usize::from(2 * k >= n && d.onsets == Onsets::Simultaneous);
            seen.1 += usize::from(d.regime == Regime::Braking);
            seen.2 += usize::from(n >= 24);
            seen.3 += usize::from(d.onsets == Onsets::Staggered);
        }
        // Every corner the issue names is drawn, often.
        assert!(
            seen.0 >= 20 && seen.1 >= 60 && seen.2 >= 20 && seen.3 >= 60,
            "{seen:?}"
        );
    }

    #[test]
    fn a_draw_written_as_toml_reads_back_the_same() {
        for seed in [3, 4, 77] {
            let s = draw(seed).scenario;
            let text = toml::to_string(&s).unwrap();
            assert_eq!(AdhesionScenario::from_toml_str(&text).unwrap(), s, "{text}");
        }
    }

    #[test]
    fn train_speed_draws_are_the_ordinary_ones_with_a_speed_and_all_at_once_loses_every_drive() {
        for seed in 0..60 {
            let (o, t) = (draw(seed), draw_kind(seed, DrawKind::TrainSpeed));
            let noise = t.scenario.train_speed.expect("a train speed").noise_std_m_s;
            assert!((TRAIN_SPEED_NOISE_M_S.0..=TRAIN_SPEED_NOISE_M_S.1).contains(&noise));
            assert_eq!(o.scenario.events, t.scenario.events, "seed {seed}");
            assert_eq!(o.scenario.load, t.scenario.load, "seed {seed}");
            assert!(o.scenario.train_speed.is_none());
            let a = draw_kind(seed, DrawKind::AllAtOnce);
            a.scenario.validate().unwrap();
            assert_eq!(a.slipping.len(), a.scenario.n_drives(), "seed {seed}");
            assert!(a.regime != Regime::Coasting && a.onsets != Onsets::Staggered);
            assert!(a.scenario.train_speed.is_some());
            let text = toml::to_string(&a.scenario).unwrap();
            assert_eq!(AdhesionScenario::from_toml_str(&text).unwrap(), a.scenario);
        }
    }

    #[test]
    fn the_split_is_by_parity() {
        assert!(is_held_out(1001) && !is_held_out(1000));
    }
}
