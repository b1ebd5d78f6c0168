//! What VB (section 4.2) and VMP (section 4.4) share: the responsibilities `E[I_i]`
//! (eq. 31-35), the weighted moments of each component (eq. 43-44, with the erratum that
//! component 0 is weighted by `1 - E[I_i]` and component 1 by `E[I_i]`), and the data part of
//! the lower bound.

use crate::special::{bernoulli_neg_entropy, LN_2PI};

/// The expectations of one component that the indicator update needs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExpectedComponent {
    /// `E[mu]`.
    pub mean: f64,
    /// `E[Lambda]`.
    pub precision: f64,
    /// `E[ln Lambda]`.
    pub ln_precision: f64,
    /// `E[Lambda (x - mu)^2] - E[Lambda] (x - E[mu])^2`: the part due to the uncertainty of
    /// `mu` (VB: `1 / beta`, eq. 47; VMP: `E[Lambda] Var[mu]`, the erratum to step (v)).
    pub spread: f64,
}

impl ExpectedComponent {
    /// `E[ln N(x | mu, 1/Lambda)]`.
    pub fn expected_log_density(&self, x: f64) -> f64 {
        let d = x - self.mean;
        0.5 * (self.ln_precision - LN_2PI - self.precision * d * d - self.spread)
    }
}

/// `(E[ln(1 - pi)], E[ln pi])`: the log prior of "adhesion" and "adhesion lost".
pub type LogMixingWeights = (f64, f64);

/// Sets `r[i] = E[I_i]` (eq. 35) from eq. (32)-(33), in log space.
pub fn update_responsibilities(
    x: &[f64],
    components: &[ExpectedComponent; 2],
    log_weights: LogMixingWeights,
    r: &mut [f64],
) {
    for (ri, &xi) in r.iter_mut().zip(x) {
        let ln_rho0 = log_weights.0 + components[0].expected_log_density(xi);
        let ln_rho1 = log_weights.1 + components[1].expected_log_density(xi);
        // rho1 / (rho0 + rho1) = logistic(ln_rho1 - ln_rho0), stable for any magnitude.
        *ri = logistic(ln_rho1 - ln_rho0);
    }
}

/// `1 / (1 + exp(-z))` without overflow.
pub fn logistic(z: f64) -> f64 {
    if z >= 0.0 {
        1.0 / (1.0 + (-z).exp())
    } else {
        let e = z.exp();
        e / (1.0 + e)
    }
}

/// `E[ln p(X | I, mu, Lambda)] + E[ln p(I | pi)] - E[ln q(I)]`: the data and indicator part of
/// the lower bound (the parameter part is `-KL(q || prior)`, added by each method).
pub fn data_bound(
    x: &[f64],
    r: &[f64],
    components: &[ExpectedComponent; 2],
    log_weights: LogMixingWeights,
) -> f64 {
    x.iter()
        .zip(r)
        .map(|(&xi, &ri)| {
            (1.0 - ri) * (log_weights.0 + components[0].expected_log_density(xi))
                + ri * (log_weights.1 + components[1].expected_log_density(xi))
                - bernoulli_neg_entropy(ri)
        })
        .sum()
}

/// The lower bound across the iterations of one VB or VMP run: when it must be computed,
/// the trace, and the stopping rule.
///
/// The bound costs more than an iteration (digamma and log-gamma of every factor), so it is
/// computed every iteration only when it decides when to stop or a trace is asked for;
/// otherwise once, after the last iteration, for the report.
pub struct BoundWatch<'a> {
    stop_tolerance: Option<f64>,
    trace: Option<&'a mut Vec<f64>>,
    max_iterations: usize,
    /// Last bound computed (`-inf` before the first).
    pub bound: f64,
}

impl<'a> BoundWatch<'a> {
    pub fn new(
        max_iterations: usize,
        stop_tolerance: Option<f64>,
        trace: Option<&'a mut Vec<f64>>,
    ) -> Self {
        BoundWatch {
            stop_tolerance,
            trace,
            max_iterations,
            bound: f64::NEG_INFINITY,
        }
    }

    /// Whether iteration `it` (1-based) needs the bound.
    pub fn needed(&self, it: usize) -> bool {
        self.stop_tolerance.is_some() || self.trace.is_some() || it >= self.max_iterations
    }

    /// Records the bound of an iteration; true when the run should stop (the bound rose by
    /// less than `stop_tolerance * |bound|`).
    pub fn record(&mut self, bound: f64) -> bool {
        if let Some(t) = self.trace.as_deref_mut() {
            t.push(bound);
        }
        let gain = bound - self.bound;
        self.bound = bound;
        self.stop_tolerance
            .is_some_and(|tol| gain.abs() <= tol * bound.abs().max(1.0))
    }
}

/// Weighted zeroth, first and second raw moments of one component.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct WeightedMoments {
    /// `N_k`, the effective number of drives in the component.
    pub count: f64,
    /// `N_k xbar_k`.
    pub sum: f64,
    /// `sum_i w_i x_i^2`.
    pub sum_sq: f64,
}

impl WeightedMoments {
    /// Moments of component `k` (0: weights `1 - r_i`, 1: weights `r_i`; eq. 43-44 erratum).
    pub fn of_component(x: &[f64], r: &[f64], k: usize) -> Self {
        let mut m = WeightedMoments::default();
        for (&xi, &ri) in x.iter().zip(r) {
            let w = if k == 0 { 1.0 - ri } else { ri };
            m.count += w;
            m.sum += w * xi;
            m.sum_sq += w * xi * xi;
        }
        m
    }

    /// `sum_i w_i (x_i - c)^2`.
    pub fn scatter_about(&self, c: f64) -> f64 {
        (self.sum_sq - 2.0 * c * self.sum + c * c * self.count).max(0.0)
    }
}

/// Initial component means as in section 5: "adhesion" at the largest torque of the step,
/// "adhesion lost" at `loss_mean_nm` (0: the wheel no longer carries load).
///
/// The paper takes the maximum over all drives *and all times*, which needs the whole record;
/// an online monitor only has the current step, so we take the maximum over the drives now.
pub fn initial_means(x: &[f64], loss_mean_nm: f64) -> [f64; 2] {
    let max = x.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    [max, loss_mean_nm]
}

/// Test support shared by the VB and VMP tests.
#[cfg(test)]
pub(crate) mod test_support {
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// Runs `fit` (which pushes the bound of every iteration to the vector it is given) on 50
    /// seeded two-cluster data sets of 3-12 drives with growing spread, and asserts that the
    /// bound never decreases (to rounding).
    pub fn assert_bound_never_decreases(seed: u64, mut fit: impl FnMut(&[f64], &mut Vec<f64>)) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        for case in 0..50 {
            let n = 3 + case % 10;
            let noise = Normal::new(0.0, 0.2 + case as f64 * 0.1).unwrap();
            let x: Vec<f64> = (0..n)
                .map(|i| if i % 3 == 0 { 0.5 } else { 25.0 } + noise.sample(&mut rng))
                .collect();
            let mut trace = Vec::new();
            fit(&x, &mut trace);
            assert!(trace.len() > 1, "case {case}");
            for w in trace.windows(2) {
                let tol = 1e-9 * w[0].abs().max(1.0);
                assert!(w[1] >= w[0] - tol, "case {case}: {} -> {}", w[0], w[1]);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moments_follow_the_erratum_weights() {
        let x = [1.0, 2.0, 10.0];
        let r = [0.0, 0.25, 1.0];
        let m0 = WeightedMoments::of_component(&x, &r, 0);
        let m1 = WeightedMoments::of_component(&x, &r, 1);
        assert_eq!(m0.count, 1.75);
        assert_eq!(m0.sum, 1.0 + 0.75 * 2.0);
        assert_eq!(m1.count, 1.25);
        assert_eq!(m1.sum, 0.5 + 10.0);
        // scatter about the mean equals N S (eq. 44)
        let mean = m1.sum / m1.count;
        let direct = 0.25 * (2.0 - mean).powi(2) + (10.0 - mean).powi(2);
        assert!((m1.scatter_about(mean) - direct).abs() < 1e-12);
    }

    #[test]
    fn logistic_is_stable() {
        assert_eq!(logistic(1000.0), 1.0);
        assert_eq!(logistic(-1000.0), 0.0);
        assert!((logistic(0.0) - 0.5).abs() < 1e-15);
    }
}
