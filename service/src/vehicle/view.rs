//! What the vehicle stream shows: the JSON of `/api/v1/vehicle...` and its history and events.
//! Units: the estimator works in cm^3/s (the JSON fields say so: `_cm3_s`, `_cm3`); the
//! Prometheus metrics are in base units, m^3/s and m^3.

use serde::Serialize;
use utoipa::ToSchema;

use crate::outbox::Outbox;

/// `GET /api/v1/vehicle`: the latest estimate.
#[derive(Clone, Debug, Default, PartialEq, Serialize, ToSchema)]
pub struct VehicleView {
    /// Stream time, s: continuous over publisher restarts and runs; null before the first frame.
    pub time_s: Option<f64>,
    /// When the newest sample used was acquired, RFC 3339 UTC.
    pub time_utc: Option<String>,
    /// Run of the source and the time within it, s.
    pub run: u32,
    pub run_time_s: Option<f64>,
    /// Sequence number of the last frame used.
    pub sequence: Option<u64>,
    /// Samples the estimator accepted from the current source.
    pub samples: u64,
    /// The estimator is still collecting its `init_samples` (no estimates yet).
    pub initialising: bool,
    /// Measured fuel flow now, cm^3/s.
    pub fuel_rate_cm3_s: Option<f64>,
    /// Measured speed now, m/s (if the source has it).
    pub speed_m_s: Option<f64>,
    /// Virtual fuel sensor: fuel now from the other channels now, cm^3/s.
    pub virtual_sensor_cm3_s: Option<f64>,
    /// 90 % interval of the virtual sensor (the mixture's predictive).
    pub virtual_sensor_interval_cm3_s: Option<IntervalView>,
    /// The paper's 0-step estimate (has seen the fuel it estimates), cm^3/s.
    pub zero_step_cm3_s: Option<f64>,
    /// Honest 1-step forecast of this sample's fuel, made a step ago, cm^3/s.
    pub one_step_forecast_cm3_s: Option<f64>,
    /// 90 % interval of the 1-step forecast (null on the first estimate: no forecast was made).
    pub one_step_interval_cm3_s: Option<IntervalView>,
    /// Step between forecast points, s (the estimator's `sample_period_s`).
    pub forecast_step_s: f64,
    /// Fuel forecast for the next `forecast_horizon_steps` steps, cm^3/s (first: one step ahead).
    pub forecast_cm3_s: Vec<f64>,
    /// 90 % interval of each forecast point (same order).
    pub forecast_interval_cm3_s: Vec<IntervalView>,
    /// Driving regime (mixture component, 0-based): the most probable one once it has been
    /// the most probable for `regime_confirm_samples` samples in a row.
    pub regime: Option<usize>,
    /// The most probable regime on this sample (the paper's pointer estimate; flickers).
    pub most_probable_regime: Option<usize>,
    /// What `regime` means, named from its component's statistics: `idle`, `accelerating`,
    /// `cruising`, `coasting`, `braking` or `unsettled` (not converged), qualified where
    /// several components fall under one of these (by mean fuel: `cruising_low_power`,
    /// `cruising_high_power`; an ordinal where the fuel does not tell them apart: `idle_1`,
    /// `idle_2`), so each component's name is unique. docs/fuel.md gives the rule.
    pub regime_name: Option<String>,
    /// The name of `most_probable_regime`.
    pub most_probable_regime_name: Option<String>,
    /// Probability of each regime (index = regime).
    pub regime_probabilities: Vec<f64>,
    /// Name of each regime (index = regime), unique per regime.
    pub regime_names: Vec<String>,
    /// Measured fuel integrated since the source started, cm^3.
    pub cumulative_fuel_cm3: f64,
    /// Virtual sensor integrated since the estimator initialised, cm^3.
    pub cumulative_virtual_fuel_cm3: Option<f64>,
    /// Measured minus 1-step forecast on the last sample, cm^3/s.
    pub forecast_error_cm3_s: Option<f64>,
    /// Root mean square of the 1-step forecast error since the source started, cm^3/s.
    pub forecast_rmse_cm3_s: Option<f64>,
    /// Regime changes since the source started.
    pub regime_changes: u64,
}

/// One point of the history ring.
#[derive(Clone, Debug, PartialEq, Serialize, ToSchema)]
pub struct VehicleHistoryPoint {
    pub time_s: f64,
    pub run: u32,
    pub run_time_s: f64,
    pub fuel_rate_cm3_s: f64,
    pub virtual_sensor_cm3_s: Option<f64>,
    pub one_step_forecast_cm3_s: Option<f64>,
    /// 90 % intervals of the virtual sensor and of the 1-step forecast.
    pub virtual_sensor_interval_cm3_s: Option<IntervalView>,
    pub one_step_interval_cm3_s: Option<IntervalView>,
    pub regime: Option<usize>,
    /// The name of `regime` (see [`VehicleView::regime_name`]).
    pub regime_name: Option<String>,
    pub regime_probabilities: Vec<f64>,
    pub cumulative_fuel_cm3: f64,
}

/// A 90 % predictive interval (5 % to 95 % quantile of the mixture's predictive), cm^3/s.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, ToSchema)]
pub struct IntervalView {
    pub lower_cm3_s: f64,
    pub upper_cm3_s: f64,
}

impl IntervalView {
    /// `None` when either end is not finite (no forecast was made yet).
    pub fn of(interval: railmon_fuel::Interval) -> Option<Self> {
        (interval.lower.is_finite() && interval.upper.is_finite()).then_some(IntervalView {
            lower_cm3_s: interval.lower,
            upper_cm3_s: interval.upper,
        })
    }
}

/// The vehicle stream's fields of a `regime_changed` event (the confirmed driving regime).
#[derive(Clone, Debug, PartialEq, Serialize, ToSchema)]
pub struct RegimeEventDetail {
    pub from_regime: usize,
    pub to_regime: usize,
    /// What the regimes mean on this sample (`idle`, `accelerating`, `cruising`, `coasting`,
    /// `braking`, `unsettled`, qualified as in [`VehicleView::regime_name`]): unique per
    /// regime, so they differ.
    pub from_name: String,
    pub to_name: String,
    /// Probability of the new regime.
    pub probability: f64,
}

impl From<railmon_fuel::RegimeChange> for RegimeEventDetail {
    fn from(c: railmon_fuel::RegimeChange) -> Self {
        Self {
            from_regime: c.from_regime,
            to_regime: c.to_regime,
            from_name: c.from_name.to_string(),
            to_name: c.to_name.to_string(),
            probability: c.probability,
        }
    }
}

/// What the ingest thread shares with the HTTP side.
pub type VehicleShared = Outbox<VehicleView, VehicleHistoryPoint>;
