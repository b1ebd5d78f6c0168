//! Load-torque jump detection on one drive's EKF innovations: a generalised likelihood ratio
//! (GLR) test with state correction (Willsky and Jones, "A generalized likelihood ratio
//! approach to the detection and estimation of jumps in linear systems", IEEE TAC 21(1), 1976).
//!
//! Why: the EKF sees the load only through the speed it changes and the back-EMF that speed
//! changes, so a sudden loss of adhesion reaches the torque estimate through a double
//! integration weighted by a filter that was tuned for a quiet load. It lags a step by ~20
//! samples at each edge of a loss (docs/adhesion.md), which caps F1 near 0.75 on an 80-step
//! slide. The GLR uses the same innovations but tests "the load jumped by `nu` at step `j`"
//! against "nothing happened" for every onset `j` of a short window, with the exact response of
//! the filter to such a jump; when the test fires, the state is corrected by the ML jump
//! `nu_hat` and the covariance widened by its variance, so the filter continues from the new
//! load instead of converging to it.
//!
//! The model of a jump of `nu` N m in the load at onset `j` (the true torque changes between
//! the posterior of step `j - 1` and the prediction of step `j`): the predicted-state error
//! gains `delta_k nu` with
//! `delta_j = e_T`, `delta_{k+1} = A_{k+1} (I - K_k C) delta_k`,
//! and the innovation gains `rho_k nu = C delta_k nu` (the two currents). With white innovations
//! of variance `sigma^2` per current, the log-likelihood ratio maximised over `nu` is
//! `l_j = a_j^2 / b_j`, `a_j = sum_k rho_k' v_k / sigma^2`, `b_j = sum_k rho_k' rho_k / sigma^2`,
//! `nu_hat = a_j / b_j` with variance `1 / b_j`; under no jump `l_j` is chi-square with one
//! degree of freedom for every `j`.
//!
//! `sigma^2` is learnt from the innovations themselves, not taken from the EKF's `R`: the
//! configured `R` (0.01 A^2, the paper's) overstates the sensor noise of every scenario by 10-100
//! times, and a test normalised by it would only see jumps of tens of N m.

use nalgebra::{SMatrix, Vector2};
use serde::{Deserialize, Serialize};

use crate::error::{check_positive, SlipError};
use crate::model::{idx, DriveMatrix, DriveState};

/// Settings of the jump test (`[ekf.jump]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct JumpConfig {
    /// Run the test. Off by default (the paper's EKF has none either): measured on every
    /// scenario (docs/adhesion.md) it raises F1 on two short losses, lowers it by up to 0.015
    /// on others, and changes no false-alarm figure; the choice is left open there.
    pub enabled: bool,
    /// Onsets tested at each step: the last `window_steps` steps. A jump older than this is
    /// left to the filter (which has then mostly absorbed it).
    pub window_steps: usize,
    /// Threshold on `l_j = 2 log LR`. Under no jump each `l_j` is chi-square(1); the max over
    /// the window exceeds 30 with probability below `window_steps * 4.3e-8` per step. Model
    /// errors (the plant's sub-steps, a smoothed load change) make the innovations less white
    /// than that: at 20 a healthy braking drive got false jumps (before the rest after a
    /// correction and `min_age_steps`), at 25 the cycle's healthy drives 0.18 % false-alarm
    /// steps (before the common-mode check; docs/adhesion.md).
    pub threshold: f64,
    /// Youngest onset tested, in steps. A jump reaches the currents through the speed two
    /// steps after its onset and is resolved only after ten or more (its signature grows with
    /// the square of its age); a younger onset's jump estimate rests on a few small residuals,
    /// which model errors (a smooth load change, the transient of a correction) fit as a jump
    /// of 15 N m on a healthy drive.
    pub min_age_steps: usize,
    /// A jump is common to the drives (and not corrected) when at least half of the others'
    /// leading onsets reach this `2 log LR` with the same sign ([`is_common_mode`]); 0 turns
    /// the check off.
    pub common_mode_threshold: f64,
    /// Smallest ML jump that is corrected, N m: below it the filter's own tracking is as good.
    pub min_jump_nm: f64,
    /// Memory of the learnt innovation variance, in steps (a running mean until then).
    pub noise_memory_steps: f64,
    /// No test in the first frames, while the filter locks on from an unknown angle and load
    /// (its innovations are then no jump's signature); the noise is learnt from the second
    /// half of them on.
    pub warmup_steps: u64,
}

impl Default for JumpConfig {
    fn default() -> Self {
        JumpConfig {
            enabled: false,
            window_steps: 24,
            threshold: 30.0,
            min_age_steps: 8,
            common_mode_threshold: 9.0,
            min_jump_nm: 1.0,
            noise_memory_steps: 2000.0,
            warmup_steps: 400,
        }
    }
}

impl JumpConfig {
    pub fn validate(&self, prefix: &str) -> Result<(), SlipError> {
        if self.window_steps < 3 {
            return Err(SlipError::invalid(
                format!("{prefix}.window_steps"),
                self.window_steps,
                "must be >= 3 (a jump reaches the currents two steps after its onset)",
            ));
        }
        check_positive(&format!("{prefix}.threshold"), self.threshold)?;
        if self.min_age_steps >= self.window_steps {
            return Err(SlipError::invalid(
                format!("{prefix}.min_age_steps"),
                self.min_age_steps,
                "must be below window_steps",
            ));
        }
        if !(self.min_jump_nm >= 0.0 && self.min_jump_nm.is_finite()) {
            return Err(SlipError::invalid(
                format!("{prefix}.min_jump_nm"),
                self.min_jump_nm,
                "must be finite and >= 0",
            ));
        }
        check_positive(
            &format!("{prefix}.noise_memory_steps"),
            self.noise_memory_steps,
        )?;
        Ok(())
    }
}

/// One onset hypothesis: the posterior-state signature of a unit jump and the GLR sums.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct Hypothesis {
    /// `(I - K C) delta` of the last step: the posterior error a unit jump leaves.
    delta_post: DriveState,
    /// `sum rho' v` (A N m^-1 times A, before dividing by `sigma^2`).
    a: f64,
    /// `sum rho' rho`.
    b: f64,
    /// Steps since the onset.
    age: usize,
}

/// A detected jump: what the filter is corrected by.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Jump {
    /// ML jump of the load torque, N m.
    pub torque_nm: f64,
    /// Steps between the onset and this step.
    pub age_steps: usize,
    /// `2 log LR` of the onset.
    pub statistic: f64,
    /// Correction of the posterior state (`nu_hat (I - K C) delta`).
    pub state_correction: DriveState,
    /// Covariance added to the posterior: the jump estimate's variance along its signature.
    pub covariance_added: DriveMatrix,
}

/// The GLR test of one drive.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JumpDetector {
    config: JumpConfig,
    /// Ring of hypotheses, newest last (at most `window_steps`).
    hypotheses: Vec<Hypothesis>,
    /// Learnt innovation variance per current, A^2 (`None` before the first innovation).
    innovation_var_a2: Option<f64>,
    /// Innovations seen (learning weight `1 / min(n, memory)`).
    innovations: f64,
    /// Jumps detected since start.
    detections: u64,
    /// Steps left without a test after a detection.
    hold_steps: usize,
    /// `(l, nu_hat)` of the leading onset tested at the last step, or of the last jump while
    /// the test rests after it (`None` when neither): what the bank compares across drives to
    /// tell a common load change.
    lead: Option<(f64, f64)>,
}

impl JumpDetector {
    pub fn new(config: JumpConfig) -> Self {
        JumpDetector {
            config,
            hypotheses: Vec::with_capacity(config.window_steps),
            innovation_var_a2: None,
            innovations: 0.0,
            detections: 0,
            hold_steps: 0,
            lead: None,
        }
    }

    /// Jumps detected since start.
    pub fn detections(&self) -> u64 {
        self.detections
    }

    /// The learnt innovation variance per current, A^2.
    pub fn innovation_var_a2(&self) -> Option<f64> {
        self.innovation_var_a2
    }

    /// One step of the test, after the EKF update of step `frame`: `a` is the Jacobian the
    /// prediction to this step used, `gain` the Kalman gain `K` of this step, `innovation` the
    /// measured minus predicted currents. Returns the jump to apply to the posterior, if one is
    /// detected; the window then starts again.
    pub fn observe(
        &mut self,
        frame: u64,
        a: &DriveMatrix,
        gain: &SMatrix<f64, 5, 2>,
        innovation: &Vector2<f64>,
    ) -> Option<Jump> {
        // Propagate every hypothesis to this step and add its innovation signature.
        for h in &mut self.hypotheses {
            let delta = a * h.delta_post;
            let rho = Vector2::new(delta[idx::I_ALPHA], delta[idx::I_BETA]);
            h.a += rho.dot(innovation);
            h.b += rho.norm_squared();
            h.delta_post = delta - gain * rho;
            h.age += 1;
        }
        // A new onset at this step: the jump is in the predicted torque, not yet in the
        // currents (rho = 0), so its posterior signature is the unit torque vector.
        if self.hypotheses.len() == self.config.window_steps {
            self.hypotheses.remove(0);
        }
        let mut unit = DriveState::zeros();
        unit[idx::TORQUE] = 1.0;
        self.hypotheses.push(Hypothesis {
            delta_post: unit,
            a: 0.0,
            b: 0.0,
            age: 0,
        });

        let var = self
            .innovation_var_a2
            .unwrap_or(innovation.norm_squared() / 2.0);
        // After a correction the filter's own transient (it re-converges with the widened
        // covariance) is no jump's signature: the test rests for a whole window, so that its
        // onsets all start after the correction. Without this rest a young onset (two or three
        // steps, tiny `b`) fitted that transient with a huge jump and the corrections fed on
        // each other until the filter diverged (a healthy braking drive, threshold 20).
        self.hold_steps = self.hold_steps.saturating_sub(1);
        // While resting after a jump the test's lead stays that jump's (a drive that has just
        // seen a load change still tells the others so).
        if self.hold_steps == 0 {
            self.lead = None;
        }
        let jump = if frame > self.config.warmup_steps && var > 0.0 && self.hold_steps == 0 {
            self.best(var)
        } else {
            None
        };
        match jump {
            Some(j) => {
                self.hypotheses.clear();
                self.hold_steps = self.config.window_steps;
                self.detections += 1;
                Some(j)
            }
            None if frame <= self.config.warmup_steps / 2 => None,
            None => {
                // Learn the noise only from steps without a detected jump, and not from the
                // lock-on (its innovations of up to amperes kept the learnt variance 25 times
                // too high for thousands of steps: no jump was found before step ~10,000).
                self.innovations += 1.0;
                let w = 1.0 / self.innovations.min(self.config.noise_memory_steps);
                let v = innovation.norm_squared() / 2.0;
                self.innovation_var_a2 = Some(match self.innovation_var_a2 {
                    Some(old) => old + w * (v - old),
                    None => v,
                });
                None
            }
        }
    }

    /// The largest `2 log LR` over the window and its ML jump (N m), before the threshold.
    pub fn statistic(&self) -> Option<(f64, f64)> {
        let var = self.innovation_var_a2?;
        self.hypotheses
            .iter()
            .filter(|h| h.b > 0.0)
            .map(|h| (h.a * h.a / (h.b * var), h.a / h.b))
            .max_by(|x, y| x.0.total_cmp(&y.0))
    }

    /// The onset of largest `l_j` if it passes the threshold and its jump is large enough.
    fn best(&mut self, var: f64) -> Option<Jump> {
        let mut best: Option<(f64, &Hypothesis)> = None;
        for h in &self.hypotheses {
            if h.b <= 0.0 || h.age < self.config.min_age_steps {
                continue;
            }
            let l = h.a * h.a / (h.b * var);
            if best.is_none_or(|(lb, _)| l > lb) {
                best = Some((l, h));
            }
        }
        let (statistic, h) = best?;
        let torque_nm = h.a / h.b;
        self.lead = Some((statistic, torque_nm));
        if statistic < self.config.threshold || torque_nm.abs() < self.config.min_jump_nm {
            return None;
        }
        Some(Jump {
            torque_nm,
            age_steps: h.age,
            statistic,
            state_correction: h.delta_post * torque_nm,
            covariance_added: h.delta_post * h.delta_post.transpose() * (var / h.b),
        })
    }

    /// `(2 log LR, ML jump in N m)` of the leading onset this step tested, if it tested.
    pub fn lead(&self) -> Option<(f64, f64)> {
        self.lead
    }
}

/// Whether a jump of `jump_nm` found on one drive is a load change common to the drives (a
/// switch of traction, coasting or braking) rather than that drive's own: at least half of
/// the other drives' leading onsets point the same way with `2 log LR >= threshold`. A common
/// change is left to the filters, which then follow it together as without the test; a
/// correction of some drives and not (yet) of others made a healthy drive leave the majority.
pub fn is_common_mode(
    jump_nm: f64,
    others: impl Iterator<Item = Option<(f64, f64)>>,
    threshold: f64,
) -> bool {
    let (mut agree, mut n) = (0usize, 0usize);
    for lead in others {
        n += 1;
        if lead.is_some_and(|(l, nu)| l >= threshold && nu.signum() == jump_nm.signum()) {
            agree += 1;
        }
    }
    n > 0 && 2 * agree >= n
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{DriveModel, MotorParams};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// A fixed Jacobian (a drive at 200 rad/s carrying 10 N m) and the steady-state gain of
    /// the default EKF for it (Riccati iteration), so the test's signatures are the filter's.
    fn steady_a_and_gain() -> (DriveMatrix, SMatrix<f64, 5, 2>) {
        let model = DriveModel::new(MotorParams::default(), 125e-6).unwrap();
        let x = DriveState::new(-1.0, 2.0, 200.0, 0.4, 10.0);
        let a = model.jacobian(&x);
        let q = DriveMatrix::from_diagonal(&[1e-5, 1e-5, 1e-4, 1e-6, 1.0].into());
        let r = nalgebra::Matrix2::identity() * 0.01;
        let mut p = DriveMatrix::identity();
        let mut gain = SMatrix::<f64, 5, 2>::zeros();
        for _ in 0..3000 {
            p = a * p * a.transpose() + q;
            let pc = p.fixed_columns::<2>(0).into_owned();
            let s = pc.fixed_rows::<2>(0).into_owned() + r;
            gain = pc * s.try_inverse().unwrap();
            let mut i_kc = DriveMatrix::identity();
            i_kc.fixed_columns_mut::<2>(0).copy_from(&(-gain));
            i_kc[(0, 0)] += 1.0;
            i_kc[(1, 1)] += 1.0;
            p = i_kc * p;
        }
        (a, gain)
    }

    fn config(threshold: f64) -> JumpConfig {
        JumpConfig {
            enabled: true,
            threshold,
            warmup_steps: 0,
            ..JumpConfig::default()
        }
    }

    /// Noise-free innovations equal to a jump's signature: the ML estimate is the jump itself
    /// and the onset is found (the GLR's analytic result with no noise).
    #[test]
    fn a_noise_free_jump_is_estimated_exactly_with_its_onset() {
        let (a, gain) = steady_a_and_gain();
        let mut det = JumpDetector::new(config(30.0));
        // Learn a noise level of 0.02 A from zero-mean innovations first.
        for t in 0..200 {
            let v = if t % 2 == 0 { 0.02 } else { -0.02 };
            assert!(det.observe(t, &a, &gain, &Vector2::new(v, -v)).is_none());
        }
        let jump_nm = -20.0;
        let onset = 200;
        let mut delta = DriveState::zeros();
        delta[idx::TORQUE] = 1.0;
        let mut found = None;
        for t in onset..onset + 23 {
            // The signature of the onset at this step: delta- = A delta+ (the onset's own step
            // has no current effect), v = C delta- * jump.
            if t > onset {
                delta = a * delta;
            }
            let rho = Vector2::new(delta[0], delta[1]);
            delta -= gain * rho;
            if let Some(j) = det.observe(t, &a, &gain, &(rho * jump_nm)) {
                found = Some((t, j));
                break;
            }
        }
        let (t, j) = found.expect("a 20 N m jump is found within the window");
        assert!(
            (j.torque_nm - jump_nm).abs() < 1e-9 * jump_nm.abs(),
            "{j:?}"
        );
        assert_eq!(t - j.age_steps as u64, onset);
        // The correction is the posterior error the jump left: the torque part is most of it.
        assert!((j.state_correction - delta * jump_nm).amax() < 1e-9);
        assert!(det.detections() == 1);
    }

    /// Under no jump, `l_j` of every onset is chi-square with one degree of freedom: its mean
    /// over many white-noise steps is 1, and the max over the window passes 30 (the default
    /// threshold) less often than the union bound `window * P(chi2_1 > 30)` allows.
    #[test]
    fn on_white_noise_the_statistic_is_chi_square_one() {
        let (a, gain) = steady_a_and_gain();
        let mut det = JumpDetector::new(config(f64::INFINITY));
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let noise = Normal::new(0.0, 0.02).unwrap();
        let (mut sum, mut count, mut over_30) = (0.0, 0usize, 0usize);
        let steps = 40_000;
        for t in 0..steps {
            let v = Vector2::new(noise.sample(&mut rng), noise.sample(&mut rng));
            assert!(det.observe(t, &a, &gain, &v).is_none());
            if t < 2000 {
                continue;
            }
            let var = det.innovation_var_a2().unwrap();
            let h = det.hypotheses.iter().find(|h| h.age == 12).unwrap();
            sum += h.a * h.a / (h.b * var);
            count += 1;
            if det.statistic().unwrap().0 > 30.0 {
                over_30 += 1;
            }
        }
        let mean = sum / count as f64;
        assert!((mean - 1.0).abs() < 0.1, "mean of l at age 12: {mean}");
        // P(chi2_1 > 30) = 4.3e-8; 24 onsets, 38,000 steps: bound 0.04 expected.
        assert_eq!(over_30, 0);
        let sd = det.innovation_var_a2().unwrap().sqrt();
        assert!((sd - 0.02).abs() < 0.001, "learnt innovation sd {sd}");
    }

    #[test]
    fn a_jump_is_common_when_half_the_others_lead_the_same_way() {
        let strong_up = Some((20.0, 5.0));
        let weak_up = Some((3.0, 5.0));
        let strong_down = Some((20.0, -5.0));
        let others = [strong_up, weak_up, strong_down, None];
        // 1 of 4 agree: the drive's own jump.
        assert!(!is_common_mode(6.0, others.into_iter(), 9.0));
        // 2 of 4 agree (half): common.
        assert!(is_common_mode(
            6.0,
            [strong_up, strong_up, None, weak_up].into_iter(),
            9.0
        ));
        assert!(is_common_mode(-6.0, [strong_down].into_iter(), 9.0));
        // With no other drive a jump is always the drive's own.
        assert!(!is_common_mode(6.0, std::iter::empty(), 9.0));
    }

    #[test]
    fn invalid_settings_are_rejected() {
        let bad = |m: fn(&mut JumpConfig), field: &str| {
            let mut c = JumpConfig::default();
            m(&mut c);
            let e = c.validate("ekf.jump").unwrap_err().to_string();
            assert!(e.contains(field), "{e}");
        };
        bad(|c| c.window_steps = 2, "ekf.jump.window_steps");
        bad(|c| c.threshold = 0.0, "ekf.jump.threshold");
        bad(|c| c.min_age_steps = 24, "ekf.jump.min_age_steps");
        bad(|c| c.min_jump_nm = f64::NAN, "ekf.jump.min_jump_nm");
        bad(
            |c| c.noise_memory_steps = -1.0,
            "ekf.jump.noise_memory_steps",
        );
    }
}
