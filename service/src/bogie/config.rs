//! `[bogie]`: the bogie stream (five inertial sensors per bogie at 1 kHz) -> one
//! `railmon_damper::DamperMonitor` per configured bogie.

use railmon_damper::DamperMonitorConfig;
use serde::{Deserialize, Serialize};

use railmon_settings::SettingsError;

use crate::stream_keys::{
    invalid, validate_stream_keys, HISTORY_CAPACITY, MAX_ABS_SAMPLE, STREAM_INTERVAL_MS,
};

/// Most bogies one service monitors (a vehicle has two per car; a unit of eight cars 16).
pub const MAX_BOGIES: usize = 16;

/// `[bogie]`: the bogie stream (five inertial sensors per bogie at 1 kHz) -> one
/// `railmon_damper::DamperMonitor` per configured bogie id.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct BogieConfig {
    /// Off by default: only vehicles with bogie sensors publish this stream, and `/readyz`
    /// requires every enabled stream to be fresh.
    pub enabled: bool,
    /// The bogie ids frames may carry (at most [`MAX_BOGIES`], unique); others are rejected
    /// (`unknown_bogie`).
    pub bogies: Vec<u32>,
    /// The stream is stale (and `/readyz` fails) when no frame came for this long; also the
    /// most the estimates may fall behind the samples' clock before the stream is `lagging`.
    #[schemars(range(min = *STREAM_INTERVAL_MS.start(), max = *STREAM_INTERVAL_MS.end()))]
    pub stale_after_ms: u64,
    /// Plausible magnitudes of the lateral accelerations (m/s^2) and of the yaw rate (rad/s):
    /// a frame beyond them is refused (`out_of_range`), not estimated. Data scaled by 1000
    /// (mm/s^2, mrad/s) once read as a damper at 10 % of its health: a false `degraded`.
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = MAX_ABS_SAMPLE))]
    pub max_abs_accel_m_s2: f64,
    /// Plausible magnitude of the yaw rate (rad/s), as `max_abs_accel_m_s2` for accelerations.
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = MAX_ABS_SAMPLE))]
    pub max_abs_yaw_rate_rad_s: f64,
    /// One history point per bogie per this much stream time.
    #[schemars(range(min = *STREAM_INTERVAL_MS.start(), max = *STREAM_INTERVAL_MS.end()))]
    pub history_interval_ms: u64,
    /// History points kept (the oldest are dropped).
    #[schemars(range(min = *HISTORY_CAPACITY.start(), max = *HISTORY_CAPACITY.end()))]
    pub history_capacity: usize,
    /// Threads stepping the bogies' filters besides the ingest thread (the frames of one
    /// sample time are stepped side by side). Unset: one fewer than the cores, at most one
    /// fewer than the bogies ([`BogieConfig::worker_threads`]); 0: all on the ingest thread.
    pub worker_threads: Option<usize>,
    /// Degraded compute: what the bogies' filters do when they cannot keep up with real time
    /// (docs/damper.md, "Degraded compute").
    pub realtime: BogieRealtimeConfig,
    /// The estimator (`railmon_damper::DamperMonitorConfig`): its default, or the preset the
    /// table names (`preset = "paper"`), with the given keys on top (e.g.
    /// `RAILMON_BOGIE__ESTIMATOR__RBPF__PARTICLES=100`). Each bogie's RBPF is seeded with
    /// `rbpf.seed + bogie id - 1`; `alarm` is the degraded / recovered rule.
    #[serde(deserialize_with = "railmon_settings::deserialize_with_preset")]
    pub estimator: DamperMonitorConfig,
}

impl Default for BogieConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            bogies: vec![1, 2],
            stale_after_ms: railmon_records::sample_clock::BOGIE_STALE_AFTER_MS,
            max_abs_accel_m_s2: 50.0,
            max_abs_yaw_rate_rad_s: 5.0,
            history_interval_ms: 100,
            history_capacity: 72_000,
            worker_threads: None,
            realtime: BogieRealtimeConfig::default(),
            estimator: DamperMonitorConfig::default(),
        }
    }
}

/// Bounds of `bogie.realtime.lag_budget_ms`: at least ten 1 kHz frames (less, the scheduler's
/// jitter alone exceeds it), at most a minute (longer, the lag's own baseline window of 30-60 s,
/// `crate::ingest`'s `RealTimeTracker`, forgets it before the budget is reached).
pub const LAG_BUDGET_MS: std::ops::RangeInclusive<u64> = 10..=60_000;

/// `[bogie.realtime]`: when the bogies' filters cannot keep up with real time (their load, or
/// their lag over the budget), every bogie's particle filter runs fewer particles (resampled
/// down, to `railmon_damper::MIN_DEGRADED_PARTICLES` at least) instead of falling behind, and
/// the configured count again once the CPU is back (`super::compute`). Reported in
/// `/api/v1/bogies` and `/api/v1/status` (`compute`), the metrics `bogie_particles` and
/// `bogie_compute_degradations_total`, and the events `compute_degraded` /
/// `compute_restored`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct BogieRealtimeConfig {
    /// The most the estimates may fall behind the samples' clock (the stream's `lag_s`) before
    /// the particles are cut; they are raised again only while the lag stays under half of it.
    #[schemars(range(min = *LAG_BUDGET_MS.start(), max = *LAG_BUDGET_MS.end()))]
    pub lag_budget_ms: u64,
}

impl Default for BogieRealtimeConfig {
    fn default() -> Self {
        // Half the 100 ms p99 target: a cut takes two windows (2 s) to show.
        Self { lag_budget_ms: 50 }
    }
}

impl BogieConfig {
    /// The worker threads to start (see the field).
    pub fn worker_threads(&self) -> usize {
        self.worker_threads.unwrap_or_else(|| {
            let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
            cores.min(self.bogies.len()).saturating_sub(1)
        })
    }

    pub(crate) fn validate(&self) -> Result<(), SettingsError> {
        validate_stream_keys(
            "bogie",
            self.stale_after_ms,
            self.history_interval_ms,
            self.history_capacity,
        )?;
        for (key, value) in [
            ("max_abs_accel_m_s2", self.max_abs_accel_m_s2),
            ("max_abs_yaw_rate_rad_s", self.max_abs_yaw_rate_rad_s),
        ] {
            if !(value > 0.0 && value <= MAX_ABS_SAMPLE) {
                return Err(invalid(
                    &format!("bogie.{key}"),
                    format!("{value} is not in (0, 1e6]"),
                ));
            }
        }
        if let Some(n) = self.worker_threads.filter(|&n| n >= MAX_BOGIES) {
            return Err(invalid(
                "bogie.worker_threads",
                format!("{n}, expected 0..{MAX_BOGIES} (one per bogie at most)"),
            ));
        }
        let budget = self.realtime.lag_budget_ms;
        if !LAG_BUDGET_MS.contains(&budget) {
            return Err(invalid(
                "bogie.realtime.lag_budget_ms",
                format!(
                    "{budget}, expected {}..={}",
                    LAG_BUDGET_MS.start(),
                    LAG_BUDGET_MS.end()
                ),
            ));
        }
        let ids = &self.bogies;
        if ids.is_empty() || ids.len() > MAX_BOGIES {
            return Err(invalid(
                "bogie.bogies",
                format!("{} ids, expected 1..={MAX_BOGIES}", ids.len()),
            ));
        }
        if let Some(id) = ids
            .iter()
            .enumerate()
            .find_map(|(k, id)| ids[..k].contains(id).then_some(id))
        {
            return Err(invalid(
                "bogie.bogies",
                format!("bogie id {id} appears twice"),
            ));
        }
        self.estimator
            .validate()
            .map_err(|e| invalid("bogie.estimator", e.to_string()))
    }
}
