//! The bogie stream: 1 kHz frames of each bogie's five inertial sensors -> one
//! `railmon_damper::DamperMonitor` (RBPF + EKF baseline) per configured bogie id -> damping of
//! the secondary lateral (`csy`) and anti-yaw (`csay`) dampers with their 90% intervals, health
//! ratios, effective sample size, degraded / recovered events, history.
//! Settings in [`config`], the JSON in [`view`], the ingest side in [`pipeline`], the
//! endpoints in [`routes`], the metric families in [`metrics`]; the bogies' filters step in
//! parallel on a few worker threads (`workers`, `bogie.worker_threads`); one more thread solves
//! the gain table's speed nodes ahead of them (`warm`). When they cannot keep up with real
//! time, every filter runs fewer particles until the CPU is back (`compute`, `bogie.realtime`).

mod compute;
pub mod config;
pub mod metrics;
pub mod pipeline;
pub mod routes;
pub mod view;
mod warm;
mod workers;

pub use config::{BogieConfig, MAX_BOGIES};
pub use metrics::BogieMetrics;
pub use pipeline::BogiePipeline;
pub use routes::{routes, BogieApi};
pub use view::{BogieShared, BogiesView, ComputeEventDetail, ComputeView, DamperEventDetail};

impl BogieConfig {
    /// The outbox of the bogie stream, sized by this config.
    pub fn outbox(&self, store: std::sync::Arc<crate::store::EventStore>) -> BogieShared {
        BogieShared::new(self.history_capacity, store)
    }
}
