//! Damper health of a bogie: the 17-state plan-view model and its simulator, a
//! Rao-Blackwellised particle filter (Liu-West kernel on the log damping coefficients, one
//! Kalman filter per particle) and the augmented-state EKF baseline. No I/O.
//!
//! Source: Li, Goodall, Kadirkamanathan, "Parameter estimation of railway vehicle dynamic
//! model using Rao-Blackwellised particle filter" (`../shared/seeds/001_68f01c1310f14ea5.txt`),
//! with the corrections of `../shared/docs/seed-notes.md`.
//!
//! The service runs one [`DamperMonitor`] per bogie (`step` one validated [`BogieSample`] at
//! a time); [`BogieSimulator`] gives samples and ground truth for a [`DamperScenario`].
//! Design, results and measurements: `docs/damper.md`.

pub mod config;
pub mod ekf;
pub mod expm;
pub mod gain_table;
pub mod kalman;
pub mod model;
pub mod monitor;
pub mod params;
pub mod rbpf;
pub mod scenario;
pub mod simulator;
pub mod track;

pub use config::{
    DamperMonitorConfig, EkfConfig, GainGridConfig, KernelSchedule, Propagation, RbpfConfig,
};
pub use ekf::{AugmentedEkf, EkfEstimate};
pub use monitor::{DamperEstimate, DamperMonitor};
pub use params::{BogieParams, Dampers};
pub use rbpf::{DamperPosterior, Rbpf, RbpfEstimate};
pub use scenario::DamperScenario;
pub use simulator::{
    BogieSample, BogieSimulator, BogieTruth, DamperFault, DamperId, FaultKind, SensorNoise,
};
pub use track::{ErriLevel, TrackSpec};

/// Errors of the damper crate.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DamperError {
    /// A configuration value is out of range.
    #[error("invalid parameter {field} = {value}: {reason}")]
    InvalidParameter {
        field: &'static str,
        value: f64,
        reason: &'static str,
    },
    /// A value that must be finite was NaN or infinite.
    #[error("non-finite value in {what}")]
    NonFinite { what: &'static str },
    /// A sensor sample was rejected before it reached the filter (the filter is unchanged).
    #[error("invalid sample: {field} = {value}")]
    InvalidSample { field: &'static str, value: f64 },
    /// The scenario or monitor configuration text could not be parsed.
    #[error("configuration: {0}")]
    Config(String),
    /// A shared numerics routine failed.
    #[error(transparent)]
    Filter(#[from] railmon_filter::FilterError),
}
