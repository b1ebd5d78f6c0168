//! What every stream section's settings share: the checks of the keys each stream has, and
//! the error of a setting. A leaf: the streams' config sections use it, and the service's
//! config (which aggregates them) does not need to be imported by them.

use railmon_settings::SettingsError;

/// The setting `key` cannot be used, and why.
pub(crate) fn invalid(key: &str, reason: String) -> SettingsError {
    SettingsError::new(key, reason)
}

/// The keys every stream section has: staleness, history and event ring sizes.
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
        if !(1..=3_600_000).contains(&value) {
            return Err(invalid(
                &format!("{section}.{key}"),
                format!("{value} is not in 1..=3600000"),
            ));
        }
    }
    if !(1..=1_000_000).contains(&history_capacity) {
        return Err(invalid(
            &format!("{section}.history_capacity"),
            format!("{history_capacity} is not in 1..=1000000"),
        ));
    }
    Ok(())
}
