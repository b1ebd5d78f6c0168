//! Simulated runs, parsed from `config/scenarios/damper-*.toml`.

use serde::{Deserialize, Serialize};

use crate::config::DamperMonitorConfig;
use crate::faults::DamperFault;
use crate::params::{positive, BogieParams, Dampers};
use crate::sample::SensorNoise;
use crate::speed_profile::SpeedProfile;
use crate::track::TrackSpec;
use crate::DamperError;

/// A scenario: the plant, its track and faults, the sensors, and the monitor settings to run
/// on it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
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
    /// The plant's forward speed over time (`[speed] profile_m_s`); without it the vehicle's
    /// `speed_m_s`, constant. Giving both is refused.
    #[serde(default)]
    pub speed: Option<SpeedProfile>,
    /// The body's load above the bogie (`[load]`): its mass, whether the samples carry it,
    /// and how it changes at stops. Without it the plant carries the design mass
    /// (`vehicle.half_body_mass_kg`), measured.
    #[serde(default)]
    pub load: LoadSpec,
    /// The estimator settings to run on it (`DamperMonitorConfig::default()` with the keys
    /// given; `preset = "paper"` starts from `DamperMonitorConfig::paper()` instead). Its
    /// `dt_s` is the scenario's (a different one is refused). Its vehicle is
    /// `[monitor.vehicle]` when given (the filter's assumed vehicle; the plant, `[vehicle]`, may
    /// differ: a wrong conicity, a wrong speed), else the plant's (the monitor knows the
    /// vehicle's design values).
    #[serde(default)]
    pub monitor: DamperMonitorConfig,
    /// Whether `[monitor.vehicle]` was given (set by [`DamperScenario::from_toml_str`]).
    #[serde(skip)]
    pub monitor_vehicle_given: bool,
}

fn default_dt_s() -> f64 {
    1e-3
}

/// The plant's body mass above the bogie over a run (`[load]`): passengers board and alight
/// while the train stands at a station, so the mass changes only at a stop.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LoadSpec {
    /// The body mass above the bogie at the start (kg); default: the design value,
    /// `vehicle.half_body_mass_kg` (the filter's design stays the vehicle's).
    pub half_body_mass_kg: Option<f64>,
    /// Whether the samples carry the plant's body mass as the measured load
    /// (`BogieSample::half_body_mass_kg`, the air springs' pressure); `false`: they carry none
    /// and the particles carry the mass (`rbpf.unmeasured_mass`; with that off the filter
    /// assumes the design mass).
    pub measured: bool,
    /// `[[time_s, half_body_mass_kg], ...]`: at each time the body mass becomes the value (kg).
    /// Times increasing, within the run, each at a stop (the `[speed]` profile at 0 m/s).
    pub changes_kg: Vec<[f64; 2]>,
}

impl Default for LoadSpec {
    fn default() -> Self {
        LoadSpec {
            half_body_mass_kg: None,
            measured: true,
            changes_kg: Vec::new(),
        }
    }
}

impl DamperScenario {
    pub fn from_toml_str(text: &str) -> Result<Self, DamperError> {
        let config = |e: &dyn std::fmt::Display| DamperError::Config(e.to_string());
        let mut table: toml::Table = text.parse().map_err(|e| config(&e))?;
        let vehicle_speed_given = table
            .get("vehicle")
            .and_then(|v| v.as_table())
            .is_some_and(|v| v.contains_key("speed_m_s"));
        if vehicle_speed_given && table.contains_key("speed") {
            return Err(DamperError::Config(
                "vehicle.speed_m_s and [speed] both given: say the speed once (a constant \
                 speed is `profile_m_s = [[0, v]]`)"
                    .into(),
            ));
        }
        let mut monitor_vehicle_given = false;
        if let Some(monitor) = table.remove("monitor") {
            let toml::Value::Table(monitor) = monitor else {
                return Err(DamperError::Config("monitor: not a table".into()));
            };
            monitor_vehicle_given = monitor.contains_key("vehicle");
            if let Some(dt) = monitor.get("dt_s") {
                return Err(DamperError::Config(format!(
                    "monitor.dt_s = {dt}: the filter runs at the scenario's sample period \
                     (dt_s); remove it"
                )));
            }
            let monitor: DamperMonitorConfig =
                railmon_settings::with_preset(monitor, "monitor").map_err(|e| config(&e))?;
            let value = toml::Value::try_from(monitor).map_err(|e| config(&e))?;
            table.insert("monitor".into(), value);
        }
        let mut s: DamperScenario = toml::Value::Table(table)
            .try_into()
            .map_err(|e| config(&e))?;
        s.monitor_vehicle_given = monitor_vehicle_given;
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
        if let Some(profile) = &self.speed {
            profile.validate()?;
            // The ERRI generator is a spatial filter realised in time at one speed, with a
            // fixed wheelset delay `2a / v`.
            if !profile.is_constant() && !matches!(self.track, TrackSpec::White { .. }) {
                return Err(DamperError::Config(
                    "speed.profile_m_s: a varying speed needs the white track (the ERRI \
                     generator runs at one speed)"
                        .into(),
                ));
            }
        }
        self.validate_load()?;
        self.monitor_config().validate()
    }

    /// `[load]`: masses finite and positive, changes in time order within the run and each
    /// at a stop; errors name the key.
    fn validate_load(&self) -> Result<(), DamperError> {
        let load = &self.load;
        let bad = |key: String, value: f64, why: &str| {
            Err(DamperError::Config(format!("{key} = {value}: {why}")))
        };
        if let Some(m) = load
            .half_body_mass_kg
            .filter(|m| !(m.is_finite() && *m > 0.0))
        {
            return bad("load.half_body_mass_kg".into(), m, "must be positive (kg)");
        }
        let speed = self.speed_profile();
        let mut previous_s = None;
        for (i, &[t_s, m]) in load.changes_kg.iter().enumerate() {
            let key = format!("load.changes_kg[{i}]");
            if !(m.is_finite() && m > 0.0) {
                return bad(key, m, "the mass must be positive (kg)");
            }
            if !(0.0..=self.duration_s).contains(&t_s) {
                return bad(key, t_s, "the time must be within the run (0..=duration_s)");
            }
            if previous_s.is_some_and(|p| t_s <= p) {
                return bad(key, t_s, "the times must increase");
            }
            if speed.at(t_s) != 0.0 {
                return Err(DamperError::Config(format!(
                    "{key} = [{t_s}, {m}]: the train runs at {} m/s then; the load changes \
                     only at a stop (a time where the [speed] profile_m_s is 0)",
                    speed.at(t_s)
                )));
            }
            previous_s = Some(t_s);
        }
        Ok(())
    }

    /// The plant's body mass above the bogie at time `t_s` (kg): the last of
    /// `load.changes_kg` at or before it, else the start's.
    pub fn half_body_mass_kg_at(&self, t_s: f64) -> f64 {
        let start = self
            .load
            .half_body_mass_kg
            .unwrap_or(self.vehicle.half_body_mass_kg);
        self.load
            .changes_kg
            .iter()
            .take_while(|[at_s, _]| *at_s <= t_s)
            .last()
            .map_or(start, |[_, m]| *m)
    }

    /// The plant's speed over time: `[speed]`, else the vehicle's constant speed.
    pub fn speed_profile(&self) -> SpeedProfile {
        self.speed
            .clone()
            .unwrap_or_else(|| SpeedProfile::constant(self.vehicle.speed_m_s))
    }

    pub fn n_steps(&self) -> usize {
        (self.duration_s / self.dt_s).round() as usize
    }

    /// The monitor to run: `[monitor]` at the scenario's `dt_s`, assuming `[monitor.vehicle]`
    /// if given, else the plant's vehicle.
    pub fn monitor_config(&self) -> DamperMonitorConfig {
        DamperMonitorConfig {
            vehicle: if self.monitor_vehicle_given {
                self.monitor.vehicle
            } else {
                self.vehicle
            },
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
            (
                "damper-speed-profile",
                include_str!("../../config/scenarios/damper-speed-profile.toml"),
            ),
            (
                "damper-load",
                include_str!("../../config/scenarios/damper-load.toml"),
            ),
        ] {
            let s = DamperScenario::from_toml_str(text).unwrap();
            assert_eq!(s.name, name);
        }
    }

    /// `[speed]` is the plant's speed; without it the vehicle's, constant; both is refused,
    /// as is a varying speed on the ERRI track, and a bad profile names its point.
    #[test]
    fn speed_profile_is_given_once_and_checked() {
        let s = DamperScenario::from_toml_str(MINIMAL).unwrap();
        assert_eq!(s.speed_profile(), SpeedProfile::constant(45.3));
        let with = format!("{MINIMAL}[speed]\nprofile_m_s = [[0, 0], [10, 20]]\n");
        let s = DamperScenario::from_toml_str(&with).unwrap();
        assert_eq!(s.speed_profile().at(5.0), 10.0);
        let both = format!("{with}[vehicle]\nspeed_m_s = 30.0\n");
        let err = DamperScenario::from_toml_str(&both)
            .unwrap_err()
            .to_string();
        assert!(err.contains("both given"), "{err}");
        let unsorted = format!("{MINIMAL}[speed]\nprofile_m_s = [[0, 10], [5, 20], [3, 1]]\n");
        let err = DamperScenario::from_toml_str(&unsorted)
            .unwrap_err()
            .to_string();
        assert!(err.contains("profile_m_s[2]"), "{err}");
        let erri = "name = \"x\"\nseed = 1\nduration_s = 1.0\n[track]\nkind = \"erri\"\n\
                    level = \"low\"\n[speed]\nprofile_m_s = [[0, 10], [1, 20]]\n";
        let err = DamperScenario::from_toml_str(erri).unwrap_err().to_string();
        assert!(err.contains("white track"), "{err}");
    }

    /// `[load]`: the start's mass and its changes at stops; a change while the train runs, out
    /// of order or out of the run, or a mass that is not positive, is refused naming the key.
    #[test]
    fn load_changes_only_at_a_stop_and_names_the_key() {
        let s = DamperScenario::from_toml_str(MINIMAL).unwrap();
        assert!(s.load.measured);
        assert_eq!(s.half_body_mass_kg_at(0.5), s.vehicle.half_body_mass_kg);
        let stop = "[speed]\nprofile_m_s = [[0, 10], [0.2, 0], [0.6, 0], [0.8, 10]]\n";
        let with = |load: &str| format!("{MINIMAL}{stop}[load]\n{load}\n");
        let s = DamperScenario::from_toml_str(&with(
            "half_body_mass_kg = 12000.0\nmeasured = false\nchanges_kg = [[0.3, 15000.0], [0.5, 14000.0]]",
        ))
        .unwrap();
        assert!(!s.load.measured);
        let at: Vec<f64> = [0.0, 0.3, 0.4, 0.5, 0.9]
            .map(|t| s.half_body_mass_kg_at(t))
            .into();
        assert_eq!(at, [12000.0, 15000.0, 15000.0, 14000.0, 14000.0]);
        for (load, want) in [
            (
                "changes_kg = [[0.1, 15000.0]]",
                "load.changes_kg[0] = [0.1, 15000]",
            ),
            (
                "changes_kg = [[0.3, 1.0], [0.3, 2.0]]",
                "load.changes_kg[1] = 0.3",
            ),
            ("changes_kg = [[0.3, 0.0]]", "load.changes_kg[0] = 0"),
            ("changes_kg = [[2.0, 1.0]]", "load.changes_kg[0] = 2"),
            ("half_body_mass_kg = -1.0", "load.half_body_mass_kg = -1"),
            ("mesured = true", "mesured"),
        ] {
            let err = DamperScenario::from_toml_str(&with(load))
                .unwrap_err()
                .to_string();
            assert!(err.contains(want), "{load}: {err}");
        }
    }

    const MINIMAL: &str = "name = \"x\"\nseed = 1\nduration_s = 1.0\n[track]\nkind = \"white\"\nvelocity_std_m_s = 0.05\n";

    /// `[monitor.vehicle]` is the filter's vehicle, the plant's stays `[vehicle]`; without
    /// it the filter assumes the plant's. Never ignored.
    #[test]
    fn monitor_vehicle_sets_the_filters_vehicle_and_the_plant_may_differ() {
        let both = format!(
            "{MINIMAL}[vehicle]\nconicity = 0.2\nspeed_m_s = 30.0\n[monitor.vehicle]\nconicity = 0.15\n"
        );
        let s = DamperScenario::from_toml_str(&both).unwrap();
        assert_eq!((s.vehicle.conicity, s.vehicle.speed_m_s), (0.2, 30.0));
        let filter = s.monitor_config().vehicle;
        assert_eq!(
            filter,
            BogieParams {
                conicity: 0.15,
                ..BogieParams::default()
            }
        );
        let plant_only = format!("{MINIMAL}[vehicle]\nconicity = 0.2\n");
        let s = DamperScenario::from_toml_str(&plant_only).unwrap();
        assert_eq!(s.monitor_config().vehicle.conicity, 0.2);
        let typo = format!("{MINIMAL}[monitor.vehicle]\nconicty = 0.15\n");
        assert!(matches!(
            DamperScenario::from_toml_str(&typo),
            Err(DamperError::Config(m)) if m.contains("conicty")
        ));
        let bad = format!("{MINIMAL}[monitor.vehicle]\nconicity = -0.15\n");
        assert!(matches!(
            DamperScenario::from_toml_str(&bad),
            Err(DamperError::InvalidParameter {
                field: "conicity",
                ..
            })
        ));
    }

    #[test]
    fn a_monitor_dt_is_refused_and_the_paper_preset_is_taken() {
        let dt = format!("{MINIMAL}[monitor]\ndt_s = 0.002\n");
        assert!(matches!(
            DamperScenario::from_toml_str(&dt),
            Err(DamperError::Config(m)) if m.contains("monitor.dt_s")
        ));
        let paper =
            format!("{MINIMAL}[monitor]\npreset = \"paper\"\n[monitor.rbpf]\nparticles = 50\n");
        let s = DamperScenario::from_toml_str(&paper).unwrap();
        let want = DamperMonitorConfig::paper();
        assert_eq!(s.monitor.rbpf.propagation, want.rbpf.propagation);
        assert_eq!(s.monitor.rbpf.kernel, want.rbpf.kernel);
        assert_eq!(s.monitor.rbpf.regeneration_fraction, 0.0);
        assert_eq!(s.monitor.rbpf.particles, 50);
        let unknown = format!("{MINIMAL}[monitor]\npreset = \"magic\"\n");
        assert!(matches!(
            DamperScenario::from_toml_str(&unknown),
            Err(DamperError::Config(m)) if m.contains("paper")
        ));
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
