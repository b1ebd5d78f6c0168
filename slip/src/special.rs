//! Special functions and the exponential-family pieces the variational estimators share
//! (expectations and KL divergences of Beta, Gamma and Normal factors).

/// `ln(2 pi)`.
pub const LN_2PI: f64 = railmon_filter::kalman::LN_2PI;

/// Digamma `psi(x)` for `x > 0`: recurrence up to `x >= 7`, then the asymptotic series to
/// the `x^-12` term (truncation error < 2e-13 there).
pub fn digamma(x: f64) -> f64 {
    digamma_minus_ln(x, 1.0)
}

/// `psi(x) - ln(y)` with one logarithm (`ln` of the shifted `x` over `y`): the expected log
/// precision `E[ln Lambda] = psi(a) - ln b` of a Gamma factor, at every VB and VMP iteration.
pub fn digamma_minus_ln(mut x: f64, y: f64) -> f64 {
    let mut acc = 0.0;
    while x < 7.0 {
        acc -= 1.0 / x;
        x += 1.0;
    }
    let inv = 1.0 / x;
    let inv2 = inv * inv;
    // ln x - 1/(2x) - sum_k B_2k / (2k x^2k), Bernoulli numbers B_2 .. B_12.
    let series = inv2
        * (1.0 / 12.0
            - inv2
                * (1.0 / 120.0
                    - inv2
                        * (1.0 / 252.0
                            - inv2
                                * (1.0 / 240.0 - inv2 * (1.0 / 132.0 - inv2 * 691.0 / 32760.0)))));
    acc + (x / y).ln() - 0.5 * inv - series
}

/// One `ln Gamma` serves the slip and the fuel estimators: `railmon_filter::special`.
pub use railmon_filter::special::ln_gamma;

/// A Beta factor over the adhesion-loss probability `pi`, written as the paper's
/// `p(pi) ∝ pi^(alpha_1 - 1) (1 - pi)^(alpha_0 - 1)` (eq. 25).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BetaFactor {
    /// Pseudo-count of drives with adhesion (component 0).
    pub alpha_0: f64,
    /// Pseudo-count of drives without adhesion (component 1).
    pub alpha_1: f64,
}

impl BetaFactor {
    /// `(E[ln(1 - pi)], E[ln pi])` (eq. 45).
    pub fn expected_logs(&self) -> (f64, f64) {
        self.expected_logs_given_total(digamma(self.alpha_0 + self.alpha_1))
    }

    /// As [`expected_logs`](Self::expected_logs) with `psi(alpha_0 + alpha_1)` given: within
    /// one VB run the total is the prior's plus the number of drives, whatever the
    /// responsibilities, so it is computed once per run.
    pub fn expected_logs_given_total(&self, digamma_total: f64) -> (f64, f64) {
        (
            digamma(self.alpha_0) - digamma_total,
            digamma(self.alpha_1) - digamma_total,
        )
    }

    /// `ln B(alpha_1, alpha_0)`, the log normaliser.
    pub fn ln_norm(&self) -> f64 {
        ln_gamma(self.alpha_0) + ln_gamma(self.alpha_1) - ln_gamma(self.alpha_0 + self.alpha_1)
    }

    /// `KL(self || prior)`.
    pub fn kl(&self, prior: &BetaFactor) -> f64 {
        self.kl_given(prior, prior.ln_norm(), self.expected_logs())
    }

    /// `KL(self || prior)` with the prior's `ln_norm` and this factor's `expected_logs` given
    /// (an iterative run has both at hand; the bound is then cheaper to evaluate).
    pub fn kl_given(
        &self,
        prior: &BetaFactor,
        prior_ln_norm: f64,
        expected_logs: (f64, f64),
    ) -> f64 {
        let (l0, l1) = expected_logs;
        prior_ln_norm - self.ln_norm()
            + (self.alpha_0 - prior.alpha_0) * l0
            + (self.alpha_1 - prior.alpha_1) * l1
    }
}

/// A Gamma factor over a precision, shape `a`, rate `b`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GammaFactor {
    pub shape: f64,
    pub rate: f64,
}

impl GammaFactor {
    pub fn mean(&self) -> f64 {
        self.shape / self.rate
    }
    /// `E[ln lambda] = psi(a) - ln b` (eq. 46 for D = 1).
    pub fn expected_ln(&self) -> f64 {
        digamma_minus_ln(self.shape, self.rate)
    }
    /// `KL(self || prior)`.
    pub fn kl(&self, prior: &GammaFactor) -> f64 {
        self.kl_given(prior, ln_gamma(prior.shape))
    }

    /// `KL(self || prior)` with `ln Gamma(prior.shape)` given.
    pub fn kl_given(&self, prior: &GammaFactor, prior_ln_gamma_shape: f64) -> f64 {
        let (a, b, a0, b0) = (self.shape, self.rate, prior.shape, prior.rate);
        (a - a0) * digamma(a) - ln_gamma(a)
            + prior_ln_gamma_shape
            + a0 * (b / b0).ln()
            + a * (b0 - b) / b
    }
}

/// `KL(N(m, 1/p) || N(m0, 1/p0))` for scalar normals given by mean and precision.
pub fn normal_kl(m: f64, p: f64, m0: f64, p0: f64) -> f64 {
    0.5 * (p0 / p + p0 * (m - m0).powi(2) - 1.0 + (p / p0).ln())
}

/// `sum_k r_k ln r_k` for a two-point distribution `(1 - r, r)` (minus its entropy).
pub fn bernoulli_neg_entropy(r: f64) -> f64 {
    let t = |v: f64| if v > 0.0 { v * v.ln() } else { 0.0 };
    t(r) + t(1.0 - r)
}

#[cfg(test)]
mod tests {
    use std::f64::consts::PI;

    use super::*;

    #[test]
    fn digamma_and_ln_gamma_reference_values() {
        // psi(1) = -Euler gamma; psi(0.5) = -gamma - 2 ln 2; ln Gamma(0.5) = ln sqrt(pi).
        let euler = 0.577_215_664_901_532_9;
        assert!((digamma(1.0) + euler).abs() < 1e-12);
        assert!((digamma(0.5) + euler + 2.0 * 2f64.ln()).abs() < 1e-12);
        assert!(
            (digamma(10.3) - (ln_gamma(10.3 + 1e-6) - ln_gamma(10.3 - 1e-6)) / 2e-6).abs() < 1e-7
        );
        assert!((ln_gamma(0.5) - 0.5 * PI.ln()).abs() < 1e-12);
        for (x, y) in [(0.3, 1e-3), (1.5, 0.005), (40.0, 250.0)] {
            assert!((digamma_minus_ln(x, y) - (digamma(x) - f64::ln(y))).abs() < 1e-12);
        }
        assert!((ln_gamma(10.0) - 362_880f64.ln()).abs() < 1e-11);
        assert!(ln_gamma(1.0).abs() < 1e-13 && ln_gamma(2.0).abs() < 1e-13);
    }

    #[test]
    fn kl_divergences_are_zero_at_equality_and_positive_elsewhere() {
        let b = BetaFactor {
            alpha_0: 2.0,
            alpha_1: 3.5,
        };
        assert!(b.kl(&b).abs() < 1e-12);
        let prior = BetaFactor {
            alpha_0: 1.0,
            alpha_1: 1.0,
        };
        let given = b.kl_given(
            &prior,
            prior.ln_norm(),
            b.expected_logs_given_total(digamma(5.5)),
        );
        assert!((given - b.kl(&prior)).abs() < 1e-14);
        assert!(
            b.kl(&BetaFactor {
                alpha_0: 1.0,
                alpha_1: 1.0
            }) > 0.0
        );
        let g = GammaFactor {
            shape: 1.5,
            rate: 0.005,
        };
        assert!(g.kl(&g).abs() < 1e-12);
        assert!(
            g.kl(&GammaFactor {
                shape: 0.1,
                rate: 0.1
            }) > 0.0
        );
        assert!(normal_kl(1.0, 2.0, 1.0, 2.0).abs() < 1e-15);
        assert!(normal_kl(1.0, 2.0, 0.0, 0.01) > 0.0);
    }
}
