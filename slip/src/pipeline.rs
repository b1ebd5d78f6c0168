//! The offline pipeline: one EKF bank feeding every adhesion method at once, so that all
//! methods see the same torque estimates (what `railmon analyze adhesion` and the benches run),
//! each with its own slip alarm.

use crate::adhesion::{AdhesionEstimator, AdhesionMethod, AdhesionOutput};
use crate::alarm::{SlipAlarm, SlipAlarmEvent};
use crate::ekf::EkfBank;
use crate::error::SlipError;
use crate::monitor::SlipMonitorConfig;
use crate::sample::{validate_frame, DriveSample};
use crate::speed_reference::{
    validate_train_speed, SpeedReference, SpeedReferenceConfig, TrainSpeedCheck,
};

/// EKF bank plus one estimator and one alarm per method.
#[derive(Debug, Clone)]
pub struct MultiMethodPipeline {
    bank: EkfBank,
    estimators: Vec<AdhesionEstimator>,
    alarms: Vec<SlipAlarm>,
    /// Per method, the alarm's events of the last step.
    events: Vec<Vec<SlipAlarmEvent>>,
    torque: Vec<f64>,
    /// Per method, its own train-speed test, as a [`crate::SlipMonitor`] of that method runs
    /// it (the test's calibration learns where the method does not flag, and the method's flag
    /// stands where the wheel has left the train): each method's probabilities, alarm and
    /// events are then those of the monitor, and `railmon analyze` raises the service's.
    train: Vec<TrainSpeedCheck>,
    /// Per method, its probability or, for the drives the train-speed test judges, the test's
    /// (steps with a train speed only).
    combined: Vec<Vec<f64>>,
    /// Per method, what its last step was judged against.
    references: Vec<SpeedReference>,
    /// Whether the last step had a train speed.
    train_steps: bool,
}

impl MultiMethodPipeline {
    /// All methods of [`AdhesionMethod::ALL`] with the settings in `config`.
    pub fn new(config: &SlipMonitorConfig, n_drives: usize) -> Result<Self, SlipError> {
        Self::with_methods(config, n_drives, &AdhesionMethod::ALL)
    }

    pub fn with_methods(
        config: &SlipMonitorConfig,
        n_drives: usize,
        methods: &[AdhesionMethod],
    ) -> Result<Self, SlipError> {
        config.validate()?;
        let bank = EkfBank::new(config.model()?, &config.ekf, n_drives)?;
        let estimators = methods
            .iter()
            .map(|&m| AdhesionEstimator::new(m, &config.adhesion, n_drives))
            .collect::<Result<_, _>>()?;
        let alarms = methods
            .iter()
            .map(|_| SlipAlarm::new(config.alarm, n_drives))
            .collect::<Result<_, _>>()?;
        Ok(MultiMethodPipeline {
            bank,
            estimators,
            alarms,
            events: vec![Vec::new(); methods.len()],
            torque: vec![0.0; n_drives],
            train: methods
                .iter()
                .map(|_| TrainSpeedCheck::new(SpeedReferenceConfig::default(), n_drives))
                .collect::<Result<_, _>>()?,
            combined: vec![vec![0.0; n_drives]; methods.len()],
            references: vec![SpeedReference::Group; methods.len()],
            train_steps: false,
        })
    }

    /// Sets the drives' geometry and the train-speed test (default:
    /// [`SpeedReferenceConfig::default`]).
    pub fn set_speed_reference(&mut self, config: SpeedReferenceConfig) -> Result<(), SlipError> {
        for t in &mut self.train {
            *t = TrainSpeedCheck::new(config, self.bank.n_drives())?;
        }
        Ok(())
    }

    /// Carries every method over `missing_steps` periods no frame covered, as
    /// [`crate::SlipMonitor::bridge`].
    pub fn bridge(&mut self, missing_steps: u64) {
        if missing_steps == 0 || !self.bank.bridge(missing_steps) {
            return;
        }
        for e in &mut self.estimators {
            e.ekfs_relocked();
        }
        for t in &mut self.train {
            t.reset();
        }
    }

    /// One frame through the EKFs and every estimator. A bad frame changes nothing.
    pub fn step(&mut self, samples: &[DriveSample]) -> Result<(), SlipError> {
        self.step_with_train_speed(samples, None)
    }

    /// [`MultiMethodPipeline::step`] with the train's measured speed (m/s) when there is one:
    /// every method's probability (and its alarm) is then the train-speed test's for the drives
    /// it judges, as [`crate::SlipMonitor::step_with_train_speed`].
    pub fn step_with_train_speed(
        &mut self,
        samples: &[DriveSample],
        train_speed_m_s: Option<f64>,
    ) -> Result<(), SlipError> {
        if let Some(v) = train_speed_m_s {
            validate_frame(samples, self.bank.n_drives())?;
            validate_train_speed(v)?;
        }
        self.bank.step(samples)?;
        for (t, f) in self.torque.iter_mut().zip(self.bank.filters()) {
            *t = f.torque_nm();
        }
        for e in &mut self.estimators {
            e.estimate(&self.torque)?;
        }
        let Some(v) = train_speed_m_s else {
            if self.train_steps {
                for t in &mut self.train {
                    t.reset();
                }
                self.references.fill(SpeedReference::Group);
                self.train_steps = false;
            }
            for ((e, alarm), events) in self
                .estimators
                .iter()
                .zip(&mut self.alarms)
                .zip(&mut self.events)
            {
                events.clear();
                alarm.update(&e.output().slip_probability, events);
            }
            return Ok(());
        };
        self.train_steps = true;
        for ((((e, alarm), events), combined), (train, reference)) in self
            .estimators
            .iter()
            .zip(&mut self.alarms)
            .zip(&mut self.events)
            .zip(&mut self.combined)
            .zip(self.train.iter_mut().zip(&mut self.references))
        {
            // The method's probability, replaced by the test's for the drives it judges.
            combined.copy_from_slice(&e.output().slip_probability);
            *reference = if train.update(&self.bank, v, combined.iter_mut()) {
                SpeedReference::TrainSpeed
            } else {
                SpeedReference::Group
            };
            events.clear();
            alarm.update(combined, events);
        }
        Ok(())
    }

    /// `(method, what its last step's probabilities were judged against)` of every method.
    pub fn references(&self) -> impl Iterator<Item = (AdhesionMethod, SpeedReference)> + '_ {
        self.estimators
            .iter()
            .zip(&self.references)
            .map(|(e, r)| (e.method(), *r))
    }

    /// `(method, its train-speed test)` (the low-passed slip velocities) of every method.
    pub fn train_speed_checks(&self) -> impl Iterator<Item = (AdhesionMethod, &TrainSpeedCheck)> {
        self.estimators
            .iter()
            .zip(&self.train)
            .map(|(e, t)| (e.method(), t))
    }

    /// `(method, slip probability per drive)` of every method after the last step: the
    /// method's own ([`MultiMethodPipeline::outputs`]) without a train speed, the train-speed
    /// test's for the drives it judges with one.
    pub fn slip_probability(&self) -> impl Iterator<Item = (AdhesionMethod, &[f64])> {
        let train = self.train_steps;
        self.estimators
            .iter()
            .zip(&self.combined)
            .map(move |(e, c)| {
                let p = if train {
                    c.as_slice()
                } else {
                    e.output().slip_probability.as_slice()
                };
                (e.method(), p)
            })
    }

    pub fn bank(&self) -> &EkfBank {
        &self.bank
    }

    /// The EKF torque estimates of the last step.
    pub fn torque_nm(&self) -> &[f64] {
        &self.torque
    }

    /// `(method, output)` of every estimator for the last step.
    pub fn outputs(&self) -> impl Iterator<Item = (AdhesionMethod, &AdhesionOutput)> {
        self.estimators.iter().map(|e| (e.method(), e.output()))
    }

    /// `(method, slipping flag per drive)` of every method's alarm after the last step.
    pub fn slipping(&self) -> impl Iterator<Item = (AdhesionMethod, &[bool])> {
        self.estimators
            .iter()
            .zip(&self.alarms)
            .map(|(e, a)| (e.method(), a.slipping()))
    }

    /// `(method, alarm events of the last step)` of every method.
    pub fn events(&self) -> impl Iterator<Item = (AdhesionMethod, &[SlipAlarmEvent])> {
        self.estimators
            .iter()
            .zip(&self.events)
            .map(|(e, v)| (e.method(), v.as_slice()))
    }
}
