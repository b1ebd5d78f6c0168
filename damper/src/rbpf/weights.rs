//! The particles' weights `exp(log_w)`, kept between the places that need them.

use std::borrow::Cow;

/// `w_i = exp(log_w_i)` with the `log_w_i` it was taken of. A step needs the same weights
/// twice (the published summary after it, the predictive weights of the next step's NIS and
/// noise estimate), and `exp` over a thousand particles was 4-5 % of the monitor's step
/// (issue 28): each entry is taken again only when its log-weight changed, so the values are
/// bit for bit `log_w_i.exp()` whoever changed the weights in between.
#[derive(Debug, Clone, Default)]
pub(super) struct LinearWeights {
    /// The log-weights `w` was taken of.
    log_w: Vec<f64>,
    w: Vec<f64>,
}

impl LinearWeights {
    /// `exp(log_w)`, the entries whose log-weight changed taken again.
    pub(super) fn of(&mut self, log_w: &[f64]) -> &[f64] {
        if self.log_w.len() != log_w.len() {
            self.log_w = vec![f64::NAN; log_w.len()];
            self.w = vec![f64::NAN; log_w.len()];
        }
        for ((kept, w), lw) in self.log_w.iter_mut().zip(&mut self.w).zip(log_w) {
            if kept.to_bits() != lw.to_bits() {
                *kept = *lw;
                *w = lw.exp();
            }
        }
        &self.w
    }

    /// `exp(log_w)`: the kept values when they were taken of exactly `log_w`, else taken now.
    pub(super) fn get(&self, log_w: &[f64]) -> Cow<'_, [f64]> {
        let kept = self.log_w.len() == log_w.len()
            && self
                .log_w
                .iter()
                .zip(log_w)
                .all(|(a, b)| a.to_bits() == b.to_bits());
        if kept {
            Cow::Borrowed(&self.w)
        } else {
            Cow::Owned(log_w.iter().map(|v| v.exp()).collect())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Whatever changed in between, the weights are `exp` of the log-weights asked about.
    #[test]
    fn kept_weights_follow_every_change_of_the_log_weights() {
        let mut lw = vec![-1.0, -2.0, f64::NEG_INFINITY];
        let mut w = LinearWeights::default();
        let exp = |lw: &[f64]| lw.iter().map(|v| v.exp()).collect::<Vec<_>>();
        assert_eq!(w.get(&lw).as_ref(), exp(&lw));
        assert_eq!(w.of(&lw), exp(&lw));
        assert!(matches!(w.get(&lw), Cow::Borrowed(_)));
        lw[1] = -0.5;
        assert!(matches!(w.get(&lw), Cow::Owned(_)));
        assert_eq!(w.get(&lw).as_ref(), exp(&lw));
        assert_eq!(w.of(&lw), exp(&lw));
        lw.push(-3.0);
        assert_eq!(w.of(&lw), exp(&lw));
        lw.truncate(1);
        assert_eq!(w.get(&lw).as_ref(), exp(&lw));
        assert_eq!(w.of(&lw), exp(&lw));
    }
}
