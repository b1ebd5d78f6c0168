//! `[drive]`: the traction-drive stream (voltages and currents of every drive at 8 kHz) ->
//! `railmon_slip::SlipMonitor`.

use railmon_bus::MAX_DRIVES;
use railmon_slip::{DriveRanges, SlipMonitorConfig, SpeedReferenceConfig};
use serde::{Deserialize, Serialize};

use railmon_settings::SettingsError;

use crate::stream_keys::{
    invalid, validate_stream_keys, HISTORY_CAPACITY, MAX_ABS_SAMPLE, STREAM_INTERVAL_MS,
};

/// Bounds of `max_drives`: a frame holds at most [`MAX_DRIVES`].
const MAX_DRIVES_RANGE: std::ops::RangeInclusive<usize> = 1..=MAX_DRIVES;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct DriveConfig {
    /// Ingest the drive stream (traction drives' currents and voltages at 8 kHz: wheel slip).
    pub enabled: bool,
    /// The stream is stale (and `/readyz` fails) when no frame came for this long; the
    /// steps still behind the slip estimate's fixed lag (111 frames) are then published.
    #[schemars(range(min = *STREAM_INTERVAL_MS.start(), max = *STREAM_INTERVAL_MS.end()))]
    pub stale_after_ms: u64,
    /// Frames with more drives are rejected (at most the frame capacity, 32).
    #[schemars(range(min = *MAX_DRIVES_RANGE.start(), max = *MAX_DRIVES_RANGE.end()))]
    pub max_drives: usize,
    /// Plausible magnitudes of the stator currents and voltages: a frame beyond them is
    /// refused (`out_of_range`), not estimated (`railmon_slip::DriveRanges`). Currents in mA
    /// instead of A once gave a load torque of 13,320 N m with no complaint.
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = MAX_ABS_SAMPLE))]
    pub max_abs_current_a: f64,
    /// Plausible magnitude of the stator voltages (V), as `max_abs_current_a` for currents.
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = MAX_ABS_SAMPLE))]
    pub max_abs_voltage_v: f64,
    /// One history point per this much stream time.
    #[schemars(range(min = *STREAM_INTERVAL_MS.start(), max = *STREAM_INTERVAL_MS.end()))]
    pub history_interval_ms: u64,
    /// History points kept (the oldest are dropped).
    #[schemars(range(min = *HISTORY_CAPACITY.start(), max = *HISTORY_CAPACITY.end()))]
    pub history_capacity: usize,
    /// The estimator and its slip alarm (`railmon_slip::SlipMonitorConfig`; the alarm's
    /// hysteresis is `[drive.estimator.alarm]`): its default, or the preset the table
    /// names (`preset = "paper"`), with the given keys on top.
    #[serde(deserialize_with = "railmon_settings::deserialize_with_preset")]
    pub estimator: SlipMonitorConfig,
    /// The train-speed reference (`railmon_slip::SpeedReferenceConfig`), used on frames that
    /// carry the train's measured speed: each drive's wheel speed against it, which sees every
    /// drive losing adhesion at once (the group comparison cannot). Set `gear_ratio` and
    /// `wheel_radius_m` to the vehicle's; without a train speed the drives are judged by the
    /// group alone (docs/adhesion.md).
    pub speed_reference: SpeedReferenceConfig,
}

impl Default for DriveConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            stale_after_ms: railmon_records::sample_clock::DRIVE_STALE_AFTER_MS,
            max_drives: MAX_DRIVES,
            max_abs_current_a: DriveRanges::default().max_abs_current_a,
            max_abs_voltage_v: DriveRanges::default().max_abs_voltage_v,
            history_interval_ms: 10,
            history_capacity: 60_000,
            estimator: SlipMonitorConfig::default(),
            speed_reference: SpeedReferenceConfig::default(),
        }
    }
}

impl DriveConfig {
    pub(crate) fn validate(&self) -> Result<(), SettingsError> {
        validate_stream_keys(
            "drive",
            self.stale_after_ms,
            self.history_interval_ms,
            self.history_capacity,
        )?;
        railmon_settings::check_in_range("drive.max_drives", self.max_drives, &MAX_DRIVES_RANGE)?;
        for (key, value) in [
            ("max_abs_current_a", self.max_abs_current_a),
            ("max_abs_voltage_v", self.max_abs_voltage_v),
        ] {
            if !(value > 0.0 && value <= MAX_ABS_SAMPLE) {
                return Err(invalid(
                    &format!("drive.{key}"),
                    format!("{value} is not in (0, 1e6]"),
                ));
            }
        }
        self.estimator
            .validate()
            .map_err(|e| invalid("drive.estimator", e.to_string()))?;
        // Named by its key (`drive.speed_reference.gear_ratio`), where a user finds it.
        self.speed_reference.validate().map_err(|e| match e {
            railmon_slip::SlipError::InvalidParameter {
                field,
                value,
                reason,
            } => invalid(&format!("drive.{field}"), format!("{value}: {reason}")),
            other => invalid("drive.speed_reference", other.to_string()),
        })
    }
}
