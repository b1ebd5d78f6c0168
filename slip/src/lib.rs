//! Wheel slip (adhesion loss) of traction drives, after Dedecius, "Centralized estimation of
//! adhesion loss in wheel-rail system using variational Bayes and variational message
//! passing" (UTIA report 2329, 2013) with the errata of `docs/seed-notes.md`. No I/O.
//!
//! Data flow: [`DriveSample`]s (voltages, currents) of N drives -> [`EkfBank`] (one 5-state
//! sensorless EKF per drive, eq. 11-17) -> N load-torque estimates -> an
//! [`AdhesionEstimator`] (VB, VMP, k-means, median, or our temporal method) -> global torque
//! `M_z^(G)` and per-drive slip probabilities -> [`SlipAlarm`] (the slipping flag and its
//! events, hysteresis on the probability). [`SlipMonitor`] ties the first two together;
//! [`DriveSimulator`] produces data with ground truth from an [`AdhesionScenario`]. With the
//! train's own speed ([`SlipMonitor::step_with_train_speed`], [`speed_reference`]) each drive is
//! also judged against it, which sees every drive losing adhesion at once.

pub mod adhesion;
pub mod alarm;
pub mod bound;
pub mod ekf;
pub mod error;
pub mod fixed_lag;
pub mod model;
pub mod monitor;
pub mod pipeline;
pub mod sample;
pub mod sampler;
pub mod scenario;
pub mod score;
pub mod simulator;
pub mod special;
pub mod speed_reference;

pub use adhesion::{AdhesionConfig, AdhesionEstimator, AdhesionMethod, AdhesionOutput};
pub use alarm::{SlipAlarm, SlipAlarmConfig, SlipAlarmEvent, SlipAlarmKind};
pub use ekf::{EkfBank, EkfConfig};
pub use error::SlipError;
pub use model::{DriveModel, MotorParams};
pub use monitor::{DriveEstimate, SlipEstimate, SlipMonitor, SlipMonitorConfig};
pub use pipeline::MultiMethodPipeline;
pub use sample::{
    is_slipping, DriveRanges, DriveSample, DriveTruth, OutOfRange, SLIP_RULE_FLOOR_NM,
    SLIP_RULE_FRACTION,
};
pub use scenario::{AdhesionScenario, SlipEvent};
pub use score::{DetectionCounter, DetectionScore};
pub use simulator::DriveSimulator;
pub use speed_reference::{
    validate_train_speed, SpeedReference, SpeedReferenceConfig, TRAIN_SPEED_RANGE_M_S,
};
