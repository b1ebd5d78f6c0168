//! `SlipMonitor`: the EKF bank plus one adhesion estimator, stepped frame by frame. This is
//! what the service runs.

use railmon_settings::Presets;
use serde::{Deserialize, Serialize};

use crate::adhesion::{AdhesionConfig, AdhesionEstimator, AdhesionMethod};
use crate::alarm::SlipAlarmConfig;
use crate::ekf::{EkfBank, EkfConfig};
use crate::error::{check_positive, SlipError};
use crate::fixed_lag::FixedLagLine;
use crate::model::{DriveModel, MotorParams};
use crate::sample::{validate_frame, DriveSample};
use crate::speed_reference::{
    validate_train_speed, SpeedReference, SpeedReferenceConfig, TrainSpeedCheck,
};

/// Everything the monitor needs: motor parameters, sampling period, EKF noise, the method and
/// the settings of every method.
///
/// `Default` is the validated setting (the seed and hard scenarios, docs/adhesion.md): the
/// EKF noise of [`EkfConfig::default`] and the temporal method. Every path takes it from here
/// (the service, `railmon analyze adhesion --input`, scenarios without `[monitor]`).
/// [`SlipMonitorConfig::paper`] is the paper's EKF noise; a TOML table asks for it with
/// `preset = "paper"` and may override single keys on top ([`railmon_settings::with_preset`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct SlipMonitorConfig {
    /// Sampling period of the drive data (the paper: 125 us).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub dt_s: f64,
    pub motor: MotorParams,
    pub ekf: EkfConfig,
    pub method: AdhesionMethod,
    pub adhesion: AdhesionConfig,
    /// The slipping flag over the chosen method's probability ([`crate::SlipAlarm`]).
    pub alarm: SlipAlarmConfig,
}

impl Default for SlipMonitorConfig {
    fn default() -> Self {
        SlipMonitorConfig {
            dt_s: 125e-6,
            motor: MotorParams::default(),
            ekf: EkfConfig::default(),
            method: AdhesionMethod::Temporal,
            adhesion: AdhesionConfig::default(),
            alarm: SlipAlarmConfig::default(),
        }
    }
}

impl Presets for SlipMonitorConfig {
    const PRESETS: &'static [&'static str] = &["paper"];
    fn preset(name: &str) -> Option<Self> {
        (name == "paper").then(Self::paper)
    }
}

impl SlipMonitorConfig {
    /// The paper's EKF noise and initialisation ([`EkfConfig::paper`]), everything else as the
    /// default: what `preset = "paper"` starts from.
    pub fn paper() -> Self {
        SlipMonitorConfig {
            ekf: EkfConfig::paper(),
            ..Self::default()
        }
    }

    pub fn validate(&self) -> Result<(), SlipError> {
        check_positive("dt_s", self.dt_s)?;
        self.motor.validate("motor")?;
        self.ekf.validate("ekf")?;
        self.adhesion.validate()?;
        self.alarm.validate()
    }

    /// Reads a TOML table of these fields: from the preset its `preset` key names (else the
    /// default), every other key overriding one value of it; then validates.
    pub fn from_toml_table(table: toml::Table) -> Result<Self, SlipError> {
        let config: SlipMonitorConfig = railmon_settings::with_preset(table, "")
            .map_err(|e| SlipError::Toml(format!("{}: {}", e.key, e.reason)))?;
        config.validate()?;
        Ok(config)
    }

    /// [`SlipMonitorConfig::from_toml_table`] of a TOML document.
    pub fn from_toml_str(text: &str) -> Result<Self, SlipError> {
        let table = text
            .parse::<toml::Table>()
            .map_err(|e| SlipError::Toml(e.to_string()))?;
        Self::from_toml_table(table)
    }

    /// The drive model these settings describe.
    pub fn model(&self) -> Result<DriveModel, SlipError> {
        DriveModel::new(self.motor, self.dt_s)
    }
}

/// One drive's estimate at one step.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DriveEstimate {
    /// EKF electrical speed.
    pub speed_rad_s: f64,
    /// EKF electrical angle, in (-pi, pi].
    pub angle_rad: f64,
    /// EKF load torque `M_z,i`.
    pub torque_nm: f64,
    /// Probability that the drive has lost adhesion, in [0, 1].
    pub slip_probability: f64,
}

/// The monitor's output for one step: the whole estimate of step `step`, published
/// `lag_steps` frames after it (the fixed lag, [`crate::fixed_lag`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SlipEstimate {
    /// The step (frames since the monitor started, from 0) every value here belongs to.
    #[serde(default)]
    pub step: u64,
    /// Frames stepped after `step` when it was published: `FIXED_LAG_STEPS` (111) in a run,
    /// fewer for the steps drained at its end or before a long gap. Its time is the newest
    /// frame's minus this many sample periods.
    #[serde(default)]
    pub lag_steps: u64,
    /// `M_z^(G)`.
    pub global_torque_nm: f64,
    pub method: AdhesionMethod,
    pub drives: Vec<DriveEstimate>,
    /// What the slip probabilities were judged against at this step: `group` (the other
    /// drives only; no train speed came with the frame) or `train_speed` (the train's measured
    /// speed as well, [`crate::speed_reference`]).
    #[serde(default)]
    pub reference: SpeedReference,
}

/// One EKF per drive plus the configured adhesion estimator.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SlipMonitor {
    bank: EkfBank,
    backup: EkfBank,
    /// The method behind the fixed lag, with the steps not yet published.
    line: FixedLagLine,
    torque: Vec<f64>,
    estimate: SlipEstimate,
    /// The train-speed test, from the first frame with a train speed (or
    /// [`SlipMonitor::set_speed_reference`]) on.
    #[serde(default)]
    train: Option<TrainSpeedCheck>,
}

impl SlipMonitor {
    /// The version of this type's serialised layout (everything in it: the EKF banks, the
    /// adhesion method's state, the estimate), which the service writes into each drive
    /// snapshot. Raise it with every change of the layout; `tests/state_layout.rs` pins the
    /// layout under it (`tests/data/golden/state-layout-slip.txt`), so a change cannot ship
    /// without it. 3: the EKF bank lost the load-jump test's state (the rejected
    /// `[ekf.jump]`, issue 27). 4: the train-speed reference (its settings and per-drive
    /// filters, the estimate's `reference`, issue 23 item 2). 5: the EKF bank keeps its
    /// initial filter, to relock after a gap (issue 26 item 3). 6: the temporal method's
    /// excess evidence per drive (a majority dragging the reference, issue 23 item 1). 7: the
    /// method behind the fixed lag (its centred window, edge line and the pending steps' EKF
    /// states; the estimate's `step` and `lag_steps`, issue 23 item 1). 8: the fixed lag's
    /// line shared by its stages, and its short-episode stage (issue 23).
    pub const STATE_FORMAT_VERSION: u32 = 8;

    pub fn new(config: &SlipMonitorConfig, n_drives: usize) -> Result<Self, SlipError> {
        config.validate()?;
        let bank = EkfBank::new(config.model()?, &config.ekf, n_drives)?;
        let estimator = AdhesionEstimator::new(config.method, &config.adhesion, n_drives)?;
        let drive = DriveEstimate {
            speed_rad_s: 0.0,
            angle_rad: 0.0,
            torque_nm: 0.0,
            slip_probability: 0.0,
        };
        Ok(SlipMonitor {
            backup: bank.clone(),
            bank,
            line: FixedLagLine::new(vec![estimator], n_drives),
            torque: vec![0.0; n_drives],
            estimate: SlipEstimate {
                step: 0,
                lag_steps: 0,
                global_torque_nm: 0.0,
                method: config.method,
                drives: vec![drive; n_drives],
                reference: SpeedReference::Group,
            },
            train: None,
        })
    }

    /// Sets the drives' geometry and the slip test against the train speed (without it, the
    /// first frame with a train speed takes [`SpeedReferenceConfig::default`]). Restarts the
    /// test's filters.
    pub fn set_speed_reference(&mut self, config: SpeedReferenceConfig) -> Result<(), SlipError> {
        self.train = Some(TrainSpeedCheck::new(config, self.n_drives())?);
        Ok(())
    }

    /// The train-speed test's settings, once set or used.
    pub fn speed_reference(&self) -> Option<&SpeedReferenceConfig> {
        self.train.as_ref().map(TrainSpeedCheck::config)
    }

    pub fn n_drives(&self) -> usize {
        self.bank.n_drives()
    }

    /// The last estimate published (zeros before the first, `FIXED_LAG_STEPS` frames in).
    pub fn last(&self) -> &SlipEstimate {
        &self.estimate
    }

    /// Whether an estimate has been published (`FIXED_LAG_STEPS` frames in; before, `last`
    /// is zeros).
    pub fn has_published(&self) -> bool {
        self.line.published() > 0
    }

    /// The EKF bank (states and covariances of every drive).
    pub fn bank(&self) -> &EkfBank {
        &self.bank
    }

    /// Carries the estimator over `missing_steps` sample periods no frame covered, before the
    /// next frame is stepped ([`EkfBank::bridge`]): a short gap is predicted through (the
    /// fixed lag's window spans it); after a longer one the steps still behind the lag are
    /// published first (`published`, as at the end of a run: [`SlipMonitor::drain`]), then
    /// the EKFs relock from the back-EMF, the adhesion method's warm-up and the lag start
    /// again and the train-speed test restarts its filters, as at start (what the method
    /// learnt about each drive is kept).
    pub fn bridge(
        &mut self,
        missing_steps: u64,
        published: &mut dyn FnMut(&SlipEstimate),
    ) -> Result<(), SlipError> {
        if missing_steps == 0 || !self.bank.relocks_after(missing_steps) {
            self.bank.bridge(missing_steps);
            return Ok(());
        }
        while let Some(e) = self.drain()? {
            published(e);
        }
        self.bank.bridge(missing_steps);
        self.line.ekfs_relocked();
        if let Some(t) = &mut self.train {
            t.reset();
        }
        Ok(())
    }

    /// Publishes the oldest step still behind the lag from the frames there are after it:
    /// call until `None` at the end of a run, so that every step stepped is published.
    pub fn drain(&mut self) -> Result<Option<&SlipEstimate>, SlipError> {
        if !self.line.drain()? {
            return Ok(None);
        }
        self.publish();
        Ok(Some(&self.estimate))
    }

    /// Frames stepped whose estimate is not yet published.
    pub fn pending(&self) -> u64 {
        self.line.pending()
    }

    /// Steps one frame; returns the estimate it publishes, that of the step
    /// `FIXED_LAG_STEPS` (111) frames before ([`crate::fixed_lag`]; `None` in the first 111:
    /// [`SlipMonitor::drain`] gives the last ones at the end of a run).
    /// Validates the whole frame first (length == n_drives, all finite): on error nothing
    /// changes. An EKF failure of any drive also leaves every filter as it was. Judged against
    /// the group only ([`SpeedReference::Group`]); the same as
    /// [`SlipMonitor::step_with_train_speed`] without a train speed.
    pub fn step(&mut self, samples: &[DriveSample]) -> Result<Option<&SlipEstimate>, SlipError> {
        self.step_with_train_speed(samples, None)
    }

    /// [`SlipMonitor::step`] with the train's own measured speed (m/s, a magnitude in
    /// [`crate::speed_reference::TRAIN_SPEED_RANGE_M_S`]; radar, GNSS or an unpowered axle) when
    /// there is one: each drive's slip probability is then that of its rotor's departure from
    /// the train speed ([`crate::speed_reference`]), which sees every drive losing adhesion at
    /// once, and the estimate's `reference` is `train_speed` (after the test's warm-up and
    /// calibration, 0.15 s by default; until then `group`, the adhesion method's). `None` is exactly [`SlipMonitor::step`] (and restarts the train-speed
    /// test's filters for when the speed returns). A reading out of range is refused before
    /// anything changes.
    pub fn step_with_train_speed(
        &mut self,
        samples: &[DriveSample],
        train_speed_m_s: Option<f64>,
    ) -> Result<Option<&SlipEstimate>, SlipError> {
        validate_frame(samples, self.n_drives())?;
        if let Some(v) = train_speed_m_s {
            validate_train_speed(v)?;
            if self.train.is_none() {
                self.set_speed_reference(SpeedReferenceConfig::default())?;
            }
        }
        // The bank commits only when every drive's update succeeds; keep a copy (reusing its
        // allocation) to roll back if the estimator then fails, so that nothing changes.
        self.backup.clone_from(&self.bank);
        self.bank.step(samples)?;
        for (k, f) in self.bank.filters().iter().enumerate() {
            self.torque[k] = f.torque_nm();
        }
        match self.line.push(&self.bank, &self.torque, train_speed_m_s) {
            Ok(false) => Ok(None),
            Ok(true) => {
                self.publish();
                Ok(Some(&self.estimate))
            }
            Err(e) => {
                std::mem::swap(&mut self.bank, &mut self.backup);
                Err(e)
            }
        }
    }

    /// The estimate of the step the line just published: its EKF states, the method's
    /// probabilities and, with that step's train speed, the train-speed test on them.
    fn publish(&mut self) {
        let lagged = self.line.last();
        let model = self.bank.model();
        self.estimate.step = lagged.step;
        self.estimate.lag_steps = lagged.lag_steps;
        self.estimate.global_torque_nm = self.line.global_torque_nm(0);
        for ((d, x), p) in self
            .estimate
            .drives
            .iter_mut()
            .zip(lagged.states)
            .zip(self.line.probability(0))
        {
            *d = DriveEstimate {
                speed_rad_s: x[crate::model::idx::OMEGA],
                angle_rad: x[crate::model::idx::THETA],
                torque_nm: x[crate::model::idx::TORQUE],
                slip_probability: *p,
            };
        }
        self.estimate.reference = match lagged.train_speed_m_s {
            None => {
                if let Some(t) = &mut self.train {
                    t.reset();
                }
                SpeedReference::Group
            }
            Some(v) => {
                let t = self.train.get_or_insert_with(|| {
                    TrainSpeedCheck::new(SpeedReferenceConfig::default(), lagged.states.len())
                        .expect("the default train-speed settings are valid")
                });
                let p = self
                    .estimate
                    .drives
                    .iter_mut()
                    .map(|d| &mut d.slip_probability);
                if t.update_states(model, lagged.states, v, p) {
                    SpeedReference::TrainSpeed
                } else {
                    SpeedReference::Group
                }
            }
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn monitor_config_from_toml_and_invalid_fields() {
        let c =
            SlipMonitorConfig::from_toml_str("method = \"vmp\"\n[adhesion.vmp]\niterations = 7\n")
                .unwrap();
        assert_eq!(c.method, AdhesionMethod::Vmp);
        assert_eq!(c.adhesion.vmp.iterations, 7);
        let e = SlipMonitorConfig::from_toml_str("dt_s = 0.0\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("dt_s"), "{e}");
        let e = SlipMonitorConfig::from_toml_str("method = \"magic\"\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("method"), "{e}");
        let e = SlipMonitorConfig::from_toml_str("[motor]\nr_s_ohm = -1.0\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("motor.r_s_ohm"), "{e}");
        assert!(SlipMonitor::new(&SlipMonitorConfig::default(), 0).is_err());
    }

    #[test]
    fn the_paper_preset_is_the_base_and_single_keys_override_it() {
        let c = SlipMonitorConfig::from_toml_str(
            "preset = \"paper\"\n[ekf]\nmeasurement_noise_a2 = 0.02\n",
        )
        .unwrap();
        assert_eq!(c.ekf.process_noise_diag, [0.05, 0.05, 0.001, 0.0001, 0.1]);
        assert_eq!(c.ekf.initial_covariance_diag, [1.0; 5]);
        assert_eq!(c.ekf.measurement_noise_a2, 0.02);
        assert_eq!(c.method, AdhesionMethod::Temporal);
        // Without a preset a key overrides the default's value only.
        let c = SlipMonitorConfig::from_toml_str("[ekf]\ninitial_torque_nm = 5.0\n").unwrap();
        assert_eq!(c.ekf.process_noise_diag, [1e-5, 1e-5, 1e-4, 1e-6, 1.0]);
        assert_eq!(c.ekf.initial_torque_nm, 5.0);
        let e = SlipMonitorConfig::from_toml_str("preset = \"magic\"\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("magic") && e.contains("paper"), "{e}");
        let e = SlipMonitorConfig::from_toml_str("preset = \"paper\"\n[ekf]\ngain = 1.0\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("ekf") && e.contains("gain"), "{e}");
    }

    #[test]
    fn method_names_round_trip() {
        for m in AdhesionMethod::ALL {
            assert_eq!(m.to_string().parse::<AdhesionMethod>().unwrap(), m);
        }
        assert_eq!(AdhesionMethod::KMeans.to_string(), "kmeans");
    }
}
