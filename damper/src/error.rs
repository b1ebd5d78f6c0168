//! The damper crate's error type.

/// Errors of the damper crate.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DamperError {
    /// A configuration value is out of range.
    #[error("invalid parameter {field} = {value}: {reason}")]
    InvalidParameter {
        field: &'static str,
        value: f64,
        reason: &'static str,
    },
    /// A value that must be finite was NaN or infinite.
    #[error("non-finite value in {what}")]
    NonFinite { what: &'static str },
    /// A sensor sample was rejected before it reached the filter (the filter is unchanged).
    #[error("invalid sample: {field} = {value}")]
    InvalidSample { field: &'static str, value: f64 },
    /// The scenario or monitor configuration text could not be parsed.
    #[error("configuration: {0}")]
    Config(String),
    /// A shared numerics routine failed.
    #[error(transparent)]
    Filter(#[from] railmon_filter::FilterError),
}
