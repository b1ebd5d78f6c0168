//! The offline pipeline: one EKF bank feeding every adhesion method at once, so that all
//! methods see the same torque estimates (what `railmon analyze adhesion` and the benches run).

use crate::adhesion::{AdhesionEstimator, AdhesionMethod, AdhesionOutput};
use crate::ekf::EkfBank;
use crate::error::SlipError;
use crate::monitor::SlipMonitorConfig;
use crate::sample::DriveSample;

/// EKF bank plus one estimator per method.
#[derive(Debug, Clone)]
pub struct MultiMethodPipeline {
    bank: EkfBank,
    estimators: Vec<AdhesionEstimator>,
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
        Ok(MultiMethodPipeline {
            bank,
            estimators,
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
}
