//! The damper's condition sampler (issue 24 item 5): scenarios drawn at random from the
//! operating envelope instead of the robustness matrix's one factor at a time. [`draw`] turns
//! a seed (and the longest run wanted) into a [`DamperScenario`] built from the ordinary
//! scenario types plus what was drawn, for the reports and the scoring; the same seed always
//! gives the same scenario (one `ChaCha8Rng` seeded from it, which also draws the simulation's
//! seed). Pure: no I/O.
//!
//! **Only the plant varies.** The scenario's monitor is `DamperMonitorConfig::default()` with
//! `[monitor.vehicle]` given as the design vehicle: the filter assumes conicity 0.15 and the
//! configured sensor noise whatever the plant is, and the design body mass unless the
//! simulator gives the plant's as the measured load (`BogieSimulator::with_mass_input`, issue
//! 24 item 1). What it cannot see must show in the results.
//!
//! **The envelope** (each draw independent, ranges inclusive):
//! - duration: 0.5-1 times the longest run asked for (whole seconds);
//! - speed: constant (35 %) in 6 m/s to the top speed; varying (30 %): holds of 15-90 s
//!   (at most half the run) joined by accelerations of 0.3-1 m/s^2 between speeds in 6 m/s to the top; or with stops
//!   (35 %, and every fault at a stop): as varying, the first stop after a first hold of 10-35 % of the run
//!   (the profile drawn again, up to 20 times, until a stop starts after 20 s and ends 20 s
//!   before the end),
//!   then at each change a stop with probability 0.3, a stop being 0 m/s (or, one in five,
//!   creeping at 1-4.5 m/s, below the filter's 5 m/s) for 5-40 s. A third of the varying
//!   runs start from rest. The top speed is 55 m/s (the filter's `speed.max_m_s`) or, lower,
//!   the plant's critical speed less 2 m/s with its drawn conicity, mass and faulted dampers:
//!   above it the linear plant grows without bound, which no real bogie does (see
//!   `SpeedConfig::max_m_s`), so such a draw would test the simulator, not the filter;
//! - track: on a constant speed the white track (half), ERRI low or high (a quarter each);
//!   on a varying speed the white track (the ERRI generator runs at one speed). The white
//!   track's velocity std 0.05-0.2 m/s (log-uniform);
//! - sensor noise: 0.5-3 times the default (log-uniform), both sensors one factor;
//! - conicity 0.08-0.3 (uniform; the filter assumes 0.15);
//! - body mass (`half_body_mass_kg`): at the start the design value in a quarter of the
//!   draws, else 0.85-1.4 times it (uniform). Half of the draws with stops change it at each
//!   stop at 0 m/s (not while creeping), at the stop's middle, to 0.85-1.4 times the design
//!   value again (uniform: passengers boarding and alighting; `[load] changes_kg`), where the
//!   plant stays stable at the run's later speeds with the new mass (else up to 10 draws
//!   more, then no change at that stop). These changes come from a second stream of the
//!   seed's generator (`ChaCha8Rng::set_stream(1)`): every other figure of a draw, the
//!   simulation's seed included, is the one drawn before load changes existed (27 Nov);
//! - faults: none (40 %); a step (30 %) of `C_sy`, `C_say` or both (a third each) to 0.2-0.6
//!   of nominal, from 30 s to 20 s before the end; a ramp (15 %) of one damper from nominal to
//!   0.2-0.6 over 60-300 s (log-uniform; it may end after the run), starting from 30 s to 60 %
//!   of the run; a step at a stop (15 %) of either or both, while the vehicle stands or creeps.
//!
//! **Split.** Even seeds are tuning draws, odd seeds held out ([`is_held_out`]).

use nalgebra::ComplexField;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::config::DamperMonitorConfig;
use crate::faults::{dampers_at, DamperFault, DamperId, FaultKind};
use crate::model::BogieModel;
use crate::params::{BogieParams, Dampers};
use crate::scenario::DamperScenario;
use crate::speed::SpeedConfig;
use crate::speed_profile::SpeedProfile;
use crate::track::{ErriLevel, TrackSpec};

/// The longest run when nothing says otherwise (s).
pub const MAX_DURATION_S: f64 = 600.0;
/// The shortest longest run [`draw`] takes (s): a fault from 30 s and 20 s after it.
pub const MIN_MAX_DURATION_S: f64 = 60.0;
/// Sensor noise factor on `SensorNoise::default()`.
pub const NOISE_FACTOR: (f64, f64) = (0.5, 3.0);
/// Plant body mass over the design value.
pub const MASS_RATIO: (f64, f64) = (0.85, 1.4);
/// Plant conicity.
pub const CONICITY: (f64, f64) = (0.08, 0.3);
/// White track velocity std (m/s).
pub const WHITE_TRACK_M_S: (f64, f64) = (0.05, 0.2);
/// A faulty damper's final ratio to nominal.
pub const FAULT_RATIO: (f64, f64) = (0.2, 0.6);
/// No fault starts before this (s): the filter has converged.
pub const FAULT_FROM_S: f64 = 30.0;
/// Moving speeds are drawn from here to the top speed (m/s).
pub const MOVING_MIN_M_S: f64 = 6.0;
/// Creeping speeds, below the filter's minimum (m/s).
pub const CREEP_M_S: (f64, f64) = (1.0, 4.5);
/// Accelerations and decelerations between speeds (m/s^2).
pub const ACCEL_M_S2: (f64, f64) = (0.3, 1.0);
/// The plant's critical speed less this is the top speed (m/s).
pub const CRITICAL_MARGIN_M_S: f64 = 2.0;
/// The share of the draws with stops whose load changes at each stop.
pub const LOAD_CHANGE_SHARE: f64 = 0.5;
/// The generator stream of the load changes (the main draw is stream 0).
const LOAD_STREAM: u64 = 1;

/// Whether `seed` is held out (odd) or a tuning draw (even).
pub fn is_held_out(seed: u64) -> bool {
    seed % 2 == 1
}

/// How the speed goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SpeedKind {
    Constant,
    Varying,
    WithStops,
}

impl SpeedKind {
    pub fn name(self) -> &'static str {
        match self {
            SpeedKind::Constant => "constant",
            SpeedKind::Varying => "varying",
            SpeedKind::WithStops => "stops",
        }
    }
}

/// What fault a draw has.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FaultShape {
    None,
    Step,
    Ramp,
    /// A step while the vehicle stands or creeps (the filter paused).
    AtStop,
}

impl FaultShape {
    pub fn name(self) -> &'static str {
        match self {
            FaultShape::None => "healthy",
            FaultShape::Step => "step",
            FaultShape::Ramp => "ramp",
            FaultShape::AtStop => "step at stop",
        }
    }
}

/// A draw: the scenario and what was drawn.
#[derive(Debug, Clone, PartialEq)]
pub struct Draw {
    pub seed: u64,
    pub speed_kind: SpeedKind,
    pub fault_shape: FaultShape,
    /// Plant body mass over the design value at the start.
    pub mass_ratio: f64,
    /// The load changes at stops: (time (s), body mass over the design value from then on).
    pub load_changes: Vec<(f64, f64)>,
    pub noise_factor: f64,
    /// The highest speed drawn from (m/s).
    pub top_speed_m_s: f64,
    /// Stretches below `MOVING_MIN_M_S` after slowing down: (from, to) (s).
    pub stops: Vec<(f64, f64)>,
    pub scenario: DamperScenario,
}

impl Draw {
    /// When `damper`'s first fault starts, if it has one.
    pub fn fault_onset_s(&self, damper: DamperId) -> Option<f64> {
        self.scenario
            .faults
            .iter()
            .filter(|f| f.damper == damper)
            .map(|f| f.at_s)
            .reduce(f64::min)
    }

    /// The true ratio of `damper` to its initial value at `t_s`.
    pub fn true_ratio(&self, damper: DamperId, t_s: f64) -> f64 {
        let s = &self.scenario;
        let (now, start) = (dampers_at(&s.dampers, &s.faults, t_s), s.dampers);
        match damper {
            DamperId::Csy => now.csy_ns_per_m / start.csy_ns_per_m,
            DamperId::Csay => now.csay_ns_per_m / start.csay_ns_per_m,
        }
    }

    /// The monitor time (s, the estimate's `time_s`) of the first sample whose step has
    /// `damper` below `threshold` times its initial value while the speed is in `speed`'s
    /// range (the filter learning): where a detection delay counts from. `None` when that
    /// never happens in the run (a ramp that has not crossed yet, a fault at a stop the
    /// vehicle never leaves).
    pub fn detectable_from_s(
        &self,
        damper: DamperId,
        threshold: f64,
        speed: &SpeedConfig,
    ) -> Option<f64> {
        let onset = self.fault_onset_s(damper)?;
        let s = &self.scenario;
        let profile = s.speed_profile();
        let first = (onset / s.dt_s).floor() as usize;
        (first..s.n_steps())
            .find(|&k| {
                let t = k as f64 * s.dt_s;
                speed.pause_reason(profile.at(t)).is_none()
                    && self.true_ratio(damper, t) < threshold
            })
            .map(|k| (k + 1) as f64 * s.dt_s)
    }

    /// The drawn conditions in a few words.
    pub fn short(&self) -> String {
        let s = &self.scenario;
        let track = match s.track {
            TrackSpec::White { velocity_std_m_s } => format!("white {velocity_std_m_s:.2}"),
            TrackSpec::Erri { level } => format!("erri {level:?}").to_lowercase(),
        };
        let profile = s.speed_profile();
        let speeds: Vec<f64> = profile.profile_m_s.iter().map(|p| p[1]).collect();
        let speed = match self.speed_kind {
            SpeedKind::Constant => format!("{:.0} m/s", speeds[0]),
            _ => format!(
                "{} {:.0}-{:.0} m/s{}",
                self.speed_kind.name(),
                speeds.iter().copied().fold(f64::MAX, f64::min),
                speeds.iter().copied().fold(0.0, f64::max),
                match self.stops.len() {
                    0 => String::new(),
                    n => format!(" ({n} stops)"),
                }
            ),
        };
        let faults: Vec<String> = s
            .faults
            .iter()
            .map(|f| match f.end_s {
                Some(end) => format!(
                    "{} ramp {:.2} {:.0}-{:.0} s",
                    f.damper.name(),
                    f.ratio,
                    f.at_s,
                    end
                ),
                None => format!("{} {:.2} at {:.0} s", f.damper.name(), f.ratio, f.at_s),
            })
            .collect();
        let masses: String = self
            .load_changes
            .iter()
            .map(|(_, r)| format!("->{r:.2}"))
            .collect();
        format!(
            "{:.0} s, {speed}, {track}, noise x{:.2}, con {:.3}, mass x{:.2}{masses}, {}",
            s.duration_s,
            self.noise_factor,
            s.vehicle.conicity,
            self.mass_ratio,
            match faults.is_empty() {
                true => "healthy".to_owned(),
                false => format!("{}: {}", self.fault_shape.name(), faults.join(" + ")),
            }
        )
    }
}

fn uniform(rng: &mut ChaCha8Rng, (lo, hi): (f64, f64)) -> f64 {
    lo + (hi - lo) * rng.random::<f64>()
}

fn log_uniform(rng: &mut ChaCha8Rng, (lo, hi): (f64, f64)) -> f64 {
    (lo.ln() + (hi.ln() - lo.ln()) * rng.random::<f64>()).exp()
}

/// The largest real part of the eigenvalues of the plant's `A` at `speed_m_s`.
fn growth_rate_per_s(vehicle: &BogieParams, dampers: &Dampers, speed_m_s: f64) -> f64 {
    let Ok(mut model) = BogieModel::new(vehicle, 0.0) else {
        return f64::INFINITY;
    };
    if model.set_speed(speed_m_s).is_err() {
        return f64::INFINITY;
    }
    model
        .a_matrix(dampers)
        .complex_eigenvalues()
        .iter()
        .map(|e| e.real())
        .fold(f64::MIN, f64::max)
}

/// The top speed: `max_m_s`, or lower, the highest whole m/s at which the plant with each of
/// `dampers` is stable `CRITICAL_MARGIN_M_S` faster (bisection: stability is lost once, at
/// the critical speed).
fn top_speed_m_s(vehicle: &BogieParams, dampers: &[Dampers], max_m_s: f64) -> f64 {
    let stable = |v: f64| {
        dampers
            .iter()
            .all(|d| growth_rate_per_s(vehicle, d, v + CRITICAL_MARGIN_M_S) < 1e-6)
    };
    if stable(max_m_s) {
        return max_m_s;
    }
    let (mut lo, mut hi) = (MOVING_MIN_M_S, max_m_s.floor());
    while hi - lo > 1.0 {
        let mid = ((lo + hi) / 2.0).floor();
        if stable(mid) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo
}

/// A varying speed profile over `duration_s` from 6 m/s to `top`, with stops when
/// `stops`; the stops as (from, to).
fn varying_profile(
    rng: &mut ChaCha8Rng,
    duration_s: f64,
    top: f64,
    stops: bool,
) -> (SpeedProfile, Vec<(f64, f64)>) {
    let moving = |rng: &mut ChaCha8Rng| uniform(rng, (MOVING_MIN_M_S, top)).round().min(top);
    let mut v = if rng.random_bool(1.0 / 3.0) {
        0.0
    } else {
        moving(rng)
    };
    let (mut t, mut points, mut stop_list) = (0.0, vec![[0.0, v]], vec![]);
    let mut first_hold = true;
    loop {
        let standing = v < MOVING_MIN_M_S;
        let hold = if standing {
            uniform(rng, (5.0, 40.0))
        } else if first_hold && stops {
            uniform(rng, (0.1, 0.35)) * duration_s
        } else {
            uniform(rng, (15.0, 90.0)).min(0.5 * duration_s)
        }
        .round()
        .max(1.0);
        first_hold &= standing;
        if standing && t > 0.0 {
            stop_list.push((t, t + hold));
        }
        t += hold;
        points.push([t, v]);
        if t >= duration_s {
            break;
        }
        let target = if standing {
            moving(rng)
        } else if stops && (stop_list.is_empty() || rng.random_bool(0.3)) {
            if rng.random_bool(0.2) {
                (10.0 * uniform(rng, CREEP_M_S)).round() / 10.0
            } else {
                0.0
            }
        } else {
            // Another speed: a change of at least 2 m/s where the top allows it.
            let mut target = moving(rng);
            for _ in 0..20 {
                if (target - v).abs() >= 2.0 {
                    break;
                }
                target = moving(rng);
            }
            target
        };
        let accel = uniform(rng, ACCEL_M_S2);
        t += ((target - v).abs() / accel).round().max(1.0);
        points.push([t, target]);
        v = target;
    }
    (
        SpeedProfile {
            profile_m_s: points,
        },
        stop_list,
    )
}

/// The load changes of a draw with `stops` on `profile` (module docs): in a share
/// [`LOAD_CHANGE_SHARE`] of such draws, at the middle of each stop at 0 m/s, a body mass of
/// [`MASS_RATIO`] times the design value (within the run) at which the plant with each of `dampers` is stable
/// at the highest speed after the change (with the margin). Draws from `rng` (the load's own
/// stream) only: the rest of the draw does not depend on it.
fn load_changes(
    rng: &mut ChaCha8Rng,
    vehicle: &BogieParams,
    dampers: &[Dampers],
    profile: &SpeedProfile,
    stops: &[(f64, f64)],
    duration_s: f64,
) -> Vec<(f64, f64)> {
    if stops.is_empty() || !rng.random_bool(LOAD_CHANGE_SHARE) {
        return vec![];
    }
    let design_kg = BogieParams::default().half_body_mass_kg;
    let mut changes = vec![];
    for &(from, to) in stops {
        let at_s = (0.5 * (from + to)).round();
        if at_s >= duration_s || profile.at(at_s) != 0.0 {
            continue;
        }
        // The highest speed from the change on: the profile's points after it (it is linear
        // between them) and the stop itself.
        let fastest = profile
            .profile_m_s
            .iter()
            .filter(|p| p[0] >= at_s)
            .map(|p| p[1])
            .fold(0.0, f64::max);
        let stable = |ratio: f64| {
            let plant = BogieParams {
                half_body_mass_kg: design_kg * ratio,
                ..*vehicle
            };
            dampers
                .iter()
                .all(|d| growth_rate_per_s(&plant, d, fastest + CRITICAL_MARGIN_M_S) < 1e-6)
        };
        if let Some(ratio) = (0..11)
            .map(|_| (100.0 * uniform(rng, MASS_RATIO)).round() / 100.0)
            .find(|&r| stable(r))
        {
            changes.push((at_s, ratio));
        }
    }
    changes
}

/// The first stop of a run of `duration_s` that starts after 20 s and ends 20 s before the
/// end (a fault there has the time to be found after moving off).
fn first_stop(stops: &[(f64, f64)], duration_s: f64) -> Option<(f64, f64)> {
    stops
        .iter()
        .copied()
        .find(|&(from, to)| from >= 20.0 && to <= duration_s - 20.0)
}

/// The scenario of `seed` for runs of at most `max_duration_s` (at least
/// [`MIN_MAX_DURATION_S`]; see the module's documentation for the envelope). The same seed
/// and longest run give the same draw.
pub fn draw(seed: u64, max_duration_s: f64) -> Draw {
    let max_duration_s = max_duration_s.max(MIN_MAX_DURATION_S);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let duration_s = (uniform(&mut rng, (0.5, 1.0)) * max_duration_s)
        .round()
        .max(MIN_MAX_DURATION_S);
    let design = BogieParams::default();
    let mass_ratio = if rng.random_bool(0.25) {
        1.0
    } else {
        uniform(&mut rng, MASS_RATIO)
    };
    let mut vehicle = BogieParams {
        half_body_mass_kg: design.half_body_mass_kg * mass_ratio,
        conicity: uniform(&mut rng, CONICITY),
        ..design
    };
    let noise_factor = log_uniform(&mut rng, NOISE_FACTOR);
    let mut sensors = crate::sample::SensorNoise::default();
    sensors.accel_std_m_s2 *= noise_factor;
    sensors.gyro_std_rad_s *= noise_factor;

    let u = rng.random::<f64>();
    let mut fault_shape = match u {
        _ if u < 0.40 => FaultShape::None,
        _ if u < 0.70 => FaultShape::Step,
        _ if u < 0.85 => FaultShape::Ramp,
        _ => FaultShape::AtStop,
    };
    let which: Vec<DamperId> = match (fault_shape, rng.random_range(0..3)) {
        (FaultShape::None, _) => vec![],
        (FaultShape::Ramp, k) => vec![DamperId::ALL[k % 2]],
        (_, 2) => DamperId::ALL.to_vec(),
        (_, k) => vec![DamperId::ALL[k]],
    };
    let ratios: Vec<f64> = which
        .iter()
        .map(|_| (100.0 * uniform(&mut rng, FAULT_RATIO)).round() / 100.0)
        .collect();
    // The plant must be stable at every speed drawn, with its dampers healthy and faulted.
    let nominal = Dampers::NOMINAL;
    let mut faulted = nominal;
    for (d, r) in which.iter().zip(&ratios) {
        match d {
            DamperId::Csy => faulted.csy_ns_per_m *= r,
            DamperId::Csay => faulted.csay_ns_per_m *= r,
        }
    }
    let speed_config = SpeedConfig::default();
    let top = top_speed_m_s(&vehicle, &[nominal, faulted], speed_config.max_m_s);

    let speed_kind = match (fault_shape, rng.random::<f64>()) {
        (FaultShape::AtStop, _) => SpeedKind::WithStops,
        (_, u) if u < 0.35 => SpeedKind::Constant,
        (_, u) if u < 0.65 => SpeedKind::Varying,
        _ => SpeedKind::WithStops,
    };
    let (speed, stops, track) = if speed_kind == SpeedKind::Constant {
        vehicle.speed_m_s = uniform(&mut rng, (MOVING_MIN_M_S, top)).round().min(top);
        let track = match rng.random_range(0..4) {
            0 => TrackSpec::Erri {
                level: ErriLevel::Low,
            },
            1 => TrackSpec::Erri {
                level: ErriLevel::High,
            },
            _ => TrackSpec::White {
                velocity_std_m_s: log_uniform(&mut rng, WHITE_TRACK_M_S),
            },
        };
        (None, vec![], track)
    } else {
        let stops = speed_kind == SpeedKind::WithStops;
        // With stops: one from 20 s on that ends 20 s before the end (a few tries; the last
        // try is kept, and a fault at a stop without one is a step).
        let mut tries = 0;
        let (profile, stop_list) = loop {
            let (profile, stop_list) = varying_profile(&mut rng, duration_s, top, stops);
            tries += 1;
            if !stops || tries == 20 || first_stop(&stop_list, duration_s).is_some() {
                break (profile, stop_list);
            }
        };
        let track = TrackSpec::White {
            velocity_std_m_s: log_uniform(&mut rng, WHITE_TRACK_M_S),
        };
        (Some(profile), stop_list, track)
    };

    let latest = (duration_s - 20.0).max(FAULT_FROM_S);
    if fault_shape == FaultShape::AtStop && first_stop(&stops, duration_s).is_none() {
        fault_shape = FaultShape::Step;
    }
    let faults = match fault_shape {
        FaultShape::None => vec![],
        FaultShape::Step | FaultShape::AtStop => {
            let at_s = match (fault_shape, first_stop(&stops, duration_s)) {
                (FaultShape::AtStop, Some((from, to))) => uniform(&mut rng, (from + 0.5, to - 0.5)),
                _ => uniform(&mut rng, (FAULT_FROM_S, latest)),
            }
            .round();
            which
                .iter()
                .zip(&ratios)
                .map(|(&damper, &ratio)| DamperFault {
                    damper,
                    kind: FaultKind::Step,
                    at_s,
                    end_s: None,
                    ratio,
                })
                .collect()
        }
        FaultShape::Ramp => {
            let at_s = uniform(
                &mut rng,
                (FAULT_FROM_S, (0.6 * duration_s).max(FAULT_FROM_S)),
            )
            .round();
            let length = log_uniform(&mut rng, (60.0, 300.0)).round();
            vec![DamperFault {
                damper: which[0],
                kind: FaultKind::Ramp,
                at_s,
                end_s: Some(at_s + length),
                ratio: ratios[0],
            }]
        }
    };
    let simulation_seed = rng.random::<u64>();
    let mut load_rng = ChaCha8Rng::seed_from_u64(seed);
    load_rng.set_stream(LOAD_STREAM);
    let load_changes = match &speed {
        Some(profile) => load_changes(
            &mut load_rng,
            &vehicle,
            &[nominal, faulted],
            profile,
            &stops,
            duration_s,
        ),
        None => vec![],
    };
    let scenario = DamperScenario {
        name: format!("damper-draw-{seed}"),
        seed: simulation_seed,
        duration_s,
        dt_s: 1e-3,
        vehicle,
        dampers: nominal,
        track,
        sensors,
        faults,
        speed,
        // The plant's mass is `vehicle`'s at the start, measured; it changes at stops.
        load: crate::scenario::LoadSpec {
            changes_kg: load_changes
                .iter()
                .map(|&(t, r)| [t, design.half_body_mass_kg * r])
                .collect(),
            ..crate::scenario::LoadSpec::default()
        },
        monitor: DamperMonitorConfig::default(),
        // The filter assumes the design vehicle, whatever the plant's.
        monitor_vehicle_given: true,
    };
    Draw {
        seed,
        speed_kind,
        fault_shape,
        mass_ratio,
        load_changes,
        noise_factor,
        top_speed_m_s: top,
        stops,
        scenario,
    }
}

/// Ramp lengths of [`ramp_draw`] (s): wear over 1 to 10 minutes (issue 24 item 3).
pub const RAMP_S: (f64, f64) = (60.0, 600.0);
/// A ramp of [`ramp_draw`] starts between these times (s): the filter has converged.
pub const RAMP_ONSET_S: (f64, f64) = (FAULT_FROM_S, 60.0);
/// A ramp draw runs this long after the truth crosses the alarm's threshold (s): the alarm's
/// delay is measured within it.
pub const RAMP_AFTER_CROSSING_S: f64 = 40.0;
/// The generator stream of a ramp draw's fault (the conditions are stream 0's, the load 1's).
const RAMP_STREAM: u64 = 2;

/// The conditions of [`draw`]`(seed, ..)` (speed profile, track, noise, conicity, mass and its
/// changes) with one damper (either, at random) ramping linearly from nominal to
/// [`FAULT_RATIO`] over [`RAMP_S`] (log-uniform), from [`RAMP_ONSET_S`]; the run lasts until
/// [`RAMP_AFTER_CROSSING_S`] after the truth crosses `threshold` (the speed profile holds its
/// last speed beyond its own end). Speeds are capped at the drawn top speed recomputed with the
/// ramp's final ratio at every mass of the run, so the plant stays stable. `healthy`: the same
/// draw without the fault (what the ramp costs a healthy damper). The fault's figures come from
/// their own generator stream: the conditions are those of `draw`.
pub fn ramp_draw(seed: u64, threshold: f64, healthy: bool) -> Draw {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(RAMP_STREAM);
    let damper = DamperId::ALL[rng.random_range(0..2)];
    let length_s = log_uniform(&mut rng, RAMP_S).round();
    let ratio = (100.0 * uniform(&mut rng, FAULT_RATIO)).round() / 100.0;
    let at_s = uniform(&mut rng, RAMP_ONSET_S).round();
    let crossing_s = at_s + length_s * (1.0 - threshold) / (1.0 - ratio);
    let duration_s = (crossing_s + RAMP_AFTER_CROSSING_S)
        .min(at_s + length_s + 20.0)
        .ceil();
    // Twice as long: the drawn run, and so its speed profile, lasts 0.5-1 times it.
    let mut d = draw(seed, 2.0 * duration_s);
    let design = BogieParams::default();
    let nominal = Dampers::NOMINAL;
    let mut faulted = nominal;
    match damper {
        DamperId::Csy => faulted.csy_ns_per_m *= ratio,
        DamperId::Csay => faulted.csay_ns_per_m *= ratio,
    }
    let s = &mut d.scenario;
    let speed = SpeedConfig::default();
    let top = std::iter::once(d.mass_ratio)
        .chain(d.load_changes.iter().map(|&(_, r)| r))
        .map(|r| {
            let plant = BogieParams {
                half_body_mass_kg: design.half_body_mass_kg * r,
                ..s.vehicle
            };
            top_speed_m_s(&plant, &[nominal, faulted], speed.max_m_s)
        })
        .fold(d.top_speed_m_s, f64::min);
    d.top_speed_m_s = top;
    s.vehicle.speed_m_s = s.vehicle.speed_m_s.min(top);
    if let Some(p) = &mut s.speed {
        p.profile_m_s.iter_mut().for_each(|q| q[1] = q[1].min(top));
    }
    s.duration_s = duration_s;
    s.name = format!("damper-ramp-{seed}");
    s.faults = if healthy {
        vec![]
    } else {
        vec![DamperFault {
            damper,
            kind: FaultKind::Ramp,
            at_s,
            end_s: Some(at_s + length_s),
            ratio,
        }]
    };
    d.fault_shape = if healthy {
        FaultShape::None
    } else {
        FaultShape::Ramp
    };
    d
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_seed_gives_the_same_scenario_and_seeds_differ() {
        assert_eq!(draw(5001, 120.0), draw(5001, 120.0));
        assert_ne!(draw(5001, 120.0).scenario, draw(5003, 120.0).scenario);
    }

    /// Over 200 draws: every drawn scenario validates and stays in the envelope, the filter
    /// keeps the design vehicle, and every corner appears: each fault shape, both dampers
    /// faulted together, stops, creeping, masses at both ends, each track, loads changing at
    /// stops (each within the envelope, at a stop).
    #[test]
    fn draws_cover_the_envelope_and_validate() {
        let design = BogieParams::default();
        let mut shapes = [0usize; 4];
        let (mut both, mut stops, mut creep, mut light, mut heavy, mut design_mass) =
            (0, 0, 0, 0, 0, 0);
        let (mut erri, mut white, mut from_rest, mut load_changing) = (0, 0, 0, 0);
        for seed in 0..200 {
            let max = if seed % 2 == 0 { 120.0 } else { 600.0 };
            let d = draw(seed, max);
            let s = &d.scenario;
            s.validate().unwrap_or_else(|e| panic!("seed {seed}: {e}"));
            assert_eq!(s.monitor_config().vehicle, design, "seed {seed}");
            assert!((0.5 * max..=max).contains(&s.duration_s), "seed {seed}");
            assert!((MASS_RATIO.0..=MASS_RATIO.1).contains(&d.mass_ratio));
            for (k, &(t, r)) in d.load_changes.iter().enumerate() {
                assert!(
                    (MASS_RATIO.0..=MASS_RATIO.1).contains(&r),
                    "seed {seed}: {r}"
                );
                let kg = design.half_body_mass_kg * r;
                assert_eq!(s.load.changes_kg[k], [t, kg], "seed {seed}");
                assert_eq!(s.half_body_mass_kg_at(t), kg, "seed {seed}");
                assert!(
                    d.stops.iter().any(|&(a, b)| a < t && t < b),
                    "seed {seed}: {t}"
                );
            }
            assert_eq!(d.load_changes.len(), s.load.changes_kg.len());
            load_changing += usize::from(!d.load_changes.is_empty());
            if d.stops.is_empty() {
                assert!(d.load_changes.is_empty(), "seed {seed}");
            }
            let c = s.vehicle.conicity;
            assert!((CONICITY.0..=CONICITY.1).contains(&c), "seed {seed}: {c}");
            assert!((NOISE_FACTOR.0..=NOISE_FACTOR.1).contains(&d.noise_factor));
            let profile = s.speed_profile();
            let top = profile.profile_m_s.iter().map(|p| p[1]).fold(0.0, f64::max);
            assert!(top <= d.top_speed_m_s && top <= 55.0, "seed {seed}: {top}");
            let constant = d.speed_kind == SpeedKind::Constant;
            assert_eq!(
                profile.is_constant(),
                constant,
                "seed {seed}: {profile:?} {d:?}"
            );
            for f in &s.faults {
                assert!(f.at_s < s.duration_s, "seed {seed}");
                assert!((FAULT_RATIO.0..=FAULT_RATIO.1).contains(&f.ratio));
            }
            shapes[d.fault_shape as usize] += 1;
            both += usize::from(s.faults.len() == 2);
            if d.fault_shape == FaultShape::AtStop {
                let at = s.faults[0].at_s;
                assert!(profile.at(at) < 5.0, "seed {seed}: fault at {at} s moving");
            } else {
                assert!(s.faults.iter().all(|f| f.at_s >= FAULT_FROM_S));
            }
            stops += usize::from(!d.stops.is_empty());
            creep += usize::from(profile.profile_m_s.iter().any(|p| p[1] > 0.0 && p[1] < 5.0));
            from_rest += usize::from(profile.at(0.0) == 0.0);
            light += usize::from(d.mass_ratio < 0.9);
            heavy += usize::from(d.mass_ratio > 1.35);
            design_mass += usize::from(d.mass_ratio == 1.0);
            erri += usize::from(matches!(s.track, TrackSpec::Erri { .. }));
            white += usize::from(matches!(s.track, TrackSpec::White { .. }));
        }
        let seen = [
            both,
            stops,
            creep,
            light,
            heavy,
            design_mass,
            erri,
            white,
            from_rest,
            load_changing,
        ];
        assert!(shapes.iter().all(|&n| n >= 15), "{shapes:?}");
        assert!((60..=100).contains(&shapes[0]), "healthy: {shapes:?}");
        assert!(seen.iter().all(|&n| n >= 5), "{seen:?}");
    }

    /// A fault at a stop counts from moving off again; a step from its time; a ramp from its
    /// crossing, or never when it does not cross within the run.
    #[test]
    fn detection_counts_from_the_crossing_seen_moving() {
        let speed = SpeedConfig::default();
        let d = (0..)
            .map(|seed| draw(seed, 600.0))
            .find(|d| d.fault_shape == FaultShape::AtStop)
            .unwrap();
        let f = d.scenario.faults[0];
        let from = d.detectable_from_s(f.damper, 0.7, &speed).unwrap();
        let profile = d.scenario.speed_profile();
        assert!(from > f.at_s && profile.at(from) >= 5.0, "{from}");
        assert!(profile.at(from - 0.01) < 5.0, "{from}");
        let step = (0..)
            .map(|seed| draw(seed, 600.0))
            .find(|d| d.fault_shape == FaultShape::Step && d.speed_kind == SpeedKind::Constant)
            .unwrap();
        let f = step.scenario.faults[0];
        let from = step.detectable_from_s(f.damper, 0.7, &speed).unwrap();
        assert!((from - f.at_s - 1e-3).abs() < 1e-9, "{from} vs {}", f.at_s);
        let other = DamperId::ALL[1 - f.damper.index()];
        if step.scenario.faults.len() == 1 {
            assert_eq!(step.detectable_from_s(other, 0.7, &speed), None);
        }
        let mut ramp = (0..)
            .map(|seed| draw(seed, 600.0))
            .find(|d| d.fault_shape == FaultShape::Ramp)
            .unwrap();
        let f = &mut ramp.scenario.faults[0];
        (f.at_s, f.end_s, f.ratio) = (30.0, Some(130.0), 0.4);
        let damper = f.damper;
        ramp.speed_kind = SpeedKind::Constant;
        ramp.scenario.speed = None;
        ramp.scenario.vehicle.speed_m_s = 30.0;
        ramp.scenario.duration_s = 200.0;
        let from = ramp.detectable_from_s(damper, 0.7, &speed).unwrap();
        assert!((from - 80.0).abs() < 2e-3, "{from}");
        ramp.scenario.duration_s = 70.0;
        assert_eq!(ramp.detectable_from_s(damper, 0.7, &speed), None);
    }

    #[test]
    fn the_top_speed_is_below_the_critical_speed() {
        let v = BogieParams::default();
        let nominal = Dampers::NOMINAL;
        assert_eq!(top_speed_m_s(&v, &[nominal], 55.0), 55.0);
        let failed = Dampers {
            csay_ns_per_m: 0.4 * nominal.csay_ns_per_m,
            ..nominal
        };
        let top = top_speed_m_s(&v, &[nominal, failed], 55.0);
        assert!((40.0..53.0).contains(&top), "{top}");
        assert!(growth_rate_per_s(&v, &failed, top + CRITICAL_MARGIN_M_S) < 1e-6);
        assert!(growth_rate_per_s(&v, &failed, top + CRITICAL_MARGIN_M_S + 1.0) > 1e-6);
    }

    #[test]
    fn ramp_draws_ramp_one_damper_within_the_envelope() {
        for seed in 0..30 {
            let d = ramp_draw(seed, 0.7, false);
            let s = &d.scenario;
            s.validate().unwrap_or_else(|e| panic!("seed {seed}: {e}"));
            assert_eq!(d, ramp_draw(seed, 0.7, false));
            assert_eq!(s.faults.len(), 1);
            let f = s.faults[0];
            let length = f.end_s.unwrap() - f.at_s;
            assert!((RAMP_S.0..=RAMP_S.1).contains(&length), "seed {seed}");
            assert!((FAULT_RATIO.0..=FAULT_RATIO.1).contains(&f.ratio));
            let crossing = f.at_s + length * 0.3 / (1.0 - f.ratio);
            assert!(s.duration_s > crossing, "seed {seed}");
            let top = s
                .speed_profile()
                .profile_m_s
                .iter()
                .map(|p| p[1])
                .fold(0.0, f64::max);
            assert!(top <= d.top_speed_m_s, "seed {seed}");
            let healthy = ramp_draw(seed, 0.7, true);
            assert!(healthy.scenario.faults.is_empty());
            assert_eq!(healthy.scenario.duration_s, s.duration_s);
        }
    }

    #[test]
    fn the_split_is_by_parity() {
        assert!(is_held_out(5001) && !is_held_out(5000));
    }
}
