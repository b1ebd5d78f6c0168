//! The baseline of section 3: an EKF on the state augmented with the two damper
//! coefficients (19 states), the coefficients modelled as random walks, discretised as the
//! paper does (`Phi ~ I + A T`, `Gamma ~ G T`, Jacobian eq. 18).
//!
//! The parameters are carried as ratios to nominal (`C = ratio * C_nominal`). An EKF is
//! invariant to a constant linear rescaling of its state, so this is the paper's filter; it
//! only keeps the covariance from spanning 1e-9 (states) to 1e10 ((N s/m)^2) in one matrix.

use nalgebra::SMatrix;
use serde::{Deserialize, Serialize};

use crate::filter_model::FilterModel;
use crate::kalman::initial_covariance;
use crate::model::{BogieModel, Matrix17, Matrix5, Matrix5x17, Vector5, N_OUTPUTS, N_STATES};
use crate::params::{non_negative, positive, Dampers};
use crate::DamperError;
use railmon_filter::kalman::update_joseph;

const N_AUG: usize = N_STATES + 2;
type Matrix19 = SMatrix<f64, N_AUG, N_AUG>;
type Vector19 = SMatrix<f64, N_AUG, 1>;

/// The augmented-state EKF of section 3 (baseline).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct EkfConfig {
    /// Run the augmented EKF beside the RBPF and publish its estimate, for comparison with
    /// the paper (its figures 2-5). Off by default: the paper's point is that this baseline
    /// fails, and it does here too (`C_sy` +20.8 % off at the end of `damper-seed`, +12.9 % of
    /// `damper-speed-profile`, each with the truth outside its +-1.645 sd band), so on a train it
    /// would publish a confidently wrong estimate beside the RBPF's, and it took 12 % of the
    /// CPU of `railmon analyze damper` (issue 28).
    pub enabled: bool,
    /// Initial parameter estimate as a ratio of nominal.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub initial_ratio: f64,
    /// Standard deviation of the initial estimate (ratio of nominal).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub initial_ratio_std: f64,
    /// Random walk of the parameters (`Q_n`, eq. 17), standard deviation per sqrt(s) in
    /// ratio units.
    #[schemars(range(min = 0.0))]
    pub ratio_random_walk_per_sqrt_s: f64,
}

impl Default for EkfConfig {
    fn default() -> Self {
        EkfConfig {
            enabled: false,
            initial_ratio: 1.0,
            initial_ratio_std: 0.5,
            ratio_random_walk_per_sqrt_s: 0.01,
        }
    }
}

impl EkfConfig {
    pub fn validate(&self) -> Result<(), DamperError> {
        positive("ekf.initial_ratio", self.initial_ratio)?;
        positive("ekf.initial_ratio_std", self.initial_ratio_std)?;
        non_negative(
            "ekf.ratio_random_walk_per_sqrt_s",
            self.ratio_random_walk_per_sqrt_s,
        )
    }
}

/// What the EKF says after a step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EkfEstimate {
    pub dampers: Dampers,
    /// Marginal standard deviations of `C_sy`, `C_say` (N s/m).
    pub std_ns_per_m: [f64; 2],
}

/// The EKF's augmented state (17 states, 2 damper ratios) and covariance, for a snapshot.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EkfState {
    xi: Vector19,
    p: Matrix19,
}

/// `f p f'` with the sums of nalgebra's `f * p * f.transpose()`: each entry of `f p`, then of
/// `(f p) f'`, summed over the inner index in increasing order from its first term. `f` is
/// sparse (`I + A T` of the 44-non-zero `A`, two parameter columns): the terms with a zero
/// factor of `f` are left out, as adding `0 * p` leaves a finite sum as it was (issue 28:
/// the dense products were most of the EKF's share of the monitor step). A row of `f` of
/// zeros does not occur (`f`'s diagonal is `1 + A_ii T`, or 1: checked).
fn congruence(f: &Matrix19, p: &Matrix19) -> Matrix19 {
    // Per row of `f`, its non-zero columns in increasing order.
    let mut cols = [[0u8; N_AUG]; N_AUG];
    let mut len = [0usize; N_AUG];
    for i in 0..N_AUG {
        for k in 0..N_AUG {
            if f[(i, k)] != 0.0 {
                cols[i][len[i]] = k as u8;
                len[i] += 1;
            }
        }
        if len[i] == 0 {
            return f * p * f.transpose();
        }
    }
    // (f p)_ij = sum_k f_ik p_kj, and (f p f')_ij = sum_k (f p)_ik f_jk: over the non-zero
    // f_ik, f_jk of row i, j, the first term taken as it is (nalgebra's `gemv` too).
    let mut fp = Matrix19::zeros();
    for j in 0..N_AUG {
        for i in 0..N_AUG {
            let ks = &cols[i][..len[i]];
            let mut sum = f[(i, ks[0] as usize)] * p[(ks[0] as usize, j)];
            for &k in &ks[1..] {
                sum += f[(i, k as usize)] * p[(k as usize, j)];
            }
            fp[(i, j)] = sum;
        }
    }
    let mut out = Matrix19::zeros();
    for j in 0..N_AUG {
        let ks = &cols[j][..len[j]];
        for i in 0..N_AUG {
            let mut sum = fp[(i, ks[0] as usize)] * f[(j, ks[0] as usize)];
            for &k in &ks[1..] {
                sum += fp[(i, k as usize)] * f[(j, k as usize)];
            }
            out[(i, j)] = sum;
        }
    }
    out
}

#[derive(Debug, Clone)]
pub struct AugmentedEkf {
    model: BogieModel,
    nominal: Dampers,
    dt_s: f64,
    h: SMatrix<f64, N_OUTPUTS, N_AUG>,
    q: Matrix19,
    q_v: Matrix5,
    xi: Vector19,
    p: Matrix19,
}

impl AugmentedEkf {
    /// The baseline on the filters' model `filter_model` with its settings `config`.
    pub fn new(filter_model: &FilterModel, config: &EkfConfig) -> Result<Self, DamperError> {
        filter_model.validate()?;
        config.validate()?;
        let model = filter_model.bogie_model()?;
        let h17: Matrix5x17 = model.h_matrix();
        let mut h = SMatrix::<f64, N_OUTPUTS, N_AUG>::zeros();
        h.fixed_view_mut::<N_OUTPUTS, N_STATES>(0, 0)
            .copy_from(&h17);
        let dt = filter_model.dt_s;
        // Gamma ~ G T (section 3), Q_n: random walk of the ratios.
        let gamma = model.g_matrix() * dt;
        let noise = filter_model.noise();
        let mut q = Matrix19::zeros();
        q.fixed_view_mut::<N_STATES, N_STATES>(0, 0)
            .copy_from(&noise.process(&gamma));
        let rw = config.ratio_random_walk_per_sqrt_s.powi(2) * dt;
        q[(N_STATES, N_STATES)] = rw;
        q[(N_STATES + 1, N_STATES + 1)] = rw;
        let mut xi = Vector19::zeros();
        xi[N_STATES] = config.initial_ratio;
        xi[N_STATES + 1] = config.initial_ratio;
        let mut p = Matrix19::zeros();
        p.fixed_view_mut::<N_STATES, N_STATES>(0, 0)
            .copy_from(&initial_covariance());
        let v0 = config.initial_ratio_std.powi(2);
        p[(N_STATES, N_STATES)] = v0;
        p[(N_STATES + 1, N_STATES + 1)] = v0;
        Ok(AugmentedEkf {
            model,
            nominal: filter_model.nominal,
            dt_s: dt,
            h,
            q,
            q_v: noise.q_v,
            xi,
            p,
        })
    }

    /// The forward speed of the next steps (m/s): `A` and `H` at it (`BogieModel::set_speed`).
    pub fn set_speed(&mut self, speed_m_s: f64) -> Result<(), DamperError> {
        if self.model.params().speed_m_s != speed_m_s {
            self.model.set_speed(speed_m_s)?;
            self.h
                .fixed_view_mut::<N_OUTPUTS, N_STATES>(0, 0)
                .copy_from(&self.model.h_matrix());
        }
        Ok(())
    }

    /// The body mass above the bogie for the next steps (kg, checked by the caller:
    /// `Rbpf::checked_half_body_mass_kg`), as the RBPF's model takes it.
    pub fn set_half_body_mass_kg(&mut self, mass_kg: f64) -> Result<(), DamperError> {
        if self.model.params().half_body_mass_kg != mass_kg {
            self.model.set_half_body_mass_kg(mass_kg)?;
            self.h
                .fixed_view_mut::<N_OUTPUTS, N_STATES>(0, 0)
                .copy_from(&self.model.h_matrix());
        }
        Ok(())
    }

    fn dampers(&self, xi: &Vector19) -> Dampers {
        Dampers {
            csy_ns_per_m: xi[N_STATES] * self.nominal.csy_ns_per_m,
            csay_ns_per_m: xi[N_STATES + 1] * self.nominal.csay_ns_per_m,
        }
    }

    /// Time propagation (eq. 16-18) then measurement update (eq. 12-15, Joseph form). On
    /// error (the estimate has left the region where the model is defined, e.g. `C_sy` through
    /// zero) the filter is unchanged and says so; the paper shows this filter diverging.
    pub fn step(&mut self, y: &Vector5) -> Result<EkfEstimate, DamperError> {
        let d = self.dampers(&self.xi);
        let x = self.xi.fixed_rows::<N_STATES>(0).into_owned();
        let a = self.model.a_matrix(&d);
        let phi = Matrix17::identity() + a * self.dt_s;
        let mut f = Matrix19::identity();
        f.fixed_view_mut::<N_STATES, N_STATES>(0, 0).copy_from(&phi);
        let mut dax = self.model.a_x_parameter_jacobian(&d, &x);
        dax.column_mut(0).scale_mut(self.nominal.csy_ns_per_m);
        dax.column_mut(1).scale_mut(self.nominal.csay_ns_per_m);
        f.fixed_view_mut::<N_STATES, 2>(0, N_STATES)
            .copy_from(&(dax * self.dt_s));
        let mut xi_pred = self.xi;
        xi_pred.fixed_rows_mut::<N_STATES>(0).copy_from(&(phi * x));
        let p_pred = congruence(&f, &self.p) + self.q;
        let innovation = y - self.h * xi_pred;
        let u = update_joseph(&xi_pred, &p_pred, &innovation, &self.h, &self.q_v)?;
        if u.p.iter().any(|v| !v.is_finite()) {
            return Err(DamperError::NonFinite {
                what: "EKF covariance",
            });
        }
        self.xi = u.x;
        self.p = u.p;
        Ok(self.estimate())
    }

    pub fn state(&self) -> EkfState {
        EkfState {
            xi: self.xi,
            p: self.p,
        }
    }

    /// The EKF of `filter_model` and `config` where `state` left it.
    pub fn resume(
        filter_model: &FilterModel,
        config: &EkfConfig,
        state: EkfState,
    ) -> Result<Self, DamperError> {
        let mut ekf = Self::new(filter_model, config)?;
        ekf.xi = state.xi;
        ekf.p = state.p;
        Ok(ekf)
    }

    pub fn estimate(&self) -> EkfEstimate {
        EkfEstimate {
            dampers: self.dampers(&self.xi),
            std_ns_per_m: [
                self.p[(N_STATES, N_STATES)].max(0.0).sqrt() * self.nominal.csy_ns_per_m,
                self.p[(N_STATES + 1, N_STATES + 1)].max(0.0).sqrt() * self.nominal.csay_ns_per_m,
            ],
        }
    }

    /// The full augmented covariance (for invariant checks).
    pub fn covariance(&self) -> &Matrix19 {
        &self.p
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::BogieParams;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The sparse `f p f'` is bit for bit nalgebra's dense product, for the EKF's own `f`
    /// (at two speeds and off-nominal dampers) and seeded symmetric `p`.
    #[test]
    fn sparse_congruence_is_the_dense_product_bit_for_bit() {
        let mut rng = ChaCha8Rng::seed_from_u64(28);
        for (speed_m_s, ratio) in [(45.3, 1.0), (12.0, 0.4)] {
            let mut model = BogieModel::new(&BogieParams::default(), 0.1).unwrap();
            model.set_speed(speed_m_s).unwrap();
            let d = Dampers {
                csy_ns_per_m: ratio * Dampers::NOMINAL.csy_ns_per_m,
                csay_ns_per_m: Dampers::NOMINAL.csay_ns_per_m / ratio,
            };
            let x = Vector19::from_fn(|_, _| rng.random::<f64>() - 0.5);
            let x17 = x.fixed_rows::<N_STATES>(0).into_owned();
            let mut f = Matrix19::identity();
            f.fixed_view_mut::<N_STATES, N_STATES>(0, 0)
                .copy_from(&(Matrix17::identity() + model.a_matrix(&d) * 1e-3));
            f.fixed_view_mut::<N_STATES, 2>(0, N_STATES)
                .copy_from(&(model.a_x_parameter_jacobian(&d, &x17) * 1e-3));
            let zeros = f.iter().filter(|v| **v == 0.0).count();
            assert!(zeros > 200, "f is sparse: {zeros} zeros of 361");
            for _ in 0..20 {
                let l = Matrix19::from_fn(|_, _| rng.random::<f64>() - 0.5);
                let p = l * l.transpose();
                let (sparse, dense) = (congruence(&f, &p), f * p * f.transpose());
                assert!(sparse
                    .iter()
                    .zip(dense.iter())
                    .all(|(a, b)| a.to_bits() == b.to_bits()));
            }
        }
    }
}
