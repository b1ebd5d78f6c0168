//! Regimes with meaning (issue 14 item 3): each mixture component is named from its own
//! statistics (idle, accelerating, cruising, coasting, braking), so the regime the monitor
//! reports says what the vehicle is doing, not which of `m_c` anonymous clusters it is in.
//!
//! The rule reads the component's **operating point**: the mean of the data vector
//! `d = [y; psi]` the component has absorbed, `E_i[d] = V_i[., 1] / (V_i[1, 1] - epsilon)`, where `1` is the
//! constant element of `psi` (eq. 10: `V_i = V_0 + sum_t w_{i;t} d_t d_t'`, so the constant's
//! column is the weighted sum of the data and its diagonal the weighted count; the prior
//! `V_0 = epsilon I` adds nothing off the diagonal). From it, in physical units, the mean fuel,
//! speed and acceleration (the derived acceleration channel, or the difference of the speed
//! now and a lag ago when speed is lagged in `psi`). In this order:
//!
//! 1. fewer than `min_samples` weighted samples: `unsettled` (not converged);
//! 2. mean speed below `standstill_speed_m_s`: `idle`;
//! 3. mean acceleration at least `acceleration_m_s2`: `accelerating`;
//! 4. mean acceleration at most `-acceleration_m_s2`: `braking`;
//! 5. mean fuel at most `coasting_fuel_cm3_s` (no traction power: engine idling or fuel cut
//!    off): `coasting`;
//! 6. otherwise `cruising`.
//!
//! The name is a function of the statistics and the configuration only: a monitor restored
//! from a snapshot names its components as before. Several components may share a name.

use serde::{Deserialize, Serialize};

/// What a mixture component means.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RegimeName {
    /// Standing (engine idling).
    Idle,
    /// Speeding up.
    Accelerating,
    /// Holding speed under power.
    Cruising,
    /// Moving without traction power (engine idling, or fuel cut off on overrun).
    Coasting,
    /// Slowing down faster than running resistance would.
    Braking,
    /// Too few samples to say (a component that has not converged, or has been forgotten).
    #[default]
    Unsettled,
}

impl RegimeName {
    /// Every name, in the order of the railcar simulator's labels, then `unsettled`.
    pub const ALL: [RegimeName; 6] = [
        RegimeName::Idle,
        RegimeName::Accelerating,
        RegimeName::Cruising,
        RegimeName::Coasting,
        RegimeName::Braking,
        RegimeName::Unsettled,
    ];

    /// The name as JSON, CSV and events write it.
    pub fn as_str(self) -> &'static str {
        match self {
            RegimeName::Idle => "idle",
            RegimeName::Accelerating => "accelerating",
            RegimeName::Cruising => "cruising",
            RegimeName::Coasting => "coasting",
            RegimeName::Braking => "braking",
            RegimeName::Unsettled => "unsettled",
        }
    }

    /// The name written `text` (as [`RegimeName::as_str`] gives it).
    pub fn parse(text: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|n| n.as_str() == text)
    }
}

impl std::fmt::Display for RegimeName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Thresholds of the naming rule (module documentation). A property of the vehicle (what
/// "standing" and "no traction power" look like), so two sets: `Default` is a road car's
/// ([`RegimeNaming::road_car`]), [`RegimeNaming::railcar`] a diesel railcar's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RegimeNaming {
    /// Weighted samples a component needs before it is named.
    pub min_samples: f64,
    /// Below this mean speed the component is standing, m/s.
    pub standstill_speed_m_s: f64,
    /// Mean acceleration beyond which the component is speeding up or braking, m/s^2.
    pub acceleration_m_s2: f64,
    /// Mean fuel at or below which a moving, steady component draws no traction power, cm^3/s.
    pub coasting_fuel_cm3_s: f64,
}

impl Default for RegimeNaming {
    fn default() -> Self {
        Self::road_car()
    }
}

impl RegimeNaming {
    /// A road car: fuel is cut off on overrun (~0 cm^3/s, the Camry files' most frequent
    /// value), below the ~0.2-0.3 cm^3/s of an idling 2.5 l engine; a deliberate acceleration
    /// or braking is 0.15 m/s^2 or more as a component's mean (a car's running resistance
    /// decelerates it by ~0.1-0.3 m/s^2 at speed, which coasting includes).
    pub fn road_car() -> Self {
        RegimeNaming {
            min_samples: 30.0,
            standstill_speed_m_s: 0.5,
            acceleration_m_s2: 0.15,
            coasting_fuel_cm3_s: 0.15,
        }
    }

    /// A diesel railcar: engines idling with the auxiliaries on burn what they burn at a
    /// station (three QSK19-R: ~10 cm^3/s in `railcar.rs`'s map), so coasting is fuel below
    /// 1.5 times that; running resistance decelerates a train by ~0.05 m/s^2, service braking
    /// by ~0.7, notching up accelerates it by 0.1-0.75, so 0.15 m/s^2 as for a car.
    pub fn railcar() -> Self {
        RegimeNaming {
            coasting_fuel_cm3_s: 15.0,
            ..Self::road_car()
        }
    }

    /// The rule of the module documentation.
    pub fn name(&self, point: &OperatingPoint) -> RegimeName {
        if point.samples.is_nan() || point.samples < self.min_samples {
            RegimeName::Unsettled
        } else if point
            .speed_m_s
            .is_some_and(|v| v < self.standstill_speed_m_s)
        {
            RegimeName::Idle
        } else if point
            .acceleration_m_s2
            .is_some_and(|a| a >= self.acceleration_m_s2)
        {
            RegimeName::Accelerating
        } else if point
            .acceleration_m_s2
            .is_some_and(|a| a <= -self.acceleration_m_s2)
        {
            RegimeName::Braking
        } else if point.fuel_cm3_s <= self.coasting_fuel_cm3_s {
            RegimeName::Coasting
        } else {
            RegimeName::Cruising
        }
    }

    pub(crate) fn validate(&self) -> Result<(), crate::FuelError> {
        let checks = [
            ("naming.min_samples", self.min_samples),
            ("naming.standstill_speed_m_s", self.standstill_speed_m_s),
            ("naming.acceleration_m_s2", self.acceleration_m_s2),
        ];
        for (field, v) in checks {
            if !(v.is_finite() && v >= 0.0) {
                return Err(crate::FuelError::invalid(
                    field,
                    v,
                    "must be finite and >= 0",
                ));
            }
        }
        if !self.coasting_fuel_cm3_s.is_finite() {
            return Err(crate::FuelError::invalid(
                "naming.coasting_fuel_cm3_s",
                self.coasting_fuel_cm3_s,
                "must be finite",
            ));
        }
        Ok(())
    }
}

/// A component's operating point: the mean of what it has absorbed, physical units.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct OperatingPoint {
    /// Weighted number of samples behind the means (`V[1, 1]` minus its prior).
    pub samples: f64,
    pub fuel_cm3_s: f64,
    /// `None` without a speed channel.
    pub speed_m_s: Option<f64>,
    /// `None` without the acceleration channel or a lagged speed.
    pub acceleration_m_s2: Option<f64>,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(samples: f64, fuel: f64, v: f64, a: f64) -> OperatingPoint {
        OperatingPoint {
            samples,
            fuel_cm3_s: fuel,
            speed_m_s: Some(v),
            acceleration_m_s2: Some(a),
        }
    }

    #[test]
    fn the_rule_names_each_regime_in_order() {
        let n = RegimeNaming::railcar();
        assert_eq!(n.name(&point(10.0, 10.0, 0.0, 0.0)), RegimeName::Unsettled);
        assert_eq!(n.name(&point(100.0, 10.0, 0.1, 0.0)), RegimeName::Idle);
        assert_eq!(
            n.name(&point(100.0, 100.0, 18.0, 0.36)),
            RegimeName::Accelerating
        );
        assert_eq!(
            n.name(&point(100.0, 10.4, 15.0, -0.72)),
            RegimeName::Braking
        );
        assert_eq!(
            n.name(&point(100.0, 12.0, 15.5, -0.003)),
            RegimeName::Coasting
        );
        assert_eq!(
            n.name(&point(100.0, 58.0, 28.8, 0.026)),
            RegimeName::Cruising
        );
        // Without speed and acceleration only fuel decides.
        let fuel_only = OperatingPoint {
            samples: 100.0,
            fuel_cm3_s: 40.0,
            speed_m_s: None,
            acceleration_m_s2: None,
        };
        assert_eq!(n.name(&fuel_only), RegimeName::Cruising);
        // NaN samples (a broken statistic) never get a name.
        assert_eq!(
            n.name(&point(f64::NAN, 10.0, 0.0, 0.0)),
            RegimeName::Unsettled
        );
    }

    #[test]
    fn names_round_trip_as_text() {
        for n in RegimeName::ALL {
            assert_eq!(RegimeName::parse(n.as_str()), Some(n));
            assert_eq!(serde_json::to_string(&n).unwrap(), format!("\"{n}\""));
        }
    }
}
