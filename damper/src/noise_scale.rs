//! Online estimate of the sensors' noise, as a variance scale per channel relative to the
//! configured `Q_v` (issue 9 item 2): the filter must not need the sensor noise exactly.
//!
//! Variational-Bayes adaptive Kalman filtering after Särkkä & Nummenmaa, "Recursive noise
//! adaptive Kalman filtering by variational Bayesian approximations", IEEE TAC 54(3), 2009:
//! each channel's variance carries an inverse-gamma distribution `IG(alpha_i, beta_i)`,
//! predicted by their heuristic forgetting (`alpha- = rho alpha`, `beta- = rho beta`, here
//! `rho = exp(-T / tau)`) and updated by the squared residual (`alpha = alpha- + 1/2`,
//! `beta = beta- + r^2 / 2`); the point estimate is `beta / alpha`. (The paper is not in
//! `../shared/seeds`; the steps are quoted from its algorithm, not checked against its text.)
//!
//! Two departures, both because every particle here runs a steady-state filter whose gain
//! and `S` come from a table built for the configured noise:
//! - The unknown is a scale `d_i` of the innovation variance `S_ii` (not of `R_ii`), and the
//!   residual is the normalised innovation `z_i = e_i^2 / S_ii` pooled over the particles with
//!   their predictive weights (one estimate shared by all particles, not one per particle).
//!   On this bogie `S` is within about 10 % of `Q_v` on the diagonal (the sensors' noise
//!   dominates the one-step prediction error at 1 kHz), so a scale of `S` is nearly the same
//!   scale of `Q_v` (`docs/damper.md`, "Unknown sensor noise").
//! - The particles weigh their innovations with `D^1/2 S D^1/2` (`D = diag(d)`): the
//!   likelihood is tempered channel by channel, the gains stay the table's (suboptimal when the
//!   noise is off, but unbiased). `ln det D` is common to all particles and cancels in the
//!   weights; it is kept in the evidence.
//!
//! The estimate is clamped to `[min_std_ratio^2, max_std_ratio^2]`: noise beyond that range
//! is not the sensors' spread any more, and the rest of the innovation shows in the
//! normalised innovation squared that `crate::ConsistencyCheck` judges (`model_mismatch`).

use serde::{Deserialize, Serialize};

use crate::model::N_OUTPUTS;
use crate::params::positive;
use crate::DamperError;

/// How the noise scale is estimated (`[monitor.rbpf.noise_scale]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct NoiseScaleConfig {
    /// `false`: the configured noise is taken as exact (scale 1), as before issue 9 item 2.
    pub enabled: bool,
    /// Forgetting time constant `tau` (s): the estimate averages the last `tau` seconds or so.
    /// Long against the 1-4 s a damper fault takes to be found (so a fault's larger
    /// innovations are not absorbed as noise), short against a 10-minute run.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub time_constant_s: f64,
    /// Weight of the prior (scale 1) in samples; forgotten like the data.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub prior_samples: f64,
    /// Smallest estimated standard deviation, as a ratio of the configured one.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub min_std_ratio: f64,
    /// Largest estimated standard deviation, as a ratio of the configured one.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub max_std_ratio: f64,
}

impl Default for NoiseScaleConfig {
    fn default() -> Self {
        NoiseScaleConfig {
            enabled: true,
            time_constant_s: 20.0,
            prior_samples: 100.0,
            min_std_ratio: 0.25,
            max_std_ratio: 4.0,
        }
    }
}

impl NoiseScaleConfig {
    pub fn validate(&self) -> Result<(), DamperError> {
        positive("rbpf.noise_scale.time_constant_s", self.time_constant_s)?;
        positive("rbpf.noise_scale.prior_samples", self.prior_samples)?;
        positive("rbpf.noise_scale.min_std_ratio", self.min_std_ratio)?;
        if !(self.max_std_ratio >= self.min_std_ratio && self.max_std_ratio.is_finite()) {
            return Err(DamperError::InvalidParameter {
                field: "rbpf.noise_scale.max_std_ratio",
                value: self.max_std_ratio,
                reason: "must be finite and at least min_std_ratio",
            });
        }
        Ok(())
    }
}

/// The running estimate: per channel `IG(alpha_i, beta_i)` of the variance scale `d_i`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct NoiseScale {
    config: NoiseScaleConfig,
    forgetting: f64,
    alpha: [f64; N_OUTPUTS],
    beta: [f64; N_OUTPUTS],
    scale: [f64; N_OUTPUTS],
}

impl NoiseScale {
    pub fn new(config: &NoiseScaleConfig, dt_s: f64) -> Self {
        // The prior IG(a0, b0) with a0 = b0: a scale of 1 (the mean b / a), worth
        // `prior_samples` observations of 1/2 each.
        let a0 = 0.5 * config.prior_samples;
        NoiseScale {
            config: *config,
            forgetting: (-dt_s / config.time_constant_s).exp(),
            alpha: [a0; N_OUTPUTS],
            beta: [a0; N_OUTPUTS],
            scale: [1.0; N_OUTPUTS],
        }
    }

    /// The variance scale per channel (1 when disabled), in the sensors' order of eq. (4).
    pub fn variance_scale(&self) -> [f64; N_OUTPUTS] {
        self.scale
    }

    /// The standard deviation per channel as a ratio of the configured one.
    pub fn std_ratio(&self) -> [f64; N_OUTPUTS] {
        self.scale.map(f64::sqrt)
    }

    /// One step with the pooled normalised squared innovations `z_i = E_w[e_i^2 / S_ii]`.
    /// Non-finite `z` (a diverged filter) leaves the estimate unchanged.
    pub fn update(&mut self, z: &[f64; N_OUTPUTS]) {
        if !self.config.enabled || z.iter().any(|v| !v.is_finite()) {
            return;
        }
        let (lo, hi) = (
            self.config.min_std_ratio.powi(2),
            self.config.max_std_ratio.powi(2),
        );
        for (((a, b), d), zi) in self
            .alpha
            .iter_mut()
            .zip(&mut self.beta)
            .zip(&mut self.scale)
            .zip(z)
        {
            *a = self.forgetting * *a + 0.5;
            *b = self.forgetting * *b + 0.5 * zi;
            // The VB point estimate `beta / alpha` (1 / E[1/d]).
            *d = (*b / *a).clamp(lo, hi);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    /// Runs the estimator on `seconds` of white innovations of variance `true_scale[i]` times
    /// a unit `S` (so `z_i = e_i^2`).
    fn run(true_scale: [f64; N_OUTPUTS], seconds: f64, seed: u64) -> NoiseScale {
        let cfg = NoiseScaleConfig::default();
        let dt = 1e-3;
        let mut est = NoiseScale::new(&cfg, dt);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        for _ in 0..(seconds / dt) as usize {
            let z = true_scale.map(|s| {
                let g: f64 = StandardNormal.sample(&mut rng);
                let e = s.sqrt() * g;
                e * e
            });
            est.update(&z);
        }
        est
    }

    #[test]
    fn recovers_a_known_scale_per_channel() {
        // std ratios 0.5, 1, 2, 3 and 1.5 on the five channels.
        let truth = [0.25, 1.0, 4.0, 9.0, 2.25];
        let est = run(truth, 60.0, 1);
        // At equilibrium `beta / alpha` is a mean of the squares with weights rho^k: an
        // effective count of (1 + rho) / (1 - rho) ~ 2 tau / T = 40,000, relative sd
        // sqrt(2 / 40,000) = 0.7 %; 4 % is more than five of them.
        for (d, t) in est.variance_scale().iter().zip(truth) {
            assert!((d / t - 1.0).abs() < 0.04, "{d} vs {t}");
        }
    }

    #[test]
    fn does_not_drift_at_the_configured_noise() {
        // Ten minutes at the right noise on five seeds: every channel stays within 4 % of 1 at
        // the end, and the mean over seeds and channels within 1 %.
        let mut sum = 0.0;
        for seed in 0..5 {
            let est = run([1.0; N_OUTPUTS], 600.0, 10 + seed);
            for d in est.variance_scale() {
                assert!((d - 1.0).abs() < 0.04, "{d}");
                sum += d;
            }
        }
        assert!((sum / 25.0 - 1.0).abs() < 0.01, "{}", sum / 25.0);
    }

    #[test]
    fn clamps_to_the_configured_range_and_ignores_non_finite_input() {
        let est = run([100.0; N_OUTPUTS], 30.0, 3);
        assert_eq!(est.std_ratio(), [4.0; N_OUTPUTS]);
        let mut e = est;
        e.update(&[f64::NAN; N_OUTPUTS]);
        assert_eq!(e, est);
        let off = NoiseScale::new(
            &NoiseScaleConfig {
                enabled: false,
                ..NoiseScaleConfig::default()
            },
            1e-3,
        );
        let mut o = off;
        o.update(&[9.0; N_OUTPUTS]);
        assert_eq!(o.variance_scale(), [1.0; N_OUTPUTS]);
    }
}
