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
    /// The speed changed faster than the vehicle can accelerate or brake since the last
    /// accepted sample (`ChannelRanges::acceleration_m_s2`): speed in another unit (km/h read
    /// as m/s multiplies every acceleration by 3.6) or a faulty speed sensor.
    #[error(
        "sample at t = {time_s} s: speed {speed_m_s} m/s after {previous_speed_m_s} m/s {step_s} s \
         before is an acceleration of {acceleration_m_s2:.3} m/s^2, outside [{min}, {max}] (a sensor \
         glitch or speed in km/h?)"
    )]
    AccelerationOutOfRange {
        speed_m_s: f64,
        previous_speed_m_s: f64,
        step_s: f64,
        acceleration_m_s2: f64,
        min: f64,
        max: f64,
        time_s: f64,
    },
    /// The time stamp is not finite or does not increase.
    #[error("sample time {time_s} s does not follow the previous time {previous_s} s")]
    TimeNotIncreasing { time_s: f64, previous_s: f64 },
    /// Consecutive time stamps not a whole number of sample periods apart, or further apart
    /// than the longest gap: data at another rate, or time in another unit (ms for s).
    #[error(
        "sample at t = {time_s} s: {step_s} s after the previous one, not a whole number of \
         the configured period {period_s} s within {max_gap_s} s (another rate, or time in ms?)"
    )]
    SamplePeriod {
        time_s: f64,
        step_s: f64,
        period_s: f64,
        max_gap_s: f64,
    },
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
    /// The time stamp of the sample refused, for errors about one sample.
    pub fn time_s(&self) -> Option<f64> {
        match self {
            FuelError::MissingChannel { time_s, .. }
            | FuelError::MissingGear { time_s }
            | FuelError::NonFinite { time_s, .. }
            | FuelError::OutOfRange { time_s, .. }
            | FuelError::AccelerationOutOfRange { time_s, .. }
            | FuelError::TimeNotIncreasing { time_s, .. }
            | FuelError::SamplePeriod { time_s, .. }
            | FuelError::UnknownCategory { time_s, .. } => Some(*time_s),
            _ => None,
        }
    }

    /// The column of the railmon vehicle layout the refusal is about and its value (empty when
    /// the channel is missing), for errors about one sample.
    pub fn field(&self) -> Option<(&'static str, String)> {
        match self {
            FuelError::MissingChannel { channel, .. } => Some((channel.column(), String::new())),
            FuelError::MissingGear { .. } => Some(("gear", String::new())),
            FuelError::NonFinite { channel, value, .. }
            | FuelError::OutOfRange { channel, value, .. } => {
                Some((channel.column(), value.to_string()))
            }
            FuelError::AccelerationOutOfRange { speed_m_s, .. } => {
                Some((Channel::Speed.column(), speed_m_s.to_string()))
            }
            FuelError::TimeNotIncreasing { time_s, .. }
            | FuelError::SamplePeriod { time_s, .. } => Some(("time_s", time_s.to_string())),
            FuelError::UnknownCategory { gear, .. } => Some(("gear", gear.to_string())),
            _ => None,
        }
    }

    /// Why a sample is refused, as the service's metric label (`reason="out_of_range"`),
    /// for errors about one sample that leave the estimator unchanged (`None` for the
    /// others: a configuration or numerical failure is not the sample's fault). The service
    /// counts a refused sample under this label and goes on; `railmon analyze` counts and
    /// skips it the same way.
    pub fn reason(&self) -> Option<&'static str> {
        match self {
            FuelError::MissingChannel { .. } | FuelError::MissingGear { .. } => {
                Some("missing_channel")
            }
            FuelError::NonFinite { .. } => Some("not_finite"),
            FuelError::OutOfRange { .. } => Some("out_of_range"),
            FuelError::AccelerationOutOfRange { .. } => Some("acceleration_out_of_range"),
            FuelError::UnknownCategory { .. } => Some("unknown_category"),
            FuelError::TimeNotIncreasing { .. } => Some("time_not_increasing"),
            FuelError::SamplePeriod { .. } => Some("period_mismatch"),
            FuelError::InvalidParameter { .. }
            | FuelError::Numerical(_)
            | FuelError::Scenario(_) => None,
        }
    }

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
