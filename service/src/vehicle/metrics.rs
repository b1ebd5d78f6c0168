//! Metric families of the vehicle stream, in base units (m^3/s, m^3, m/s).

use prometheus::{Histogram, IntCounter, IntGauge};

use crate::metrics::{EstimateGauge, EstimateGaugeVec, Families};

/// Buckets of the absolute fuel forecast error, m^3/s: 0.01 to 10 cm^3/s (a 2.5 l engine at
/// full load burns ~10 cm^3/s).
pub const FUEL_ERROR_BUCKETS_M3_S: [f64; 10] =
    [1e-8, 2e-8, 5e-8, 1e-7, 2e-7, 5e-7, 1e-6, 2e-6, 5e-6, 1e-5];

pub struct VehicleMetrics {
    pub fuel_rate: EstimateGaugeVec,
    pub fuel_forecast: EstimateGaugeVec,
    pub fuel_consumed: EstimateGaugeVec,
    pub forecast_error: EstimateGauge,
    pub forecast_abs_error: Histogram,
    pub regime_probability: EstimateGaugeVec,
    pub regime_active: IntGauge,
    pub regime_changes: IntCounter,
    pub snapshot_refused: IntCounter,
    pub speed: EstimateGauge,
    pub initialising: IntGauge,
}

impl VehicleMetrics {
    pub fn new(f: &Families) -> Result<Self, prometheus::Error> {
        Ok(Self {
            fuel_rate: f.estimate_gauge_vec(
                "vehicle_fuel_rate_cubic_meters_per_second",
                "Fuel flow now: measured, virtual sensor, 0-step estimate, 1-step forecast made a step ago.",
                &["kind"],
            )?,
            fuel_forecast: f.estimate_gauge_vec(
                "vehicle_fuel_forecast_cubic_meters_per_second",
                "Forecast fuel flow horizon_s seconds ahead.",
                &["horizon_s"],
            )?,
            fuel_consumed: f.estimate_gauge_vec(
                "vehicle_fuel_consumed_cubic_meters",
                "Fuel used since the source started: measured, and from the virtual sensor since initialisation.",
                &["kind"],
            )?,
            forecast_error: f.estimate_gauge(
                "vehicle_fuel_forecast_error_cubic_meters_per_second",
                "Measured fuel minus its honest 1-step forecast, last sample.",
            )?,
            forecast_abs_error: f.histogram(
                "vehicle_fuel_forecast_absolute_error_cubic_meters_per_second",
                "Absolute error of the honest 1-step fuel forecast.",
                &FUEL_ERROR_BUCKETS_M3_S,
            )?,
            regime_probability: f.estimate_gauge_vec(
                "vehicle_regime_probability_ratio",
                "Probability of each driving regime (mixture component, 0-based).",
                &["regime"],
            )?,
            regime_active: f.int_gauge(
                "vehicle_regime_active",
                "The most probable regime (0-based; -1 while initialising).",
            )?,
            regime_changes: f.int_counter(
                "vehicle_regime_changes_total",
                "Changes of the most probable regime.",
            )?,
            snapshot_refused: f.int_counter(
                "vehicle_snapshot_refused_total",
                "Vehicle snapshots found at start and refused (another format version, other \
                 settings, too old, corrupt): the fuel estimator started from its prior.",
            )?,
            speed: f.estimate_gauge(
                "vehicle_speed_meters_per_second",
                "Measured vehicle speed.",
            )?,
            initialising: f.int_gauge(
                "vehicle_estimator_initialising",
                "1 while the fuel estimator collects its initial samples.",
            )?,
        })
    }
}
