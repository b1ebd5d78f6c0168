//! When two components of one regime are one (issue 25 item 1): the Bayes factor of merging
//! them, from their Gauss-inverse-Wishart statistics alone.
//!
//! With every regime given (`pointer_regimes`) the mixture has a budget of components per
//! regime; how many of them the data need is not a constant of the route. Two components of a
//! regime whose fuel regressions the data cannot tell apart are merged (their statistics pooled,
//! one slot freed at its prior); a freed slot learns again from the samples the merged component
//! explains worst (the quasi-Bayes weights of eq. 9 give it their share), which is the split.
//!
//! The test is the one the virtual sensor depends on: fuel (`d_0`) regressed on everything else
//! in `d = [y; psi]` (the other channels now and the lags, as
//! [`crate::RegressionStats::condition_first_on_rest`] reads it). For a scalar normal regression
//! with statistics `V` (eq. 10) and count `kappa` (eq. 11), the GiW normaliser is
//! `I(V, kappa) = Gamma(kappa / 2) (Lambda / 2)^(-kappa / 2) |V_rr|^(-1/2) (2 pi)^(p / 2)`,
//! `V_rr` the block of the regressors (`p` of them) and `Lambda = V_00 - V_0r V_rr^-1 V_r0 =
//! |V| / |V_rr|` the least-squares remainder (seed-notes erratum to eq. 13). The evidence of
//! data is `I(V_n, kappa_n) / I(V_0, kappa_0) (2 pi)^(-n / 2)`, so the log Bayes factor of one
//! component for the data of both against one each is
//! `ln I(V_i + V_j - V_0, kappa_i + kappa_j - kappa_0) + ln I(V_0, kappa_0) - ln I(V_i, kappa_i)
//! - ln I(V_j, kappa_j)`: the factors of `2` and `2 pi` cancel. With stabilised forgetting the
//! statistics are `V_0` plus forgotten data, so the pooled ones are too.

use nalgebra::DMatrix;
use railmon_filter::special::ln_gamma;

/// `ln |A|` of a symmetric positive definite `A`, `None` if it is not.
fn ln_det(a: DMatrix<f64>) -> Option<f64> {
    let chol = a.cholesky()?;
    let l = chol.l_dirty();
    Some((0..l.nrows()).map(|i| 2.0 * l[(i, i)].ln()).sum())
}

/// `ln I(V, kappa)` of element `k` of `d` regressed on the elements after it (fuel on the
/// rest for `k = 0`), without the terms that cancel in [`log_merge_factor`] (module
/// documentation); `None` for statistics that are not positive definite.
pub fn log_normaliser(v: &DMatrix<f64>, kappa: f64, k: usize) -> Option<f64> {
    let d = v.nrows();
    let ln_v = ln_det(v.view((k, k), (d - k, d - k)).into_owned())?;
    let ln_rr = ln_det(v.view((k + 1, k + 1), (d - k - 1, d - k - 1)).into_owned())?;
    let ln_lambda = ln_v - ln_rr;
    Some(ln_gamma(0.5 * kappa) - 0.5 * kappa * ln_lambda - 0.5 * ln_rr)
}

/// `ln` of the Bayes factor for one component holding the data of statistics `(v_i, kappa_i)`
/// and `(v_j, kappa_j)` against one each, both from the prior `(v0, kappa0)` (module
/// documentation), for the first `outputs` elements of `d` by the chain rule: element 0 given
/// the rest, element 1 given those after it, .. (1: the fuel's regression; all of `y` for the
/// pointer's levels, whose regressor is the constant). Positive: the data say they are one.
/// `None` if any statistics are not positive definite.
pub fn log_merge_factor(
    (v_i, kappa_i): (&DMatrix<f64>, f64),
    (v_j, kappa_j): (&DMatrix<f64>, f64),
    (v0, kappa0): (&DMatrix<f64>, f64),
    outputs: usize,
) -> Option<f64> {
    let pooled = v_i + v_j - v0;
    let mut sum = 0.0;
    for k in 0..outputs {
        sum += log_normaliser(&pooled, kappa_i + kappa_j - kappa0, k)?
            + log_normaliser(v0, kappa0, k)?
            - log_normaliser(v_i, kappa_i, k)?
            - log_normaliser(v_j, kappa_j, k)?;
    }
    Some(sum)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DVector;
    use rand::{Rng, SeedableRng};
    use rand_distr::{Distribution, Normal};

    /// Statistics of `n` samples of `y = a + b x + e`, `e ~ N(0, 0.1^2)`, `d = [y, x, 1]`.
    fn stats(n: usize, a: f64, b: f64, rng: &mut impl Rng) -> (DMatrix<f64>, f64) {
        let noise = Normal::new(0.0, 0.1).unwrap();
        let mut v = DMatrix::identity(3, 3) * 1e-3;
        for _ in 0..n {
            let x: f64 = rng.random_range(-1.0..1.0);
            let d = DVector::from_vec(vec![a + b * x + noise.sample(rng), x, 1.0]);
            v += &d * d.transpose();
        }
        (v, 1.0 + n as f64)
    }

    /// The factor favours merging two samples of one regression and refuses two that differ
    /// by a slope of 0.2 (twice the noise at the ends), for every seed.
    #[test]
    fn one_regression_merges_two_do_not() {
        let v0 = DMatrix::identity(3, 3) * 1e-3;
        for seed in 0..20 {
            let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
            let (vi, ki) = stats(200, 1.0, 0.5, &mut rng);
            let (vj, kj) = stats(200, 1.0, 0.5, &mut rng);
            let (vk, kk) = stats(200, 1.0, 0.7, &mut rng);
            let same = log_merge_factor((&vi, ki), (&vj, kj), (&v0, 1.0), 1).unwrap();
            let other = log_merge_factor((&vi, ki), (&vk, kk), (&v0, 1.0), 1).unwrap();
            assert!(same > 0.0, "seed {seed}: {same}");
            assert!(other < -10.0, "seed {seed}: {other}");
        }
    }

    /// `ln I` is the marginal likelihood: for one datum it equals `ln` of the Student-t
    /// predictive computed directly (intercept-only model, `d = [y, 1]`).
    #[test]
    fn the_normaliser_gives_the_predictive_density() {
        let v0 = DMatrix::from_row_slice(2, 2, &[2.0, 1.0, 1.0, 4.0]);
        let kappa0 = 3.0;
        let y = 0.7;
        let d = DVector::from_vec(vec![y, 1.0]);
        let v1 = &v0 + &d * d.transpose();
        // Cancelled terms restored: (Lambda / 2)^(-kappa/2) has 2^(kappa/2), and one datum
        // (2 pi)^(-1/2).
        let with =
            |v: &DMatrix<f64>, k: f64| log_normaliser(v, k, 0).unwrap() + 0.5 * k * 2f64.ln();
        let evidence =
            with(&v1, kappa0 + 1.0) - with(&v0, kappa0) - 0.5 * (2.0 * std::f64::consts::PI).ln();
        // Student-t: mean V_01 / V_11, scale^2 = Lambda / kappa (1 + 1 / V_11), dof kappa.
        let mean = v0[(0, 1)] / v0[(1, 1)];
        let lambda = v0[(0, 0)] - v0[(0, 1)] * v0[(0, 1)] / v0[(1, 1)];
        let s2 = lambda / kappa0 * (1.0 + 1.0 / v0[(1, 1)]);
        let z = (y - mean) * (y - mean) / s2;
        let nu = kappa0;
        let t = ln_gamma(0.5 * (nu + 1.0))
            - ln_gamma(0.5 * nu)
            - 0.5 * (nu * std::f64::consts::PI * s2).ln()
            - 0.5 * (nu + 1.0) * (1.0 + z / nu).ln();
        assert!((evidence - t).abs() < 1e-12, "{evidence} {t}");
    }
}
