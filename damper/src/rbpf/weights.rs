//! The particles' weights `exp(log_w)`, kept between the places that need them.

use std::borrow::Cow;

use railmon_filter::FilterError;

use super::fast_exp::exp_shifted_in_place;

/// `w_i = exp(log_w_i)` with the `log_w_i` it was taken of. A step needs the same weights
/// twice (the published summary after it, the predictive weights of the next step's NIS and
/// noise estimate), and `exp` over a thousand particles was 4-5 % of the monitor's step
/// (issue 28): they are taken again only when a log-weight changed, always by the same
/// vectorised `exp` (`fast_exp`, within 2 ulp of `f64::exp`), so the values are a function
/// of the log-weights whoever changed them in between.
#[derive(Debug, Clone, Default)]
pub(super) struct LinearWeights {
    /// The log-weights `w` was taken of.
    log_w: Vec<f64>,
    w: Vec<f64>,
}

impl LinearWeights {
    /// `exp(log_w)`, taken again (over the whole slice, vectorised) when any log-weight
    /// changed: after a resampling or a normalisation nearly all do.
    pub(super) fn of(&mut self, log_w: &[f64]) -> &[f64] {
        if !self.holds(log_w) {
            self.take(log_w);
        }
        &self.w
    }

    /// Keeps `exp(log_w)` and the log-weights it was taken of.
    fn take(&mut self, log_w: &[f64]) {
        self.log_w.clear();
        self.log_w.extend_from_slice(log_w);
        self.w.clear();
        self.w.extend_from_slice(log_w);
        exp_shifted_in_place(&mut self.w, 0.0);
    }

    /// Normalises `log_w` in place (`sum_i exp(log_w_i) = 1`), keeps its weights and returns
    /// the log of the old sum (the log-evidence increment) and the effective sample size
    /// `1 / sum w_i^2`: what `railmon_filter::logspace`'s normaliser, ESS and `exp` took
    /// three libm passes for, in two vectorised ones (`fast_exp`, issue 28). The weights are
    /// a function of the normalised log-weights alone (not of the sum they were normalised
    /// by), so a filter resumed from its log-weights publishes the same bits.
    pub(super) fn normalise(&mut self, log_w: &mut [f64]) -> Result<(f64, f64), FilterError> {
        if log_w.iter().any(|v| v.is_nan()) {
            return Err(FilterError::NonFinite {
                what: "log-weights",
            });
        }
        let max = log_w.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        if !max.is_finite() {
            return Err(FilterError::AllWeightsZero);
        }
        // `exp(log_w_i - max)` in place of the weights, summed in the particles' order.
        self.w.clear();
        self.w.extend_from_slice(log_w);
        exp_shifted_in_place(&mut self.w, -max);
        let total = max + self.w.iter().sum::<f64>().ln();
        for lw in log_w.iter_mut() {
            *lw -= total;
        }
        // Every normalised log-weight differs from the kept ones: no comparison first.
        self.take(log_w);
        Ok((total, 1.0 / self.w.iter().map(|w| w * w).sum::<f64>()))
    }

    /// `exp(log_w)`: the kept values when they were taken of exactly `log_w`, else taken now.
    pub(super) fn get(&self, log_w: &[f64]) -> Cow<'_, [f64]> {
        if self.holds(log_w) {
            Cow::Borrowed(&self.w)
        } else {
            let mut w = log_w.to_vec();
            exp_shifted_in_place(&mut w, 0.0);
            Cow::Owned(w)
        }
    }

    /// Whether the kept weights were taken of exactly `log_w`.
    fn holds(&self, log_w: &[f64]) -> bool {
        self.log_w.len() == log_w.len()
            && self
                .log_w
                .iter()
                .zip(log_w)
                .all(|(a, b)| a.to_bits() == b.to_bits())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn within_2_ulp_of_std(w: &[f64], lw: &[f64]) -> bool {
        w.iter()
            .zip(lw)
            .all(|(w, lw)| w.to_bits().abs_diff(lw.exp().to_bits()) <= 2)
    }

    /// Whatever changed in between, the weights are `exp` of the log-weights asked about.
    #[test]
    fn kept_weights_follow_every_change_of_the_log_weights() {
        let mut lw = vec![-1.0, -2.0, f64::NEG_INFINITY];
        let mut w = LinearWeights::default();
        let first = w.get(&lw).into_owned();
        assert!(within_2_ulp_of_std(&first, &lw));
        assert_eq!(w.of(&lw), first);
        assert!(matches!(w.get(&lw), Cow::Borrowed(_)));
        lw[1] = -0.5;
        assert!(matches!(w.get(&lw), Cow::Owned(_)));
        let changed = w.get(&lw).into_owned();
        assert!(within_2_ulp_of_std(&changed, &lw));
        assert_eq!(w.of(&lw), changed);
        lw.push(-3.0);
        assert!(within_2_ulp_of_std(w.of(&lw), &lw));
        lw.truncate(1);
        assert_eq!(
            w.get(&lw).as_ref(),
            LinearWeights::default().get(&lw).as_ref()
        );
        assert!(within_2_ulp_of_std(w.of(&lw), &lw));
    }

    /// Two passes give what normalising, the ESS and `exp` gave in three, up to rounding;
    /// the kept weights are those of the normalised log-weights, as a fresh filter takes them.
    #[test]
    fn normalising_keeps_the_weights_of_the_normalised_log_weights() {
        use railmon_filter::logspace::{effective_sample_size, normalize_log_weights};
        let raw: Vec<f64> = (0..1000)
            .map(|i| -3e4 - 40.0 * ((i as f64) * 0.731).sin().powi(2))
            .chain([f64::NEG_INFINITY])
            .collect();
        let mut expected = raw.clone();
        let ln_total = normalize_log_weights(&mut expected).unwrap();
        let mut lw = raw.clone();
        let mut w = LinearWeights::default();
        let (total, ess) = w.normalise(&mut lw).unwrap();
        // The sum's `exp` differs from libm's by up to 2 ulp: the log-sum by ~1 ulp of 3e4.
        let tol = 1e-15 * ln_total.abs();
        assert!((total - ln_total).abs() <= tol, "{total} {ln_total}");
        for (a, b) in lw.iter().zip(&expected) {
            assert!(a == b || (a - b).abs() <= tol, "{a} {b}");
        }
        // Log-weights rounded at the raw weights' magnitude (3e4: ~4e-12 absolute) carry that
        // into the ESS and the weights, relative.
        let rel_tol = 4.0 * 3e4 * f64::EPSILON;
        let ess_expected = effective_sample_size(&expected);
        assert!(
            (ess / ess_expected - 1.0).abs() < rel_tol,
            "{ess} {ess_expected}"
        );
        assert!(matches!(w.get(&lw), Cow::Borrowed(_)));
        assert!(within_2_ulp_of_std(&w.get(&lw), &lw));
        assert_eq!(
            w.get(&lw).as_ref(),
            LinearWeights::default().get(&lw).as_ref()
        );
        assert_eq!(w.get(&lw)[1000], 0.0);
        let mut all_zero = vec![f64::NEG_INFINITY; 3];
        assert!(w.normalise(&mut all_zero).is_err());
        let mut nan = vec![0.0, f64::NAN];
        assert!(w.normalise(&mut nan).is_err());
    }
}
