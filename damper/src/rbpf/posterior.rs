//! The RBPF's posterior summaries: mean and 90% interval of each coefficient.

/// Posterior summary of one damper coefficient.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DamperPosterior {
    /// Posterior mean (N s/m).
    pub mean_ns_per_m: f64,
    /// 5% and 95% quantiles (N s/m).
    pub q05_ns_per_m: f64,
    pub q95_ns_per_m: f64,
    /// Mean / nominal.
    pub health_ratio: f64,
}

impl DamperPosterior {
    /// `value_ns_per_m` lies inside the 90 % interval (bounds included).
    pub fn covers(&self, value_ns_per_m: f64) -> bool {
        self.q05_ns_per_m <= value_ns_per_m && value_ns_per_m <= self.q95_ns_per_m
    }
}

/// What the RBPF says after a step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RbpfEstimate {
    pub csy: DamperPosterior,
    pub csay: DamperPosterior,
    pub effective_sample_size: f64,
}

/// Per coefficient: particle indices in increasing order of the coefficient, and the
/// coefficients (N s/m) in that order. Valid until the parameters move.
#[derive(Debug, Clone, Default)]
pub(super) struct SortedParticles {
    pub(super) stale: bool,
    pub(super) order: [Vec<usize>; 2],
    pub(super) values: [Vec<f64>; 2],
}

impl SortedParticles {
    pub(super) fn refresh(&mut self, ln_theta: &[[f64; 2]]) {
        for k in 0..2 {
            let order = &mut self.order[k];
            order.clear();
            order.extend(0..ln_theta.len());
            order.sort_unstable_by(|&i, &j| ln_theta[i][k].total_cmp(&ln_theta[j][k]));
            self.values[k].clear();
            self.values[k].extend(order.iter().map(|&i| ln_theta[i][k].exp()));
        }
        self.stale = false;
    }
}

impl SortedParticles {
    /// Weighted mean, 5% and 95% quantiles of coefficient `k` (weights `w`, normalised), in
    /// one pass over the sorted particles: each quantile is the first value whose cumulative
    /// weight (summed from the smallest) reaches it, the last value when rounding leaves the
    /// total short; the mean is summed in the same order (from `-0.0`, as `Iterator::sum`).
    pub(super) fn posterior(&self, k: usize, w: &[f64], nominal: f64) -> DamperPosterior {
        let (order, values) = (&self.order[k], &self.values[k]);
        let last = values[values.len() - 1];
        let (mut mean, mut cum) = (-0.0, 0.0);
        let (mut q05, mut q95) = (None, None);
        for (&i, &v) in order.iter().zip(values) {
            mean += w[i] * v;
            cum += w[i];
            if q05.is_none() && cum >= 0.05 {
                q05 = Some(v);
            }
            if q95.is_none() && cum >= 0.95 {
                q95 = Some(v);
            }
        }
        let (q05, q95) = (q05.unwrap_or(last), q95.unwrap_or(last));
        DamperPosterior {
            mean_ns_per_m: mean,
            q05_ns_per_m: q05,
            q95_ns_per_m: q95,
            health_ratio: mean / nominal,
        }
    }
}
