//! The plant: the 17-state model driven by the track, with damper faults and sensor noise,
//! giving the five sensor signals and the ground truth beside them.

use nalgebra::Vector2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use crate::expm::{discretize, Discrete};
use crate::faults::dampers_at;
use crate::model::{BogieModel, Vector17, Vector5};
use crate::params::Dampers;
use crate::sample::BogieSample;
use crate::scenario::DamperScenario;
use crate::speed_profile::SpeedProfile;
use crate::track::TrackGenerator;
use crate::DamperError;

/// Ground truth beside each sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BogieTruth {
    pub time_s: f64,
    pub dampers: Dampers,
    /// The plant state after the step.
    pub state: Vector17,
    /// The track velocities held over the step (m/s).
    pub track_velocity_m_s: Vector2<f64>,
    /// The plant's body mass above the bogie over the step (kg; `[load]`).
    pub half_body_mass_kg: f64,
}

/// Simulates a scenario: `x_{k+1} = Phi(theta_k) x_k + Gamma(theta_k) beta_k`,
/// `y_{k+1} = H x_{k+1} + v`, seeded from the scenario.
#[derive(Debug, Clone)]
pub struct BogieSimulator {
    plant: BogieModel,
    scenario: DamperScenario,
    disc: Discrete,
    disc_dampers: Dampers,
    disc_speed_m_s: f64,
    disc_mass_kg: f64,
    speed: SpeedProfile,
    /// The speed the plant runs at and the samples carry (m/s): the profile's, held while
    /// within [`SPEED_HOLD_RELATIVE`] of it.
    held_speed_m_s: f64,
    x: Vector17,
    track: TrackGenerator,
    noise_std: Vector5,
    h: crate::model::Matrix5x17,
    rng: ChaCha8Rng,
    step: usize,
    n_steps: usize,
    last: Option<(BogieSample, BogieTruth)>,
    /// Whether the samples carry the plant's body mass (`BogieSample::half_body_mass_kg`).
    gives_mass: bool,
}

impl BogieSimulator {
    pub fn new(scenario: &DamperScenario) -> Result<Self, DamperError> {
        scenario.validate()?;
        let speed = scenario.speed_profile();
        let mut vehicle = scenario.vehicle;
        vehicle.speed_m_s = plant_speed(speed.at(0.0));
        vehicle.half_body_mass_kg = scenario.half_body_mass_kg_at(0.0);
        let plant = BogieModel::new(&vehicle, 0.0)?;
        let mut rng = ChaCha8Rng::seed_from_u64(scenario.seed);
        let track = TrackGenerator::new(
            &scenario.track,
            vehicle.speed_m_s,
            vehicle.wheelset_delay_s(),
            scenario.dt_s,
            &mut rng,
        )?;
        let d0 = dampers_at(&scenario.dampers, &scenario.faults, 0.0);
        let disc = discretize(&plant.a_matrix(&d0), &plant.g_matrix(), scenario.dt_s)?;
        Ok(BogieSimulator {
            h: plant.h_matrix(),
            plant,
            disc,
            disc_dampers: d0,
            disc_speed_m_s: vehicle.speed_m_s,
            disc_mass_kg: vehicle.half_body_mass_kg,
            held_speed_m_s: speed.at(0.0),
            speed,
            x: Vector17::zeros(),
            track,
            noise_std: scenario.sensors.std_vector(),
            rng,
            step: 0,
            n_steps: scenario.n_steps(),
            scenario: scenario.clone(),
            last: None,
            gives_mass: scenario.load.measured,
        })
    }

    /// Whether the samples carry the plant's body mass above the bogie as the measured load
    /// (`BogieSample::half_body_mass_kg`; from the start, as a real train's air-spring
    /// pressure does; default: the scenario's `load.measured`). `false` withholds it (`None`:
    /// the particles carry the mass, or with `rbpf.unmeasured_mass` off the filter assumes its
    /// design mass), to measure what the input is worth. Draws no random number: the samples
    /// are otherwise the same.
    pub fn with_mass_input(mut self, gives_mass: bool) -> Self {
        self.gives_mass = gives_mass;
        self
    }

    pub fn n_steps(&self) -> usize {
        self.n_steps
    }

    /// The next sample and its truth, or `None` after `n_steps`.
    pub fn step(&mut self) -> Option<(&BogieSample, &BogieTruth)> {
        if self.step >= self.n_steps {
            return None;
        }
        let dt = self.scenario.dt_s;
        let t_start = self.step as f64 * dt;
        let d = dampers_at(&self.scenario.dampers, &self.scenario.faults, t_start);
        // The speed over the step is the profile's at its start (held, as the track input),
        // and held over the next steps while the profile stays within `SPEED_HOLD_RELATIVE`
        // of it: the plant then runs at exactly the speed its samples carry.
        let profile_m_s = self.speed.at(t_start);
        if (profile_m_s - self.held_speed_m_s).abs() > SPEED_HOLD_RELATIVE * self.held_speed_m_s {
            self.held_speed_m_s = profile_m_s;
        }
        let speed_m_s = self.held_speed_m_s;
        let v = plant_speed(speed_m_s);
        // The load changes only at a stop (`[load] changes_kg`, checked by the scenario).
        let mass_kg = self.scenario.half_body_mass_kg_at(t_start);
        if d != self.disc_dampers || v != self.disc_speed_m_s || mass_kg != self.disc_mass_kg {
            // Only during faults, speed and load changes; the exponential of a valid model
            // (positive speed, mass and dampers) cannot fail.
            let rediscretised = self
                .plant
                .set_speed(v)
                .and_then(|_| self.plant.set_half_body_mass_kg(mass_kg))
                .and_then(|_| discretize(&self.plant.a_matrix(&d), &self.plant.g_matrix(), dt));
            if let Ok(disc) = rediscretised {
                self.disc = disc;
                self.disc_dampers = d;
                self.disc_speed_m_s = v;
                self.disc_mass_kg = mass_kg;
                self.h = self.plant.h_matrix();
            }
        }
        let beta = self.track.next(&mut self.rng);
        self.x = self.disc.phi * self.x + self.disc.gamma * beta;
        let noise = self
            .noise_std
            .map(|s| s * self.rng.sample::<f64, _>(StandardNormal));
        let y = self.h * self.x + noise;
        self.step += 1;
        self.last = Some((
            BogieSample {
                half_body_mass_kg: self
                    .gives_mass
                    .then_some(self.plant.params().half_body_mass_kg),
                ..BogieSample::from_vector(&y, speed_m_s)
            },
            BogieTruth {
                time_s: self.step as f64 * dt,
                dampers: d,
                state: self.x,
                track_velocity_m_s: beta,
                half_body_mass_kg: self.plant.params().half_body_mass_kg,
            },
        ));
        self.last.as_ref().map(|(s, t)| (s, t))
    }
}

/// How far (relative) the speed profile may move from the speed the plant runs at before the
/// plant takes the new one. Each new speed costs an exponential of the 19 x 19 augmented
/// matrix (~10 us): taken every step of an accelerating or braking profile it was 10 % of
/// `railmon analyze damper`'s CPU on `damper-speed-profile` (issue 28). Held within 0.1 %
/// (3 cm/s at 30 m/s, finer than a wheel-speed sensor's resolution), the plant and the samples
/// still agree exactly; only the scenario's profile is followed in steps of at most 0.1 %.
const SPEED_HOLD_RELATIVE: f64 = 1e-3;

/// The creep forces have `1 / v`: below this speed (standstill) the plant is simulated at it
/// (the wheelsets' lateral and yaw velocities are then pinned to the rail by creep damping of
/// 1.6e5/s, which the exact discretisation handles); the samples carry the true speed.
const PLANT_MIN_SPEED_M_S: f64 = 0.1;

fn plant_speed(speed_m_s: f64) -> f64 {
    speed_m_s.max(PLANT_MIN_SPEED_M_S)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_same_samples() {
        let text = include_str!("../../config/scenarios/damper-spectral.toml");
        let mut s = DamperScenario::from_toml_str(text).unwrap();
        s.duration_s = 0.5;
        let run = |s: &DamperScenario| {
            let mut sim = BogieSimulator::new(s).unwrap();
            let mut out = vec![];
            while let Some((y, _)) = sim.step() {
                out.push(*y);
            }
            out
        };
        let a = run(&s);
        assert_eq!(a.len(), 500);
        assert_eq!(a, run(&s));
        s.seed += 1;
        assert_ne!(a, run(&s));
    }
}
