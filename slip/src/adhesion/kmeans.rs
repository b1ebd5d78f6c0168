//! k-means with two centroids (the paper's baseline: scipy `kmeans2`, initialised at randomly
//! chosen points, two iterations).
//!
//! The global torque is the centroid of the larger cluster (ties: the higher centroid, since
//! adhesion loss lowers the load). Drives in the other cluster get probability 1: k-means
//! always splits the drives in two, so when none slips it splits healthy ones too, which is
//! the weakness the detection table shows.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::AdhesionOutput;
use crate::error::SlipError;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct KMeansConfig {
    /// Assignment/update iterations per step (the paper: 2).
    #[schemars(range(min = *super::ITERATIONS.start(), max = *super::ITERATIONS.end()))]
    pub iterations: usize,
    /// Seed of the generator that picks the initial points.
    pub seed: u64,
}

impl Default for KMeansConfig {
    fn default() -> Self {
        KMeansConfig {
            iterations: 2,
            seed: 2013,
        }
    }
}

impl KMeansConfig {
    pub fn validate(&self) -> Result<(), SlipError> {
        if !super::ITERATIONS.contains(&self.iterations) {
            return Err(SlipError::invalid(
                "kmeans.iterations",
                self.iterations,
                "must be in 1..=10000",
            ));
        }
        Ok(())
    }
}

/// Two-means of `x` from the initial centroids; returns the centroids and writes each
/// point's cluster (0 or 1) into `labels`. An empty cluster keeps its centroid (as kmeans2).
pub fn two_means(
    x: &[f64],
    mut centroids: [f64; 2],
    iterations: usize,
    labels: &mut [u8],
) -> [f64; 2] {
    for _ in 0..iterations {
        for (l, &xi) in labels.iter_mut().zip(x) {
            *l = u8::from((xi - centroids[1]).abs() < (xi - centroids[0]).abs());
        }
        for (k, c) in centroids.iter_mut().enumerate() {
            let (sum, count) = x
                .iter()
                .zip(labels.iter())
                .filter(|(_, &l)| usize::from(l) == k)
                .fold((0.0, 0usize), |(s, n), (xi, _)| (s + xi, n + 1));
            if count > 0 {
                *c = sum / count as f64;
            }
        }
    }
    // Final assignment to the final centroids.
    for (l, &xi) in labels.iter_mut().zip(x) {
        *l = u8::from((xi - centroids[1]).abs() < (xi - centroids[0]).abs());
    }
    centroids
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct KMeansEstimator {
    config: KMeansConfig,
    rng: ChaCha8Rng,
    labels: Vec<u8>,
    out: AdhesionOutput,
}

impl KMeansEstimator {
    pub fn new(config: KMeansConfig, n_drives: usize) -> Self {
        KMeansEstimator {
            rng: ChaCha8Rng::seed_from_u64(config.seed),
            config,
            labels: vec![0; n_drives],
            out: AdhesionOutput::new(n_drives),
        }
    }

    pub fn output(&self) -> &AdhesionOutput {
        &self.out
    }

    pub fn estimate(&mut self, x: &[f64]) -> &AdhesionOutput {
        let n = x.len();
        // Two distinct random points (one drive: both centroids on it).
        let a = self.rng.random_range(0..n);
        let b = if n > 1 {
            (a + 1 + self.rng.random_range(0..n - 1)) % n
        } else {
            a
        };
        let centroids = two_means(x, [x[a], x[b]], self.config.iterations, &mut self.labels);
        let count1 = self.labels.iter().filter(|&&l| l == 1).count();
        let count0 = n - count1;
        let global_cluster = match count0.cmp(&count1) {
            std::cmp::Ordering::Greater => 0,
            std::cmp::Ordering::Less => 1,
            std::cmp::Ordering::Equal => usize::from(centroids[1] > centroids[0]),
        };
        self.out.global_torque_nm = centroids[global_cluster];
        for (p, &l) in self.out.slip_probability.iter_mut().zip(&self.labels) {
            *p = if usize::from(l) == global_cluster {
                0.0
            } else {
                1.0
            };
        }
        self.out.lower_bound = None;
        self.out.iterations = self.config.iterations;
        &self.out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_means_on_hand_computed_input() {
        // x = [1, 2, 10, 12], start at 1 and 2:
        // it 1: labels [0,1,1,1] -> centroids 1, 8; it 2: labels [0,0,1,1] -> 1.5, 11.
        let x = [1.0, 2.0, 10.0, 12.0];
        let mut labels = [0u8; 4];
        let c = two_means(&x, [1.0, 2.0], 1, &mut labels);
        assert_eq!(c, [1.0, 8.0]);
        let c = two_means(&x, [1.0, 2.0], 2, &mut labels);
        assert_eq!(c, [1.5, 11.0]);
        assert_eq!(labels, [0, 0, 1, 1]);
    }

    #[test]
    fn global_is_the_majority_cluster_and_outlier_flagged() {
        let mut e = KMeansEstimator::new(KMeansConfig::default(), 3);
        for _ in 0..20 {
            // Whatever the random start, two iterations separate 0 from {20, 20.2}.
            let out = e.estimate(&[0.0, 20.0, 20.2]);
            assert!(
                (out.global_torque_nm - 20.1).abs() < 1e-12,
                "{}",
                out.global_torque_nm
            );
            assert_eq!(out.slip_probability, vec![1.0, 0.0, 0.0]);
        }
    }

    #[test]
    fn invalid_iterations_rejected() {
        let c = KMeansConfig {
            iterations: 0,
            ..KMeansConfig::default()
        };
        assert!(c
            .validate()
            .unwrap_err()
            .to_string()
            .contains("kmeans.iterations"));
    }
}
