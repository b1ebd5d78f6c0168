//! A normal regression component `y_t ~ N(theta' psi_t, r)` with Gauss-inverse-Wishart
//! statistics (eq. 2, 10, 11, 13, 14).
//!
//! The statistics are the extended information matrix `V = sum w d d'` of the data vector
//! `d = [y; psi]` and the count `kappa = sum w`. Point estimates follow the least-squares split
//! of `V` (seed-notes erratum to eq. 13: the printed partition (14) puts a scalar `V_1` where the
//! regressor block is, and mixes the roles of its blocks):
//! `V = [[V_yy, V_psiy'], [V_psiy, V_psi]]`, `theta = V_psi^-1 V_psiy`,
//! `r = (V_yy - V_psiy' theta) / kappa`.

use nalgebra::{Cholesky, DMatrix, DMatrixView, DVector, SymmetricEigen};
use railmon_filter::kalman::LN_2PI;

use crate::kernel::{
    cholesky_in_place, cholesky_solve_in_place, gemm_is_nalgebras, lower_solve_in_place,
    nalgebra_dot, small_product, with_size,
};
use crate::FuelError;

/// GiW statistics of one component and the point estimates derived from them.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct RegressionStats {
    k_y: usize,
    /// Extended information matrix over `d = [y; psi]`, `(k_y + p) x (k_y + p)`.
    v: DMatrix<f64>,
    kappa: f64,
    /// Smallest eigenvalue allowed for `r` (a component that only ever sees exact zeros, the
    /// fuel cut-off, would otherwise get a zero variance and an infinite density).
    min_variance: f64,
    // Point estimates, recomputed after each update (eq. 13).
    theta: DMatrix<f64>,
    r: DMatrix<f64>,
    r_chol: Cholesky<f64, nalgebra::Dyn>,
    r_log_det: f64,
    v_psi_chol: Cholesky<f64, nalgebra::Dyn>,
    /// Buffers of earlier recomputes (not statistics: not in snapshots).
    #[serde(skip)]
    scratch: Scratch,
}

/// The storage [`RegressionStats::recompute`] fills (the point estimates and factors it
/// replaced, its temporaries), so that a step allocates none of them: each a buffer or `None`
/// (first use, after a restore or a failed recompute).
#[derive(Clone, Debug, Default)]
struct Scratch {
    v_psi_factor: Option<DMatrix<f64>>,
    theta: Option<DMatrix<f64>>,
    v_psiy_t: Option<DMatrix<f64>>,
    r: Option<DMatrix<f64>>,
    shifted: Option<DMatrix<f64>>,
    r_factor: Option<DMatrix<f64>>,
}

impl Scratch {
    /// The buffer in `slot` if it is `rows x cols`, else a new one (contents unspecified).
    fn take(
        &mut self,
        slot: impl FnOnce(&mut Self) -> &mut Option<DMatrix<f64>>,
        rows: usize,
        cols: usize,
    ) -> DMatrix<f64> {
        match slot(self).take() {
            Some(m) if m.shape() == (rows, cols) => m,
            _ => DMatrix::zeros(rows, cols),
        }
    }
}

impl RegressionStats {
    /// Statistics from a prior `v0` (must be symmetric positive definite) and `kappa0 > 0`.
    pub fn new(
        k_y: usize,
        v0: DMatrix<f64>,
        kappa0: f64,
        min_variance: f64,
    ) -> Result<Self, FuelError> {
        let d = v0.nrows();
        if d <= k_y || v0.ncols() != d {
            return Err(FuelError::Numerical(
                "regression statistics of the wrong size",
            ));
        }
        let p = d - k_y;
        let mut s = RegressionStats {
            k_y,
            v: v0,
            kappa: kappa0,
            min_variance,
            theta: DMatrix::zeros(p, k_y),
            r: DMatrix::identity(k_y, k_y),
            r_chol: Cholesky::new(DMatrix::identity(k_y, k_y)).expect("identity is SPD"),
            r_log_det: 0.0,
            v_psi_chol: Cholesky::new(DMatrix::identity(p, p)).expect("identity is SPD"),
            scratch: Scratch::default(),
        };
        s.recompute()?;
        Ok(s)
    }

    pub fn k_y(&self) -> usize {
        self.k_y
    }

    /// Dimension of the regressor `psi`.
    pub fn k_psi(&self) -> usize {
        self.v.nrows() - self.k_y
    }

    pub fn v(&self) -> &DMatrix<f64> {
        &self.v
    }

    pub fn kappa(&self) -> f64 {
        self.kappa
    }

    /// Regression coefficients, `k_psi x k_y`: the mean of `y` is `theta' psi`.
    pub fn theta(&self) -> &DMatrix<f64> {
        &self.theta
    }

    /// Noise covariance estimate `r` (after the variance floor).
    pub fn r(&self) -> &DMatrix<f64> {
        &self.r
    }

    /// Eq. (10)-(11) with optional stabilised forgetting: `V <- lambda V + (1 - lambda) V0 + w d d'`,
    /// `kappa <- lambda kappa + (1 - lambda) kappa0 + w`. Forgetting towards the prior `V0`
    /// (rather than towards zero) keeps `V_psi` invertible for a component that is rarely active.
    pub fn update(
        &mut self,
        d: &DVector<f64>,
        weight: f64,
        forgetting: Option<(f64, &DMatrix<f64>, f64)>,
    ) -> Result<(), FuelError> {
        if let Some((lambda, v0, kappa0)) = forgetting {
            self.v *= lambda;
            // v += v0 (1 - lambda), element by element.
            self.v.zip_apply(v0, |v, v0| *v += v0 * (1.0 - lambda));
            self.kappa = lambda * self.kappa + (1.0 - lambda) * kappa0;
        }
        self.v.syger(weight, d, d, 1.0);
        self.kappa += weight;
        self.recompute()
    }

    /// Makes `self` hold `other`'s statistics (`V`, `kappa`) in its own buffers, for an update
    /// that must leave `other` as it is should it fail; the point estimates are `other`'s only
    /// after [`Self::recompute`] (which [`Self::update`] calls).
    pub(crate) fn take_statistics_of(&mut self, other: &RegressionStats) {
        if self.v.shape() != other.v.shape() {
            *self = other.clone();
            return;
        }
        self.v.copy_from(&other.v);
        self.kappa = other.kappa;
        self.k_y = other.k_y;
        self.min_variance = other.min_variance;
    }

    /// Adds `w d d'` without recomputing the point estimates (batch initialisation).
    pub(crate) fn accumulate(&mut self, d: &DVector<f64>, weight: f64) {
        self.v.syger(weight, d, d, 1.0);
        self.kappa += weight;
    }

    /// Eq. (13), least-squares split (see the module comment).
    pub fn recompute(&mut self) -> Result<(), FuelError> {
        let k = self.k_y;
        let p = self.k_psi();
        // Keep V exactly symmetric: syger writes the lower triangle only.
        let d = k + p;
        let v = self.v.as_mut_slice();
        for j in 0..d {
            for i in (j + 1)..d {
                v[i * d + j] = v[j * d + i];
            }
        }
        // Views of V; every result in a buffer of an earlier recompute (`Scratch`), filled by
        // the same operations as a fresh one (the same numbers), swapped in on success.
        let v_psiy = self.v.view((k, 0), (p, k));
        let v_psi = self.v.view((k, k), (p, p));
        let mut factor = self.scratch.take(|s| &mut s.v_psi_factor, p, p);
        // The blocks of V copied column by column (nalgebra's strided copy, the same numbers).
        let v = self.v.as_slice();
        for (b, column) in factor.as_mut_slice().chunks_exact_mut(p).enumerate() {
            column.copy_from_slice(&v[(k + b) * d + k..(k + b + 1) * d]);
        }
        let chol = cholesky_with_jitter(v_psi, factor)
            .ok_or(FuelError::Numerical("V_psi not positive definite"))?;
        let mut theta = self.scratch.take(|s| &mut s.theta, p, k);
        for (j, column) in theta.as_mut_slice().chunks_exact_mut(p).enumerate() {
            column.copy_from_slice(&v[j * d + k..(j + 1) * d]);
        }
        let l = chol.l_dirty().as_slice();
        with_size!(p, |s| cholesky_solve_in_place(s, l, theta.as_mut_slice()));
        // r = (V_yy - V_psiy' theta) / kappa, element by element in the product's storage.
        let kappa = self.kappa.max(f64::MIN_POSITIVE);
        let mut r = self.scratch.take(|s| &mut s.r, k, k);
        if !gemm_is_nalgebras(k, p, k) {
            // nalgebra's product of these sizes is `matrixmultiply`'s (its own order).
            let mut v_psiy_t = self.scratch.take(|s| &mut s.v_psiy_t, k, p);
            v_psiy.transpose_to(&mut v_psiy_t);
            v_psiy_t.mul_to(&theta, &mut r);
            self.scratch.v_psiy_t = Some(v_psiy_t);
        } else {
            // The same product, V_psiy' read from V.
            let (v, t) = (self.v.as_slice(), theta.as_slice());
            small_product(
                k,
                p,
                k,
                |i, a| v[i * d + k + a],
                |a, j| t[j * p + a],
                r.as_mut_slice(),
            );
        }
        for (j, column) in r.as_mut_slice().chunks_exact_mut(k).enumerate() {
            for (x, v_yy) in column.iter_mut().zip(&v[j * d..j * d + k]) {
                *x = (v_yy - *x) / kappa;
            }
        }
        // Floor the eigenvalues at `min_variance`: rounding in V_yy - V_psiy' theta (a
        // difference of two large, nearly equal numbers after 10^6 steps) can leave r
        // indefinite. Fast path: `r - floor I` positive definite means no eigenvalue is below
        // the floor, and r stays as it is; otherwise clamp the eigenvalues.
        symmetrise(&mut r);
        let above_floor = r.iter().all(|v| v.is_finite()) && {
            // r - floor I, in one copy of r.
            let mut shifted = self.scratch.take(|s| &mut s.shifted, k, k);
            shifted.as_mut_slice().copy_from_slice(r.as_slice());
            for i in 0..k {
                shifted.as_mut_slice()[i * k + i] -= self.min_variance;
            }
            let positive = with_size!(k, |s| cholesky_in_place(s, shifted.as_mut_slice()));
            self.scratch.shifted = Some(shifted);
            positive
        };
        if !above_floor {
            let eig = SymmetricEigen::new(r);
            let vals = eig.eigenvalues.map(|l| {
                if l.is_finite() {
                    l.max(self.min_variance)
                } else {
                    self.min_variance
                }
            });
            if gemm_is_nalgebras(k, k, k) {
                // Q diag(vals) Q', as nalgebra's two products compute it (zeros included),
                // in r's own storage and the scratch's.
                let q = eig.eigenvectors.as_slice();
                let mut scaled = self.scratch.take(|s| &mut s.shifted, k, k);
                let mut product = self.scratch.take(|s| &mut s.r_factor, k, k);
                let diagonal = |a: usize, j: usize| if a == j { vals[a] } else { 0.0 };
                small_product(
                    k,
                    k,
                    k,
                    |i, a| q[a * k + i],
                    diagonal,
                    scaled.as_mut_slice(),
                );
                let qd = scaled.as_slice();
                let q_t = |a: usize, j: usize| q[a * k + j];
                small_product(k, k, k, |i, a| qd[a * k + i], q_t, product.as_mut_slice());
                r = product;
                self.scratch.shifted = Some(scaled);
                self.scratch.r_factor = Some(eig.eigenvectors);
            } else {
                r = &eig.eigenvectors
                    * DMatrix::from_diagonal(&vals)
                    * eig.eigenvectors.transpose();
            }
            symmetrise(&mut r);
        }
        let mut r_factor = self.scratch.take(|s| &mut s.r_factor, k, k);
        r_factor.as_mut_slice().copy_from_slice(r.as_slice());
        let r_chol = cholesky_with_jitter(r.as_view(), r_factor).ok_or(FuelError::Numerical(
            "noise covariance not positive definite",
        ))?;
        if theta.iter().any(|v| !v.is_finite()) {
            return Err(FuelError::Numerical("regression coefficients not finite"));
        }
        self.r_log_det = r_chol
            .l_dirty()
            .diagonal()
            .iter()
            .map(|l| 2.0 * l.ln())
            .sum();
        self.scratch.theta = Some(std::mem::replace(&mut self.theta, theta));
        self.scratch.r = Some(std::mem::replace(&mut self.r, r));
        self.scratch.r_factor = Some(std::mem::replace(&mut self.r_chol, r_chol).unpack_dirty());
        self.scratch.v_psi_factor =
            Some(std::mem::replace(&mut self.v_psi_chol, chol).unpack_dirty());
        Ok(())
    }

    /// Mean of `y` given the regressor: `theta' psi`.
    pub fn mean(&self, psi: &DVector<f64>) -> DVector<f64> {
        self.theta.tr_mul(psi)
    }

    /// [`mean`](Self::mean) written into `out` (of length `k_y`; the same numbers).
    pub fn mean_into(&self, psi: &DVector<f64>, out: &mut DVector<f64>) {
        self.theta.tr_mul_to(psi, out);
    }

    /// `zeta = psi' V_psi^-1 psi`: the parameter uncertainty at this regressor, relative to the
    /// noise (the GiW predictive covariance is `r (1 + zeta)`).
    pub fn zeta(&self, psi: &DVector<f64>) -> f64 {
        let x = self.v_psi_chol.solve(psi);
        psi.dot(&x).max(0.0)
    }

    /// [`zeta`](Self::zeta) with the solve written into `work` (of length `k_psi`; the same
    /// numbers).
    pub fn zeta_with(&self, psi: &DVector<f64>, work: &mut DVector<f64>) -> f64 {
        work.copy_from(psi);
        let (l, n) = (self.v_psi_chol.l_dirty().as_slice(), psi.len());
        with_size!(n, |s| cholesky_solve_in_place(s, l, work.as_mut_slice()));
        psi.dot(work).max(0.0)
    }

    /// The lower Cholesky factor `L` of `V_psi` (`V_psi = L L'`), column-major, its lower
    /// triangle (the upper holds other numbers): the forecast solves with the factors of all
    /// components at once ([`crate::kernel::cholesky_solve_each`]), as [`Self::zeta_with`].
    pub(crate) fn v_psi_factor(&self) -> &[f64] {
        self.v_psi_chol.l_dirty().as_slice()
    }

    /// `L^-1`, `L` the lower Cholesky factor of `V_psi` (`V_psi = L L'`), written into `out`
    /// (resized to fit; zero above the diagonal): with it `zeta = |L^-1 psi|^2` is a
    /// triangular product of independent rows, for the forecast's steps beyond its first.
    /// Rounding differs from [`zeta`](Self::zeta)'s two solves: not for the mixture's step,
    /// whose recursion carries such differences on (docs/fuel.md, "Benchmark").
    pub(crate) fn v_psi_factor_inverse_into(&self, out: &mut DMatrix<f64>) {
        let l = self.v_psi_chol.l_dirty();
        let n = l.nrows();
        if out.shape() != (n, n) {
            *out = DMatrix::zeros(n, n);
        }
        // The diagonal of a Cholesky factor is positive: L is invertible.
        let (l, out) = (l.as_slice(), out.as_mut_slice());
        crate::kernel::with_size!(n, |s| crate::kernel::lower_inverse(s, l, out));
    }

    /// What the component predicts at `psi`: the mean `theta' psi` and the inflation of the
    /// covariance, `1 + zeta` with `parameter_uncertainty` (the GiW predictive's `r (1 + zeta)`),
    /// else 1. The monitor's virtual sensor and the mixture's step both need it at the same
    /// `psi` from the same statistics: computed once, it serves both.
    pub fn predict(&self, psi: &DVector<f64>, parameter_uncertainty: bool) -> Prediction {
        let inflate = if parameter_uncertainty {
            1.0 + self.zeta(psi)
        } else {
            1.0
        };
        Prediction {
            mean: self.mean(psi),
            inflate,
        }
    }

    /// Log of the component's "proximity" to `y` (Algorithm 3.4 step 2), in log space (seed-notes:
    /// a 5-dimensional density underflows). With `parameter_uncertainty` the covariance is
    /// `r (1 + zeta)`, the GiW predictive's covariance; without it, the paper's plug-in `r`.
    pub fn log_proximity(
        &self,
        y: &DVector<f64>,
        psi: &DVector<f64>,
        parameter_uncertainty: bool,
    ) -> f64 {
        self.log_proximity_at(y, &self.predict(psi, parameter_uncertainty))
    }

    /// [`log_proximity`](Self::log_proximity) from the component's [`Prediction`] at `psi`.
    pub fn log_proximity_at(&self, y: &DVector<f64>, prediction: &Prediction) -> f64 {
        let e = y - &prediction.mean;
        let inflate = prediction.inflate;
        let mut solved = e.clone();
        let l = self.r_chol.l_dirty().as_slice();
        with_size!(self.k_y, |s| cholesky_solve_in_place(
            s,
            l,
            solved.as_mut_slice()
        ));
        let q = e.dot(&solved) / inflate;
        let k = self.k_y as f64;
        -0.5 * (k * LN_2PI + self.r_log_det + k * inflate.ln() + q)
    }

    /// Log-density of channels `channels` of `y` (`y` of length `k_y`, the others ignored)
    /// under the marginal of the component's predictive Gaussian at `psi`: the principal
    /// block of `N(theta' psi, r (1 + zeta))` (`1 + zeta` with `parameter_uncertainty`).
    pub fn log_marginal_density(
        &self,
        channels: &[usize],
        y: &DVector<f64>,
        psi: &DVector<f64>,
        parameter_uncertainty: bool,
    ) -> f64 {
        let prediction = self.predict(psi, parameter_uncertainty);
        let n = channels.len();
        let r = DMatrix::from_fn(n, n, |a, b| {
            self.r[(channels[a], channels[b])] * prediction.inflate
        });
        let e = DVector::from_fn(n, |a, _| y[channels[a]] - prediction.mean[channels[a]]);
        gaussian_log_density(r, &e)
    }

    /// Degrees of freedom of the Student-t predictive of one channel: `kappa - k_y + 1` (the
    /// marginal of the inverse-Wishart part), at least 1.
    pub fn predictive_dof(&self) -> f64 {
        (self.kappa - self.k_y as f64 + 1.0).max(1.0)
    }

    /// Fuel (channel 0) conditioned on the other channels `y_other` (channels 1..k_y) now: the
    /// conditional mean and variance of `y_0` and the log-density of `y_other` under the
    /// marginal of the component's predictive Gaussian, used to weight the components (virtual
    /// sensor). Without other channels: the 1-step predictive of `y_0`.
    pub fn condition_first_on_rest(
        &self,
        psi: &DVector<f64>,
        y_other: &DVector<f64>,
        parameter_uncertainty: bool,
    ) -> Conditional {
        self.condition_first_on_rest_at(&self.predict(psi, parameter_uncertainty), y_other)
    }

    /// [`condition_first_on_rest`](Self::condition_first_on_rest) from the component's
    /// [`Prediction`] at `psi`.
    pub fn condition_first_on_rest_at(
        &self,
        prediction: &Prediction,
        y_other: &DVector<f64>,
    ) -> Conditional {
        let (mean, inflate) = (&prediction.mean, prediction.inflate);
        let k = self.k_y;
        let unconditional = Conditional {
            mean: mean[0],
            variance: self.r[(0, 0)] * inflate,
            log_density: 0.0,
        };
        if k == 1 {
            return unconditional;
        }
        // With r_oo = L L' (the other channels' block of r), z = L^-1 e and w = L^-1 r_of:
        // the inflation s scales r_oo and r_fo alike, so the conditional mean
        // r_fo r_oo^-1 e = w.z does not depend on it, the Schur complement is
        // s (r_ff - w.w), e' (s r_oo)^-1 e = z.z / s and ln det(s r_oo) = ln det r_oo +
        // (k - 1) ln s. Two triangular solves on r's own block (no copies scaled by s).
        // nalgebra's Cholesky factor, solves and dot products on flat storage (the same
        // bits), on the stack up to 12 other channels: the virtual sensor asks at every step.
        let o = k - 1;
        let mut stack = [0.0; 12 * 14];
        let mut heap = Vec::new();
        let work: &mut [f64] = match stack.get_mut(..o * (o + 2)) {
            Some(w) => w,
            None => {
                heap.resize(o * (o + 2), 0.0);
                &mut heap
            }
        };
        let (l, zw) = work.split_at_mut(o * o);
        let r = self.r.as_slice();
        for (b, column) in l.chunks_exact_mut(o).enumerate() {
            column.copy_from_slice(&r[(b + 1) * k + 1..(b + 2) * k]);
        }
        if !with_size!(o, |s| cholesky_in_place(s, l)) {
            // Cannot happen: a principal block of an SPD matrix is SPD. Fall back to the mean.
            return unconditional;
        }
        let (z, w) = zw.split_at_mut(o);
        for ((z, y), m) in z.iter_mut().zip(y_other.iter()).zip(&mean.as_slice()[1..]) {
            *z = y - m;
        }
        w.copy_from_slice(&r[1..k]);
        with_size!(o, |s| {
            lower_solve_in_place(s, l, z);
            lower_solve_in_place(s, l, w);
        });
        let log_det: f64 = (0..o).map(|i| 2.0 * l[i * o + i].ln()).sum();
        let others = o as f64;
        let (z, w) = (&*z, &*w);
        Conditional {
            mean: mean[0] + nalgebra_dot(w, z),
            // Positive as r is PD (floored); the floor guards rounding.
            variance: (unconditional.variance - (0.0 + nalgebra_dot(w, w)) * inflate)
                .max(self.min_variance * inflate),
            log_density: -0.5
                * (others * LN_2PI
                    + log_det
                    + others * inflate.ln()
                    + (0.0 + nalgebra_dot(z, z)) / inflate),
        }
    }
}

/// What a component predicts at a regressor: see [`RegressionStats::predict`].
#[derive(Clone, Debug, PartialEq)]
pub struct Prediction {
    /// `theta' psi`.
    pub mean: DVector<f64>,
    /// `1 + zeta` (1 without parameter uncertainty).
    pub inflate: f64,
}

/// Channel 0 of a component's predictive given the other channels: see
/// [`RegressionStats::condition_first_on_rest`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Conditional {
    pub mean: f64,
    pub variance: f64,
    /// Log-density of the other channels under the component (0 without them).
    pub log_density: f64,
}

impl Conditional {
    /// `ln N(y_0; mean, variance)`: the log-density of the first channel's value `y0` under
    /// this conditional.
    pub fn log_density_of(&self, y0: f64) -> f64 {
        let e = y0 - self.mean;
        -0.5 * (LN_2PI + self.variance.ln() + e * e / self.variance)
    }
}

/// `ln N(e; 0, r)` for a covariance `r` (a principal block of an SPD matrix: SPD; should its
/// factorisation fail all the same, the density is 0, `-inf`).
fn gaussian_log_density(r: DMatrix<f64>, e: &DVector<f64>) -> f64 {
    let n = e.len() as f64;
    let Some(chol) = Cholesky::new(r) else {
        return f64::NEG_INFINITY;
    };
    let log_det: f64 = chol.l().diagonal().iter().map(|l| 2.0 * l.ln()).sum();
    -0.5 * (n * LN_2PI + log_det + e.dot(&chol.solve(e)))
}

/// `m <- (m + m') / 2` in place (each element as `(m_ij + m_ji) * 0.5`, the diagonal too: the
/// same numbers as the expression, without its two temporaries).
fn symmetrise(m: &mut DMatrix<f64>) {
    let n = m.nrows().min(m.ncols());
    let m = &mut m.as_mut_slice()[..n * n];
    for i in 0..n {
        for j in i..n {
            let s = (m[j * n + i] + m[i * n + j]) * 0.5;
            m[j * n + i] = s;
            m[i * n + j] = s;
        }
    }
}

/// Cholesky factor of a matrix that is positive definite in exact arithmetic but may not be in
/// floating point: `V_psi = V_0 + sum w psi psi'` after 10^6 updates of size 10^12 has lost the
/// `V_0 = 10^-3 I` of its small directions to rounding. Retries with a jitter `eps max(diag) I`,
/// `eps = 10^-14 .. 10^-8`, used for the factor only (the statistics are left as they are).
/// `m` is a view, `copy` its copy to factor in (copied again only when the first attempt
/// fails).
fn cholesky_with_jitter(
    m: DMatrixView<f64>,
    mut copy: DMatrix<f64>,
) -> Option<Cholesky<f64, nalgebra::Dyn>> {
    // nalgebra's `Cholesky::new(copy)`, on flat storage (the same bits).
    if with_size!(copy.nrows(), |s| cholesky_in_place(s, copy.as_mut_slice())) {
        return Some(Cholesky::pack_dirty(copy));
    }
    let scale = m.diagonal().iter().fold(0.0f64, |a, d| a.max(d.abs()));
    if !scale.is_finite() {
        return None;
    }
    let n = m.nrows();
    [1e-14, 1e-12, 1e-10, 1e-8]
        .iter()
        .find_map(|eps| Cholesky::new(m + DMatrix::identity(n, n) * (eps * scale)))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The in-place symmetrisation gives the expression's numbers to the bit.
    #[test]
    fn symmetrise_equals_the_expression() {
        let m = DMatrix::from_fn(5, 5, |i, j| ((i * 7 + j * 3) as f64).sin() * 1e3 + 0.1);
        let want = (&m + m.transpose()) * 0.5;
        let mut got = m.clone();
        symmetrise(&mut got);
        assert!(got
            .iter()
            .zip(want.iter())
            .all(|(a, b)| a.to_bits() == b.to_bits()));
    }

    /// An update in another component's buffers (the mixture's spare) gives the numbers of an
    /// update of a copy, to the bit, whatever those buffers held before.
    #[test]
    fn an_update_in_spare_buffers_equals_an_update_of_a_copy() {
        let v0 = DMatrix::from_fn(4, 4, |i, j| if i == j { 2.0 + i as f64 } else { 0.3 });
        let mut source = RegressionStats::new(2, v0.clone(), 3.0, 1e-9).unwrap();
        let mut spare = RegressionStats::new(2, v0 * 7.0, 11.0, 1e-9).unwrap();
        for t in 0..20 {
            let x = t as f64;
            let d = DVector::from_vec(vec![x.sin(), (0.3 * x).cos(), 0.1 * x, 1.0]);
            let mut copy = source.clone();
            copy.update(&d, 0.7, Some((0.9, &DMatrix::identity(4, 4), 1.0)))
                .unwrap();
            spare.take_statistics_of(&source);
            spare
                .update(&d, 0.7, Some((0.9, &DMatrix::identity(4, 4), 1.0)))
                .unwrap();
            let bits = |s: &RegressionStats| {
                let m = [s.v(), s.theta(), s.r()];
                let mut b: Vec<u64> = m
                    .iter()
                    .flat_map(|m| m.iter().map(|v| v.to_bits()))
                    .collect();
                b.extend([s.kappa().to_bits(), s.r_log_det.to_bits()]);
                b
            };
            assert_eq!(bits(&spare), bits(&copy));
            std::mem::swap(&mut source, &mut spare);
        }
    }

    /// The point estimates on flat storage are nalgebra's (`Cholesky::new`, `solve_mut`,
    /// `transpose_to` and `mul_to`) to the bit, at sizes below and above nalgebra's switch to
    /// `matrixmultiply` (`k_y` and `k_psi` both above 5).
    #[test]
    fn point_estimates_are_nalgebras_to_the_bit() {
        for (k, p) in [(1, 1), (2, 3), (5, 7), (5, 12), (6, 5), (6, 7), (4, 13)] {
            let d = k + p;
            let half = DMatrix::from_fn(d, d + 3, |i, j| ((i * 29 + j * 13) as f64 + 0.2).sin());
            let v = &half * half.transpose() + DMatrix::from_diagonal_element(d, d, 0.5);
            let kappa = 7.0;
            let s = RegressionStats::new(k, v.clone(), kappa, 1e-9).unwrap();
            let chol = Cholesky::new(v.view((k, k), (p, p)).into_owned()).unwrap();
            let mut theta = v.view((k, 0), (p, k)).into_owned();
            chol.solve_mut(&mut theta);
            let mut v_psiy_t = DMatrix::zeros(k, p);
            v.view((k, 0), (p, k)).transpose_to(&mut v_psiy_t);
            let mut r = DMatrix::zeros(k, k);
            v_psiy_t.mul_to(&theta, &mut r);
            r.zip_apply(&v.view((0, 0), (k, k)), |x, v_yy| *x = (v_yy - *x) / kappa);
            symmetrise(&mut r);
            assert_eq!(s.theta(), &theta, "{k} {p}");
            assert_eq!(s.r(), &r, "{k} {p}");
            assert_eq!(s.v_psi_chol.l_dirty(), chol.l_dirty(), "{k} {p}");
        }
    }

    #[test]
    fn proximity_is_the_gaussian_log_density() {
        // k_y = 1, psi = [1]: V = diag(v_yy, v_1) with v_psiy = 2 -> theta = 2 / v_1.
        let v0 = DMatrix::from_row_slice(2, 2, &[10.0, 2.0, 2.0, 4.0]);
        let s = RegressionStats::new(1, v0, 5.0, 1e-9).unwrap();
        let theta = 0.5;
        let r = (10.0 - 2.0 * theta) / 5.0;
        assert!((s.theta()[0] - theta).abs() < 1e-12);
        assert!((s.r()[(0, 0)] - r).abs() < 1e-12);
        let y = DVector::from_element(1, 1.3);
        let psi = DVector::from_element(1, 1.0);
        let expected = -0.5 * (LN_2PI + r.ln() + (1.3 - theta).powi(2) / r);
        assert!((s.log_proximity(&y, &psi, false) - expected).abs() < 1e-12);
        // zeta = psi' V_psi^-1 psi = 1/4.
        assert!((s.zeta(&psi) - 0.25).abs() < 1e-12);
    }

    #[test]
    fn conditioning_matches_the_bivariate_formula() {
        // y = [a, b], psi = [1], V chosen so that theta = [1, 2], r = [[1, .5], [.5, 2]] (kappa 1).
        let theta = [1.0, 2.0];
        let r = [[1.0, 0.5], [0.5, 2.0]];
        let v_psi = 1.0;
        let mut v = DMatrix::zeros(3, 3);
        for i in 0..2 {
            for j in 0..2 {
                v[(i, j)] = r[i][j] + theta[i] * theta[j] * v_psi;
            }
            v[(i, 2)] = theta[i] * v_psi;
            v[(2, i)] = theta[i] * v_psi;
        }
        v[(2, 2)] = v_psi;
        let s = RegressionStats::new(2, v, 1.0, 1e-12).unwrap();
        let psi = DVector::from_element(1, 1.0);
        let c = s.condition_first_on_rest(&psi, &DVector::from_element(1, 3.0), false);
        assert!((c.mean - (1.0 + 0.5 / 2.0 * (3.0 - 2.0))).abs() < 1e-12);
        // Var(a | b) = 1 - 0.5^2 / 2.
        assert!((c.variance - (1.0 - 0.25 / 2.0)).abs() < 1e-12);
        let expected_ld = -0.5 * (LN_2PI + 2f64.ln() + 1.0 / 2.0);
        assert!((c.log_density - expected_ld).abs() < 1e-12);
        // Inflated by s = 3 (r 3): the same mean, Var(a | b) and Var(b) three times as large.
        let inflated = Prediction {
            mean: s.mean(&psi),
            inflate: 3.0,
        };
        let c = s.condition_first_on_rest_at(&inflated, &DVector::from_element(1, 3.0));
        assert!((c.mean - (1.0 + 0.5 / 2.0 * (3.0 - 2.0))).abs() < 1e-12);
        assert!((c.variance - 3.0 * (1.0 - 0.25 / 2.0)).abs() < 1e-12);
        let expected_ld = -0.5 * (LN_2PI + 6f64.ln() + 1.0 / 6.0);
        assert!((c.log_density - expected_ld).abs() < 1e-12);
    }
}
