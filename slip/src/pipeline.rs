//! The offline pipeline: one EKF bank feeding every adhesion method at once, so that all
//! methods see the same torque estimates (what `railmon analyze adhesion` and the benches run),
//! each with its own slip alarm.

use crate::adhesion::{AdhesionEstimator, AdhesionMethod, AdhesionOutput};
use crate::alarm::{SlipAlarm, SlipAlarmEvent};
use crate::ekf::EkfBank;
use crate::error::SlipError;
use crate::monitor::SlipMonitorConfig;
use crate::sample::DriveSample;

/// EKF bank plus one estimator and one alarm per method.
#[derive(Debug, Clone)]
pub struct MultiMethodPipeline {
    bank: EkfBank,
    estimators: Vec<AdhesionEstimator>,
    alarms: Vec<SlipAlarm>,
    /// Per method, the alarm's events of the last step.
    events: Vec<Vec<SlipAlarmEvent>>,
    torque: Vec<f64>,
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
        })
    }

    /// One frame through the EKFs and every estimator. A bad frame changes nothing.
    pub fn step(&mut self, samples: &[DriveSample]) -> Result<(), SlipError> {
        self.bank.step(samples)?;
        for (t, f) in self.torque.iter_mut().zip(self.bank.filters()) {
            *t = f.torque_nm();
        }
        for e in &mut self.estimators {
            e.estimate(&self.torque)?;
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
        Ok(())
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
