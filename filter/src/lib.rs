//! Numerics shared by the railmon estimators.
//!
//! Everything here is pure maths on `f64`, no I/O. The estimator crates (`railmon-slip`,
//! `railmon-damper`, `railmon-fuel`) use these pieces so that one implementation serves
//! wherever the logic is the same:
//! - [`kalman`]: the measurement update in Joseph form and covariance hygiene;
//! - [`logspace`]: log-sum-exp, normalising log-weights, effective sample size;
//! - [`normal`]: the standard normal CDF (`erfc`);
//! - [`resample`]: systematic resampling;
//! - [`special`]: `ln Gamma`;
//! - [`stats`]: order statistics and the summaries written to CSV reports.

pub mod kalman;
pub mod logspace;
pub mod normal;
pub mod resample;
pub mod special;
pub mod stats;

/// Errors of the shared numerics.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FilterError {
    /// The innovation covariance `S = H P H' + R` could not be inverted (not positive definite).
    #[error("innovation covariance is not positive definite")]
    InnovationNotPositiveDefinite,
    /// A value that must be finite was NaN or infinite.
    #[error("non-finite value in {what}")]
    NonFinite { what: &'static str },
    /// All log-weights were -inf (or NaN): nothing to normalise.
    #[error("all weights are zero")]
    AllWeightsZero,
}
