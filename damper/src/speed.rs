//! The speeds the filters' model is valid at (`[monitor.speed]`) and why a monitor pauses
//! outside them. A leaf: the monitor pauses by it, the gain table spans it, the RBPF's jump
//! search times its settling by it.

use serde::{Deserialize, Serialize};

use crate::params::{non_negative, positive};
use crate::DamperError;

/// Bounds of `grid_ratio` (declared to the settings reference and checked).
const GRID_RATIO: std::ops::RangeInclusive<f64> = 1.001..=2.0;

/// The speeds the filter's model is valid at, and its speed schedule (`gain_table` docs).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct SpeedConfig {
    /// Below this speed (standstill, shunting) the filter holds its parameter posterior and
    /// reports `paused: low_speed`: the creep model `~ 1 / v` is not valid there (m/s).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub min_m_s: f64,
    /// Above it the filter holds likewise (`paused: high_speed`): the range the gain table
    /// covers (m/s). The default stays below the linear model's critical speed: with the
    /// paper's parameters an eigenvalue of `A` crosses into the right half-plane (hunting)
    /// between 58 and 60 m/s with nominal dampers, and between 50 and 55 m/s with `C_say` at
    /// 40 % (`tests::the_default_top_speed_is_below_the_critical_speed`). Beyond it the linear
    /// plant grows without bound, which no real bogie does (it hunts in a limit cycle the
    /// linear model cannot represent), so a filter built on it would learn nonsense.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub max_m_s: f64,
    /// Ratio of neighbouring speed nodes of the gain table (geometric grid about the
    /// vehicle's configured speed).
    #[schemars(range(min = *GRID_RATIO.start(), max = *GRID_RATIO.end()))]
    pub grid_ratio: f64,
    /// After a pause the per-particle state estimates are those of the last valid sample (or,
    /// with the jump search after a long pause, at rest): for at least this long they are run
    /// (predict and update) without weighting the particles, so that the transient of stale
    /// states does not move the posterior (s).
    #[schemars(range(min = 0.0))]
    pub resume_settle_s: f64,
}

impl Default for SpeedConfig {
    fn default() -> Self {
        SpeedConfig {
            min_m_s: 5.0,
            max_m_s: 55.0,
            grid_ratio: 1.05,
            resume_settle_s: 1.0,
        }
    }
}

impl SpeedConfig {
    pub fn validate(&self) -> Result<(), DamperError> {
        positive("speed.min_m_s", self.min_m_s)?;
        positive("speed.max_m_s", self.max_m_s)?;
        if self.max_m_s <= self.min_m_s {
            return Err(DamperError::InvalidParameter {
                field: "speed.max_m_s",
                value: self.max_m_s,
                reason: "must exceed speed.min_m_s",
            });
        }
        // At most 2 (a node every factor of 2 would be no schedule); at least 1.001 (a
        // thousand nodes between 5 and 70 m/s would be a gigabyte of grids).
        if !GRID_RATIO.contains(&self.grid_ratio) {
            return Err(DamperError::InvalidParameter {
                field: "speed.grid_ratio",
                value: self.grid_ratio,
                reason: "must be in [1.001, 2]",
            });
        }
        non_negative("speed.resume_settle_s", self.resume_settle_s)
    }

    /// Why the filter pauses at `speed_m_s`, if it does.
    pub fn pause_reason(&self, speed_m_s: f64) -> Option<PauseReason> {
        if speed_m_s < self.min_m_s {
            Some(PauseReason::LowSpeed)
        } else if speed_m_s > self.max_m_s {
            Some(PauseReason::HighSpeed)
        } else {
            None
        }
    }
}

/// Why a damper monitor holds its posterior.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PauseReason {
    /// Below `speed.min_m_s`.
    LowSpeed,
    /// Above `speed.max_m_s`.
    HighSpeed,
    /// Samples were missing (lost at the source, or the time across a restart of the
    /// service): the states settle on the data again before the posterior learns
    /// (`DamperMonitor::bridge`).
    Gap,
}

impl PauseReason {
    pub const ALL: [PauseReason; 3] = [
        PauseReason::LowSpeed,
        PauseReason::HighSpeed,
        PauseReason::Gap,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            PauseReason::LowSpeed => "low_speed",
            PauseReason::HighSpeed => "high_speed",
            PauseReason::Gap => "gap",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The largest real part of the eigenvalues of `A` at `speed_m_s`, leaving out the two
    /// drift modes (eigenvalue 0 up to rounding).
    fn growth_rate_per_s(dampers: &crate::Dampers, speed_m_s: f64) -> f64 {
        let params = crate::BogieParams::default();
        let mut model = crate::model::BogieModel::new(&params, 0.0).unwrap();
        model.set_speed(speed_m_s).unwrap();
        let a = model.a_matrix(dampers);
        a.complex_eigenvalues()
            .iter()
            .map(|e| e.re)
            .fold(f64::MIN, f64::max)
    }

    /// Hunting: above the critical speed the linear model is unstable (an eigenvalue of `A`
    /// in the right half-plane), so the filter's valid range must end below it.
    #[test]
    fn the_default_top_speed_is_below_the_critical_speed() {
        let top = SpeedConfig::default().max_m_s;
        let nominal = crate::Dampers::NOMINAL;
        assert!(
            growth_rate_per_s(&nominal, top) < 1e-6,
            "unstable at {top} m/s"
        );
        assert!(growth_rate_per_s(&nominal, 58.0) < 1e-6);
        // The critical speed exists and lies just above: the check above can fail.
        assert!(growth_rate_per_s(&nominal, 60.0) > 0.1);
        // A failed anti-yaw damper lowers it (why such a bogie is dangerous at speed).
        let failed = crate::Dampers {
            csay_ns_per_m: 0.4 * nominal.csay_ns_per_m,
            ..nominal
        };
        assert!(growth_rate_per_s(&failed, 50.0) < 1e-6);
        assert!(growth_rate_per_s(&failed, 55.0) > 0.1);
    }
}
