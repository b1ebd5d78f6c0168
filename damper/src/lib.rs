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

pub mod alarm;
pub mod burst;
pub mod config;
pub mod consistency;
pub mod ekf;
pub mod error;
pub mod estimate;
pub mod expm;
pub mod faults;
pub mod filter_model;
pub mod fingerprint;
pub mod gain_table;
pub mod kalman;
pub mod model;
pub mod monitor;
pub mod noise_scale;
pub mod params;
pub mod rbpf;
pub mod sample;
pub mod sampler;
pub mod scenario;
pub mod simulator;
pub mod speed;
pub mod speed_profile;
pub mod status;
pub mod track;
pub mod trend;

pub use alarm::{DamperAlarm, DamperAlarmConfig, DamperEvent, DamperEventKind};
pub use config::DamperMonitorConfig;
pub use consistency::{ConsistencyCheck, ConsistencyConfig};
pub use ekf::{AugmentedEkf, EkfConfig, EkfEstimate};
pub use error::DamperError;
pub use estimate::{BodyMass, DamperEstimate, MassSource};
pub use faults::{DamperFault, DamperId, FaultKind};
pub use filter_model::FilterModel;
pub use gain_table::GainGridConfig;
pub use monitor::{DamperMonitor, DamperMonitorState, MAX_STEPPED_OVER_SAMPLES};
pub use noise_scale::{NoiseScale, NoiseScaleConfig};
pub use params::{BogieParams, Dampers, DEFAULT_SPEED_M_S};
pub use rbpf::{
    slowest_time_constant_s, DamperPosterior, JumpSearchConfig, KernelSchedule, Propagation, Rbpf,
    RbpfConfig, RbpfEstimate, RbpfState, UnmeasuredMassConfig, MIN_DEGRADED_PARTICLES, N_SENTINELS,
};
pub use sample::{BogieSample, SampleRanges, SensorNoise};
pub use scenario::DamperScenario;
pub use simulator::{BogieSimulator, BogieTruth};
pub use speed::{PauseReason, SpeedConfig};
pub use speed_profile::SpeedProfile;
pub use status::{
    BogieStatusEvent, BogieStatusEventDetail, BogieStatusEventKind, BogieStatusWatch,
};
pub use track::{ErriLevel, TrackSpec};
pub use trend::{DegradationTrend, TimeToThreshold, TrendEstimate};
