//! The filter's own check of its model: the normalised innovation squared `e' S^-1 e`, which
//! is chi-square with 5 degrees of freedom (mean 5) when the filter's model (vehicle, speed,
//! sensor noise, track input) is the plant's, averaged over windows; a window mean outside its
//! band for a sustained time is `model_mismatch`, so that a wrong configuration shows as a
//! warning instead of as a damper fault ([`crate::DamperAlarm`] does not judge meanwhile).

use serde::{Deserialize, Serialize};

use crate::model::N_OUTPUTS;
use crate::params::positive;
use crate::DamperError;

/// The band and the times of the check.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct ConsistencyConfig {
    /// The normalised innovation squared is averaged over windows this long (s).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub window_s: f64,
    /// Lower end of the band of a window mean, as a ratio of its expectation (5, the number of
    /// sensors).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub nis_low_ratio: f64,
    /// Upper end of that band, as a ratio of the expectation.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub nis_high_ratio: f64,
    /// Window means outside the band for this long in a row raise `model_mismatch`; inside
    /// for this long clear it (s).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub sustain_s: f64,
}

impl Default for ConsistencyConfig {
    fn default() -> Self {
        ConsistencyConfig {
            window_s: 1.0,
            nis_low_ratio: 0.2,
            nis_high_ratio: 3.0,
            sustain_s: 5.0,
        }
    }
}

impl ConsistencyConfig {
    pub fn validate(&self) -> Result<(), DamperError> {
        positive("consistency.window_s", self.window_s)?;
        positive("consistency.nis_low_ratio", self.nis_low_ratio)?;
        positive("consistency.sustain_s", self.sustain_s)?;
        if !(self.nis_high_ratio > self.nis_low_ratio && self.nis_high_ratio.is_finite()) {
            return Err(DamperError::InvalidParameter {
                field: "consistency.nis_high_ratio",
                value: self.nis_high_ratio,
                reason: "must be finite and above nis_low_ratio",
            });
        }
        Ok(())
    }
}

/// The running check of one bogie's filter.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ConsistencyCheck {
    config: ConsistencyConfig,
    window_steps: u64,
    sum: f64,
    count: u64,
    last_mean: Option<f64>,
    outside_s: f64,
    inside_s: f64,
    mismatch: bool,
}

impl ConsistencyCheck {
    pub fn new(config: &ConsistencyConfig, dt_s: f64) -> Self {
        ConsistencyCheck {
            config: *config,
            window_steps: ((config.window_s / dt_s).round() as u64).max(1),
            sum: 0.0,
            count: 0,
            last_mean: None,
            outside_s: 0.0,
            inside_s: 0.0,
            mismatch: false,
        }
    }

    /// One step's normalised innovation squared (a non-finite one is not counted).
    pub fn update(&mut self, nis: f64) {
        if !nis.is_finite() {
            return;
        }
        self.sum += nis;
        self.count += 1;
        if self.count < self.window_steps {
            return;
        }
        let mean = self.sum / self.count as f64;
        self.sum = 0.0;
        self.count = 0;
        self.last_mean = Some(mean);
        let ratio = mean / N_OUTPUTS as f64;
        let w = self.config.window_s;
        if ratio < self.config.nis_low_ratio || ratio > self.config.nis_high_ratio {
            self.outside_s += w;
            self.inside_s = 0.0;
        } else {
            self.inside_s += w;
            self.outside_s = 0.0;
        }
        // Half a window of slack against the floating-point sum of window lengths.
        let sustained = |t: f64| t + 0.5 * w >= self.config.sustain_s;
        if !self.mismatch && sustained(self.outside_s) {
            self.mismatch = true;
        } else if self.mismatch && sustained(self.inside_s) {
            self.mismatch = false;
        }
    }

    /// The filter's model does not explain the data (sustained).
    pub fn mismatch(&self) -> bool {
        self.mismatch
    }

    /// The mean of the last complete window (`None` before the first).
    pub fn window_mean(&self) -> Option<f64> {
        self.last_mean
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{ChiSquared, Distribution};

    /// Chi-square(5) innovations (a filter whose model is the plant's) never raise it; the
    /// same scaled by 4 (four times the variance the filter expects, beyond the band of 3) raise it after the
    /// sustain time, and it clears after as long back in the band.
    #[test]
    fn a_sustained_excess_raises_model_mismatch_and_a_consistent_filter_never_does() {
        let config = ConsistencyConfig::default();
        let mut check = ConsistencyCheck::new(&config, 1e-3);
        let chi2 = ChiSquared::new(5.0).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for _ in 0..600_000 {
            check.update(chi2.sample(&mut rng));
            assert!(!check.mismatch());
        }
        let mean = check.window_mean().unwrap();
        assert!((mean - 5.0).abs() < 0.5, "{mean}");
        let steps_to_raise = (0..20_000)
            .position(|_| {
                check.update(4.0 * chi2.sample(&mut rng));
                check.mismatch()
            })
            .unwrap();
        // 5 windows of 1 s.
        assert_eq!(steps_to_raise + 1, 5_000);
        let steps_to_clear = (0..20_000)
            .position(|_| {
                check.update(chi2.sample(&mut rng));
                !check.mismatch()
            })
            .unwrap();
        assert_eq!(steps_to_clear + 1, 5_000);
    }
}
