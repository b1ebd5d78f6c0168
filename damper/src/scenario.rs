//! Simulated runs, parsed from `config/scenarios/damper-*.toml`.

use serde::Deserialize;

use crate::config::DamperMonitorConfig;
use crate::params::{positive, BogieParams, Dampers};
use crate::simulator::{DamperFault, SensorNoise};
use crate::track::TrackSpec;
use crate::DamperError;

/// A scenario: the plant, its track and faults, the sensors, and the monitor settings to run
/// on it.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DamperScenario {
    pub name: String,
    /// Seed of the plant's random numbers (track, sensor noise).
    pub seed: u64,
    pub duration_s: f64,
    #[serde(default = "default_dt_s")]
    pub dt_s: f64,
    /// The true vehicle (defaults: appendix, conicity 0.15).
    #[serde(default)]
    pub vehicle: BogieParams,
    /// The true dampers at the start.
    #[serde(default)]
    pub dampers: Dampers,
    pub track: TrackSpec,
    #[serde(default)]
    pub sensors: SensorNoise,
    #[serde(default)]
    pub faults: Vec<DamperFault>,
    /// The estimator settings to run on it; `vehicle` and `dt_s` are taken from the
    /// scenario's (the monitor knows the vehicle's design values).
    #[serde(default)]
    pub monitor: DamperMonitorConfig,
}

fn default_dt_s() -> f64 {
    1e-3
}

impl DamperScenario {
    pub fn from_toml_str(text: &str) -> Result<Self, DamperError> {
        let s: DamperScenario =
            toml::from_str(text).map_err(|e| DamperError::Config(e.to_string()))?;
        s.validate()?;
        Ok(s)
    }

    pub fn validate(&self) -> Result<(), DamperError> {
        positive("duration_s", self.duration_s)?;
        positive("dt_s", self.dt_s)?;
        // A bound on the steps, so a typo (1e20 s) is an error rather than a simulation that
        // never ends: a million seconds is 11.6 days.
        if self.duration_s > 1e6 {
            return Err(DamperError::InvalidParameter {
                field: "duration_s",
                value: self.duration_s,
                reason: "must be at most 1e6 s",
            });
        }
        self.vehicle.validate()?;
        self.dampers.validate()?;
        self.track.validate()?;
        self.sensors.validate()?;
        for f in &self.faults {
            f.validate()?;
        }
        self.monitor_config().validate()
    }

    pub fn n_steps(&self) -> usize {
        (self.duration_s / self.dt_s).round() as usize
    }

    pub fn monitor_config(&self) -> DamperMonitorConfig {
        DamperMonitorConfig {
            vehicle: self.vehicle,
            dt_s: self.dt_s,
            ..self.monitor
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scenario_files_parse() {
        for (name, text) in [
            (
                "damper-seed",
                include_str!("../../config/scenarios/damper-seed.toml"),
            ),
            (
                "damper-fault",
                include_str!("../../config/scenarios/damper-fault.toml"),
            ),
            (
                "damper-spectral",
                include_str!("../../config/scenarios/damper-spectral.toml"),
            ),
            (
                "damper-spectral-high",
                include_str!("../../config/scenarios/damper-spectral-high.toml"),
            ),
        ] {
            let s = DamperScenario::from_toml_str(text).unwrap();
            assert_eq!(s.name, name);
        }
    }

    #[test]
    fn unknown_fields_and_bad_values_are_errors() {
        let ok = "name = \"x\"\nseed = 1\nduration_s = 1.0\n[track]\nkind = \"white\"\nvelocity_std_m_s = 0.05\n";
        DamperScenario::from_toml_str(ok).unwrap();
        let typo = format!("{ok}speling = 3\n");
        assert!(matches!(
            DamperScenario::from_toml_str(&typo.replace("[track]", "bogus = 1\n[track]")),
            Err(DamperError::Config(_))
        ));
        let neg = ok.replace("duration_s = 1.0", "duration_s = -1.0");
        assert!(matches!(
            DamperScenario::from_toml_str(&neg),
            Err(DamperError::InvalidParameter {
                field: "duration_s",
                ..
            })
        ));
        let ramp =
            format!("{ok}[[faults]]\ndamper = \"csy\"\nkind = \"ramp\"\nat_s = 5.0\nratio = 0.5\n");
        assert!(matches!(
            DamperScenario::from_toml_str(&ramp),
            Err(DamperError::InvalidParameter {
                field: "faults.end_s",
                ..
            })
        ));
    }
}
