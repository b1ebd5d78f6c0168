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
    /// A sensor value beyond its plausible magnitude (`SampleRanges`, `key` its setting):
    /// data in other units (mm/s^2, mrad/s) or a broken sensor. The sample is refused.
    #[error("{field} = {value:.4e} is beyond +-{max} ({key}; wrong units?)")]
    SampleOutOfRange {
        field: &'static str,
        value: f64,
        max: f64,
        key: &'static str,
    },
    /// The scenario or monitor configuration text could not be parsed.
    #[error("configuration: {0}")]
    Config(String),
    /// A shared numerics routine failed.
    #[error(transparent)]
    Filter(#[from] railmon_filter::FilterError),
}

impl DamperError {
    /// Why a sample is refused, as the service's metric label (`reason="not_finite"`), for
    /// errors about one sample that leave the estimator unchanged; `None` for the others.
    /// The service counts a refused sample under it and goes on; `railmon analyze damper`
    /// counts and skips it the same way.
    pub fn reason(&self) -> Option<&'static str> {
        match self {
            DamperError::InvalidSample {
                field: "speed_m_s",
                value,
            } if value.is_finite() => Some("speed_out_of_range"),
            DamperError::InvalidSample {
                field: "half_body_mass_kg",
                value,
            } if value.is_finite() => Some("mass_out_of_range"),
            DamperError::InvalidSample { .. } => Some("not_finite"),
            DamperError::SampleOutOfRange { .. } => Some("out_of_range"),
            _ => None,
        }
    }
}
