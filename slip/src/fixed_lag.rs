//! Fixed-lag publication of the slip probability (issue 23 item 1, eighth round): the
//! probability of step `t` is published at `t + FIXED_LAG_STEPS`, and the look-ahead buys two
//! things a causal monitor cannot have:
//! 1. the adhesion method judges a *centred* mean of the torque estimates over
//!    `2 CENTRED_HALF_WINDOW_STEPS + 1` steps: the EKF's noise averaged as by a causal filter
//!    of the same variance, without its delay of every edge (fixed-interval smoothing's
//!    point, e.g. Simon, "Optimal State Estimation", 2006, section 9.2);
//! 2. an episode's edges are moved back by the lag they carry: its onset by
//!    `ONSET_BACKDATE_STEPS`, its release by `RELEASE_BACKDATE_STEPS` (the EKF's estimate
//!    follows a load step some 20 steps late; what is left after the centred mean is measured
//!    in `sample_matrix --lag-study`).
//!
//! Pure maths, no allocation per step. A fleet dashboard or a maintenance event cannot tell
//! 7.9 ms; a traction controller's anti-slip loop would need the causal probability.

use crate::adhesion::{check_torques, AdhesionEstimator};
use crate::error::SlipError;

/// Half-width of the centred mean of the torque estimates (95 steps in all, 11.9 ms at 8 kHz).
/// Tuning draws (`sample_matrix --draws 100 --split tuning --lag-study`), F1 >= 0.95 of 419:
/// 31 steps 337, 47 349, 63 338, 127 296; draws with a healthy drive over 0.1 % 6, 0, 0, 0.
pub const CENTRED_HALF_WINDOW_STEPS: usize = 47;
/// Steps an episode's onset is moved back (tuning: 0 349, 8 357, 16 with the release's 8 365).
pub const ONSET_BACKDATE_STEPS: usize = 16;
/// Steps an episode's release is moved back.
pub const RELEASE_BACKDATE_STEPS: usize = 8;
/// Steps from a step's torque estimate to its published probability (63 steps, 7.9 ms).
pub const FIXED_LAG_STEPS: usize = CENTRED_HALF_WINDOW_STEPS + EDGE_LAG_STEPS;
const EDGE_LAG_STEPS: usize = if ONSET_BACKDATE_STEPS > RELEASE_BACKDATE_STEPS {
    ONSET_BACKDATE_STEPS
} else {
    RELEASE_BACKDATE_STEPS
};
/// The probability an episode is made of (the scores' "p > 0.5").
const EPISODE_PROBABILITY: f64 = 0.5;

/// The centred mean over `2 half + 1` steps of a vector per step: after the push of step
/// `t`, the mean of steps `t - 2 half ..= t`, which is the centred mean of step `t - half`.
#[derive(Debug, Clone)]
pub struct CentredMean {
    half: usize,
    /// Ring of the last `2 half + 1` vectors, row-major.
    ring: Vec<f64>,
    sum: Vec<f64>,
    mean: Vec<f64>,
    seen: usize,
}

impl CentredMean {
    pub fn new(half: usize, n: usize) -> Self {
        CentredMean {
            half,
            ring: vec![0.0; (2 * half + 1) * n],
            sum: vec![0.0; n],
            mean: vec![0.0; n],
            seen: 0,
        }
    }

    /// Pushes step `t`; the centred mean of step `t - half` once `2 half + 1` steps are in.
    /// The running sum is corrected exactly: each value enters and leaves it once.
    pub fn push(&mut self, x: &[f64]) -> Option<&[f64]> {
        let n = self.sum.len();
        let w = 2 * self.half + 1;
        let row = &mut self.ring[(self.seen % w) * n..][..n];
        for ((s, r), &v) in self.sum.iter_mut().zip(row.iter_mut()).zip(x) {
            *s += v - *r;
            *r = v;
        }
        self.seen += 1;
        if self.seen < w {
            return None;
        }
        // Re-summed from the ring once per window so that rounding cannot drift.
        if self.seen.is_multiple_of(w) {
            self.sum.fill(0.0);
            for r in self.ring.chunks_exact(n) {
                for (s, v) in self.sum.iter_mut().zip(r) {
                    *s += v;
                }
            }
        }
        for (m, s) in self.mean.iter_mut().zip(&self.sum) {
            *m = s / w as f64;
        }
        Some(&self.mean)
    }
}

/// Per drive, a delay line of `max(on, off) + 1` probabilities: when an episode starts
/// (p above 0.5 after a step at or below) the `on` steps before are raised to its
/// probability, when it ends the `off` steps before are lowered to it; the oldest is
/// published.
#[derive(Debug, Clone)]
pub struct EdgeBackdate {
    on: usize,
    off: usize,
    /// Ring of the last `max(on, off) + 1` probability vectors, row-major.
    ring: Vec<f64>,
    published: Vec<f64>,
    last_in_episode: Vec<bool>,
    seen: usize,
}

impl EdgeBackdate {
    pub fn new(on: usize, off: usize, n: usize) -> Self {
        EdgeBackdate {
            on,
            off,
            ring: vec![0.0; (on.max(off) + 1) * n],
            published: vec![0.0; n],
            last_in_episode: vec![false; n],
            seen: 0,
        }
    }

    /// Pushes the probabilities of step `t`; those of step `t - max(on, off)` once that many
    /// steps are in.
    pub fn push(&mut self, p: &[f64]) -> Option<&[f64]> {
        let n = self.published.len();
        let w = self.on.max(self.off) + 1;
        let head = self.seen % w;
        self.ring[head * n..][..n].copy_from_slice(p);
        for (k, &pk) in p.iter().enumerate() {
            let now = pk > EPISODE_PROBABILITY;
            let (back, raise) = match (self.last_in_episode[k], now) {
                (false, true) => (self.on, true),
                (true, false) => (self.off, false),
                _ => (0, false),
            };
            // Steps before the first are not there to move.
            for j in 1..=back.min(self.seen) {
                let q = &mut self.ring[((head + w - j) % w) * n + k];
                *q = if raise { q.max(pk) } else { q.min(pk) };
            }
            self.last_in_episode[k] = now;
        }
        self.seen += 1;
        if self.seen < w {
            return None;
        }
        let tail = self.seen % w;
        self.published.copy_from_slice(&self.ring[tail * n..][..n]);
        Some(&self.published)
    }
}

/// An adhesion method behind the fixed lag: torque estimates of step `t` in, slip
/// probabilities of step `t - FIXED_LAG_STEPS` out.
#[derive(Debug, Clone)]
pub struct FixedLagEstimator {
    window: CentredMean,
    estimator: AdhesionEstimator,
    edges: EdgeBackdate,
}

impl FixedLagEstimator {
    pub fn new(estimator: AdhesionEstimator) -> Self {
        let n = estimator.n_drives();
        FixedLagEstimator {
            window: CentredMean::new(CENTRED_HALF_WINDOW_STEPS, n),
            estimator,
            edges: EdgeBackdate::new(ONSET_BACKDATE_STEPS, RELEASE_BACKDATE_STEPS, n),
        }
    }

    /// One step of torque estimates (one per drive, finite); the probabilities of the step
    /// `FIXED_LAG_STEPS` before, `None` until there is one: the first
    /// `CENTRED_HALF_WINDOW_STEPS` steps have no centred mean and get none, so the first
    /// answer comes at step `FIXED_LAG_STEPS + CENTRED_HALF_WINDOW_STEPS` (for step
    /// `CENTRED_HALF_WINDOW_STEPS`). Bad input is rejected before anything changes.
    pub fn estimate(&mut self, torque_nm: &[f64]) -> Result<Option<&[f64]>, SlipError> {
        let n = self.estimator.n_drives();
        check_torques(torque_nm, n)?;
        let Some(mean) = self.window.push(torque_nm) else {
            return Ok(None);
        };
        let p = &self.estimator.estimate(mean)?.slip_probability;
        Ok(self.edges.push(p))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::adhesion::{AdhesionConfig, AdhesionMethod};

    #[test]
    fn centred_mean_is_the_mean_of_the_window_around_its_step() {
        let mut c = CentredMean::new(2, 2);
        let xs: Vec<f64> = (0..40)
            .map(|t| (t as f64 * 0.7).sin() * 10.0 + t as f64)
            .collect();
        for (t, &x) in xs.iter().enumerate() {
            let out = c.push(&[x, -x]).map(<[f64]>::to_vec);
            if t < 4 {
                assert!(out.is_none());
                continue;
            }
            let m = out.unwrap();
            let want = xs[t - 4..=t].iter().sum::<f64>() / 5.0;
            assert!((m[0] - want).abs() < 1e-12, "step {t}: {} vs {want}", m[0]);
            assert!((m[1] + want).abs() < 1e-12);
        }
    }

    /// The edges of a hand-made episode move as documented: `[a, b)` -> `[a - on, b - off)`.
    #[test]
    fn edges_move_back_by_their_steps() {
        let (on, off) = (4, 2);
        let mut e = EdgeBackdate::new(on, off, 1);
        let p: Vec<f64> = (0..30)
            .map(|t| if (10..20).contains(&t) { 0.9 } else { 0.1 })
            .collect();
        let mut out = Vec::new();
        for &pt in &p {
            if let Some(q) = e.push(&[pt]) {
                out.push(q[0]);
            }
        }
        assert_eq!(out.len(), 30 - on);
        let flagged: Vec<usize> = (0..out.len()).filter(|&t| out[t] > 0.5).collect();
        assert_eq!(flagged, (10 - on..20 - off).collect::<Vec<_>>());
    }

    /// A short blip shorter than `off - on` is removed; one longer keeps its shortened part.
    #[test]
    fn a_release_moved_further_than_the_onset_shortens_episodes() {
        let mut e = EdgeBackdate::new(1, 3, 1);
        let p = [0.1, 0.1, 0.1, 0.1, 0.9, 0.9, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1];
        let out: Vec<f64> = p
            .iter()
            .filter_map(|&x| e.push(&[x]).map(|q| q[0]))
            .collect();
        assert!(out.iter().all(|&q| q <= 0.5), "{out:?}");
    }

    #[test]
    fn the_stage_answers_after_its_lag_and_rejects_bad_input() {
        let est = AdhesionEstimator::new(AdhesionMethod::Temporal, &AdhesionConfig::default(), 3)
            .unwrap();
        let mut s = FixedLagEstimator::new(est);
        assert!(s.estimate(&[1.0, 2.0]).is_err());
        assert!(s.estimate(&[1.0, f64::NAN, 2.0]).is_err());
        let mut first = None;
        for t in 0..200 {
            if s.estimate(&[10.0, 10.1, 9.9]).unwrap().is_some() && first.is_none() {
                first = Some(t);
            }
        }
        assert_eq!(first, Some(FIXED_LAG_STEPS + CENTRED_HALF_WINDOW_STEPS));
    }
}
