//! The paper's data vector from vehicle samples: each sample reduced to its channels and
//! levels ([`Prepared`]), standardised ([`Standardiser`]), and the past it is conditioned on
//! ([`Past`]) laid out ([`Layout`]) as the regressor `psi_t = [y_{t-1}, .., y_{t-m_y},
//! z_{t-1}, 1]`, the categorical condition `[z_{t-1}, s_{t-1}]` and the switching condition
//! `[f_{t-1}, ..]` (section 4.2). The monitor's step and its forecast build them alike.

use std::collections::VecDeque;

use nalgebra::DVector;
use serde::{Deserialize, Serialize};

use crate::config::FuelMonitorConfig;
use crate::kinematic::KinematicState;
use crate::mixture::MixtureSpec;
use crate::predictive::StudentT;

/// A sample reduced to what the mixture uses, checked.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub(crate) struct Prepared {
    pub(crate) time_s: f64,
    /// Continuous channels in the monitor's order (fuel first), raw units.
    pub(crate) y: Vec<f64>,
    pub(crate) category: Option<usize>,
    /// Speed below the standstill threshold (only with `pointer_standing`; false otherwise).
    #[serde(default)]
    pub(crate) standing: bool,
    /// `ln P` of each physical regime, component order (only with `pointer_regimes`).
    #[serde(default)]
    pub(crate) given: Option<Vec<f64>>,
    /// `ln P` of each component's regime as the rule is sure of it (the speed filter's
    /// spread of the acceleration), for the published probabilities only (not kept: the
    /// mixture learns from `given`).
    #[serde(skip)]
    pub(crate) reported_given: Option<Vec<f64>>,
    pub(crate) speed_level: usize,
    pub(crate) fuel_level: usize,
    /// Discretised `v_t - v_{t-1}` (0 when acceleration bins are off or on the first sample).
    pub(crate) acceleration_level: usize,
    pub(crate) speed_m_s: Option<f64>,
    /// The kinematic filter's state after this sample (`speed_noise_m_s` > 0 only).
    pub(crate) kinematic: Option<KinematicState>,
}

/// Mean and spread of each channel from the initial samples. The continuous channels are
/// standardised with them so that one prior and one variance floor fit fuel in cm^3/s and
/// engine speed in rpm alike; the proximities only shift by a constant common to all
/// components, so the pointer is unaffected.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub(crate) struct Standardiser {
    pub(crate) mean: Vec<f64>,
    pub(crate) scale: Vec<f64>,
}

impl Standardiser {
    /// `min_scales[c]`: the floor of channel `c`'s spread.
    pub(crate) fn from_samples(min_scales: &[f64], samples: &[Prepared]) -> Self {
        let n = samples.len() as f64;
        let mut mean = vec![0.0; min_scales.len()];
        let mut scale = vec![0.0; min_scales.len()];
        for (c, floor) in min_scales.iter().enumerate() {
            let m = samples.iter().map(|s| s.y[c]).sum::<f64>() / n;
            let var = samples.iter().map(|s| (s.y[c] - m).powi(2)).sum::<f64>() / n;
            mean[c] = m;
            scale[c] = var.sqrt().max(*floor);
        }
        Standardiser { mean, scale }
    }

    pub(crate) fn apply(&self, y: &[f64]) -> DVector<f64> {
        DVector::from_iterator(
            y.len(),
            y.iter()
                .enumerate()
                .map(|(c, v)| (v - self.mean[c]) / self.scale[c]),
        )
    }

    pub(crate) fn fuel(&self, standardised: f64) -> f64 {
        self.mean[0] + self.scale[0] * standardised
    }

    /// A Student-t term of fuel from its standardised location and variance.
    pub(crate) fn fuel_term(
        &self,
        weight: f64,
        location: f64,
        variance: f64,
        dof: f64,
    ) -> StudentT {
        StudentT {
            weight,
            location: self.fuel(location),
            scale: self.scale[0] * variance.max(0.0).sqrt(),
            dof,
        }
    }
}

/// What the regressors need from the past: newest first.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub(crate) struct Past {
    pub(crate) y: VecDeque<DVector<f64>>,
    pub(crate) category: Option<usize>,
    pub(crate) speed_level: usize,
    pub(crate) fuel_levels: VecDeque<usize>,
    pub(crate) acceleration_level: usize,
}

impl Past {
    /// `y` (standardised) and the levels of `p` as the newest past, `m_y` values of `y` and
    /// `m_alpha` fuel levels kept.
    pub(crate) fn push(&mut self, y: DVector<f64>, p: &Prepared, m_y: usize, m_alpha: usize) {
        self.y.push_front(y);
        self.y.truncate(m_y);
        self.category = p.category;
        self.speed_level = p.speed_level;
        self.fuel_levels.push_front(p.fuel_level);
        self.fuel_levels.truncate(m_alpha);
        self.acceleration_level = p.acceleration_level;
    }
}

/// How the monitor lays out the data vectors: its settings, the mixture's sizes and the
/// channels whose past enters `psi`, borrowed from the monitor for each use.
#[derive(Clone, Copy)]
pub(crate) struct Layout<'a> {
    pub(crate) config: &'a FuelMonitorConfig,
    pub(crate) spec: &'a MixtureSpec,
    /// Indices (into the measured channels) of the channels whose past enters `psi`.
    pub(crate) lagged: &'a [usize],
}

impl Layout<'_> {
    /// `psi_t = [y_{t-1}, .., y_{t-m_y}, z_{t-1}, 1]`, `y` its lagged channels only.
    pub(crate) fn regressor(&self, past: &Past) -> DVector<f64> {
        let mut psi = Vec::with_capacity(self.spec.k_psi);
        for y in past.y.iter().take(self.config.regression_memory) {
            psi.extend(self.lagged.iter().map(|&i| y[i]));
        }
        let notches = self.config.notch_categories();
        if notches > 0 {
            // The paper puts the gear itself in psi (section 4.2); centred, so that it does
            // not compete with the constant.
            let l = past.category.unwrap_or(0) as f64;
            psi.push(l - 0.5 * (notches - 1) as f64);
        }
        psi.push(1.0);
        DVector::from_vec(psi)
    }

    /// The categorical cell `(q, l)` of the sample `now`: `q` the previous notch and speed
    /// level, `l` the notch now.
    pub(crate) fn category_cell(&self, past: &Past, now: &Prepared) -> Option<(usize, usize)> {
        now.category.map(|l| {
            (
                past.category.unwrap_or(0) * self.config.speed_levels() + past.speed_level,
                l,
            )
        })
    }

    /// The switching condition `[f_{t-1}, .., f_{t-m_alpha}]` with the acceleration level.
    pub(crate) fn switching_row(&self, past: &Past) -> usize {
        self.switching_row_of(past.fuel_levels.iter().copied(), past.acceleration_level)
    }

    /// Row of the switching table for fuel levels (newest first) and an acceleration level:
    /// the newest level is the least significant digit (base: the number of levels).
    pub(crate) fn switching_row_of(
        &self,
        levels_newest_first: impl Iterator<Item = usize>,
        acceleration_level: usize,
    ) -> usize {
        let n_f = self.config.fuel_levels();
        let (k_f, _) =
            levels_newest_first.fold((0, 1), |(k, digit), f| (k + f * digit, digit * n_f));
        k_f * self.config.acceleration_levels() + acceleration_level
    }
}
