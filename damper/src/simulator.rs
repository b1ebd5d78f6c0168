//! The plant: the 17-state model driven by the track, with damper faults and sensor noise,
//! giving the five sensor signals and the ground truth beside them.

use nalgebra::Vector2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::Deserialize;

use crate::expm::{discretize, Discrete};
use crate::model::{BogieModel, Matrix5, Vector17, Vector5, OUTPUT_NAMES};
use crate::params::{non_negative, positive, Dampers};
use crate::scenario::DamperScenario;
use crate::track::TrackGenerator;
use crate::DamperError;

/// One 1 kHz sample of the five sensors (paper fig. 1, eq. 4), what a real bogie gives.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct BogieSample {
    /// Lateral acceleration of the leading wheelset `y_w1''` (m/s^2).
    pub wheelset1_accel_m_s2: f64,
    /// Lateral acceleration of the trailing wheelset `y_w2''` (m/s^2).
    pub wheelset2_accel_m_s2: f64,
    /// Lateral acceleration of the bogie frame `y_b''` (m/s^2).
    pub bogie_accel_m_s2: f64,
    /// Yaw rate of the bogie frame `psi_b'` (rad/s).
    pub bogie_yaw_rate_rad_s: f64,
    /// Lateral acceleration of the body above the bogie `y_bd''` (m/s^2).
    pub body_accel_m_s2: f64,
}

impl BogieSample {
    /// The measurement vector `y` in the order of eq. 4.
    pub fn to_vector(&self) -> Vector5 {
        Vector5::new(
            self.wheelset1_accel_m_s2,
            self.wheelset2_accel_m_s2,
            self.bogie_accel_m_s2,
            self.bogie_yaw_rate_rad_s,
            self.body_accel_m_s2,
        )
    }

    pub fn from_vector(y: &Vector5) -> Self {
        BogieSample {
            wheelset1_accel_m_s2: y[0],
            wheelset2_accel_m_s2: y[1],
            bogie_accel_m_s2: y[2],
            bogie_yaw_rate_rad_s: y[3],
            body_accel_m_s2: y[4],
        }
    }

    /// Every field finite, else an error naming the first bad one.
    pub fn validate(&self) -> Result<Vector5, DamperError> {
        let y = self.to_vector();
        for (i, v) in y.iter().enumerate() {
            if !v.is_finite() {
                return Err(DamperError::InvalidSample {
                    field: OUTPUT_NAMES[i],
                    value: *v,
                });
            }
        }
        Ok(y)
    }
}

/// Standard deviations of the sensor noise (white, independent).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SensorNoise {
    /// Each of the four lateral accelerometers (m/s^2).
    pub accel_std_m_s2: f64,
    /// The bogie yaw-rate gyro (rad/s).
    pub gyro_std_rad_s: f64,
}

impl Default for SensorNoise {
    /// A 100 ug/sqrt(Hz) accelerometer and a 0.01 deg/s/sqrt(Hz) gyro over 500 Hz bandwidth:
    /// roughly 0.02 m/s^2 and 0.004 rad/s.
    fn default() -> Self {
        SensorNoise {
            accel_std_m_s2: 0.02,
            gyro_std_rad_s: 0.004,
        }
    }
}

impl SensorNoise {
    pub fn validate(&self) -> Result<(), DamperError> {
        positive("accel_std_m_s2", self.accel_std_m_s2)?;
        positive("gyro_std_rad_s", self.gyro_std_rad_s)
    }

    pub fn std_vector(&self) -> Vector5 {
        let (a, g) = (self.accel_std_m_s2, self.gyro_std_rad_s);
        Vector5::new(a, a, a, g, a)
    }

    /// `Q_v = diag(sigma^2)`.
    pub fn covariance(&self) -> Matrix5 {
        Matrix5::from_diagonal(&self.std_vector().map(|s| s * s))
    }
}

/// Which damper a fault acts on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DamperId {
    Csy,
    Csay,
}

impl DamperId {
    pub const ALL: [DamperId; 2] = [DamperId::Csy, DamperId::Csay];

    pub fn name(self) -> &'static str {
        match self {
            DamperId::Csy => "csy",
            DamperId::Csay => "csay",
        }
    }

    pub fn index(self) -> usize {
        match self {
            DamperId::Csy => 0,
            DamperId::Csay => 1,
        }
    }
}

/// Shape of a fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FaultKind {
    /// Jumps to `ratio` at `at_s`.
    Step,
    /// Linear from its value at `at_s` to `ratio` at `end_s`.
    Ramp,
}

/// A damper fault: the coefficient becomes `ratio` times the scenario's initial value.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DamperFault {
    pub damper: DamperId,
    pub kind: FaultKind,
    pub at_s: f64,
    #[serde(default)]
    pub end_s: Option<f64>,
    pub ratio: f64,
}

impl DamperFault {
    pub fn validate(&self) -> Result<(), DamperError> {
        non_negative("faults.at_s", self.at_s)?;
        positive("faults.ratio", self.ratio)?;
        if self.kind == FaultKind::Ramp {
            let end = self.end_s.ok_or(DamperError::InvalidParameter {
                field: "faults.end_s",
                value: f64::NAN,
                reason: "a ramp needs end_s",
            })?;
            if !(end.is_finite() && end > self.at_s) {
                return Err(DamperError::InvalidParameter {
                    field: "faults.end_s",
                    value: end,
                    reason: "must be after at_s",
                });
            }
        }
        Ok(())
    }
}

/// The true dampers at time `t`: faults applied in the order given.
pub fn dampers_at(initial: &Dampers, faults: &[DamperFault], t_s: f64) -> Dampers {
    let mut ratio = [1.0, 1.0];
    for f in faults.iter().filter(|f| t_s >= f.at_s) {
        let r = &mut ratio[f.damper.index()];
        *r = match (f.kind, f.end_s) {
            (FaultKind::Ramp, Some(end)) => {
                *r + (f.ratio - *r) * ((t_s - f.at_s) / (end - f.at_s)).min(1.0)
            }
            _ => f.ratio,
        };
    }
    Dampers {
        csy_ns_per_m: initial.csy_ns_per_m * ratio[0],
        csay_ns_per_m: initial.csay_ns_per_m * ratio[1],
    }
}

/// Ground truth beside each sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BogieTruth {
    pub time_s: f64,
    pub dampers: Dampers,
    /// The plant state after the step.
    pub state: Vector17,
    /// The track velocities held over the step (m/s).
    pub track_velocity_m_s: Vector2<f64>,
}

/// Simulates a scenario: `x_{k+1} = Phi(theta_k) x_k + Gamma(theta_k) beta_k`,
/// `y_{k+1} = H x_{k+1} + v`, seeded from the scenario.
#[derive(Debug, Clone)]
pub struct BogieSimulator {
    plant: BogieModel,
    scenario: DamperScenario,
    disc: Discrete,
    disc_dampers: Dampers,
    x: Vector17,
    track: TrackGenerator,
    noise_std: Vector5,
    h: crate::model::Matrix5x17,
    rng: ChaCha8Rng,
    step: usize,
    n_steps: usize,
    last: Option<(BogieSample, BogieTruth)>,
}

impl BogieSimulator {
    pub fn new(scenario: &DamperScenario) -> Result<Self, DamperError> {
        scenario.validate()?;
        let plant = BogieModel::new(&scenario.vehicle, 0.0)?;
        let mut rng = ChaCha8Rng::seed_from_u64(scenario.seed);
        let track = TrackGenerator::new(
            &scenario.track,
            scenario.vehicle.speed_m_s,
            scenario.vehicle.wheelset_delay_s(),
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
            x: Vector17::zeros(),
            track,
            noise_std: scenario.sensors.std_vector(),
            rng,
            step: 0,
            n_steps: scenario.n_steps(),
            scenario: scenario.clone(),
            last: None,
        })
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
        if d != self.disc_dampers {
            // Only during faults; the exponential of a valid model cannot fail.
            if let Ok(disc) = discretize(&self.plant.a_matrix(&d), &self.plant.g_matrix(), dt) {
                self.disc = disc;
                self.disc_dampers = d;
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
            BogieSample::from_vector(&y),
            BogieTruth {
                time_s: self.step as f64 * dt,
                dampers: d,
                state: self.x,
                track_velocity_m_s: beta,
            },
        ));
        self.last.as_ref().map(|(s, t)| (s, t))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fault_schedule_steps_and_ramps() {
        let faults = [
            DamperFault {
                damper: DamperId::Csay,
                kind: FaultKind::Step,
                at_s: 30.0,
                end_s: None,
                ratio: 0.4,
            },
            DamperFault {
                damper: DamperId::Csy,
                kind: FaultKind::Ramp,
                at_s: 60.0,
                end_s: Some(120.0),
                ratio: 0.6,
            },
        ];
        let n = Dampers::NOMINAL;
        let at = |t| dampers_at(&n, &faults, t);
        assert_eq!(at(29.999), n);
        assert_eq!(at(30.0).csay_ns_per_m, 0.4 * 160e3);
        assert_eq!(at(60.0).csy_ns_per_m, 16e3);
        assert!((at(90.0).csy_ns_per_m - 0.8 * 16e3).abs() < 1e-9);
        assert!((at(500.0).csy_ns_per_m - 0.6 * 16e3).abs() < 1e-9);
        assert_eq!(at(500.0).csay_ns_per_m, 0.4 * 160e3);
    }

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

    #[test]
    fn nan_sample_is_rejected_by_field_name() {
        let s = BogieSample {
            bogie_yaw_rate_rad_s: f64::NAN,
            ..BogieSample::default()
        };
        assert!(matches!(
            s.validate(),
            Err(DamperError::InvalidSample {
                field: "bogie_yaw_rate_rad_s",
                ..
            })
        ));
    }
}
