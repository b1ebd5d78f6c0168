//! The drive stream: frames of all traction drives -> `railmon_slip::SlipMonitor` -> per-drive
//! slip probability, speed, load torque, slipping flag with hysteresis, slip events, history.
//! Settings in [`config`], the JSON in [`view`], the ingest side in [`pipeline`], the
//! endpoints in [`routes`], the metric families in [`metrics`].

pub mod config;
pub mod metrics;
pub mod pipeline;
pub mod routes;
pub mod view;

pub use config::DriveConfig;
pub use metrics::DriveMetrics;
pub use pipeline::DrivePipeline;
pub use routes::{routes, DriveApi};
pub use view::{DriveShared, DriveView, DrivesView, HistoryPoint, SlipEventDetail};

impl DriveConfig {
    /// The outbox of the drive stream, sized by this config.
    pub fn outbox(&self, store: std::sync::Arc<crate::store::EventStore>) -> DriveShared {
        DriveShared::new(self.history_capacity, store)
    }
}
