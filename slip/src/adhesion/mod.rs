//! Adhesion-loss estimators over the N per-drive torque estimates of one time step
//! (paper section 4-5): each gives a global torque `M_z^(G)` and a per-drive probability of
//! adhesion loss.
//!
//! Component 0 of every mixture is "adhesion" (regular operation), component 1 "adhesion
//! lost", as in eq. (21)-(23).

use std::fmt;

use serde::{Deserialize, Serialize};

use crate::error::SlipError;

/// Bounds of the iterative methods' iterations per step (declared to the settings reference and
/// checked): 10,000 iterations of 8 kHz steps is already far slower than real time.
pub(crate) const ITERATIONS: std::ops::RangeInclusive<usize> = 1..=10_000;
/// Bounds of the mixtures' `stop_tolerance` (a relative rise of the bound) and of their
/// `initial_loss_probability` (declared to the settings reference and checked).
pub(crate) const STOP_TOLERANCE: std::ops::RangeInclusive<f64> = 0.0..=1.0;
pub(crate) const INITIAL_LOSS_PROBABILITY: std::ops::RangeInclusive<f64> = 1e-9..=1.0 - 1e-9;

pub mod kmeans;
pub mod median;
pub mod mixture;
pub mod temporal;
pub mod vb;
pub mod vmp;

pub use kmeans::{KMeansConfig, KMeansEstimator};
pub use median::{MedianConfig, MedianEstimator};
pub use temporal::{TemporalConfig, TemporalEstimator};
pub use vb::{VbConfig, VbEstimator};
pub use vmp::{VmpConfig, VmpEstimator};

/// Which estimator turns the N torque estimates into a global torque and slip probabilities.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum AdhesionMethod {
    /// Variational Bayes, eq. (21)-(47).
    Vb,
    /// Variational message passing, section 4.4.
    Vmp,
    /// k-means with two centroids (paper's baseline).
    KMeans,
    /// Median of the drives (paper's baseline).
    Median,
    /// Our temporal method: a majority reference carried over time (kernel mean started from
    /// the last reference), the slip rule above each drive's own resolution, and a two-state
    /// Markov chain per drive over that evidence.
    Temporal,
}

impl AdhesionMethod {
    /// Every method, in the order the reports list them.
    pub const ALL: [AdhesionMethod; 5] = [
        AdhesionMethod::Vb,
        AdhesionMethod::Vmp,
        AdhesionMethod::KMeans,
        AdhesionMethod::Median,
        AdhesionMethod::Temporal,
    ];

    pub fn name(self) -> &'static str {
        match self {
            AdhesionMethod::Vb => "vb",
            AdhesionMethod::Vmp => "vmp",
            AdhesionMethod::KMeans => "kmeans",
            AdhesionMethod::Median => "median",
            AdhesionMethod::Temporal => "temporal",
        }
    }
}

impl fmt::Display for AdhesionMethod {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for AdhesionMethod {
    type Err = SlipError;
    fn from_str(s: &str) -> Result<Self, SlipError> {
        AdhesionMethod::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                SlipError::invalid("method", s, "expected vb, vmp, kmeans, median or temporal")
            })
    }
}

/// Settings of every estimator (each section defaults to the paper's values).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct AdhesionConfig {
    pub vb: VbConfig,
    pub vmp: VmpConfig,
    pub kmeans: KMeansConfig,
    pub median: MedianConfig,
    pub temporal: TemporalConfig,
}

impl AdhesionConfig {
    /// Errors name the key by its place in the settings (`adhesion.vb.iterations`), where a
    /// user finds it.
    pub fn validate(&self) -> Result<(), SlipError> {
        let methods = || {
            self.vb.validate("vb")?;
            self.vmp.validate()?;
            self.kmeans.validate()?;
            self.median.validate()?;
            self.temporal.validate()
        };
        methods().map_err(|e| e.under("adhesion"))
    }
}

/// What an estimator gives for one time step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AdhesionOutput {
    /// The global torque `M_z^(G)`.
    pub global_torque_nm: f64,
    /// Per drive, the probability that adhesion is lost, in [0, 1].
    pub slip_probability: Vec<f64>,
    /// Variational lower bound after the last iteration (VB, VMP, temporal).
    pub lower_bound: Option<f64>,
    /// Iterations run this step (1 for the median).
    pub iterations: usize,
}

impl AdhesionOutput {
    fn new(n_drives: usize) -> Self {
        AdhesionOutput {
            global_torque_nm: 0.0,
            slip_probability: vec![0.0; n_drives],
            lower_bound: None,
            iterations: 0,
        }
    }

    fn check(&self, method: &'static str) -> Result<(), SlipError> {
        if !self.global_torque_nm.is_finite() {
            return Err(SlipError::NonFiniteEstimate {
                method,
                what: "global torque",
            });
        }
        if self
            .slip_probability
            .iter()
            .any(|p| !(0.0..=1.0).contains(p))
        {
            return Err(SlipError::NonFiniteEstimate {
                method,
                what: "slip probability",
            });
        }
        Ok(())
    }
}

/// One estimator of any method (enum dispatch: five fixed methods, no trait objects needed).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub enum AdhesionEstimator {
    Vb(VbEstimator),
    Vmp(VmpEstimator),
    KMeans(KMeansEstimator),
    Median(MedianEstimator),
    Temporal(TemporalEstimator),
}

impl AdhesionEstimator {
    pub fn new(
        method: AdhesionMethod,
        config: &AdhesionConfig,
        n_drives: usize,
    ) -> Result<Self, SlipError> {
        config.validate()?;
        if n_drives == 0 {
            return Err(SlipError::invalid("n_drives", 0, "must be >= 1"));
        }
        Ok(match method {
            AdhesionMethod::Vb => {
                AdhesionEstimator::Vb(VbEstimator::new(config.vb.clone(), n_drives))
            }
            AdhesionMethod::Vmp => {
                AdhesionEstimator::Vmp(VmpEstimator::new(config.vmp.clone(), n_drives))
            }
            AdhesionMethod::KMeans => {
                AdhesionEstimator::KMeans(KMeansEstimator::new(config.kmeans.clone(), n_drives))
            }
            AdhesionMethod::Median => {
                AdhesionEstimator::Median(MedianEstimator::new(config.median.clone(), n_drives))
            }
            AdhesionMethod::Temporal => AdhesionEstimator::Temporal(TemporalEstimator::new(
                config.temporal.clone(),
                n_drives,
            )),
        })
    }

    pub fn method(&self) -> AdhesionMethod {
        match self {
            AdhesionEstimator::Vb(_) => AdhesionMethod::Vb,
            AdhesionEstimator::Vmp(_) => AdhesionMethod::Vmp,
            AdhesionEstimator::KMeans(_) => AdhesionMethod::KMeans,
            AdhesionEstimator::Median(_) => AdhesionMethod::Median,
            AdhesionEstimator::Temporal(_) => AdhesionMethod::Temporal,
        }
    }

    /// One time step over the per-drive torque estimates `torque_nm` (one per drive, all
    /// finite). Bad input is rejected before anything changes.
    pub fn estimate(&mut self, torque_nm: &[f64]) -> Result<&AdhesionOutput, SlipError> {
        let method = self.method();
        let n = self.n_drives();
        check_torques(torque_nm, n)?;
        let out = match self {
            AdhesionEstimator::Vb(e) => e.estimate(torque_nm),
            AdhesionEstimator::Vmp(e) => e.estimate(torque_nm),
            AdhesionEstimator::KMeans(e) => e.estimate(torque_nm),
            AdhesionEstimator::Median(e) => e.estimate(torque_nm),
            AdhesionEstimator::Temporal(e) => e.estimate(torque_nm)?,
        };
        out.check(method.name())?;
        Ok(out)
    }

    pub fn n_drives(&self) -> usize {
        self.output().slip_probability.len()
    }

    /// The EKFs relocked after a gap: the methods with a warm-up run it again (the others
    /// judge each step on its own and have nothing to restart).
    pub fn ekfs_relocked(&mut self) {
        if let AdhesionEstimator::Temporal(e) = self {
            e.restart_warmup();
        }
    }

    /// The output of the last step (zeros before the first).
    pub fn output(&self) -> &AdhesionOutput {
        match self {
            AdhesionEstimator::Vb(e) => e.output(),
            AdhesionEstimator::Vmp(e) => e.output(),
            AdhesionEstimator::KMeans(e) => e.output(),
            AdhesionEstimator::Median(e) => e.output(),
            AdhesionEstimator::Temporal(e) => e.output(),
        }
    }
}

/// The largest torque estimate a method is given, N m: 10^5 times a traction motor's
/// (~10^4 N m), so never a drive's; it keeps every sum, square and mean a method or the
/// fixed lag's window forms finite, so that a method cannot fail on checked input and a
/// failure cannot leave the fixed lag's buffers half-advanced (`fixed_lag::FixedLagLine::push`).
pub const MAX_TORQUE_ESTIMATE_NM: f64 = 1e9;

/// One torque estimate per drive of `n_drives`, every one finite and within
/// +-[`MAX_TORQUE_ESTIMATE_NM`]; else the error naming the drive and value (what every
/// consumer of a step's torque estimates checks first).
pub(crate) fn check_torques(torque_nm: &[f64], n_drives: usize) -> Result<(), SlipError> {
    if torque_nm.len() != n_drives {
        return Err(SlipError::WrongDriveCount {
            expected: n_drives,
            got: torque_nm.len(),
        });
    }
    if let Some((k, t)) = torque_nm.iter().enumerate().find(|(_, t)| !t.is_finite()) {
        return Err(SlipError::NonFiniteSample {
            drive: k + 1,
            field: "torque_nm",
            value: *t,
        });
    }
    if let Some((k, t)) = torque_nm
        .iter()
        .enumerate()
        .find(|(_, t)| t.abs() > MAX_TORQUE_ESTIMATE_NM)
    {
        return Err(SlipError::TorqueBeyondRange {
            drive: k + 1,
            value_nm: *t,
            limit_nm: MAX_TORQUE_ESTIMATE_NM,
        });
    }
    Ok(())
}
