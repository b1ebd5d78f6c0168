//! The vehicle's forward speed over a simulated run: a scenario's
//! `[speed] profile_m_s = [[t_s, v_m_s], ...]`, piecewise linear in time.

use serde::{Deserialize, Serialize};

use crate::sample::MAX_SPEED_M_S;
use crate::DamperError;

/// Speed against time: linear between the points, the first speed before the first point,
/// the last after the last; one point is a constant speed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpeedProfile {
    /// `[t_s, v_m_s]` pairs, times strictly increasing and non-negative, speeds in
    /// `0..=MAX_SPEED_M_S`.
    pub profile_m_s: Vec<[f64; 2]>,
}

impl SpeedProfile {
    pub fn constant(speed_m_s: f64) -> Self {
        SpeedProfile {
            profile_m_s: vec![[0.0, speed_m_s]],
        }
    }

    /// A clear error for an empty profile, a non-finite or negative time, times out of
    /// order, a speed that is negative, non-finite or above `MAX_SPEED_M_S`.
    pub fn validate(&self) -> Result<(), DamperError> {
        let err =
            |k: usize, what: String| DamperError::Config(format!("speed.profile_m_s[{k}]: {what}"));
        if self.profile_m_s.is_empty() {
            return Err(DamperError::Config(
                "speed.profile_m_s: empty (give at least one [t_s, v_m_s])".into(),
            ));
        }
        let mut previous: Option<f64> = None;
        for (k, &[t, v]) in self.profile_m_s.iter().enumerate() {
            if !(t.is_finite() && t >= 0.0) {
                return Err(err(k, format!("time {t} s must be finite and >= 0")));
            }
            if let Some(p) = previous.filter(|p| t <= *p) {
                return Err(err(
                    k,
                    format!("time {t} s must be after the previous point's {p} s"),
                ));
            }
            if !(0.0..=MAX_SPEED_M_S).contains(&v) {
                return Err(err(
                    k,
                    format!("speed {v} m/s must be in 0..={MAX_SPEED_M_S}"),
                ));
            }
            previous = Some(t);
        }
        Ok(())
    }

    /// The speed at `t_s` (m/s).
    pub fn at(&self, t_s: f64) -> f64 {
        let p = &self.profile_m_s;
        let after = p.partition_point(|q| q[0] <= t_s);
        match after {
            0 => p[0][1],
            n if n == p.len() => p[n - 1][1],
            n => {
                let ([t0, v0], [t1, v1]) = (p[n - 1], p[n]);
                v0 + (v1 - v0) * (t_s - t0) / (t1 - t0)
            }
        }
    }

    /// Whether the speed never changes.
    pub fn is_constant(&self) -> bool {
        self.profile_m_s.windows(2).all(|w| w[0][1] == w[1][1])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn profile(points: &[[f64; 2]]) -> SpeedProfile {
        SpeedProfile {
            profile_m_s: points.to_vec(),
        }
    }

    #[test]
    fn interpolates_linearly_and_holds_the_ends() {
        let p = profile(&[[10.0, 0.0], [30.0, 20.0], [40.0, 20.0], [50.0, 0.0]]);
        p.validate().unwrap();
        assert_eq!(p.at(0.0), 0.0);
        assert_eq!(p.at(10.0), 0.0);
        assert_eq!(p.at(15.0), 5.0);
        assert_eq!(p.at(30.0), 20.0);
        assert_eq!(p.at(35.0), 20.0);
        assert_eq!(p.at(47.5), 5.0);
        assert_eq!(p.at(1e6), 0.0);
        assert!(!p.is_constant());
        let c = SpeedProfile::constant(45.3);
        c.validate().unwrap();
        assert_eq!(c.at(0.0), 45.3);
        assert_eq!(c.at(123.4), 45.3);
        assert!(c.is_constant());
    }

    #[test]
    fn bad_profiles_are_named_by_point() {
        let message = |points: &[[f64; 2]]| match profile(points).validate() {
            Err(DamperError::Config(m)) => m,
            other => panic!("{points:?}: {other:?}"),
        };
        assert!(message(&[]).contains("empty"));
        let m = message(&[[0.0, 10.0], [5.0, 20.0], [4.0, 30.0]]);
        assert!(m.contains("profile_m_s[2]") && m.contains("after"), "{m}");
        let m = message(&[[0.0, 10.0], [0.0, 20.0]]);
        assert!(m.contains("profile_m_s[1]"), "{m}");
        let m = message(&[[0.0, -1.0]]);
        assert!(
            m.contains("profile_m_s[0]") && m.contains("speed -1"),
            "{m}"
        );
        let m = message(&[[0.0, 10.0], [1.0, f64::NAN]]);
        assert!(m.contains("profile_m_s[1]") && m.contains("NaN"), "{m}");
        let m = message(&[[f64::NAN, 10.0]]);
        assert!(m.contains("time NaN"), "{m}");
        let m = message(&[[0.0, 200.0]]);
        assert!(m.contains("200"), "{m}");
    }
}
