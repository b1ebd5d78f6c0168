//! A wear rate per particle: how the filter's particles follow a damper losing oil (issue 24
//! item 3).
//!
//! The drift read off the posterior mean (`super::wear_evolution`) moves every particle by
//! the mean's past velocity, so the cloud follows a ramp late: on the sampler's held-out
//! ramps a median lag of 13.8 s, the 90 % interval covering the truth a median 49.6 % of the
//! ramp (docs/notes/damper-log.md, 29 Nov). Here each particle carries its own
//! `r = d ln C / dt` per damper beside `ln C` as well (a local linear trend per particle:
//! Harvey 1989, section 2.3.2, `mu_t = mu_{t-1} + beta_{t-1}`; Liu & West 2001, section 3.3,
//! artificial evolution), and its level moves by it between kernel moves: a ramp's slope is a
//! hypothesis the weights test, and the particles whose rate matches the ramp keep up with it
//! and earn the weight. At each kernel move the rates get
//!
//! 1. **Liu-West** (eq. 24, per damper: shrink to the cloud's mean rate by `a`, jitter by `h^2`
//!    of its variance), so that resampling's copies spread again;
//! 2. **a reversion to 0** (Ornstein-Uhlenbeck, `dr = -r / T_r dt + sqrt(q_r) dW`, memory
//!    [`RATE_MEMORY_S`]): a rate is a belief the data must keep confirming, so a healthy damper
//!    cannot run away on a rate learned from a transient;
//! 3. **a walk** [`RATE_WALK_PER_S`] that keeps rates in the cloud for the data to pick;
//! 4. **a bound**, the fastest wear [`super::MAX_WEAR_PER_S`] over the health ratio (linear oil
//!    loss falls faster in `ln C` as `C` falls): anything faster is a failure, for the jump
//!    search.
//!
//! A rate's stationary spread is `sqrt(q_r T_r / 2)` = 0.0030 / s: a healthy mean wanders by
//! about that times the filter's memory (seconds), the price paid for following a ramp. The
//! levels advance by their rates once every [`LEVEL_ADVANCE_STEPS`], not every step: each
//! advance moves every particle, and the sorted order the Kalman bank's gain-table lookups
//! rely on must then be rebuilt (every step: 2.8x the wall time).
//!
//! Why the mean's drift stays beside the rates: without it, after one damper's step at low
//! speed the other's jump hypotheses explained the misfit while the failed damper's level
//! was still settling (sampler draws 5006, 5150, 5109: a false `damper_degraded` on the
//! healthy damper); the drift and its widening move the failed damper's particles to the truth
//! first. Measured and not kept (docs/notes/damper-log.md, 29 Nov): the rates alone (a walk
//! of 1e-7 lost the ramps; 1e-6 cost 10-15 points of "both means within 5 %" on healthy
//! dampers), the walk sized by the data's information (tag
//! `rejected-damper-wear-rate-informed-2026-11-29`: a false alarm on a tuning draw), a rate
//! that is either 0 or wearing (spike and slab: false alarms, ramps less covered).

use rand::Rng;
use rand_distr::StandardNormal;

/// The memory of a wear rate without fresh evidence (s): the shortest ramp the issue asks to
/// follow (one minute). A rate held longer must be confirmed by the data.
pub const RATE_MEMORY_S: f64 = 60.0;

/// The rate's walk, `q_r` ((ln C / s)^2 per s). Chosen on the sampler's tuning draws (ramps,
/// the healthy robustness cells, 100 mixed draws), between the values that lost the ramps
/// (1e-7) and the healthy accuracy (1e-6).
pub const RATE_WALK_PER_S: f64 = 3e-7;

/// Steps between the levels' advances by their rates (0.1 s at 1 kHz): short beside the
/// filter's memory (seconds), long enough that the particles' re-sort is rare.
pub const LEVEL_ADVANCE_STEPS: u64 = 100;

/// One kernel move's rule for the rates: the cloud's weighted rate moments and the interval's
/// reversion, walk and bound.
pub struct RateMove {
    mean: [f64; 2],
    jitter: [f64; 2],
    reversion: f64,
    walk: f64,
    fastest: [f64; 2],
}

impl RateMove {
    /// For the cloud's `rates` with normalised log-weights `log_w`, whose dampers' health
    /// ratios are `health_ratio` now, `since_s` after the last move, with Liu-West's `h`.
    pub fn new(
        rates: &[[f64; 2]],
        log_w: &[f64],
        health_ratio: [f64; 2],
        since_s: f64,
        h: f64,
    ) -> RateMove {
        let (mut mean, mut var) = ([0.0; 2], [0.0; 2]);
        for (r, lw) in rates.iter().zip(log_w) {
            let w = lw.exp();
            for k in 0..2 {
                mean[k] += w * r[k];
            }
        }
        for (r, lw) in rates.iter().zip(log_w) {
            let w = lw.exp();
            for k in 0..2 {
                var[k] += w * (r[k] - mean[k]).powi(2);
            }
        }
        RateMove {
            mean,
            jitter: var.map(|v| h * v.sqrt()),
            reversion: (-since_s / RATE_MEMORY_S).exp(),
            walk: (RATE_WALK_PER_S * since_s).sqrt(),
            fastest: health_ratio.map(|c| super::MAX_WEAR_PER_S / c.max(f64::MIN_POSITIVE)),
        }
    }

    /// A particle's rates `r` after the move, with Liu-West's `a`.
    pub fn moved<R: Rng>(&self, r: [f64; 2], a: f64, rng: &mut R) -> [f64; 2] {
        let mut next = [0.0; 2];
        for k in 0..2 {
            let z: f64 = rng.sample(StandardNormal);
            let shrunk = a * r[k] + (1.0 - a) * self.mean[k] + self.jitter[k] * z;
            let z: f64 = rng.sample(StandardNormal);
            next[k] =
                (self.reversion * shrunk + self.walk * z).clamp(-self.fastest[k], self.fastest[k]);
        }
        next
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    /// Without weights' evidence (every particle alike, kernel moves every 0.5 s), the rates'
    /// spread settles at the OU's stationary `sqrt(q_r T_r / 2)`, not growing: a healthy damper's
    /// rate stays bounded however long it runs.
    #[test]
    fn rates_settle_at_the_stationary_spread() {
        let n = 2000;
        let (a, h) = (0.98_f64, (1.0 - 0.98_f64 * 0.98).sqrt());
        let mut rates = vec![[0.0; 2]; n];
        let log_w = vec![-(n as f64).ln(); n];
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for _ in 0..600 {
            let rule = RateMove::new(&rates, &log_w, [1.0; 2], 0.5, h);
            rates = rates.iter().map(|r| rule.moved(*r, a, &mut rng)).collect();
        }
        let var = rates.iter().map(|r| r[0] * r[0]).sum::<f64>() / n as f64;
        let stationary = RATE_WALK_PER_S * RATE_MEMORY_S / 2.0;
        assert!(
            (var / stationary - 1.0).abs() < 0.1,
            "spread {} against {}",
            var.sqrt(),
            stationary.sqrt()
        );
    }

    /// The bound holds: no rate is faster than the fastest wear at the damper's health.
    #[test]
    fn rates_are_bounded_by_the_fastest_wear() {
        let rates = vec![[0.05, -0.05]; 10];
        let log_w = vec![-(10f64).ln(); 10];
        let rule = RateMove::new(&rates, &log_w, [0.5, 1.0], 1.0, 0.2);
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for r in &rates {
            let m = rule.moved(*r, 0.98, &mut rng);
            assert!(m[0] <= super::super::MAX_WEAR_PER_S / 0.5 + 1e-15);
            assert!(m[1] >= -super::super::MAX_WEAR_PER_S - 1e-15);
        }
    }
}
