//! What the five sensors of a bogie give (paper fig. 1, eq. 4): one sample, and the noise
//! of their channels. The live input of [`crate::DamperMonitor`] and the output of the
//! simulator.

use serde::{Deserialize, Serialize};

use crate::model::{Matrix5, Vector5, OUTPUT_NAMES};
use crate::params::{positive, DEFAULT_SPEED_M_S};
use crate::DamperError;

/// No train in service runs faster (540 km/h): a larger speed is a broken input (m/s).
pub const MAX_SPEED_M_S: f64 = 150.0;

/// One 1 kHz sample of the five sensors (paper fig. 1, eq. 4), what a real bogie gives, and
/// the vehicle's forward speed at that moment.
#[derive(Debug, Clone, Copy, PartialEq)]
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
    /// Forward speed of the vehicle `v` (m/s), in `0..=MAX_SPEED_M_S`.
    pub speed_m_s: f64,
    /// The measured mass of the body above this bogie `m_bd` (kg): the load its secondary
    /// suspension carries (air-spring pressure times area over `g`), half the body of a
    /// two-bogie car, the quantity of [`crate::BogieParams::half_body_mass_kg`]. Passengers
    /// move it from tare to crush load (0.85-1.4 times the design value); the filters'
    /// model, gains and settling follow it. Within
    /// [`crate::params::HALF_BODY_MASS_RATIO`] of the design value (else the sample is
    /// refused, `mass_out_of_range`). `None`: the design value is assumed.
    pub half_body_mass_kg: Option<f64>,
}

impl Default for BogieSample {
    /// All sensors zero at the paper's speed.
    fn default() -> Self {
        BogieSample::from_vector(&Vector5::zeros(), DEFAULT_SPEED_M_S)
    }
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

    pub fn from_vector(y: &Vector5, speed_m_s: f64) -> Self {
        BogieSample {
            wheelset1_accel_m_s2: y[0],
            wheelset2_accel_m_s2: y[1],
            bogie_accel_m_s2: y[2],
            bogie_yaw_rate_rad_s: y[3],
            body_accel_m_s2: y[4],
            speed_m_s,
            half_body_mass_kg: None,
        }
    }

    /// Every sensor finite, the speed in `0..=MAX_SPEED_M_S` and the body mass, if given,
    /// finite and positive (its range about the design value is the filter's check,
    /// `params::checked_half_body_mass_kg`), else an error naming the first bad field.
    pub fn validate(&self) -> Result<Vector5, DamperError> {
        if !(0.0..=MAX_SPEED_M_S).contains(&self.speed_m_s) {
            return Err(DamperError::InvalidSample {
                field: "speed_m_s",
                value: self.speed_m_s,
            });
        }
        if let Some(m) = self
            .half_body_mass_kg
            .filter(|m| !(m.is_finite() && *m > 0.0))
        {
            return Err(DamperError::InvalidSample {
                field: "half_body_mass_kg",
                value: m,
            });
        }
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

/// Plausible magnitudes of a bogie's sensors: a sample beyond them is refused
/// (`out_of_range`), not estimated. Data scaled by 1000 (mm/s^2, mrad/s) once read as a
/// damper at 10 % of its health: a false `degraded`. The service's `[bogie]
/// max_abs_accel_m_s2` / `max_abs_yaw_rate_rad_s`, `railmon analyze damper`'s defaults.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SampleRanges {
    /// Each lateral acceleration, m/s^2.
    pub max_abs_accel_m_s2: f64,
    /// The yaw rate, rad/s.
    pub max_abs_yaw_rate_rad_s: f64,
}

impl Default for SampleRanges {
    fn default() -> Self {
        SampleRanges {
            max_abs_accel_m_s2: 50.0,
            max_abs_yaw_rate_rad_s: 5.0,
        }
    }
}

impl SampleRanges {
    /// The checks the service refuses a bogie sample by, in its order: every value finite
    /// (`not_finite`), the speed in `0..=MAX_SPEED_M_S` (`speed_out_of_range`), a given body
    /// mass positive (`mass_out_of_range`), every sensor within its magnitude
    /// (`out_of_range`); [`DamperError::reason`] names which.
    pub fn check(&self, s: &BogieSample) -> Result<(), DamperError> {
        let (max_a, max_r) = (self.max_abs_accel_m_s2, self.max_abs_yaw_rate_rad_s);
        let (accel, yaw) = ("max_abs_accel_m_s2", "max_abs_yaw_rate_rad_s");
        let channels = [
            ("wheelset1_accel_m_s2", s.wheelset1_accel_m_s2, max_a, accel),
            ("wheelset2_accel_m_s2", s.wheelset2_accel_m_s2, max_a, accel),
            ("bogie_accel_m_s2", s.bogie_accel_m_s2, max_a, accel),
            ("bogie_yaw_rate_rad_s", s.bogie_yaw_rate_rad_s, max_r, yaw),
            ("body_accel_m_s2", s.body_accel_m_s2, max_a, accel),
        ];
        let speed = ("speed_m_s", s.speed_m_s);
        let mass = s.half_body_mass_kg.map(|m| ("half_body_mass_kg", m));
        let all = channels
            .iter()
            .map(|c| (c.0, c.1))
            .chain([speed])
            .chain(mass);
        if let Some((field, value)) = all.into_iter().find(|(_, v)| !v.is_finite()) {
            return Err(DamperError::InvalidSample { field, value });
        }
        s.validate()?;
        match channels.into_iter().find(|c| c.1.abs() > c.2) {
            Some((field, value, max, key)) => Err(DamperError::SampleOutOfRange {
                field,
                value,
                max,
                key,
            }),
            None => Ok(()),
        }
    }
}

/// Standard deviations of the sensor noise (white, independent).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct SensorNoise {
    /// Each of the four lateral accelerometers (m/s^2).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub accel_std_m_s2: f64,
    /// The bogie yaw-rate gyro (rad/s).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_refuse_in_the_service_order_with_its_reasons() {
        let ranges = SampleRanges::default();
        let reason = |s: BogieSample| ranges.check(&s).unwrap_err().reason();
        let ok = BogieSample::default();
        assert!(ranges.check(&ok).is_ok());
        let nan_speed = BogieSample {
            speed_m_s: f64::NAN,
            ..ok
        };
        assert_eq!(reason(nan_speed), Some("not_finite"));
        let fast = BogieSample {
            speed_m_s: 200.0,
            body_accel_m_s2: 1e3,
            ..ok
        };
        assert_eq!(reason(fast), Some("speed_out_of_range"));
        let mm = BogieSample {
            bogie_yaw_rate_rad_s: 6.0,
            ..ok
        };
        assert_eq!(reason(mm), Some("out_of_range"));
        for (m, want) in [(f64::NAN, "not_finite"), (-13e3, "mass_out_of_range")] {
            let s = BogieSample {
                half_body_mass_kg: Some(m),
                ..ok
            };
            assert_eq!(reason(s), Some(want), "{m}");
        }
        let msg = ranges.check(&mm).unwrap_err().to_string();
        assert!(
            msg.contains("bogie_yaw_rate_rad_s") && msg.contains("max_abs_yaw_rate_rad_s"),
            "{msg}"
        );
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
        for speed_m_s in [f64::NAN, -0.1, f64::INFINITY, MAX_SPEED_M_S * 1.01] {
            let s = BogieSample {
                speed_m_s,
                ..BogieSample::default()
            };
            assert!(matches!(
                s.validate(),
                Err(DamperError::InvalidSample {
                    field: "speed_m_s",
                    ..
                })
            ));
        }
        let standstill = BogieSample {
            speed_m_s: 0.0,
            ..BogieSample::default()
        };
        assert!(standstill.validate().is_ok());
    }
}
