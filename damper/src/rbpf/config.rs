//! The RBPF's settings (`[monitor.rbpf]`), validated, beside the filter that reads them.

use serde::{Deserialize, Serialize};

use crate::gain_table::GainGridConfig;
use crate::noise_scale::NoiseScaleConfig;
use crate::params::{non_negative, positive, HALF_BODY_MASS_RATIO};
use crate::DamperError;

use super::bank::Propagation;
use super::jump::JumpSearchConfig;

/// When the Liu-West kernel moves the particles.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum KernelSchedule {
    /// Every step, as in the paper (section 4.3: draw `theta_k(i)` from eq. 24 each step).
    EveryStep,
    /// Only right after a resampling (resample-move): between resamplings the parameters are
    /// fixed and each particle's Kalman filter is that of one static `theta`.
    #[default]
    AtResampling,
}

/// `delta` must exceed this (declared to the settings reference and checked): the shrinkage
/// `a = (3 delta - 1) / (2 delta)` must lie in (0, 1).
const DELTA_ABOVE: f64 = 1.0 / 3.0;
/// Bounds of `particles` (declared to the settings reference and checked): each particle holds
/// a 17-state covariance (~2.5 kB), and 1e9 particles aborted the service on a 136 GB allocation
/// at its first frame.
const PARTICLES: std::ops::RangeInclusive<usize> = 2..=1_000_000;
/// Upper bound of `taylor_truncation` (declared and checked): looser, the series' error
/// reaches the likelihood (at 1e-3 and 45.3 m/s, 0.5 nats over 20 s, `benches/accuracy.rs`).
const TAYLOR_TRUNCATION_MAX: f64 = 1e-3;

/// The Rao-Blackwellised particle filter (section 4).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct RbpfConfig {
    /// `N`.
    #[schemars(range(min = *PARTICLES.start(), max = *PARTICLES.end()))]
    pub particles: usize,
    /// Liu-West discount factor `delta` (eq. 24): `a = (3 delta - 1) / (2 delta)`,
    /// `h^2 = 1 - a^2`.
    #[schemars(extend("exclusiveMinimum" = DELTA_ABOVE, "exclusiveMaximum" = 1.0))]
    pub delta: f64,
    /// Resample when the effective sample size falls below this fraction of `N`.
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = 1.0))]
    pub resample_ess_fraction: f64,
    /// Prior mean: `ln C ~ N(ln(prior_ratio * nominal), prior_ln_std^2)` for each damper.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub prior_ratio: f64,
    /// Prior standard deviation of `ln C` (0: the parameters are known).
    #[schemars(range(min = 0.0))]
    pub prior_ln_std: f64,
    /// Extra random walk of `ln C` (1/sqrt(s)) added to the Liu-West move, so that the filter
    /// can follow a damper that fails after the posterior has narrowed. `0` is the paper's
    /// static-parameter filter.
    #[schemars(range(min = 0.0))]
    pub ln_diffusion_per_sqrt_s: f64,
    /// Probability, per particle and coefficient, of being redrawn (log-uniform over the gain
    /// grid's range) at each kernel move, so that a damper that fails suddenly (a step far
    /// outside the narrowed posterior) is found again. `0` is the paper's filter.
    #[schemars(range(min = 0.0), extend("exclusiveMaximum" = 0.5))]
    pub regeneration_fraction: f64,
    /// Weight of a regenerated particle relative to the others, in (0, 1].
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = 1.0))]
    pub regeneration_weight: f64,
    /// Evidence-triggered search for a failed damper (`crate::rbpf::jump`): sentinels beside
    /// the particles whose posterior odds of a jump, once high enough, become particles.
    pub jump_search: JumpSearchConfig,
    pub propagation: Propagation,
    pub kernel: KernelSchedule,
    /// Truncation of the Taylor series for `Phi(theta) x` (steady-state propagation): the
    /// order is the least at which the first omitted term of the stiffest creep mode,
    /// `(|A_ii| T)^(k+1) / (k+1)!`, is below this (the creep terms grow as `1 / v`: order 5
    /// at 45.3 m/s, 15 at 5 m/s). Each particle's log-likelihood over 20 s is within 0.003
    /// nats of the series to 1e-9 (order 8 and 20) and the likelihood's mode within 0.001 %
    /// of the coefficient (`benches/accuracy.rs`, 6-45 m/s, `C_sy` 0.1-1 x); at 1e-4 0.04
    /// nats, at 1e-3 0.5. Tighter costs time (`benches/rbpf_variants.rs`, `:taylor-1e-9`).
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = TAYLOR_TRUNCATION_MAX))]
    pub taylor_truncation: f64,
    pub gain_grid: GainGridConfig,
    /// The online estimate of the sensors' noise (issue 9 item 2).
    pub noise_scale: NoiseScaleConfig,
    /// The body mass as a third parameter of the particles while the samples carry no measured
    /// load (issue 24 item 1).
    pub unmeasured_mass: UnmeasuredMassConfig,
    /// Seed of the filter's own random numbers (kernel moves, resampling).
    pub seed: u64,
}

impl Default for RbpfConfig {
    fn default() -> Self {
        RbpfConfig {
            particles: 1000,
            delta: 0.99,
            resample_ess_fraction: 0.5,
            prior_ratio: 1.0,
            prior_ln_std: 0.5,
            ln_diffusion_per_sqrt_s: 0.002,
            regeneration_fraction: 0.01,
            regeneration_weight: 0.1,
            jump_search: JumpSearchConfig::default(),
            propagation: Propagation::SteadyState,
            kernel: KernelSchedule::AtResampling,
            taylor_truncation: 1e-5,
            gain_grid: GainGridConfig::default(),
            noise_scale: NoiseScaleConfig::default(),
            unmeasured_mass: UnmeasuredMassConfig::default(),
            seed: 0,
        }
    }
}

impl RbpfConfig {
    pub fn validate(&self) -> Result<(), DamperError> {
        if !PARTICLES.contains(&self.particles) {
            return Err(DamperError::InvalidParameter {
                field: "rbpf.particles",
                value: self.particles as f64,
                reason: "must be in 2..=1000000",
            });
        }
        if !(self.delta > DELTA_ABOVE && self.delta < 1.0) {
            // a = (3 delta - 1) / (2 delta) must lie in (0, 1).
            return Err(DamperError::InvalidParameter {
                field: "rbpf.delta",
                value: self.delta,
                reason: "must be in (1/3, 1)",
            });
        }
        if !(self.resample_ess_fraction > 0.0 && self.resample_ess_fraction <= 1.0) {
            return Err(DamperError::InvalidParameter {
                field: "rbpf.resample_ess_fraction",
                value: self.resample_ess_fraction,
                reason: "must be in (0, 1]",
            });
        }
        positive("rbpf.prior_ratio", self.prior_ratio)?;
        non_negative("rbpf.prior_ln_std", self.prior_ln_std)?;
        if !(0.0..0.5).contains(&self.regeneration_fraction) {
            return Err(DamperError::InvalidParameter {
                field: "rbpf.regeneration_fraction",
                value: self.regeneration_fraction,
                reason: "must be in [0, 0.5)",
            });
        }
        non_negative("rbpf.ln_diffusion_per_sqrt_s", self.ln_diffusion_per_sqrt_s)?;
        if !(self.regeneration_weight > 0.0 && self.regeneration_weight <= 1.0) {
            return Err(DamperError::InvalidParameter {
                field: "rbpf.regeneration_weight",
                value: self.regeneration_weight,
                reason: "must be in (0, 1]",
            });
        }
        if !(self.taylor_truncation > 0.0 && self.taylor_truncation <= TAYLOR_TRUNCATION_MAX) {
            return Err(DamperError::InvalidParameter {
                field: "rbpf.taylor_truncation",
                value: self.taylor_truncation,
                reason: "must be in (0, 1e-3]",
            });
        }
        self.gain_grid.validate()?;
        if self.jump_search.enabled && self.kernel != KernelSchedule::AtResampling {
            return Err(DamperError::Config(
                "rbpf.jump_search needs kernel = \"at_resampling\"".into(),
            ));
        }
        self.jump_search.validate()?;
        self.noise_scale.validate()?;
        self.unmeasured_mass.validate()
    }

    /// Liu-West shrinkage `a` and kernel variance factor `h^2` (eq. 24).
    pub fn liu_west(&self) -> (f64, f64) {
        let a = (3.0 * self.delta - 1.0) / (2.0 * self.delta);
        (a, 1.0 - a * a)
    }
}

/// The body mass above the bogie when a sample carries none (`BogieSample::half_body_mass_kg`
/// = `None`): each particle carries its own `ln m_bd` beside `ln C`, drawn log-uniform over
/// `[min_ratio, max_ratio]` of the design mass when the measurement first goes missing, moved
/// by the same Liu-West kernel (jointly with `ln C`: the data confound a heavier body with a
/// weaker `C_sy`, so the kernel keeps their correlation), and propagated at its own mass with
/// the gains of its nearest mass node. The published dampers then marginalise the mass: where
/// the data tell the mass (the body's sway frequency `sqrt(k / m_bd)`) the bias of assuming the
/// design mass goes; where they do not, the interval widens. A measured mass ends it (every
/// particle at the measured mass). Off: the design mass is assumed, as before.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct UnmeasuredMassConfig {
    /// Whether the particles carry the mass while none is measured (off: the design mass is
    /// assumed).
    pub enabled: bool,
    /// The lightest body the prior holds, as a ratio of the design mass (tare: 0.8-0.9).
    #[schemars(range(min = *HALF_BODY_MASS_RATIO.start(), max = *HALF_BODY_MASS_RATIO.end()))]
    pub min_ratio: f64,
    /// The heaviest, as a ratio of the design mass (crush load: 1.2-1.4).
    #[schemars(range(min = *HALF_BODY_MASS_RATIO.start(), max = *HALF_BODY_MASS_RATIO.end()))]
    pub max_ratio: f64,
}

impl Default for UnmeasuredMassConfig {
    fn default() -> Self {
        UnmeasuredMassConfig {
            enabled: true,
            min_ratio: 0.85,
            max_ratio: 1.4,
        }
    }
}

impl UnmeasuredMassConfig {
    /// The masses the prior spans (kg) for a design mass of `design_half_body_mass_kg`: those
    /// a filter runs at when a sample carries no mass; `None` when disabled (the design
    /// mass).
    pub fn prior_masses_kg(
        &self,
        design_half_body_mass_kg: f64,
    ) -> Option<std::ops::RangeInclusive<f64>> {
        self.enabled.then_some(
            design_half_body_mass_kg * self.min_ratio..=design_half_body_mass_kg * self.max_ratio,
        )
    }

    pub fn validate(&self) -> Result<(), DamperError> {
        for (field, value) in [
            ("rbpf.unmeasured_mass.min_ratio", self.min_ratio),
            ("rbpf.unmeasured_mass.max_ratio", self.max_ratio),
        ] {
            if !HALF_BODY_MASS_RATIO.contains(&value) {
                return Err(DamperError::InvalidParameter {
                    field,
                    value,
                    reason: "must be in 0.7..=1.6 (params::HALF_BODY_MASS_RATIO)",
                });
            }
        }
        if self.max_ratio <= self.min_ratio {
            return Err(DamperError::InvalidParameter {
                field: "rbpf.unmeasured_mass.max_ratio",
                value: self.max_ratio,
                reason: "must exceed min_ratio",
            });
        }
        Ok(())
    }
}
