//! The RBPF's posterior summaries: mean and 90% interval of each coefficient.

/// Posterior summary of one damper coefficient.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DamperPosterior {
    /// Posterior mean (N s/m).
    pub mean_ns_per_m: f64,
    /// 5% and 95% quantiles (N s/m).
    pub q05_ns_per_m: f64,
    pub q95_ns_per_m: f64,
    /// Mean / nominal.
    pub health_ratio: f64,
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
    /// Weighted mean, 5% and 95% quantiles of coefficient `k` (weights `w`, normalised).
    pub(super) fn posterior(&self, k: usize, w: &[f64], nominal: f64) -> DamperPosterior {
        let (order, values) = (&self.order[k], &self.values[k]);
        let mean: f64 = order.iter().zip(values).map(|(&i, v)| w[i] * v).sum();
        let quantile = |q: f64| {
            let mut cum = 0.0;
            for (&i, v) in order.iter().zip(values) {
                cum += w[i];
                if cum >= q {
                    return *v;
                }
            }
            values[values.len() - 1]
        };
        DamperPosterior {
            mean_ns_per_m: mean,
            q05_ns_per_m: quantile(0.05),
            q95_ns_per_m: quantile(0.95),
            health_ratio: mean / nominal,
        }
    }
}
