//! The vehicle stream: 1 Hz frames of the vehicle's channels -> `railmon_fuel::FuelMonitor` ->
//! fuel rate now, virtual fuel sensor, forecast over the horizon, driving regime and its
//! probabilities, cumulative fuel, forecast error, regime-change events, history.
//! Settings in [`config`], the JSON in [`view`], the ingest side in [`pipeline`], the
//! endpoints in [`routes`], the metric families in [`metrics`].

pub mod config;
pub mod metrics;
pub mod pipeline;
pub mod routes;
pub mod view;

pub use config::VehicleConfig;
pub use metrics::VehicleMetrics;
pub use pipeline::VehiclePipeline;
pub use routes::{routes, VehicleApi};
pub use view::{IntervalView, RegimeEventDetail, VehicleHistoryPoint, VehicleShared, VehicleView};

impl VehicleConfig {
    /// The outbox of the vehicle stream, sized by this config.
    pub fn outbox(&self, store: std::sync::Arc<crate::store::EventStore>) -> VehicleShared {
        VehicleShared::new(self.history_capacity, store)
    }
}
