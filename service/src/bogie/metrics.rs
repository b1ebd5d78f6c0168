//! Metric families of the bogie stream (labels `bogie`, `damper`: `csy` or `csay`).

use prometheus::{GaugeVec, IntCounterVec, IntGaugeVec};

use crate::metrics::Families;

pub struct BogieMetrics {
    pub damping: GaugeVec,
    pub health: GaugeVec,
    pub degraded: IntGaugeVec,
    pub effective_sample_size: GaugeVec,
    pub events: IntCounterVec,
}

impl BogieMetrics {
    pub fn new(f: &Families) -> Result<Self, prometheus::Error> {
        let damper = &["bogie", "damper"];
        Ok(Self {
            damping: f.gauge_vec(
                "bogie_damping_newton_seconds_per_meter",
                "Estimated damping coefficient (RBPF posterior mean and 5%/95% quantiles).",
                &["bogie", "damper", "quantity"],
            )?,
            health: f.gauge_vec(
                "bogie_damper_health_ratio",
                "Damper health: posterior mean over nominal damping.",
                damper,
            )?,
            degraded: f.int_gauge_vec(
                "bogie_damper_degraded",
                "1 while the damper is flagged degraded (hysteresis on the health ratio).",
                damper,
            )?,
            effective_sample_size: f.gauge_vec(
                "bogie_effective_sample_size",
                "Effective sample size of the bogie's particle filter (particles).",
                &["bogie"],
            )?,
            events: f.int_counter_vec(
                "bogie_damper_events_total",
                "Damper degraded / recovered events.",
                &["bogie", "damper", "kind"],
            )?,
        })
    }
}
