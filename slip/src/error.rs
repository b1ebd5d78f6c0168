//! The one error type of the slip library.

use railmon_filter::FilterError;

/// Errors of the slip library. Every variant names what was wrong, so a caller can print it as
/// is: `invalid parameter motor.r_s_ohm = -1: must be > 0`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SlipError {
    /// A configuration or scenario parameter is out of its domain.
    #[error("invalid parameter {field} = {value}: {reason}")]
    InvalidParameter {
        field: String,
        value: String,
        reason: &'static str,
    },
    /// A frame has a different number of drives than the monitor was built for.
    #[error("frame has {got} drives, the monitor expects {expected}")]
    WrongDriveCount { expected: usize, got: usize },
    /// A sample value is NaN or infinite; `drive` is 1-based as in the paper.
    #[error("drive {drive}: {field} = {value} is not a finite number")]
    NonFiniteSample {
        drive: usize,
        field: &'static str,
        value: f64,
    },
    /// A torque estimate beyond [`crate::adhesion::MAX_TORQUE_ESTIMATE_NM`]: an EKF that has
    /// diverged, not a drive; refused before any method sees it.
    #[error("drive {drive}: torque estimate {value_nm} N m is beyond +-{limit_nm} N m")]
    TorqueBeyondRange {
        drive: usize,
        value_nm: f64,
        limit_nm: f64,
    },
    /// A TOML document (scenario, monitor settings) could not be parsed.
    #[error("TOML: {0}")]
    Toml(String),

    /// A gap the EKFs relock after, with steps still behind the fixed lag (drain them first).
    #[error("{pending} steps still behind the fixed lag before a gap the EKFs relock after")]
    PendingBeforeGap { pending: u64 },
    /// The EKF of one drive failed (e.g. innovation covariance lost positive definiteness);
    /// the monitor state is left as it was before the frame.
    #[error("drive {drive}: EKF update failed: {source}")]
    Filter {
        drive: usize,
        #[source]
        source: FilterError,
    },
    /// An adhesion estimator produced a non-finite value (never expected; reported rather than
    /// propagated into the estimates).
    #[error("adhesion estimator {method}: non-finite {what}")]
    NonFiniteEstimate {
        method: &'static str,
        what: &'static str,
    },
}

impl SlipError {
    pub(crate) fn invalid(
        field: impl Into<String>,
        value: impl ToString,
        reason: &'static str,
    ) -> Self {
        SlipError::InvalidParameter {
            field: field.into(),
            value: value.to_string(),
            reason,
        }
    }

    /// The same error with a parameter's field named under `table` (`table.field`).
    pub(crate) fn under(self, table: &str) -> Self {
        match self {
            SlipError::InvalidParameter {
                field,
                value,
                reason,
            } => SlipError::InvalidParameter {
                field: format!("{table}.{field}"),
                value,
                reason,
            },
            other => other,
        }
    }
}

/// `Ok(())` when `value` is finite and `> 0`, else an error naming `field`.
pub(crate) fn check_positive(field: &str, value: f64) -> Result<(), SlipError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(SlipError::invalid(field, value, "must be finite and > 0"))
    }
}

/// `Ok(())` when `value` is finite and `>= 0`.
pub(crate) fn check_non_negative(field: &str, value: f64) -> Result<(), SlipError> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(SlipError::invalid(field, value, "must be finite and >= 0"))
    }
}

/// `Ok(())` when `value` is finite.
pub(crate) fn check_finite(field: &str, value: f64) -> Result<(), SlipError> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(SlipError::invalid(field, value, "must be finite"))
    }
}

/// `Ok(())` when `lo <= value <= hi` (inclusive bounds given by the caller).
pub(crate) fn check_in(
    field: &str,
    value: f64,
    lo: f64,
    hi: f64,
    reason: &'static str,
) -> Result<(), SlipError> {
    if value.is_finite() && value >= lo && value <= hi {
        Ok(())
    } else {
        Err(SlipError::invalid(field, value, reason))
    }
}
