//! The train-speed reference (issue 23 item 2): each drive's rotor speed against the speed the
//! train's own measurement (radar, GNSS, an unpowered axle) implies for it.
//!
//! **Why.** The group comparison of the adhesion methods judges each drive's load against the
//! other drives': when every drive loses adhesion at once the group moves together and nothing
//! stands out. Wheel-slide and anti-slip protection on real vehicles compare each axle's
//! speed with a *reference speed* of the vehicle instead (EN 15595, railway applications,
//! braking, wheel slide protection: the slide of an axle is its speed's departure from the
//! vehicle's reference speed). Physically, an adhering wheel rolls with the train up to a
//! small creep (the creep force grows with the relative slip velocity up to the adhesion limit,
//! Kalker; Polach, "Creep forces in simulations of traction vehicles running on adhesion
//! limit", Wear 258, 2005); past the limit the wheel no longer follows the train and its rotor
//! runs away from the train's speed, ahead of it in traction, behind it in braking, driven by
//! the motor torque the rail no longer takes. That departure, in the direction of the drive's
//! effort, is the evidence here; it needs no other drive.
//!
//! The wheel speed of drive `k` is `v_k = |omega_k| r / (G p_p)` (`omega_k` the EKF's electrical
//! speed, `p_p` the pole pairs, `G` the gear ratio motor:axle, `r` the wheel radius); its slip
//! velocity in the direction of the effort is `s_k = (v_k - v) sign(T_e,k omega_k)` with
//! `T_e,k = k_t i_q,k` the motor torque from the EKF's currents (traction: the wheel runs ahead,
//! `s > 0`; braking: it falls behind, `s > 0` again).
//!
//! **Calibration.** `v_k` is first divided by the drive's ratio `c_k` of wheel speed to train
//! speed, learnt while the drive is not flagged (a running mean over the first
//! `calibration_time_constant_s`, an exponential mean after). Wheel-slide protection
//! calibrates each axle's wheel diameter against the reference speed the same way; here the
//! ratio also takes the sensorless EKF's speed bias: its speed comes from the back-EMF
//! `Psi_pm omega`, so a flux linkage 5 % off the nominal one puts the speed 5 % off
//! (measured: 6.5 % on sampler draw 1001, far above any slip threshold). The test starts
//! `warmup_s` after the train speed appears (the EKFs lock on) and judges after a further
//! `calibration_min_s`. `s_k` is low-passed (time constant
//! `time_constant_s`, which also averages the train-speed sensor's noise) and compared with
//! `max(slip_threshold_m_s, slip_threshold_fraction * v)`; the probability is a logistic in
//! the margin, 0.5 at the threshold. Once a drive is calibrated this probability replaces the
//! adhesion method's ([`TrainSpeedCheck::update`] says why).

use serde::{Deserialize, Serialize};

use crate::ekf::EkfBank;
use crate::error::{check_in, check_non_negative, check_positive, SlipError};
use crate::model::{idx, DriveModel, DriveState};

/// Lowest and highest plausible train speed, m/s (0 to 360 km/h; a reading outside is a
/// sensor fault, refused like a non-finite current). The speed is a magnitude: the direction
/// of travel follows from the rotors'.
pub const TRAIN_SPEED_RANGE_M_S: (f64, f64) = (0.0, 100.0);

/// Checks one train-speed reading: finite and within [`TRAIN_SPEED_RANGE_M_S`].
pub fn validate_train_speed(train_speed_m_s: f64) -> Result<(), SlipError> {
    check_in(
        "train_speed_m_s",
        train_speed_m_s,
        TRAIN_SPEED_RANGE_M_S.0,
        TRAIN_SPEED_RANGE_M_S.1,
        "must be in 0..=100 m/s",
    )
}

/// Which reference the drives' slip was judged against at a step.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum SpeedReference {
    /// The other drives (the adhesion method): no train speed this step, or the train-speed
    /// test still warming up or calibrating some drive (then those drives are judged by the
    /// group).
    #[default]
    Group,
    /// The train's measured speed, every drive.
    TrainSpeed,
}

impl SpeedReference {
    /// `group` or `train_speed`, as serialised.
    pub fn name(self) -> &'static str {
        match self {
            SpeedReference::Group => "group",
            SpeedReference::TrainSpeed => "train_speed",
        }
    }
}

impl std::fmt::Display for SpeedReference {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The drives' geometry and the slip test against the train speed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct SpeedReferenceConfig {
    /// Gear ratio `G`, motor revolutions per wheel revolution.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub gear_ratio: f64,
    /// Wheel radius `r` (a 920 mm wheel: 0.46 m).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub wheel_radius_m: f64,
    /// Time constant of the low-pass on each drive's slip velocity.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub time_constant_s: f64,
    /// Slip velocity (in the direction of the effort) at which the probability is 0.5, at
    /// least; above creep (< 1 % of the speed), a worn wheel's smaller radius and the sensor's
    /// noise after the low-pass.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub slip_threshold_m_s: f64,
    /// The threshold as a fraction of the train speed, where that is larger.
    #[schemars(range(min = 0.0))]
    pub slip_threshold_fraction: f64,
    /// Time after the train speed appears (or the monitor starts) before it is used: the EKFs
    /// lock on to the rotor speed in some 50 ms.
    #[schemars(range(min = 0.0))]
    pub warmup_s: f64,
    /// Time constant of each drive's calibration (the ratio of its wheel speed to the train
    /// speed, learnt while it is not flagged).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub calibration_time_constant_s: f64,
    /// Calibration time after the warm-up before a drive is judged.
    #[schemars(range(min = 0.0))]
    pub calibration_min_s: f64,
}

impl Default for SpeedReferenceConfig {
    fn default() -> Self {
        SpeedReferenceConfig {
            gear_ratio: 4.0,
            wheel_radius_m: 0.46,
            time_constant_s: 0.01,
            slip_threshold_m_s: 0.1,
            slip_threshold_fraction: 0.02,
            warmup_s: 0.1,
            calibration_time_constant_s: 5.0,
            calibration_min_s: 0.05,
        }
    }
}

impl SpeedReferenceConfig {
    pub fn validate(&self) -> Result<(), SlipError> {
        check_positive("speed_reference.gear_ratio", self.gear_ratio)?;
        check_positive("speed_reference.wheel_radius_m", self.wheel_radius_m)?;
        check_positive("speed_reference.time_constant_s", self.time_constant_s)?;
        check_positive(
            "speed_reference.slip_threshold_m_s",
            self.slip_threshold_m_s,
        )?;
        check_non_negative(
            "speed_reference.slip_threshold_fraction",
            self.slip_threshold_fraction,
        )?;
        check_non_negative("speed_reference.warmup_s", self.warmup_s)?;
        check_positive(
            "speed_reference.calibration_time_constant_s",
            self.calibration_time_constant_s,
        )?;
        check_non_negative("speed_reference.calibration_min_s", self.calibration_min_s)
    }

    /// Wheel rim speed (m/s) of an electrical rotor speed (rad/s) with `pole_pairs`.
    pub fn wheel_speed_m_s(&self, omega_electrical_rad_s: f64, pole_pairs: f64) -> f64 {
        omega_electrical_rad_s * self.wheel_radius_m / (self.gear_ratio * pole_pairs)
    }
}

/// The per-drive state of the test: the low-passed slip velocities.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainSpeedCheck {
    config: SpeedReferenceConfig,
    /// Low-passed slip velocity in the direction of the effort per drive, m/s.
    slip_m_s: Vec<f64>,
    /// Per drive, the ratio of its wheel speed to the train speed while it adheres.
    ratio: Vec<f64>,
    /// Per drive, the steps its ratio has been learnt over.
    calibrated: Vec<u64>,
    /// Per drive, whether the last step judged it.
    judged: Vec<bool>,
    /// Steps with a train speed since it last appeared.
    steps: u64,
}

impl TrainSpeedCheck {
    pub fn new(config: SpeedReferenceConfig, n_drives: usize) -> Result<Self, SlipError> {
        config.validate()?;
        Ok(TrainSpeedCheck {
            config,
            slip_m_s: vec![0.0; n_drives],
            ratio: vec![1.0; n_drives],
            calibrated: vec![0; n_drives],
            judged: vec![false; n_drives],
            steps: 0,
        })
    }

    pub fn config(&self) -> &SpeedReferenceConfig {
        &self.config
    }

    /// The low-passed slip velocities (m/s, in the direction of each drive's effort).
    pub fn slip_m_s(&self) -> &[f64] {
        &self.slip_m_s
    }

    /// Forgets the filters (the train speed is gone: it starts afresh when it returns).
    pub fn reset(&mut self) {
        self.slip_m_s.fill(0.0);
        self.ratio.fill(1.0);
        self.calibrated.fill(0);
        self.judged.fill(false);
        self.steps = 0;
    }

    /// Per drive, whether the last step judged it (its probability is the test's).
    pub fn judged(&self) -> &[bool] {
        &self.judged
    }

    /// Per drive, the learnt ratio of its wheel speed (from the EKF) to the train speed.
    pub fn ratio(&self) -> &[f64] {
        &self.ratio
    }

    /// One step with the train speed `v` (m/s, already validated) and the bank after its step:
    /// replaces each drive's probability in `p` (the adhesion method's) by the train-speed
    /// test's once the drive is calibrated; returns whether every drive was (the reference is
    /// then the train speed, else still the group for some).
    ///
    /// Replaced, not combined: with a train speed a drive whose wheel rolls with the train
    /// adheres, whatever its torque next to the other drives'. The group comparison, combined,
    /// flagged healthy drives for thousands of steps on the torque-controlled plant (the
    /// partner of a drive being pulled back into adhesion carries less than it, draw 1017 of
    /// `sample_matrix --kind train-speed`).
    pub fn update<'a>(
        &mut self,
        bank: &EkfBank,
        train_speed_m_s: f64,
        p: impl IntoIterator<Item = &'a mut f64>,
    ) -> bool {
        let states = bank.filters().iter().map(|f| &f.x);
        self.update_states(bank.model(), states, train_speed_m_s, p)
    }

    /// [`TrainSpeedCheck::update`] on the EKF states of the step the probabilities `p` belong
    /// to: behind the fixed lag ([`crate::fixed_lag::FixedLagLine`]) the test runs on the
    /// states of the published step, so that it judges the same step as the method.
    pub fn update_states<'a, 's>(
        &mut self,
        model: &DriveModel,
        states: impl IntoIterator<Item = &'s DriveState>,
        train_speed_m_s: f64,
        p: impl IntoIterator<Item = &'a mut f64>,
    ) -> bool {
        let pole_pairs = model.params.pole_pairs;
        let k_t = model.params.torque_constant_nm_per_a();
        let c = &self.config;
        let alpha = model.dt_s / (c.time_constant_s + model.dt_s);
        let threshold = c
            .slip_threshold_m_s
            .max(c.slip_threshold_fraction * train_speed_m_s);
        // Logistic width: a quarter of the threshold (p = 0.018 at 0, 0.98 at twice it).
        let width = 0.25 * threshold;
        self.steps += 1;
        if (self.steps as f64) * model.dt_s < c.warmup_s {
            return false;
        }
        let mut all_judged = true;
        let full = (c.calibration_time_constant_s / model.dt_s).max(1.0);
        let judge_after = (c.calibration_min_s / model.dt_s).round() as u64;
        // Below 1 m/s the ratio is mostly the sensor's noise: learnt only above.
        let learn = train_speed_m_s >= 1.0;
        for (((((s, x), p), ratio), n), judged_now) in self
            .slip_m_s
            .iter_mut()
            .zip(states)
            .zip(p)
            .zip(&mut self.ratio)
            .zip(&mut self.calibrated)
            .zip(&mut self.judged)
        {
            let omega = x[idx::OMEGA];
            let (sin, cos) = x[idx::THETA].sin_cos();
            let i_q = -x[idx::I_ALPHA] * sin + x[idx::I_BETA] * cos;
            // Traction when the motor torque turns the rotor the way it turns.
            let direction = if k_t * i_q * omega >= 0.0 { 1.0 } else { -1.0 };
            let wheel = c.wheel_speed_m_s(omega.abs(), pole_pairs);
            if *n == 0 {
                if !learn {
                    all_judged = false;
                    continue;
                }
                *ratio = wheel / train_speed_m_s;
            }
            *s += alpha * ((wheel / *ratio - train_speed_m_s) * direction - *s);
            let judged = *n >= judge_after;
            *judged_now = judged;
            let q = if judged {
                1.0 / (1.0 + (-(*s - threshold) / width).exp())
            } else {
                0.0
            };
            // Learn while the drive is not flagged (else the calibration would take the slip it
            // is there to show): by this test once judged, by the adhesion method before.
            let flagged = if judged { q } else { *p } > 0.5;
            if learn && !flagged {
                *n += 1;
                let w = 1.0 / (*n as f64).min(full);
                *ratio += w * (wheel / train_speed_m_s - *ratio);
            }
            if judged {
                // The adhesion method's flag stands where the wheel has left the train by half
                // the threshold in the direction of the effort (its torque evidence comes
                // first; the departure confirms it).
                let half = 0.5 * threshold;
                let confirmed = 1.0 / (1.0 + (-(*s - half) / (0.25 * half)).exp());
                *p = q.max(p.min(confirmed));
            } else {
                all_judged = false;
            }
        }
        all_judged
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_range() {
        assert_eq!(SpeedReference::Group.to_string(), "group");
        assert_eq!(
            toml::Value::try_from(SpeedReference::TrainSpeed)
                .unwrap()
                .as_str(),
            Some("train_speed")
        );
        assert!(validate_train_speed(0.0).is_ok() && validate_train_speed(100.0).is_ok());
        for bad in [-0.1, 100.1, f64::NAN, f64::INFINITY] {
            let e = validate_train_speed(bad).unwrap_err().to_string();
            assert!(e.contains("train_speed_m_s"), "{e}");
        }
        let c = SpeedReferenceConfig {
            wheel_radius_m: 0.0,
            ..SpeedReferenceConfig::default()
        };
        assert!(c.validate().is_err());
        // 200 rad/s electrical, 4 pole pairs, gear 4, r 0.46: 5.75 m/s.
        let v = SpeedReferenceConfig::default().wheel_speed_m_s(200.0, 4.0);
        assert!((v - 5.75).abs() < 1e-12);
    }
}
