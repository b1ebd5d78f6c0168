//! Physical parameters of the plan-view half vehicle (paper appendix), as a validated value.

use serde::{Deserialize, Serialize};

use crate::DamperError;

/// The two damping coefficients the filters estimate (`theta = [C_sy, C_say]`, section 2).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Dampers {
    /// Secondary lateral damping per bogie `C_sy` (N s/m).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub csy_ns_per_m: f64,
    /// Secondary anti-yaw damping per bogie `C_say` (N s/m).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub csay_ns_per_m: f64,
}

impl Dampers {
    /// Paper appendix: `C_sy = 16 kN s/m`, `C_say = 160 kN s/m`.
    pub const NOMINAL: Dampers = Dampers {
        csy_ns_per_m: 16e3,
        csay_ns_per_m: 160e3,
    };

    /// Both coefficients must be finite and positive (they are divided by and logged).
    pub fn validate(&self) -> Result<(), DamperError> {
        positive("csy_ns_per_m", self.csy_ns_per_m)?;
        positive("csay_ns_per_m", self.csay_ns_per_m)
    }

    /// `[ln C_sy, ln C_say]`: the coordinates the Liu-West kernel works in (seed notes: the
    /// coefficients are positive, so the kernel acts on their logarithms).
    pub fn ln(&self) -> [f64; 2] {
        [self.csy_ns_per_m.ln(), self.csay_ns_per_m.ln()]
    }

    /// Inverse of [`Dampers::ln`].
    pub fn from_ln(ln: [f64; 2]) -> Dampers {
        Dampers {
            csy_ns_per_m: ln[0].exp(),
            csay_ns_per_m: ln[1].exp(),
        }
    }
}

impl Default for Dampers {
    fn default() -> Self {
        Dampers::NOMINAL
    }
}

/// The paper's forward speed `v` (appendix, 45.3 m/s): the vehicle's speed when nothing
/// says otherwise (a scenario without `[speed]`, a recording without a `speed_m_s` column).
pub const DEFAULT_SPEED_M_S: f64 = 45.3;

/// The measured body mass above a bogie ([`crate::BogieSample::half_body_mass_kg`]) a filter
/// takes, as a ratio of the design value ([`BogieParams::half_body_mass_kg`]): tare is about
/// 0.8-0.9 of a design (half-laden) mass and crush load 1.2-1.4, so a reading outside
/// 0.7-1.6 is a broken load signal (a failed air-spring pressure sensor reads 0 or full
/// scale), refused with the field and value rather than read as a damper fault.
pub const HALF_BODY_MASS_RATIO: std::ops::RangeInclusive<f64> = 0.7..=1.6;

/// The measured body mass `measured_kg`, if any, checked against the design mass
/// `design_kg` ([`HALF_BODY_MASS_RATIO`]); without one, the design mass.
pub fn checked_half_body_mass_kg(
    design_kg: f64,
    measured_kg: Option<f64>,
) -> Result<f64, DamperError> {
    match measured_kg {
        None => Ok(design_kg),
        Some(m) if HALF_BODY_MASS_RATIO.contains(&(m / design_kg)) => Ok(m),
        Some(value) => Err(DamperError::InvalidSample {
            field: "half_body_mass_kg",
            value,
        }),
    }
}

/// Everything in equations (1) except the two dampers. Defaults are the paper's appendix;
/// the conicity, which the paper does not print, defaults to 0.15 (seed notes).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct BogieParams {
    /// `m_w`, each wheelset (kg).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub wheelset_mass_kg: f64,
    /// `I_w`, wheelset yaw inertia (kg m^2).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub wheelset_yaw_inertia_kg_m2: f64,
    /// `m_b` (kg).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub bogie_mass_kg: f64,
    /// `I_b` (kg m^2).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub bogie_yaw_inertia_kg_m2: f64,
    /// `m_bd`, half of the body mass (kg): the design (configured) load of the body above
    /// one bogie. A sample's measured load ([`crate::BogieSample::half_body_mass_kg`])
    /// replaces it in the filters.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub half_body_mass_kg: f64,
    /// `K_y`, primary lateral stiffness per wheelset (N/m).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub primary_lateral_stiffness_n_per_m: f64,
    /// `K_x`, primary longitudinal stiffness per wheelset (N/m).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub primary_longitudinal_stiffness_n_per_m: f64,
    /// `K_sy`, secondary lateral stiffness per bogie (N/m).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub secondary_lateral_stiffness_n_per_m: f64,
    /// `K_sry`, secondary lateral end stiffness (in series with `C_sy`) (N/m).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub secondary_end_stiffness_n_per_m: f64,
    /// `f_11`, longitudinal creep coefficient (N).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub longitudinal_creep_n: f64,
    /// `f_22`, lateral creep coefficient (N).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub lateral_creep_n: f64,
    /// `a`, semi wheelbase (m).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub semi_wheelbase_m: f64,
    /// `l`, half gauge (m).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub half_gauge_m: f64,
    /// `lambda`, effective conicity (dimensionless).
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = 1.0))]
    pub conicity: f64,
    /// `v`, forward speed (m/s). The filters take the measured speed of each sample
    /// ([`crate::BogieSample::speed_m_s`]); this one anchors their speed grid.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub speed_m_s: f64,
    /// `r_0`, rolling radius (m).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub wheel_radius_m: f64,
    /// `l_bw`, semi bogie width: the anti-yaw dampers' lever arm (m).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub semi_bogie_width_m: f64,
}

impl Default for BogieParams {
    fn default() -> Self {
        BogieParams {
            wheelset_mass_kg: 1250.0,
            wheelset_yaw_inertia_kg_m2: 700.0,
            bogie_mass_kg: 2580.0,
            bogie_yaw_inertia_kg_m2: 2160.0,
            half_body_mass_kg: 13000.0,
            primary_lateral_stiffness_n_per_m: 5000e3,
            primary_longitudinal_stiffness_n_per_m: 9726e3,
            secondary_lateral_stiffness_n_per_m: 242e3,
            secondary_end_stiffness_n_per_m: 2420e3,
            longitudinal_creep_n: 10e6,
            lateral_creep_n: 10e6,
            semi_wheelbase_m: 1.3,
            half_gauge_m: 0.717,
            conicity: 0.15,
            speed_m_s: DEFAULT_SPEED_M_S,
            wheel_radius_m: 0.455,
            semi_bogie_width_m: 1.3,
        }
    }
}

impl BogieParams {
    /// Every parameter must be finite and strictly positive; the conicity at most 1 (profiles
    /// seen in service are 0.05-0.4, anything near 1 is a typo).
    pub fn validate(&self) -> Result<(), DamperError> {
        let fields = [
            ("wheelset_mass_kg", self.wheelset_mass_kg),
            (
                "wheelset_yaw_inertia_kg_m2",
                self.wheelset_yaw_inertia_kg_m2,
            ),
            ("bogie_mass_kg", self.bogie_mass_kg),
            ("bogie_yaw_inertia_kg_m2", self.bogie_yaw_inertia_kg_m2),
            ("half_body_mass_kg", self.half_body_mass_kg),
            (
                "primary_lateral_stiffness_n_per_m",
                self.primary_lateral_stiffness_n_per_m,
            ),
            (
                "primary_longitudinal_stiffness_n_per_m",
                self.primary_longitudinal_stiffness_n_per_m,
            ),
            (
                "secondary_lateral_stiffness_n_per_m",
                self.secondary_lateral_stiffness_n_per_m,
            ),
            (
                "secondary_end_stiffness_n_per_m",
                self.secondary_end_stiffness_n_per_m,
            ),
            ("longitudinal_creep_n", self.longitudinal_creep_n),
            ("lateral_creep_n", self.lateral_creep_n),
            ("semi_wheelbase_m", self.semi_wheelbase_m),
            ("half_gauge_m", self.half_gauge_m),
            ("conicity", self.conicity),
            ("speed_m_s", self.speed_m_s),
            ("wheel_radius_m", self.wheel_radius_m),
            ("semi_bogie_width_m", self.semi_bogie_width_m),
        ];
        for (field, value) in fields {
            positive(field, value)?;
        }
        if self.conicity > 1.0 {
            return Err(DamperError::InvalidParameter {
                field: "conicity",
                value: self.conicity,
                reason: "must be at most 1",
            });
        }
        Ok(())
    }

    /// Time the trailing wheelset lags the leading one on the same track: `2a / v` (s).
    pub fn wheelset_delay_s(&self) -> f64 {
        2.0 * self.semi_wheelbase_m / self.speed_m_s
    }
}

/// Error unless `value` is finite and `> 0`.
pub(crate) fn positive(field: &'static str, value: f64) -> Result<(), DamperError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(DamperError::InvalidParameter {
            field,
            value,
            reason: "must be finite and positive",
        })
    }
}

/// Error unless `value` is finite and `>= 0`.
pub(crate) fn non_negative(field: &'static str, value: f64) -> Result<(), DamperError> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(DamperError::InvalidParameter {
            field,
            value,
            reason: "must be finite and non-negative",
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_the_wheelset_delay_is_57_ms() {
        BogieParams::default().validate().unwrap();
        Dampers::NOMINAL.validate().unwrap();
        assert!((BogieParams::default().wheelset_delay_s() - 0.057_395).abs() < 1e-5);
    }

    /// One test per parameter: each invalid value is rejected and the error names the field.
    #[test]
    fn each_invalid_parameter_is_rejected_by_name() {
        type Setter = fn(&mut BogieParams, f64);
        let setters: [(&str, Setter); 17] = [
            ("wheelset_mass_kg", |p, v| p.wheelset_mass_kg = v),
            ("wheelset_yaw_inertia_kg_m2", |p, v| {
                p.wheelset_yaw_inertia_kg_m2 = v
            }),
            ("bogie_mass_kg", |p, v| p.bogie_mass_kg = v),
            ("bogie_yaw_inertia_kg_m2", |p, v| {
                p.bogie_yaw_inertia_kg_m2 = v
            }),
            ("half_body_mass_kg", |p, v| p.half_body_mass_kg = v),
            ("primary_lateral_stiffness_n_per_m", |p, v| {
                p.primary_lateral_stiffness_n_per_m = v
            }),
            ("primary_longitudinal_stiffness_n_per_m", |p, v| {
                p.primary_longitudinal_stiffness_n_per_m = v
            }),
            ("secondary_lateral_stiffness_n_per_m", |p, v| {
                p.secondary_lateral_stiffness_n_per_m = v
            }),
            ("secondary_end_stiffness_n_per_m", |p, v| {
                p.secondary_end_stiffness_n_per_m = v
            }),
            ("longitudinal_creep_n", |p, v| p.longitudinal_creep_n = v),
            ("lateral_creep_n", |p, v| p.lateral_creep_n = v),
            ("semi_wheelbase_m", |p, v| p.semi_wheelbase_m = v),
            ("half_gauge_m", |p, v| p.half_gauge_m = v),
            ("conicity", |p, v| p.conicity = v),
            ("speed_m_s", |p, v| p.speed_m_s = v),
            ("wheel_radius_m", |p, v| p.wheel_radius_m = v),
            ("semi_bogie_width_m", |p, v| p.semi_bogie_width_m = v),
        ];
        for (name, set) in setters {
            for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
                let mut p = BogieParams::default();
                set(&mut p, bad);
                match p.validate() {
                    Err(DamperError::InvalidParameter { field, .. }) => assert_eq!(field, name),
                    other => panic!("{name} = {bad}: {other:?}"),
                }
            }
        }
        let p = BogieParams {
            conicity: 1.5,
            ..BogieParams::default()
        };
        assert!(matches!(
            p.validate(),
            Err(DamperError::InvalidParameter {
                field: "conicity",
                ..
            })
        ));
    }

    #[test]
    fn invalid_dampers_are_rejected_by_name() {
        for bad in [0.0, -5.0, f64::NAN] {
            let d = Dampers {
                csy_ns_per_m: bad,
                ..Dampers::NOMINAL
            };
            assert!(matches!(
                d.validate(),
                Err(DamperError::InvalidParameter {
                    field: "csy_ns_per_m",
                    ..
                })
            ));
            let d = Dampers {
                csay_ns_per_m: bad,
                ..Dampers::NOMINAL
            };
            assert!(matches!(
                d.validate(),
                Err(DamperError::InvalidParameter {
                    field: "csay_ns_per_m",
                    ..
                })
            ));
        }
    }
}
