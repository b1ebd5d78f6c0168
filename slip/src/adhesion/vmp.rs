//! Variational message passing for the mixture of section 4.4: independent Normal means and
//! Gamma precisions per component (Fig. 4), Bernoulli indicators driven by a Beta `pi`.
//!
//! Erratum (seed-notes): the message to a precision in step (v) needs the expected square
//! `E[(x_i - mu_j)^2] = x_i^2 - 2 x_i E[mu_j] + E[mu_j^2] = (x_i - E[mu_j])^2 + Var[mu_j]`,
//! not `(x_i - E[mu_j])^2`; without the variance term the update is not the VMP fixed point
//! and the bound can decrease. Also the second entry of that message is
//! `-E[(x_i - mu_j)^2] / 2`, matching the factor 1/2 of the log-density above it.

use serde::{Deserialize, Serialize};

use super::mixture::{
    data_bound, initial_means, update_responsibilities, BoundWatch, ExpectedComponent,
    WeightedMoments,
};
use super::AdhesionOutput;
use crate::error::{check_finite, check_in, check_positive, SlipError};
use crate::special::{digamma, normal_kl, BetaFactor, GammaFactor};

/// VMP settings; defaults are the paper's (section 5).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct VmpConfig {
    /// Iterations per step (the paper: 5); the maximum when `stop_tolerance` is set.
    #[schemars(range(min = *super::ITERATIONS.start(), max = *super::ITERATIONS.end()))]
    pub iterations: usize,
    /// Stop when the bound rises by less than this fraction of its magnitude.
    #[schemars(range(min = *super::STOP_TOLERANCE.start(), max = *super::STOP_TOLERANCE.end()))]
    pub stop_tolerance: Option<f64>,
    /// Beta prior pseudo-count of "adhesion" (the paper: 1).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub alpha_adhesion: f64,
    /// Beta prior pseudo-count of "adhesion lost" (the paper: 1).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub alpha_loss: f64,
    /// `pi` in the first indicator update.
    #[schemars(range(min = *super::INITIAL_LOSS_PROBABILITY.start(), max = *super::INITIAL_LOSS_PROBABILITY.end()))]
    pub initial_loss_probability: f64,
    /// Prior precision of each component mean (the paper: 0.01).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub mean_precision: f64,
    /// Shape of the Gamma prior of each precision (the paper: (0.1, 0.1), after Gelman et al.).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub gamma_shape: f64,
    /// Rate of the Gamma prior of each precision (the paper: 0.1).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub gamma_rate: f64,
    /// Prior mean of "adhesion lost" (0); "adhesion" starts at the largest torque.
    pub loss_mean_nm: f64,
}

impl Default for VmpConfig {
    fn default() -> Self {
        VmpConfig {
            iterations: 5,
            stop_tolerance: None,
            alpha_adhesion: 1.0,
            alpha_loss: 1.0,
            initial_loss_probability: 0.5,
            mean_precision: 0.01,
            gamma_shape: 0.1,
            gamma_rate: 0.1,
            loss_mean_nm: 0.0,
        }
    }
}

impl VmpConfig {
    pub fn validate(&self) -> Result<(), SlipError> {
        if !super::ITERATIONS.contains(&self.iterations) {
            return Err(SlipError::invalid(
                "vmp.iterations",
                self.iterations,
                "must be in 1..=10000",
            ));
        }
        if let Some(t) = self.stop_tolerance {
            check_in(
                "vmp.stop_tolerance",
                t,
                *super::STOP_TOLERANCE.start(),
                *super::STOP_TOLERANCE.end(),
                "must be in [0, 1]",
            )?;
        }
        check_positive("vmp.alpha_adhesion", self.alpha_adhesion)?;
        check_positive("vmp.alpha_loss", self.alpha_loss)?;
        check_in(
            "vmp.initial_loss_probability",
            self.initial_loss_probability,
            *super::INITIAL_LOSS_PROBABILITY.start(),
            *super::INITIAL_LOSS_PROBABILITY.end(),
            "must be in [1e-9, 1 - 1e-9]",
        )?;
        check_positive("vmp.mean_precision", self.mean_precision)?;
        check_positive("vmp.gamma_shape", self.gamma_shape)?;
        check_positive("vmp.gamma_rate", self.gamma_rate)?;
        check_finite("vmp.loss_mean_nm", self.loss_mean_nm)?;
        Ok(())
    }
}

/// `q(mu) = N(mean, 1/precision)`, `q(Lambda) = Gamma`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct Node {
    mean: f64,
    mean_precision: f64,
    lambda: GammaFactor,
}

impl Node {
    fn expected(&self) -> ExpectedComponent {
        ExpectedComponent {
            mean: self.mean,
            precision: self.lambda.mean(),
            ln_precision: self.lambda.expected_ln(),
            spread: self.lambda.mean() / self.mean_precision,
        }
    }
}

/// Runs VMP over `x`; returns the adhesion mean, the bound and the iterations; `r` ends as
/// `E[I_i]`. Pushes every bound to `trace` when given.
fn run(
    config: &VmpConfig,
    x: &[f64],
    r: &mut [f64],
    trace: Option<&mut Vec<f64>>,
) -> (f64, f64, usize) {
    let mut watch = BoundWatch::new(config.iterations, config.stop_tolerance, trace);
    let digamma_total = digamma(config.alpha_adhesion + config.alpha_loss + x.len() as f64);
    let means = initial_means(x, config.loss_mean_nm);
    let lambda_prior = GammaFactor {
        shape: config.gamma_shape,
        rate: config.gamma_rate,
    };
    let prior = |mean| Node {
        mean,
        mean_precision: config.mean_precision,
        lambda: lambda_prior,
    };
    let priors = [prior(means[0]), prior(means[1])];
    let pi_prior = BetaFactor {
        alpha_0: config.alpha_adhesion,
        alpha_1: config.alpha_loss,
    };
    let mut nodes = priors;
    let p0 = config.initial_loss_probability;
    update_responsibilities(
        x,
        &[nodes[0].expected(), nodes[1].expected()],
        ((1.0 - p0).ln(), p0.ln()),
        r,
    );
    let mut iterations = 0;
    for it in 1..=config.iterations {
        for (k, node) in nodes.iter_mut().enumerate() {
            let m = WeightedMoments::of_component(x, r, k);
            // (i)-(iii): messages E[Lambda] x_i, -E[Lambda]/2 scaled by the indicator weights.
            let e_lambda = node.lambda.mean();
            let precision = priors[k].mean_precision + e_lambda * m.count;
            node.mean = (priors[k].mean_precision * priors[k].mean + e_lambda * m.sum) / precision;
            node.mean_precision = precision;
            // (iv)-(vi) with the erratum: E[(x - mu)^2] = (x - E mu)^2 + Var mu.
            let expected_sq = m.scatter_about(node.mean) + m.count / precision;
            node.lambda = GammaFactor {
                shape: lambda_prior.shape + 0.5 * m.count,
                rate: lambda_prior.rate + 0.5 * expected_sq,
            };
        }
        let m1 = WeightedMoments::of_component(x, r, 1);
        let pi = BetaFactor {
            alpha_0: pi_prior.alpha_0 + (x.len() as f64 - m1.count),
            alpha_1: pi_prior.alpha_1 + m1.count,
        };
        let expected = [nodes[0].expected(), nodes[1].expected()];
        let log_weights = pi.expected_logs_given_total(digamma_total);
        update_responsibilities(x, &expected, log_weights, r);
        iterations = it;
        if watch.needed(it) {
            let kl: f64 = nodes
                .iter()
                .zip(&priors)
                .map(|(q, p)| {
                    normal_kl(q.mean, q.mean_precision, p.mean, p.mean_precision)
                        + q.lambda.kl(&p.lambda)
                })
                .sum();
            if watch.record(data_bound(x, r, &expected, log_weights) - pi.kl(&pi_prior) - kl) {
                break;
            }
        }
    }
    (nodes[0].mean, watch.bound, iterations)
}

/// The paper's VMP estimator.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct VmpEstimator {
    config: VmpConfig,
    out: AdhesionOutput,
}

impl VmpEstimator {
    pub fn new(config: VmpConfig, n_drives: usize) -> Self {
        VmpEstimator {
            config,
            out: AdhesionOutput::new(n_drives),
        }
    }

    pub fn output(&self) -> &AdhesionOutput {
        &self.out
    }

    pub fn estimate(&mut self, x: &[f64]) -> &AdhesionOutput {
        let (global, bound, iterations) =
            run(&self.config, x, &mut self.out.slip_probability, None);
        self.out.global_torque_nm = global;
        self.out.lower_bound = Some(bound);
        self.out.iterations = iterations;
        &self.out
    }
}

#[cfg(test)]
mod tests {
    use super::super::mixture::test_support::assert_bound_never_decreases;
    use super::*;

    #[test]
    fn lower_bound_never_decreases() {
        let config = VmpConfig {
            iterations: 40,
            ..VmpConfig::default()
        };
        assert_bound_never_decreases(3, |x, trace| {
            let mut r = vec![0.0; x.len()];
            run(&config, x, &mut r, Some(trace));
        });
    }

    #[test]
    fn separates_a_dropped_drive() {
        let mut e = VmpEstimator::new(VmpConfig::default(), 3);
        let out = e.estimate(&[0.1, 20.0, 20.02]);
        assert!(out.slip_probability[0] > 0.99, "{:?}", out.slip_probability);
        assert!(out.slip_probability[1] < 0.01 && out.slip_probability[2] < 0.01);
        assert!(
            (out.global_torque_nm - 20.01).abs() < 0.05,
            "{}",
            out.global_torque_nm
        );
    }

    #[test]
    fn each_invalid_vmp_parameter_is_rejected() {
        let bad = |m: fn(&mut VmpConfig), field: &str| {
            let mut c = VmpConfig::default();
            m(&mut c);
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains(field), "{e}");
        };
        bad(|c| c.iterations = 0, "vmp.iterations");
        bad(|c| c.stop_tolerance = Some(2.0), "vmp.stop_tolerance");
        bad(|c| c.alpha_adhesion = -1.0, "vmp.alpha_adhesion");
        bad(|c| c.alpha_loss = 0.0, "vmp.alpha_loss");
        bad(
            |c| c.initial_loss_probability = 0.0,
            "vmp.initial_loss_probability",
        );
        bad(|c| c.mean_precision = 0.0, "vmp.mean_precision");
        bad(|c| c.gamma_shape = f64::NAN, "vmp.gamma_shape");
        bad(|c| c.gamma_rate = -0.1, "vmp.gamma_rate");
        bad(|c| c.loss_mean_nm = f64::NAN, "vmp.loss_mean_nm");
    }
}
