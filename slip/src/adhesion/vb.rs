//! Variational Bayes for the two-component mixture of section 4.2 (eq. 21-47), univariate
//! (`D = 1`: the Normal-Wishart of eq. 27-28 is a Normal-Gamma), with its lower bound.
//!
//! Wishart `W(W, nu)` in one dimension is `Gamma(shape = nu / 2, rate = 1 / (2 W))`, so the
//! paper's `nu = 3, W = 100` give `E[Lambda] = 300` (a prior standard deviation of 0.06 N m).

use serde::{Deserialize, Serialize};

use super::mixture::{
    data_bound, initial_means, update_responsibilities, BoundWatch, ExpectedComponent,
    LogMixingWeights, WeightedMoments,
};
use super::AdhesionOutput;
use crate::error::{check_finite, check_in, check_positive, SlipError};
use crate::special::{digamma, ln_gamma, BetaFactor, GammaFactor};

/// VB settings; defaults are the paper's (section 5).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct VbConfig {
    /// Iterations per step (the paper: 5); the maximum when `stop_tolerance` is set.
    #[schemars(range(min = *super::ITERATIONS.start(), max = *super::ITERATIONS.end()))]
    pub iterations: usize,
    /// Stop when the lower bound rises by less than this fraction of its magnitude (the paper's
    /// suggestion); absent: always run `iterations`.
    #[schemars(range(min = *super::STOP_TOLERANCE.start(), max = *super::STOP_TOLERANCE.end()))]
    pub stop_tolerance: Option<f64>,
    /// Beta prior pseudo-count of "adhesion" (`alpha_0`; the paper: 1).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub alpha_adhesion: f64,
    /// Beta prior pseudo-count of "adhesion lost" (`alpha_1`; the paper: 1).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub alpha_loss: f64,
    /// `pi` used in the first indicator update, before `q(pi)` exists (the paper: 0.5).
    #[schemars(range(min = *super::INITIAL_LOSS_PROBABILITY.start(), max = *super::INITIAL_LOSS_PROBABILITY.end()))]
    pub initial_loss_probability: f64,
    /// Wishart degrees of freedom `nu` of both components (the paper: 3).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub wishart_dof: f64,
    /// Wishart scale `W` of both components (the paper: 100).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub wishart_scale: f64,
    /// Wishart scale of the "adhesion lost" component when it should differ from
    /// `wishart_scale` (absent: the paper's, the same for both). A small value makes that
    /// component broad, so it takes any outlier rather than letting the adhesion component
    /// widen to swallow a drive that departs slowly.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub loss_wishart_scale: Option<f64>,
    /// Normal-Wishart `beta`, the prior precision scale of the means. Not printed in the paper
    /// (its "alpha = beta = 1" may mean this too); 1 serves both readings.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub mean_scale: f64,
    /// Prior mean of the "adhesion lost" component (the paper: 0). The "adhesion" component
    /// starts at the largest torque of the step.
    pub loss_mean_nm: f64,
}

impl Default for VbConfig {
    fn default() -> Self {
        VbConfig {
            iterations: 5,
            stop_tolerance: None,
            alpha_adhesion: 1.0,
            alpha_loss: 1.0,
            initial_loss_probability: 0.5,
            wishart_dof: 3.0,
            wishart_scale: 100.0,
            loss_wishart_scale: None,
            mean_scale: 1.0,
            loss_mean_nm: 0.0,
        }
    }
}

impl VbConfig {
    pub fn validate(&self, prefix: &str) -> Result<(), SlipError> {
        let f = |n: &str| format!("{prefix}.{n}");
        if !super::ITERATIONS.contains(&self.iterations) {
            return Err(SlipError::invalid(
                f("iterations"),
                self.iterations,
                "must be in 1..=10000",
            ));
        }
        if let Some(t) = self.stop_tolerance {
            check_in(
                &f("stop_tolerance"),
                t,
                *super::STOP_TOLERANCE.start(),
                *super::STOP_TOLERANCE.end(),
                "must be in [0, 1]",
            )?;
        }
        check_positive(&f("alpha_adhesion"), self.alpha_adhesion)?;
        check_positive(&f("alpha_loss"), self.alpha_loss)?;
        check_in(
            &f("initial_loss_probability"),
            self.initial_loss_probability,
            *super::INITIAL_LOSS_PROBABILITY.start(),
            *super::INITIAL_LOSS_PROBABILITY.end(),
            "must be in [1e-9, 1 - 1e-9]",
        )?;
        // The Wishart needs nu > D - 1 = 0; nu > 0 keeps the Gamma proper.
        check_positive(&f("wishart_dof"), self.wishart_dof)?;
        check_positive(&f("wishart_scale"), self.wishart_scale)?;
        if let Some(w) = self.loss_wishart_scale {
            check_positive(&f("loss_wishart_scale"), w)?;
        }
        check_positive(&f("mean_scale"), self.mean_scale)?;
        check_finite(&f("loss_mean_nm"), self.loss_mean_nm)?;
        Ok(())
    }

    /// The prior of one step, with the component means of section 5.
    pub fn priors(&self, x: &[f64]) -> VbPriors {
        let means = initial_means(x, self.loss_mean_nm);
        let comp = |mean, scale: f64| NormalGamma {
            mean,
            beta: self.mean_scale,
            gamma: GammaFactor {
                shape: 0.5 * self.wishart_dof,
                rate: 0.5 / scale,
            },
        };
        let loss_scale = self.loss_wishart_scale.unwrap_or(self.wishart_scale);
        VbPriors {
            pi: BetaFactor {
                alpha_0: self.alpha_adhesion,
                alpha_1: self.alpha_loss,
            },
            components: [
                comp(means[0], self.wishart_scale),
                comp(means[1], loss_scale),
            ],
        }
    }

    fn initial_log_weights(&self) -> LogMixingWeights {
        (
            (1.0 - self.initial_loss_probability).ln(),
            self.initial_loss_probability.ln(),
        )
    }
}

/// `N(mu | mean, 1 / (beta Lambda)) Gamma(Lambda | shape, rate)`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct NormalGamma {
    pub mean: f64,
    pub beta: f64,
    pub gamma: GammaFactor,
}

impl NormalGamma {
    fn expected(&self) -> ExpectedComponent {
        ExpectedComponent {
            mean: self.mean,
            precision: self.gamma.mean(),
            ln_precision: self.gamma.expected_ln(),
            // eq. (47): E[(x - mu)^2 Lambda] = 1/beta + nu W (x - m)^2
            spread: 1.0 / self.beta,
        }
    }

    /// `KL(self || prior)`: the Gamma part plus the expected KL of the conditional normals.
    pub fn kl(&self, prior: &NormalGamma) -> f64 {
        self.kl_given(prior, ln_gamma(prior.gamma.shape))
    }

    /// `KL(self || prior)` with `ln Gamma` of the prior's shape given.
    fn kl_given(&self, prior: &NormalGamma, prior_ln_gamma_shape: f64) -> f64 {
        let ratio = prior.beta / self.beta;
        self.gamma.kl_given(&prior.gamma, prior_ln_gamma_shape)
            + 0.5
                * (ratio - 1.0 - ratio.ln()
                    + prior.beta * self.gamma.mean() * (self.mean - prior.mean).powi(2))
    }

    /// Posterior after absorbing weighted data (eq. 39-42). `scatter_about(c)` must return
    /// `sum_i w_i (x_i - c)^2`.
    fn absorb(&self, m: &WeightedMoments) -> NormalGamma {
        let beta = self.beta + m.count;
        let mean = (self.beta * self.mean + m.sum) / beta;
        // (41) for D = 1: N S + beta N / (beta + N) (xbar - m)^2
        //               = sum w (x - m+)^2 + beta (m+ - m)^2.
        let scatter = m.scatter_about(mean) + self.beta * (mean - self.mean).powi(2);
        NormalGamma {
            mean,
            beta,
            gamma: GammaFactor {
                shape: self.gamma.shape + 0.5 * m.count,
                rate: self.gamma.rate + 0.5 * scatter,
            },
        }
    }

    /// Variance of the posterior marginal of `mu` (Student t), finite also for shape <= 1.
    pub fn mean_variance(&self) -> f64 {
        let inv_precision = if self.gamma.shape > 1.0 {
            self.gamma.rate / (self.gamma.shape - 1.0)
        } else {
            self.gamma.rate / self.gamma.shape
        };
        inv_precision / self.beta
    }
}

/// Prior of one VB run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct VbPriors {
    pub pi: BetaFactor,
    pub components: [NormalGamma; 2],
}

/// Posterior of one VB run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct VbPosterior {
    pub pi: BetaFactor,
    pub components: [NormalGamma; 2],
    pub lower_bound: f64,
    pub iterations: usize,
}

/// Runs VB from the responsibilities `r` (updated in place to `E[I_i]`): each iteration is
/// the parameter update (37)-(44) then the indicator update (31)-(35), and the bound after
/// it. Stops after `max_iterations`, or earlier when `stop_tolerance` is set and the bound
/// rose by less than `stop_tolerance * |bound|`. Pushes every bound to `trace` when given.
pub fn fit(
    x: &[f64],
    priors: &VbPriors,
    r: &mut [f64],
    max_iterations: usize,
    stop_tolerance: Option<f64>,
    trace: Option<&mut Vec<f64>>,
) -> VbPosterior {
    let mut watch = BoundWatch::new(max_iterations, stop_tolerance, trace);
    let digamma_total = digamma(priors.pi.alpha_0 + priors.pi.alpha_1 + x.len() as f64);
    // The prior's part of the KL terms, the same for every iteration.
    let prior_consts = (
        priors.pi.ln_norm(),
        priors.components.map(|c| ln_gamma(c.gamma.shape)),
    );
    let mut post = VbPosterior {
        pi: priors.pi,
        components: priors.components,
        lower_bound: f64::NEG_INFINITY,
        iterations: 0,
    };
    for it in 1..=max_iterations {
        let m0 = WeightedMoments::of_component(x, r, 0);
        let m1 = WeightedMoments::of_component(x, r, 1);
        post.pi = BetaFactor {
            alpha_0: priors.pi.alpha_0 + m0.count,
            alpha_1: priors.pi.alpha_1 + m1.count,
        };
        post.components = [
            priors.components[0].absorb(&m0),
            priors.components[1].absorb(&m1),
        ];
        let expected = [post.components[0].expected(), post.components[1].expected()];
        let log_weights = post.pi.expected_logs_given_total(digamma_total);
        update_responsibilities(x, &expected, log_weights, r);
        post.iterations = it;
        if watch.needed(it) {
            let bound = data_bound(x, r, &expected, log_weights)
                - post.pi.kl_given(&priors.pi, prior_consts.0, log_weights)
                - post.components[0].kl_given(&priors.components[0], prior_consts.1[0])
                - post.components[1].kl_given(&priors.components[1], prior_consts.1[1]);
            if watch.record(bound) {
                break;
            }
        }
    }
    post.lower_bound = watch.bound;
    post
}

/// The first indicator update, from the prior (the paper's initialisation).
pub fn initial_responsibilities(
    x: &[f64],
    priors: &VbPriors,
    log_weights: LogMixingWeights,
    r: &mut [f64],
) {
    let expected = [
        priors.components[0].expected(),
        priors.components[1].expected(),
    ];
    update_responsibilities(x, &expected, log_weights, r);
}

/// The paper's VB: fresh priors every step, a fixed number of iterations.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct VbEstimator {
    config: VbConfig,
    out: AdhesionOutput,
}

impl VbEstimator {
    pub fn new(config: VbConfig, n_drives: usize) -> Self {
        VbEstimator {
            config,
            out: AdhesionOutput::new(n_drives),
        }
    }

    pub fn output(&self) -> &AdhesionOutput {
        &self.out
    }

    pub fn estimate(&mut self, x: &[f64]) -> &AdhesionOutput {
        let priors = self.config.priors(x);
        let r = &mut self.out.slip_probability;
        initial_responsibilities(x, &priors, self.config.initial_log_weights(), r);
        let post = fit(
            x,
            &priors,
            r,
            self.config.iterations,
            self.config.stop_tolerance,
            None,
        );
        self.out.global_torque_nm = post.components[0].mean;
        self.out.lower_bound = Some(post.lower_bound);
        self.out.iterations = post.iterations;
        &self.out
    }
}

#[cfg(test)]
mod tests {
    use super::super::mixture::test_support::assert_bound_never_decreases;
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    #[test]
    fn lower_bound_never_decreases() {
        let config = VbConfig {
            iterations: 40,
            ..VbConfig::default()
        };
        assert_bound_never_decreases(11, |x, trace| {
            let priors = config.priors(x);
            let mut r = vec![0.0; x.len()];
            initial_responsibilities(x, &priors, config.initial_log_weights(), &mut r);
            fit(x, &priors, &mut r, config.iterations, None, Some(trace));
        });
    }

    #[test]
    fn recovers_the_means_of_two_separated_clusters() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let noise = Normal::new(0.0, 0.05).unwrap();
        let mut x: Vec<f64> = (0..40).map(|_| 20.0 + noise.sample(&mut rng)).collect();
        x.extend((0..10).map(|_| 3.0 + noise.sample(&mut rng)));
        let config = VbConfig {
            iterations: 50,
            mean_scale: 1e-3,
            ..VbConfig::default()
        };
        let priors = config.priors(&x);
        let mut r = vec![0.0; x.len()];
        initial_responsibilities(&x, &priors, config.initial_log_weights(), &mut r);
        let post = fit(&x, &priors, &mut r, config.iterations, None, None);
        let mean = |lo: usize, hi: usize| x[lo..hi].iter().sum::<f64>() / (hi - lo) as f64;
        assert!(
            (post.components[0].mean - mean(0, 40)).abs() < 1e-3,
            "{:?}",
            post.components[0]
        );
        assert!(
            (post.components[1].mean - mean(40, 50)).abs() < 1e-3,
            "{:?}",
            post.components[1]
        );
        assert!(r[..40].iter().all(|&p| p < 1e-6) && r[40..].iter().all(|&p| p > 1.0 - 1e-6));
        // precision of the adhesion component near 1 / 0.05^2 = 400
        let prec = post.components[0].gamma.mean();
        assert!((200.0..800.0).contains(&prec), "{prec}");
    }

    #[test]
    fn stop_tolerance_stops_early_on_easy_data() {
        let x = [10.0, 10.01, 0.0];
        let config = VbConfig {
            iterations: 100,
            stop_tolerance: Some(1e-9),
            ..VbConfig::default()
        };
        let mut e = VbEstimator::new(config, 3);
        let out = e.estimate(&x);
        assert!(out.iterations < 100);
        assert!(out.slip_probability[2] > 0.99 && out.slip_probability[0] < 0.01);
        assert!((out.global_torque_nm - 10.005).abs() < 0.01);
    }

    #[test]
    fn each_invalid_vb_parameter_is_rejected() {
        let bad = |m: fn(&mut VbConfig), field: &str| {
            let mut c = VbConfig::default();
            m(&mut c);
            let e = c.validate("vb").unwrap_err().to_string();
            assert!(e.contains(field), "{e}");
        };
        bad(|c| c.iterations = 0, "vb.iterations");
        bad(|c| c.stop_tolerance = Some(-1.0), "vb.stop_tolerance");
        bad(|c| c.alpha_adhesion = 0.0, "vb.alpha_adhesion");
        bad(|c| c.alpha_loss = f64::NAN, "vb.alpha_loss");
        bad(
            |c| c.initial_loss_probability = 1.0,
            "vb.initial_loss_probability",
        );
        bad(|c| c.wishart_dof = -3.0, "vb.wishart_dof");
        bad(|c| c.wishart_scale = 0.0, "vb.wishart_scale");
        bad(
            |c| c.loss_wishart_scale = Some(-1.0),
            "vb.loss_wishart_scale",
        );
        bad(|c| c.mean_scale = 0.0, "vb.mean_scale");
        bad(|c| c.loss_mean_nm = f64::INFINITY, "vb.loss_mean_nm");
    }
}
