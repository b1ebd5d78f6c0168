//! The particles' weights `exp(log_w)`, kept between the places that need them.

use std::borrow::Cow;

use railmon_filter::FilterError;

use crate::fast_exp::{exp_in_place, exp_into};

/// `w_i = exp(log_w_i)` with the `log_w_i` it was taken of. A step needs the same weights
/// twice (the published summary after it, the predictive weights of the next step's NIS and
/// noise estimate), and `exp` over a thousand particles was 4-5 % of the monitor's step
/// (issue 28): they are taken again only when a log-weight changed, so the values are bit for
/// bit `log_w_i.exp()` whoever changed the weights in between.
#[derive(Debug, Clone, Default)]
pub(super) struct LinearWeights {
    /// The log-weights `w` was taken of.
    log_w: Vec<f64>,
    w: Vec<f64>,
}

impl LinearWeights {
    /// `exp(log_w)`, taken again when a log-weight changed.
    pub(super) fn of(&mut self, log_w: &[f64]) -> &[f64] {
        if !same_bits(&self.log_w, log_w) {
            self.log_w.clear();
            self.log_w.extend_from_slice(log_w);
            self.w.resize(log_w.len(), 0.0);
            exp_into(log_w, &mut self.w);
        }
        &self.w
    }

    /// `exp(log_w)`: the kept values when they were taken of exactly `log_w`, else taken now.
    pub(super) fn get(&self, log_w: &[f64]) -> Cow<'_, [f64]> {
        let kept = same_bits(&self.log_w, log_w);
        if kept {
            Cow::Borrowed(&self.w)
        } else {
            Cow::Owned(log_w.iter().map(|v| v.exp()).collect())
        }
    }
}

/// Whether `a` and `b` hold the same values to the bit.
fn same_bits(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(a, b)| a.to_bits() == b.to_bits())
}

/// `railmon_filter::logspace::normalize_log_weights`, bit for bit (the same checks, sums
/// and order), its exponentials taken by `fast_exp` into `scratch`: normalises `log_w` so
/// that `sum exp(w_i) = 1` and returns the log of the old sum.
pub(super) fn normalize_log_weights(
    log_w: &mut [f64],
    scratch: &mut Vec<f64>,
) -> Result<f64, FilterError> {
    if log_w.iter().any(|v| v.is_nan()) {
        return Err(FilterError::NonFinite {
            what: "log-weights",
        });
    }
    let max = log_w.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let total = if max.is_infinite() {
        max
    } else {
        scratch.clear();
        scratch.extend(log_w.iter().map(|v| v - max));
        exp_in_place(scratch);
        max + scratch.iter().sum::<f64>().ln()
    };
    if !total.is_finite() {
        return Err(FilterError::AllWeightsZero);
    }
    for w in log_w.iter_mut() {
        *w -= total;
    }
    Ok(total)
}

/// `railmon_filter::logspace::effective_sample_size` (`1 / sum w_i^2` of normalised
/// log-weights), bit for bit, its exponentials taken by `fast_exp` into `scratch`.
pub(super) fn effective_sample_size(normalized_log_w: &[f64], scratch: &mut Vec<f64>) -> f64 {
    scratch.clear();
    scratch.extend(normalized_log_w.iter().map(|w| 2.0 * w));
    exp_in_place(scratch);
    1.0 / scratch.iter().sum::<f64>()
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

    /// The same bits and errors as the filter crate's functions they stand in for.
    #[test]
    fn normalising_and_ess_match_the_filter_crate_bit_for_bit() {
        use railmon_filter::logspace as reference;
        let mut scratch = vec![];
        let cases: Vec<Vec<f64>> = vec![
            (0..1000)
                .map(|i| -((i * 7919) % 1000) as f64 * 0.037 - 3.0)
                .collect(),
            vec![-1.0, f64::NEG_INFINITY, -2.5],
            vec![-700.0; 8],
            vec![f64::NEG_INFINITY; 3],
            vec![-1.0, f64::NAN],
            vec![0.5, f64::INFINITY],
        ];
        for case in cases {
            let (mut a, mut b) = (case.clone(), case.clone());
            let (ra, rb) = (
                normalize_log_weights(&mut a, &mut scratch),
                reference::normalize_log_weights(&mut b),
            );
            assert_eq!(ra, rb, "{case:?}");
            assert!(same_bits(&a, &b), "{case:?}");
            if ra.is_ok() {
                let ess = effective_sample_size(&a, &mut scratch);
                assert_eq!(
                    ess.to_bits(),
                    reference::effective_sample_size(&b).to_bits()
                );
            }
        }
    }
}
