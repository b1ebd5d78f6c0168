//! Metric families of the bogie stream (labels `bogie`, `damper`: `csy` or `csay`).

use prometheus::{IntCounter, IntCounterVec, IntGaugeVec};

use crate::metrics::{EstimateGaugeVec, EstimateIntGaugeVec, Families};

pub struct BogieMetrics {
    pub damping: EstimateGaugeVec,
    pub health: EstimateGaugeVec,
    pub degraded: EstimateIntGaugeVec,
    pub trend: EstimateGaugeVec,
    pub hours_to_threshold: EstimateGaugeVec,
    pub effective_sample_size: EstimateGaugeVec,
    pub events: IntCounterVec,
    pub paused: EstimateIntGaugeVec,
    pub speed: EstimateGaugeVec,
    pub snapshot_refused: IntCounter,
    pub particles: IntGaugeVec,
    pub compute_degradations: IntCounter,
}

impl BogieMetrics {
    pub fn new(f: &Families) -> Result<Self, prometheus::Error> {
        let damper = &["bogie", "damper"];
        Ok(Self {
            damping: f.estimate_gauge_vec(
                "bogie_damping_newton_seconds_per_meter",
                "Estimated damping coefficient (RBPF posterior mean and 5%/95% quantiles).",
                &["bogie", "damper", "quantity"],
            )?,
            health: f.estimate_gauge_vec(
                "bogie_damper_health_ratio",
                "Damper health: posterior mean over nominal damping.",
                damper,
            )?,
            degraded: f.estimate_gauge_vec(
                "bogie_damper_degraded",
                "1 while the damper is flagged degraded (hysteresis on the health ratio).",
                damper,
            )?,
            trend: f.estimate_gauge_vec(
                "bogie_damper_health_trend_per_operating_hour",
                "Damper degradation trend: change of the health ratio per operating hour over the \
                 last operating hour (quantity: rate, q05, q95; NaN before two operating minutes).",
                &["bogie", "damper", "quantity"],
            )?,
            hours_to_threshold: f.estimate_gauge_vec(
                "bogie_damper_operating_hours_to_threshold",
                "Operating hours until the health ratio reaches the degraded threshold at its \
                 trend (0 once below; NaN unless the trend is significantly negative).",
                damper,
            )?,
            effective_sample_size: f.estimate_gauge_vec(
                "bogie_effective_sample_size",
                "Effective sample size of the bogie's particle filter (particles).",
                &["bogie"],
            )?,
            events: f.int_counter_vec(
                "bogie_damper_events_total",
                "Damper degraded / recovered events.",
                &["bogie", "damper", "kind"],
            )?,
            paused: f.estimate_gauge_vec(
                "bogie_damper_paused",
                "1 while the bogie's filter holds its posterior: the speed outside its valid \
                 range (reason: low_speed, high_speed) or its states settling after missing \
                 samples (gap).",
                &["bogie", "reason"],
            )?,
            speed: f.estimate_gauge_vec(
                "bogie_speed_meters_per_second",
                "Vehicle speed of the bogie's last sample.",
                &["bogie"],
            )?,
            snapshot_refused: f.int_counter(
                "bogie_snapshot_refused_total",
                "Bogie snapshots found at start and refused (another format version, other \
                 settings, too old, corrupt): the filters started from their prior.",
            )?,
            particles: f.int_gauge_vec(
                "bogie_particles",
                "Particles the bogie's filter runs now: the configured count (estimator.rbpf.\
                 particles) unless the compute is degraded (bogie.realtime).",
                &["bogie"],
            )?,
            compute_degradations: f.int_counter(
                "bogie_compute_degradations_total",
                "Cuts of the bogies' particles because the filters could not keep up with real \
                 time (each a compute_degraded event).",
            )?,
        })
    }
}
