//! What every stream section's settings share: the checks of the keys each stream has, and
//! the error of a setting. A leaf: the streams' config sections use it, and the service's
//! config (which aggregates them) does not need to be imported by them.

use railmon_settings::{check_in_range, SettingsError};

/// The setting `key` cannot be used, and why.
pub(crate) fn invalid(key: &str, reason: String) -> SettingsError {
    SettingsError::new(key, reason)
}

/// The keys every stream section has: staleness, history and event ring sizes.
/// Bounds of every stream's `stale_after_ms` and `history_interval_ms` (ms), and of its
/// `history_capacity` (points), declared to the reference on each stream's fields.
pub(crate) const STREAM_INTERVAL_MS: std::ops::RangeInclusive<u64> = 1..=3_600_000;
pub(crate) const HISTORY_CAPACITY: std::ops::RangeInclusive<usize> = 1..=1_000_000;
/// Upper end of the plausible sample magnitudes (`drive.max_abs_current_a`, ...): each is
/// in `(0, MAX_ABS_SAMPLE]` (declared to the settings reference and checked).
pub(crate) const MAX_ABS_SAMPLE: f64 = 1e6;

pub(crate) fn validate_stream_keys(
    section: &str,
    stale_after_ms: u64,
    history_interval_ms: u64,
    history_capacity: usize,
) -> Result<(), SettingsError> {
    for (key, value) in [
        ("stale_after_ms", stale_after_ms),
        ("history_interval_ms", history_interval_ms),
    ] {
        check_in_range(&format!("{section}.{key}"), value, &STREAM_INTERVAL_MS)?;
    }
    check_in_range(
        &format!("{section}.history_capacity"),
        history_capacity,
        &HISTORY_CAPACITY,
    )
}
