//! The Kalman measurement update in Joseph form, for fixed-size (`SMatrix`) models.
//!
//! The Joseph form `P+ = (I - K H) P (I - K H)' + K R K'` keeps `P` symmetric positive
//! (semi)definite under rounding, where the short form `(I - K H) P` does not. We also
//! re-symmetrise after each step: cheap, and it stops asymmetry from accumulating over
//! millions of steps.

use nalgebra::{Cholesky, SMatrix, SVector};

use crate::FilterError;

/// `log(2 pi)`, used by Gaussian log-densities.
pub const LN_2PI: f64 = 1.837_877_066_409_345_5;

/// Result of one measurement update.
#[derive(Debug, Clone)]
pub struct Update<const N: usize> {
    /// Posterior mean.
    pub x: SVector<f64, N>,
    /// Posterior covariance (symmetric).
    pub p: SMatrix<f64, N, N>,
    /// Log-density of the observation under the predictive `N(H x-, H P- H' + R)`.
    pub log_likelihood: f64,
}

/// Replaces `p` by `(p + p') / 2`.
pub fn symmetrize<const N: usize>(p: &mut SMatrix<f64, N, N>) {
    for i in 0..N {
        for j in (i + 1)..N {
            let m = 0.5 * (p[(i, j)] + p[(j, i)]);
            p[(i, j)] = m;
            p[(j, i)] = m;
        }
    }
}

/// Kalman measurement update for `y = H x + v`, `v ~ N(0, R)`, in Joseph form.
///
/// `innovation` is `y - h(x-)`: for a linear model `y - H x-`, for an EKF the residual of the
/// non-linear measurement function (then `h` is its Jacobian). Returns the posterior and the
/// log-likelihood `log N(innovation; 0, S)` with `S = H P- H' + R` (not `R` alone: see
/// seed-notes, erratum to eq. 10 of the adhesion paper).
pub fn update_joseph<const N: usize, const M: usize>(
    x: &SVector<f64, N>,
    p: &SMatrix<f64, N, N>,
    innovation: &SVector<f64, M>,
    h: &SMatrix<f64, M, N>,
    r: &SMatrix<f64, M, M>,
) -> Result<Update<N>, FilterError> {
    let ph_t = p * h.transpose();
    let mut s = h * ph_t + r;
    symmetrize(&mut s);
    let chol = Cholesky::new(s).ok_or(FilterError::InnovationNotPositiveDefinite)?;
    // K = P H' S^-1, computed as (S^-1 (H P))' using the Cholesky factor.
    let k = chol.solve(&ph_t.transpose()).transpose();
    let x_post = x + k * innovation;
    let i_kh = SMatrix::<f64, N, N>::identity() - k * h;
    let mut p_post = i_kh * p * i_kh.transpose() + k * r * k.transpose();
    symmetrize(&mut p_post);

    let log_det_s: f64 = 2.0 * chol.l().diagonal().iter().map(|d| d.ln()).sum::<f64>();
    let mahalanobis = innovation.dot(&chol.solve(innovation));
    let log_likelihood = -0.5 * (M as f64 * LN_2PI + log_det_s + mahalanobis);
    if !log_likelihood.is_finite() || x_post.iter().any(|v| !v.is_finite()) {
        return Err(FilterError::NonFinite {
            what: "Kalman update",
        });
    }
    Ok(Update {
        x: x_post,
        p: p_post,
        log_likelihood,
    })
}

/// True when `p` is symmetric (to `tol`, relative) and its Cholesky factorisation exists.
pub fn is_symmetric_positive_definite<const N: usize>(p: &SMatrix<f64, N, N>, tol: f64) -> bool {
    let scale = p.amax().max(f64::MIN_POSITIVE);
    let asym = (p - p.transpose()).amax();
    asym <= tol * scale && Cholesky::new(*p).is_some()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix1, Matrix2, Vector1, Vector2};

    #[test]
    fn scalar_update_matches_textbook() {
        // x ~ N(1, 4), y = x + v, v ~ N(0, 1), y = 3.
        let x = Vector1::new(1.0);
        let p = Matrix1::new(4.0);
        let h = Matrix1::new(1.0);
        let r = Matrix1::new(1.0);
        let innov = Vector1::new(3.0 - 1.0);
        let u = update_joseph(&x, &p, &innov, &h, &r).unwrap();
        // K = 4/5, x+ = 1 + 0.8*2 = 2.6, P+ = 0.8
        assert!((u.x[0] - 2.6).abs() < 1e-12);
        assert!((u.p[(0, 0)] - 0.8).abs() < 1e-12);
        // log N(2; 0, 5)
        let expected = -0.5 * (LN_2PI + 5f64.ln() + 4.0 / 5.0);
        assert!((u.log_likelihood - expected).abs() < 1e-12);
    }

    #[test]
    fn joseph_equals_short_form_for_optimal_gain() {
        let x = Vector2::new(0.5, -1.0);
        let p = Matrix2::new(2.0, 0.3, 0.3, 1.0);
        let h = nalgebra::Matrix1x2::new(1.0, 2.0);
        let r = Matrix1::new(0.5);
        let innov = Vector1::new(0.7);
        let u = update_joseph(&x, &p, &innov, &h, &r).unwrap();
        let s = (h * p * h.transpose())[(0, 0)] + 0.5;
        let k = p * h.transpose() / s;
        let p_short = (Matrix2::identity() - k * h) * p;
        assert!((u.p - p_short).amax() < 1e-12);
        assert!(is_symmetric_positive_definite(&u.p, 1e-12));
    }

    #[test]
    fn singular_innovation_is_an_error_not_a_panic() {
        let x = Vector1::new(0.0);
        let p = Matrix1::new(0.0);
        let h = Matrix1::new(1.0);
        let r = Matrix1::new(0.0);
        let err = update_joseph(&x, &p, &Vector1::new(1.0), &h, &r).unwrap_err();
        assert_eq!(err, FilterError::InnovationNotPositiveDefinite);
    }
}
