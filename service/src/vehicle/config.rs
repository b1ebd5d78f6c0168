//! `[vehicle]`: the vehicle stream (fuel flow, speed and the other channels at 1 Hz) ->
//! `railmon_fuel::FuelMonitor`.

use railmon_fuel::FuelMonitorConfig;
use serde::{Deserialize, Serialize};

use railmon_settings::SettingsError;

use crate::stream_keys::{invalid, validate_stream_keys, HISTORY_CAPACITY, STREAM_INTERVAL_MS};

/// `[vehicle]`: the road-vehicle stream (fuel flow, speed, ... at 1 Hz) -> `railmon_fuel::FuelMonitor`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct VehicleConfig {
    /// Off by default: only vehicles with a fuel meter publish this stream, and `/readyz`
    /// requires every enabled stream to be fresh.
    pub enabled: bool,
    /// The stream is stale (and `/readyz` fails) when no frame came for this long.
    #[schemars(range(min = *STREAM_INTERVAL_MS.start(), max = *STREAM_INTERVAL_MS.end()))]
    pub stale_after_ms: u64,
    /// One history point per this much stream time.
    #[schemars(range(min = *STREAM_INTERVAL_MS.start(), max = *STREAM_INTERVAL_MS.end()))]
    pub history_interval_ms: u64,
    /// History points kept (the oldest are dropped).
    #[schemars(range(min = *HISTORY_CAPACITY.start(), max = *HISTORY_CAPACITY.end()))]
    pub history_capacity: usize,
    /// The estimator (`railmon_fuel::FuelMonitorConfig`): its default, or the preset the table
    /// names (`preset = "railcar"`), with the given keys on top.
    #[serde(deserialize_with = "railmon_settings::deserialize_with_preset")]
    pub estimator: FuelMonitorConfig,
}

impl Default for VehicleConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            stale_after_ms: railmon_records::sample_clock::VEHICLE_STALE_AFTER_MS,
            history_interval_ms: 1000,
            history_capacity: 86_400,
            estimator: FuelMonitorConfig::default(),
        }
    }
}

impl VehicleConfig {
    pub(crate) fn validate(&self) -> Result<(), SettingsError> {
        validate_stream_keys(
            "vehicle",
            self.stale_after_ms,
            self.history_interval_ms,
            self.history_capacity,
        )?;
        self.estimator
            .validate()
            .map_err(|e| invalid("vehicle.estimator", e.to_string()))
    }
}
