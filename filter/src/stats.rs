//! Order statistics and the summaries the offline reports print.

/// Quantile `q` in [0, 1] of sorted data, by linear interpolation between order statistics
/// (numpy's default, "type 7"), so our tables compare with numpy/pandas output.
pub fn quantile_sorted(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let pos = q.clamp(0.0, 1.0) * (sorted.len() - 1) as f64;
    let lo = pos.floor() as usize;
    let hi = pos.ceil() as usize;
    sorted[lo] + (pos - lo as f64) * (sorted[hi] - sorted[lo])
}

/// Median of unsorted data (copies and sorts). NaN for empty input.
pub fn median(values: &[f64]) -> f64 {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    quantile_sorted(&v, 0.5)
}

/// The columns of the adhesion paper's Table 1: min, quartiles, max, mean, standard deviation
/// and interquartile range.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Summary {
    pub min: f64,
    pub q1: f64,
    pub median: f64,
    pub q3: f64,
    pub max: f64,
    pub mean: f64,
    /// Sample standard deviation (divides by n - 1).
    pub std: f64,
    pub iqr: f64,
    pub n: usize,
}

impl Summary {
    /// Summary of `values`; `None` when empty or any value is not finite.
    pub fn of(values: &[f64]) -> Option<Summary> {
        if values.is_empty() || values.iter().any(|v| !v.is_finite()) {
            return None;
        }
        let mut v = values.to_vec();
        v.sort_by(f64::total_cmp);
        let n = v.len();
        let mean = v.iter().sum::<f64>() / n as f64;
        let var = if n > 1 {
            v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64
        } else {
            0.0
        };
        let q1 = quantile_sorted(&v, 0.25);
        let q3 = quantile_sorted(&v, 0.75);
        Some(Summary {
            min: v[0],
            q1,
            median: quantile_sorted(&v, 0.5),
            q3,
            max: v[n - 1],
            mean,
            std: var.sqrt(),
            iqr: q3 - q1,
            n,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn summary_matches_numpy() {
        // numpy: np.percentile([1,2,3,4,10], [25,50,75]) = [2, 3, 4]; std(ddof=1) = 3.5355339
        let s = Summary::of(&[4.0, 1.0, 10.0, 3.0, 2.0]).unwrap();
        assert_eq!(
            (s.min, s.q1, s.median, s.q3, s.max),
            (1.0, 2.0, 3.0, 4.0, 10.0)
        );
        assert!((s.mean - 4.0).abs() < 1e-12);
        assert!((s.std - 3.535_533_905_932_737_6).abs() < 1e-12);
        assert_eq!(s.iqr, 2.0);
        // interpolated: np.percentile([1,2,3,4], 25) = 1.75
        assert!((quantile_sorted(&[1.0, 2.0, 3.0, 4.0], 0.25) - 1.75).abs() < 1e-12);
        assert_eq!(median(&[5.0, 1.0, 3.0, 2.0]), 2.5);
    }

    #[test]
    fn summary_rejects_empty_and_nan() {
        assert!(Summary::of(&[]).is_none());
        assert!(Summary::of(&[1.0, f64::NAN]).is_none());
    }
}
