//! The recursive-least-squares peer of the virtual sensor (issue 14): fuel now from
//! `x_t = [v_t, a_t, max(a_t, 0) v_t, 1]` with `a_t = (v_t - v_{t-1}) / dt`, four parameters,
//! exponential forgetting `lambda` (1: none). A simple physical model of a fuel map (rolling
//! and inertial power), estimated on line; the estimate of `y_t` is made before `y_t` updates
//! the parameters, so it is a virtual sensor in the same sense as the mixture's.

use nalgebra::{Matrix4, Vector4};

#[derive(Clone, Debug)]
pub struct RlsPeer {
    theta: Vector4<f64>,
    /// `P = (sum lambda^k x x')^-1`, symmetric positive definite.
    p: Matrix4<f64>,
    lambda: f64,
    previous: Option<(f64, f64)>,
}

impl RlsPeer {
    /// `P_0 = p0 I` (a weak prior on the parameters), forgetting `lambda` in (0, 1].
    pub fn new(lambda: f64, p0: f64) -> Self {
        RlsPeer {
            theta: Vector4::zeros(),
            p: Matrix4::identity() * p0,
            lambda,
            previous: None,
        }
    }

    fn regressor(&self, time_s: f64, speed_m_s: f64) -> Vector4<f64> {
        let a = self
            .previous
            .map_or(0.0, |(t, v)| (speed_m_s - v) / (time_s - t));
        Vector4::new(speed_m_s, a, a.max(0.0) * speed_m_s, 1.0)
    }

    /// The estimate of fuel at `time_s` from the speed then (before seeing the fuel).
    pub fn estimate(&self, time_s: f64, speed_m_s: f64) -> f64 {
        self.theta.dot(&self.regressor(time_s, speed_m_s))
    }

    /// Updates with the measured fuel at `time_s`.
    pub fn update(&mut self, time_s: f64, speed_m_s: f64, fuel_cm3_s: f64) {
        let x = self.regressor(time_s, speed_m_s);
        let px = self.p * x;
        let gain = px / (self.lambda + x.dot(&px));
        self.theta += gain * (fuel_cm3_s - self.theta.dot(&x));
        // P <- (P - k x' P) / lambda, symmetrised against rounding.
        let p = (self.p - gain * px.transpose()) / self.lambda;
        self.p = (p + p.transpose()) * 0.5;
        self.previous = Some((time_s, speed_m_s));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_noise_free_linear_fuel_map() {
        // fuel = 0.2 + 0.03 v + 0.5 a + 0.04 max(a, 0) v on a varied speed trace.
        let mut rls = RlsPeer::new(1.0, 1e6);
        let (mut v_prev, mut last_error) = (0.0, f64::NAN);
        for t in 0..600 {
            let v = 10.0 + 8.0 * (t as f64 * 0.05).sin() + 3.0 * (t as f64 * 0.31).cos();
            let a = if t == 0 { 0.0 } else { v - v_prev };
            let fuel = 0.2 + 0.03 * v + 0.5 * a + 0.04 * a.max(0.0) * v;
            last_error = rls.estimate(t as f64, v) - fuel;
            rls.update(t as f64, v, fuel);
            v_prev = v;
        }
        assert!(last_error.abs() < 1e-6, "{last_error}");
        let want = Vector4::new(0.03, 0.5, 0.04, 0.2);
        assert!((rls.theta - want).amax() < 1e-6, "{}", rls.theta);
    }
}
