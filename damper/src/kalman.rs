//! The Kalman filter of one parameter value (section 4.3): exact time-varying predict and
//! Joseph-form update, and the steady-state (Riccati) solution the fast filter uses.

use nalgebra::{Cholesky, Matrix2, SMatrix};

use crate::expm::Discrete;
use crate::model::{state, Matrix17, Matrix5, Matrix5x17, Vector17, Vector5, N_OUTPUTS, N_STATES};
use crate::DamperError;
use railmon_filter::kalman::{symmetrize, update_joseph, LN_2PI};

/// Noise of the filter model: `x_k = Phi x_{k-1} + Gamma w_k`, `w_k ~ N(0, Q_w)`;
/// `y_k = H x_k + v_k`, `v_k ~ N(0, Q_v)` (eq. 20-21, both diagonal).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseCovariances {
    /// `Q_w`: variance of the track lateral velocities held over one step ((m/s)^2).
    pub q_w: Matrix2<f64>,
    /// `Q_v`: sensor noise covariance.
    pub q_v: Matrix5,
    /// Variance added to every state each step (see `DamperMonitorConfig::
    /// process_noise_floor_std_per_step`).
    pub q_floor: f64,
}

impl NoiseCovariances {
    /// The state noise of one step: `Gamma Q_w Gamma' + q_floor I`.
    pub fn process(&self, gamma: &crate::model::Matrix17x2) -> Matrix17 {
        gamma * self.q_w * gamma.transpose() + Matrix17::identity() * self.q_floor
    }
}

/// Mean and covariance of the state for one parameter value.
#[derive(Debug, Clone, PartialEq)]
pub struct StateEstimate {
    pub x: Vector17,
    pub p: Matrix17,
}

/// Time propagation (section 4.3): `x- = Phi x`, `P- = Phi P Phi' + Gamma Q_w Gamma' + q_floor I`.
pub fn predict(est: &StateEstimate, disc: &Discrete, noise: &NoiseCovariances) -> StateEstimate {
    let mut p = disc.phi * est.p * disc.phi.transpose() + noise.process(&disc.gamma);
    symmetrize(&mut p);
    StateEstimate {
        x: disc.phi * est.x,
        p,
    }
}

/// Measurement update in Joseph form; returns the posterior and `ln p(y | Z_{k-1}, theta)`
/// under `N(H x-, H P- H' + Q_v)` (eq. 22).
pub fn update(
    est: &StateEstimate,
    y: &Vector5,
    h: &Matrix5x17,
    q_v: &Matrix5,
) -> Result<(StateEstimate, f64), DamperError> {
    let innovation = y - h * est.x;
    let u = update_joseph(&est.x, &est.p, &innovation, h, q_v)?;
    Ok((StateEstimate { x: u.x, p: u.p }, u.log_likelihood))
}

/// The steady state of the predict/update recursion for one parameter value: the predicted
/// covariance `P-` solving the filter Riccati equation, the gain `K = P- H' S^-1` and the
/// innovation covariance `S = H P- H' + Q_v` as `S^-1`, `ln det S` and its diagonal (the
/// innovation variance per sensor, which the noise-scale estimate normalises by).
#[derive(Debug, Clone, PartialEq)]
pub struct SteadyState {
    pub p_pred: Matrix17,
    pub gain: SMatrix<f64, N_STATES, N_OUTPUTS>,
    pub s_inv: Matrix5,
    pub ln_det_s: f64,
    pub s_diag: Vector5,
}

impl SteadyState {
    /// `ln N(e; 0, S)` of an innovation `e`.
    pub fn log_likelihood(&self, innovation: &Vector5) -> f64 {
        -0.5 * (N_OUTPUTS as f64 * LN_2PI
            + self.ln_det_s
            + innovation.dot(&(self.s_inv * innovation)))
    }
}

/// Solves `P = Phi P Phi' - Phi P H' (H P H' + R)^-1 H P Phi' + Q` (`Q = Gamma Q_w Gamma'`)
/// with the structure-preserving doubling algorithm (Chu, Fan, Lin, Wang, "Structure-preserving
/// algorithms for periodic discrete-time algebraic Riccati equations", Int. J. Control 77(8),
/// 2004): with `A_0 = Phi'`, `G_0 = H' R^-1 H`, `X_0 = Q`,
/// `A+ = A (I + G X)^-1 A`, `G+ = G + A (I + G X)^-1 G A'`, `X+ = X + A' X (I + G X)^-1 A`,
/// `X` converges quadratically to `P-`. The filter's rigid drift must be leaked (eps > 0):
/// otherwise the pair is not detectable and `X` grows without bound.
pub fn steady_state(
    disc: &Discrete,
    h: &Matrix5x17,
    noise: &NoiseCovariances,
) -> Result<SteadyState, DamperError> {
    let r_inv = Cholesky::new(noise.q_v)
        .ok_or(DamperError::InvalidParameter {
            field: "sensor noise",
            value: f64::NAN,
            reason: "covariance must be positive definite",
        })?
        .inverse();
    let id = Matrix17::identity();
    let mut a = disc.phi.transpose();
    let mut g = h.transpose() * r_inv * h;
    let mut x = noise.process(&disc.gamma);
    const MAX_DOUBLINGS: usize = 60;
    for _ in 0..MAX_DOUBLINGS {
        let m = (id + g * x)
            .lu()
            .try_inverse()
            .ok_or(DamperError::NonFinite {
                what: "Riccati doubling",
            })?;
        let a_m = a * m;
        let x_next = x + a.transpose() * x * m * a;
        let g_next = g + a_m * g * a.transpose();
        a = a_m * a;
        let change = (x_next - x).amax();
        x = x_next;
        g = g_next;
        symmetrize(&mut x);
        symmetrize(&mut g);
        if change <= 1e-14 * x.amax() {
            return steady_from_p(x, h, &noise.q_v);
        }
    }
    Err(DamperError::NonFinite {
        what: "Riccati doubling did not converge",
    })
}

/// Gain, `S^-1` and `ln det S` from a predicted covariance.
pub fn steady_from_p(
    p_pred: Matrix17,
    h: &Matrix5x17,
    q_v: &Matrix5,
) -> Result<SteadyState, DamperError> {
    let mut s = h * p_pred * h.transpose() + q_v;
    symmetrize(&mut s);
    let chol =
        Cholesky::new(s).ok_or(railmon_filter::FilterError::InnovationNotPositiveDefinite)?;
    let s_inv = chol.inverse();
    let ln_det_s = 2.0 * chol.l().diagonal().iter().map(|d| d.ln()).sum::<f64>();
    Ok(SteadyState {
        gain: p_pred * h.transpose() * s_inv,
        p_pred,
        s_inv,
        ln_det_s,
        s_diag: s.diagonal(),
    })
}

/// Initial state covariance of the exact filter: the vehicle starts near rest; standard
/// deviations 1 cm (displacements, track), 1 mrad, 1 cm/s, 10 mrad/s.
pub fn initial_covariance() -> Matrix17 {
    let mut d = Vector17::repeat(1e-2f64.powi(2));
    for i in [state::PSIW1, state::PSIW2, state::PSIB] {
        d[i] = 1e-3f64.powi(2);
    }
    for i in [state::PSIW1_DOT, state::PSIW2_DOT, state::PSIB_DOT] {
        d[i] = 1e-2f64.powi(2);
    }
    Matrix17::from_diagonal(&d)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::expm::discretize;
    use crate::model::BogieModel;
    use crate::{BogieParams, Dampers};

    pub(crate) fn test_noise() -> NoiseCovariances {
        NoiseCovariances {
            q_w: Matrix2::identity() * 0.05f64.powi(2),
            q_v: Matrix5::from_diagonal(
                &Vector5::new(0.02, 0.02, 0.02, 0.004, 0.02).map(|s| s * s),
            ),
            q_floor: 1e-16,
        }
    }

    /// The doubling solution is the limit of the predict/update recursion and solves the DARE.
    #[test]
    fn riccati_doubling_equals_the_recursion_limit() {
        let model = BogieModel::new(&BogieParams::default(), 0.5).unwrap();
        let d = Dampers::NOMINAL;
        let disc = discretize(&model.a_matrix(&d), &model.g_matrix(), 1e-3).unwrap();
        let h = model.h_matrix();
        let noise = test_noise();
        let ss = steady_state(&disc, &h, &noise).unwrap();
        // DARE residual.
        let p = ss.p_pred;
        let s = h * p * h.transpose() + noise.q_v;
        let rhs = disc.phi * p * disc.phi.transpose()
            - disc.phi
                * p
                * h.transpose()
                * s.try_inverse().unwrap()
                * h
                * p
                * disc.phi.transpose()
            + noise.process(&disc.gamma);
        assert!((rhs - p).amax() < 1e-9 * p.amax(), "{}", (rhs - p).amax());
        // The plain recursion converges to the same P-, slowly: its slowest covariance mode
        // decays at ~0.2/s (measured), so it takes ~120 s of 1 kHz steps to agree to 1e-6.
        let mut est = StateEstimate {
            x: Vector17::zeros(),
            p: Matrix17::identity() * 1e-4,
        };
        for _ in 0..120_000 {
            est = predict(&est, &disc, &noise);
            let (post, _) = update(&est, &Vector5::zeros(), &h, &noise.q_v).unwrap();
            est = post;
        }
        let p_rec = predict(&est, &disc, &noise).p;
        let rel = (p_rec - p).amax() / p.amax();
        assert!(rel < 1e-6, "recursion vs doubling: {rel}");
    }
}
