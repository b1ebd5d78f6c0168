//! Median filtering (the paper's simplest baseline): the global torque is the median of the
//! drives' torques, and "the others are compared to it". The comparison is the slip rule
//! itself: a drive whose torque is off the median by more than `relative_threshold` of it is
//! flagged (probability 1), otherwise 0.

use serde::{Deserialize, Serialize};

use super::AdhesionOutput;
use crate::error::{check_in, SlipError};
use crate::sample::SLIP_RULE_FRACTION;

/// Bounds of `relative_threshold` (declared to the settings reference and checked).
const RELATIVE_THRESHOLD: std::ops::RangeInclusive<f64> = 0.0..=10.0;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct MedianConfig {
    /// Flag a drive when `|T_i - median| > relative_threshold * |median|`.
    #[schemars(range(min = *RELATIVE_THRESHOLD.start(), max = *RELATIVE_THRESHOLD.end()))]
    pub relative_threshold: f64,
}

impl Default for MedianConfig {
    fn default() -> Self {
        MedianConfig {
            relative_threshold: SLIP_RULE_FRACTION,
        }
    }
}

impl MedianConfig {
    pub fn validate(&self) -> Result<(), SlipError> {
        check_in(
            "median.relative_threshold",
            self.relative_threshold,
            *RELATIVE_THRESHOLD.start(),
            *RELATIVE_THRESHOLD.end(),
            "must be in [0, 10]",
        )
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MedianEstimator {
    config: MedianConfig,
    sorted: Vec<f64>,
    out: AdhesionOutput,
}

impl MedianEstimator {
    pub fn new(config: MedianConfig, n_drives: usize) -> Self {
        MedianEstimator {
            config,
            sorted: Vec::with_capacity(n_drives),
            out: AdhesionOutput::new(n_drives),
        }
    }

    pub fn output(&self) -> &AdhesionOutput {
        &self.out
    }

    pub fn estimate(&mut self, x: &[f64]) -> &AdhesionOutput {
        let med = median_with(&mut self.sorted, x);
        let limit = self.config.relative_threshold * med.abs();
        for (p, &xi) in self.out.slip_probability.iter_mut().zip(x) {
            *p = if (xi - med).abs() > limit { 1.0 } else { 0.0 };
        }
        self.out.global_torque_nm = med;
        self.out.lower_bound = None;
        self.out.iterations = 1;
        &self.out
    }
}

/// The median of `x`, sorting a copy in `scratch` (its allocation is reused).
pub(crate) fn median_with(scratch: &mut Vec<f64>, x: &[f64]) -> f64 {
    scratch.clear();
    scratch.extend_from_slice(x);
    scratch.sort_unstable_by(f64::total_cmp);
    railmon_filter::stats::quantile_sorted(scratch, 0.5)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_on_hand_computed_input() {
        let mut e = MedianEstimator::new(MedianConfig::default(), 3);
        let out = e.estimate(&[0.0, 20.0, 19.5]);
        assert_eq!(out.global_torque_nm, 19.5);
        assert_eq!(out.slip_probability, vec![1.0, 0.0, 0.0]);
        let mut e = MedianEstimator::new(MedianConfig::default(), 4);
        // even count: mean of the middle two, (10 + 11) / 2; 8 is off by 2.5 > 1.05.
        let out = e.estimate(&[11.0, 8.0, 10.0, 11.5]);
        assert_eq!(out.global_torque_nm, 10.5);
        assert_eq!(out.slip_probability, vec![0.0, 1.0, 0.0, 0.0]);
    }

    #[test]
    fn invalid_threshold_rejected() {
        let c = MedianConfig {
            relative_threshold: -0.1,
        };
        assert!(c
            .validate()
            .unwrap_err()
            .to_string()
            .contains("median.relative_threshold"));
    }
}
