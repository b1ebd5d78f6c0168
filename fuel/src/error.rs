//! The errors of the fuel estimator and the vehicle simulator.

use crate::sample::Channel;

/// Everything that can go wrong in `railmon-fuel`. Every variant names what was wrong and the
/// offending value, so that a caller can print it without more context.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FuelError {
    /// A configuration parameter is out of its domain.
    #[error("invalid parameter `{field}` = {value}: {reason}")]
    InvalidParameter {
        field: &'static str,
        value: String,
        reason: &'static str,
    },
    /// A configured channel is absent from the sample.
    #[error("sample at t = {time_s} s: channel `{channel}` is missing")]
    MissingChannel { channel: Channel, time_s: f64 },
    /// The categorical channel (gear) is configured but absent from the sample.
    #[error("sample at t = {time_s} s: the gear is missing (a categorical channel is configured)")]
    MissingGear { time_s: f64 },
    /// A channel value is NaN or infinite.
    #[error("sample at t = {time_s} s: channel `{channel}` is not finite ({value})")]
    NonFinite {
        channel: Channel,
        value: f64,
        time_s: f64,
    },
    /// A channel value is outside its physically plausible range.
    #[error("sample at t = {time_s} s: channel `{channel}` = {value} is outside [{min}, {max}]")]
    OutOfRange {
        channel: Channel,
        value: f64,
        min: f64,
        max: f64,
        time_s: f64,
    },
    /// The time stamp is not finite or does not increase.
    #[error("sample time {time_s} s does not follow the previous time {previous_s} s")]
    TimeNotIncreasing { time_s: f64, previous_s: f64 },
    /// A gear (categorical value) that the configured category groups do not contain.
    #[error("sample at t = {time_s} s: gear {gear} is in no configured category group")]
    UnknownCategory { gear: i32, time_s: f64 },
    /// Numerical breakdown (should not happen with validated parameters; reported, not panicked).
    #[error("numerical failure: {0}")]
    Numerical(&'static str),
    /// A scenario file that does not parse.
    #[error("scenario: {0}")]
    Scenario(String),
}

impl FuelError {
    pub(crate) fn invalid(field: &'static str, value: impl ToString, reason: &'static str) -> Self {
        FuelError::InvalidParameter {
            field,
            value: value.to_string(),
            reason,
        }
    }
}

impl From<railmon_filter::FilterError> for FuelError {
    fn from(e: railmon_filter::FilterError) -> Self {
        match e {
            railmon_filter::FilterError::InnovationNotPositiveDefinite => {
                FuelError::Numerical("covariance not positive definite")
            }
            railmon_filter::FilterError::NonFinite { .. } => {
                FuelError::Numerical("non-finite log-weights")
            }
            railmon_filter::FilterError::AllWeightsZero => {
                FuelError::Numerical("all pointer weights are zero")
            }
        }
    }
}
