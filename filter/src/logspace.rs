//! Weights and likelihoods in log space.
//!
//! Products of many densities (a 17-state innovation over thousands of steps, a 5-dimensional
//! normal with a small covariance) underflow `f64` long before they are meaningless, so the
//! estimators keep `ln w` and only exponentiate after subtracting the maximum.

use crate::FilterError;

/// `ln(sum_i exp(a_i))`, stable for large or very negative `a_i`. Returns `-inf` for an empty
/// slice or one that is all `-inf`.
pub fn log_sum_exp(a: &[f64]) -> f64 {
    let max = a.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if max == f64::NEG_INFINITY || max.is_nan() {
        return max;
    }
    if max == f64::INFINITY {
        return f64::INFINITY;
    }
    max + a.iter().map(|v| (v - max).exp()).sum::<f64>().ln()
}

/// Normalises log-weights in place so that `sum exp(w_i) = 1`; returns the log of the old sum
/// (the log marginal likelihood increment when the weights were `ln w + ln p(y|.)`).
pub fn normalize_log_weights(log_w: &mut [f64]) -> Result<f64, FilterError> {
    if log_w.iter().any(|v| v.is_nan()) {
        return Err(FilterError::NonFinite {
            what: "log-weights",
        });
    }
    let total = log_sum_exp(log_w);
    if !total.is_finite() {
        return Err(FilterError::AllWeightsZero);
    }
    for w in log_w.iter_mut() {
        *w -= total;
    }
    Ok(total)
}

/// Probabilities `exp(w_i - logsumexp(w))` written into `out` (same length as `log_w`).
pub fn softmax_into(log_w: &[f64], out: &mut [f64]) -> Result<(), FilterError> {
    assert_eq!(log_w.len(), out.len(), "softmax_into: length mismatch");
    let total = log_sum_exp(log_w);
    if !total.is_finite() {
        return Err(FilterError::AllWeightsZero);
    }
    for (o, w) in out.iter_mut().zip(log_w) {
        *o = (w - total).exp();
    }
    Ok(())
}

/// Effective sample size `1 / sum w_i^2` of *normalised* log-weights.
pub fn effective_sample_size(normalized_log_w: &[f64]) -> f64 {
    1.0 / normalized_log_w
        .iter()
        .map(|w| (2.0 * w).exp())
        .sum::<f64>()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_sum_exp_survives_underflow() {
        let a = [-1000.0, -1000.0];
        assert!((log_sum_exp(&a) - (-1000.0 + 2f64.ln())).abs() < 1e-12);
        assert_eq!(log_sum_exp(&[]), f64::NEG_INFINITY);
        assert_eq!(log_sum_exp(&[f64::NEG_INFINITY; 3]), f64::NEG_INFINITY);
    }

    #[test]
    fn normalised_weights_sum_to_one_and_ess_is_n_for_equal_weights() {
        let mut w = vec![-700.0; 8];
        normalize_log_weights(&mut w).unwrap();
        let s: f64 = w.iter().map(|v| v.exp()).sum();
        assert!((s - 1.0).abs() < 1e-12);
        assert!((effective_sample_size(&w) - 8.0).abs() < 1e-9);
    }

    #[test]
    fn degenerate_weights_are_errors() {
        assert_eq!(
            normalize_log_weights(&mut [f64::NEG_INFINITY, f64::NEG_INFINITY]),
            Err(FilterError::AllWeightsZero)
        );
        assert!(normalize_log_weights(&mut [0.0, f64::NAN]).is_err());
    }
}
