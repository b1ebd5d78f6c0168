//! Lateral track input: the paper's white track velocities, or a realistic alignment
//! irregularity from the ERRI B176 spectrum with the trailing wheelset running over the same
//! track `2a / v` later.
//!
//! ERRI B176 (ORE B176, "Bogies with steered or steering wheelsets", report RP1, 1989) gives
//! the one-sided lateral alignment PSD
//! `S(Omega) = A Omega_c^2 / ((Omega^2 + Omega_r^2)(Omega^2 + Omega_c^2))` (m^2 / (rad/m)),
//! `Omega_c = 0.8246 rad/m`, `Omega_r = 0.0206 rad/m`, `A = 2.119e-7 m rad` (low level) or
//! `6.125e-7 m rad` (high level). It is rational, so the alignment is exactly the output of
//! the second-order shaping filter `b / ((s + Omega_r)(s + Omega_c))`, `b = Omega_c sqrt(pi A)`,
//! driven by unit spatial white noise: a stream with flat memory, no FFT blocks.

use nalgebra::{Matrix2, Matrix4, Vector2};
use rand::Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use crate::expm::expm;
use crate::params::positive;
use crate::DamperError;

/// ERRI B176 corner wavenumbers (rad/m).
pub const ERRI_OMEGA_C: f64 = 0.8246;
pub const ERRI_OMEGA_R: f64 = 0.0206;

/// ERRI B176 irregularity level.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ErriLevel {
    Low,
    High,
}

impl ErriLevel {
    /// The roughness factor `A` of the lateral alignment (m rad).
    pub fn roughness_m_rad(self) -> f64 {
        match self {
            ErriLevel::Low => 2.119e-7,
            ErriLevel::High => 6.125e-7,
        }
    }
}

/// What the scenario asks for.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum TrackSpec {
    /// The paper's model: `beta_k ~ N(0, sigma^2 I)` held over each step, the two wheelsets
    /// independent.
    White { velocity_std_m_s: f64 },
    /// ERRI B176 alignment, trailing wheelset delayed by `2a / v`.
    Erri { level: ErriLevel },
}

impl TrackSpec {
    pub fn validate(&self) -> Result<(), DamperError> {
        match self {
            TrackSpec::White { velocity_std_m_s } => {
                positive("velocity_std_m_s", *velocity_std_m_s)
            }
            TrackSpec::Erri { .. } => Ok(()),
        }
    }
}

/// `integral_0^inf S(Omega) dOmega` of the ERRI alignment spectrum (m^2):
/// `A Omega_c pi / (2 Omega_r (Omega_r + Omega_c))`.
pub fn erri_alignment_variance_m2(level: ErriLevel) -> f64 {
    let (oc, or) = (ERRI_OMEGA_C, ERRI_OMEGA_R);
    level.roughness_m_rad() * oc * std::f64::consts::PI / (2.0 * or * (or + oc))
}

/// Exact discretisation of the shaping filter in time at speed `v`: state `z = [y, dy/dx]`,
/// `z_{k+1} = F z_k + w_k`, `w_k ~ N(0, Q)`.
#[derive(Debug, Clone, PartialEq)]
pub struct ErriShapingFilter {
    pub f: Matrix2<f64>,
    pub q: Matrix2<f64>,
    /// Cholesky factor of `q`.
    q_chol: Matrix2<f64>,
}

impl ErriShapingFilter {
    pub fn new(level: ErriLevel, speed_m_s: f64, dt_s: f64) -> Result<Self, DamperError> {
        positive("speed_m_s", speed_m_s)?;
        positive("dt_s", dt_s)?;
        let (oc, or) = (ERRI_OMEGA_C, ERRI_OMEGA_R);
        let b = oc * (std::f64::consts::PI * level.roughness_m_rad()).sqrt();
        // d z / dx = F_x z + [0, b] w(x); in time x = v t and w(v t) has intensity 1 / v,
        // so d z / dt = v F_x z + noise of intensity v [0, b][0, b]'.
        let f_t = Matrix2::new(0.0, 1.0, -or * oc, -(or + oc)) * speed_m_s;
        let qc = Matrix2::new(0.0, 0.0, 0.0, speed_m_s * b * b);
        // Van Loan: expm([[-F, Qc], [0, F']] T) = [[., F^-1 Qd], [0, F']].
        let mut m = Matrix4::zeros();
        m.fixed_view_mut::<2, 2>(0, 0).copy_from(&(-f_t * dt_s));
        m.fixed_view_mut::<2, 2>(0, 2).copy_from(&(qc * dt_s));
        m.fixed_view_mut::<2, 2>(2, 2)
            .copy_from(&(f_t.transpose() * dt_s));
        let e = expm(&m)?;
        let f = e.fixed_view::<2, 2>(2, 2).transpose();
        let mut q = f * e.fixed_view::<2, 2>(0, 2);
        q = (q + q.transpose()) * 0.5;
        let q_chol = q
            .cholesky()
            .ok_or(DamperError::NonFinite {
                what: "track noise covariance",
            })?
            .l();
        Ok(ErriShapingFilter { f, q, q_chol })
    }

    /// Stationary covariance: solves `P = F P F' + Q` by doubling (Smith's method).
    pub fn stationary_covariance(&self) -> Matrix2<f64> {
        let mut p = self.q;
        let mut f = self.f;
        for _ in 0..64 {
            p += f * p * f.transpose();
            f = f * f;
        }
        p
    }
}

/// Streaming generator of `beta_k = [y_t1', y_t2']` (m/s).
#[derive(Debug, Clone)]
pub struct TrackGenerator {
    kind: Generator,
}

#[derive(Debug, Clone)]
enum Generator {
    White {
        std_m_s: f64,
    },
    Erri {
        filter: ErriShapingFilter,
        speed_m_s: f64,
        z: Vector2<f64>,
        /// Ring buffer of the leading wheelset's track velocity.
        history: Vec<f64>,
        head: usize,
        delay_steps: f64,
    },
}

impl TrackGenerator {
    pub fn new(
        spec: &TrackSpec,
        speed_m_s: f64,
        wheelset_delay_s: f64,
        dt_s: f64,
        rng: &mut impl Rng,
    ) -> Result<Self, DamperError> {
        spec.validate()?;
        let kind = match *spec {
            TrackSpec::White { velocity_std_m_s } => Generator::White {
                std_m_s: velocity_std_m_s,
            },
            TrackSpec::Erri { level } => {
                let filter = ErriShapingFilter::new(level, speed_m_s, dt_s)?;
                // Start in the stationary distribution, so there is no start-up transient.
                let chol = filter
                    .stationary_covariance()
                    .cholesky()
                    .ok_or(DamperError::NonFinite {
                        what: "track stationary covariance",
                    })?
                    .l();
                let z = chol * Vector2::new(rng.sample(StandardNormal), rng.sample(StandardNormal));
                let delay_steps = wheelset_delay_s / dt_s;
                let len = delay_steps.ceil() as usize + 2;
                let mut generator = Generator::Erri {
                    filter,
                    speed_m_s,
                    z,
                    history: vec![0.0; len],
                    head: 0,
                    delay_steps,
                };
                // Fill the delay line with the track the trailing wheelset is already on.
                for _ in 0..len {
                    generator.advance(rng);
                }
                generator
            }
        };
        Ok(TrackGenerator { kind })
    }

    /// The next step's (held) track velocities.
    pub fn next(&mut self, rng: &mut impl Rng) -> Vector2<f64> {
        self.kind.advance(rng)
    }
}

impl Generator {
    fn advance(&mut self, rng: &mut impl Rng) -> Vector2<f64> {
        match self {
            Generator::White { std_m_s } => Vector2::new(
                *std_m_s * rng.sample::<f64, _>(StandardNormal),
                *std_m_s * rng.sample::<f64, _>(StandardNormal),
            ),
            Generator::Erri {
                filter,
                speed_m_s,
                z,
                history,
                head,
                delay_steps,
            } => {
                let w = filter.q_chol
                    * Vector2::new(rng.sample(StandardNormal), rng.sample(StandardNormal));
                *z = filter.f * *z + w;
                let lead = *speed_m_s * z[1];
                let len = history.len();
                *head = (*head + 1) % len;
                history[*head] = lead;
                // Linear interpolation between the samples bracketing t - 2a/v.
                let whole = delay_steps.floor() as usize;
                let frac = *delay_steps - whole as f64;
                let at = |k: usize| history[(*head + len - k) % len];
                let trail = (1.0 - frac) * at(whole) + frac * at(whole + 1);
                Vector2::new(lead, trail)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn shaping_filter_has_the_erri_variance() {
        for level in [ErriLevel::Low, ErriLevel::High] {
            let f = ErriShapingFilter::new(level, 45.3, 1e-3).unwrap();
            let p = f.stationary_covariance();
            let want = erri_alignment_variance_m2(level);
            assert!(
                (p[(0, 0)] - want).abs() < 1e-6 * want,
                "{} vs {want}",
                p[(0, 0)]
            );
        }
        // Low level: about 4 mm standard deviation.
        let sd = erri_alignment_variance_m2(ErriLevel::Low).sqrt();
        assert!((sd - 3.97e-3).abs() < 0.05e-3, "{sd}");
    }

    #[test]
    fn trailing_wheelset_sees_the_leading_input_later() {
        let dt = 1e-3;
        let delay = 0.057;
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut g = TrackGenerator::new(
            &TrackSpec::Erri {
                level: ErriLevel::Low,
            },
            45.3,
            delay,
            dt,
            &mut rng,
        )
        .unwrap();
        let seq: Vec<_> = (0..500).map(|_| g.next(&mut rng)).collect();
        for k in 57..500 {
            assert!((seq[k][1] - seq[k - 57][0]).abs() < 1e-15);
        }
    }
}
