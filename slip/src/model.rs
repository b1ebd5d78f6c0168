//! Discrete PMSM drive model in the stationary alpha-beta frame (paper eq. 11-13), with the
//! load torque as a fifth, random-walk state (section 3.2.1).
//!
//! State `x = [i_alpha_a, i_beta_a, omega_rad_s, theta_rad, torque_nm]` where `omega` and
//! `theta` are the *electrical* rotor speed and angle. Input `u = [u_alpha_v, u_beta_v]`.

use nalgebra::{SMatrix, SVector, Vector2};
use serde::{Deserialize, Serialize};

use crate::error::{check_non_negative, check_positive, SlipError};

/// Drive state `[i_alpha_a, i_beta_a, omega_rad_s, theta_rad, torque_nm]`.
pub type DriveState = SVector<f64, 5>;
/// 5x5 state matrix (Jacobian, covariance).
pub type DriveMatrix = SMatrix<f64, 5, 5>;

/// Index of each state in [`DriveState`].
pub mod idx {
    pub const I_ALPHA: usize = 0;
    pub const I_BETA: usize = 1;
    pub const OMEGA: usize = 2;
    pub const THETA: usize = 3;
    pub const TORQUE: usize = 4;
}

/// PMSM parameters. The paper prints none; the defaults are those of Smidl and Peroutka's
/// sensorless PMSM work (seed-notes), kept in config because they are not verified.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct MotorParams {
    /// Stator resistance `R_s`.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub r_s_ohm: f64,
    /// Stator inductance `L_s` (= `L_d` = `L_q`, the paper's simplification).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub l_s_h: f64,
    /// Permanent-magnet flux linkage `Psi_pm`.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub psi_pm_wb: f64,
    /// Number of pole pairs `p_p`.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub pole_pairs: f64,
    /// Moment of inertia `J`.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub inertia_kg_m2: f64,
    /// Viscous friction `B` (N m s / rad).
    #[schemars(range(min = 0.0))]
    pub friction_nm_s_per_rad: f64,
    /// Park constant `k_p` (1.5 for the amplitude-invariant Clarke transform).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub park_constant: f64,
}

impl Default for MotorParams {
    fn default() -> Self {
        MotorParams {
            r_s_ohm: 0.28,
            l_s_h: 3.465e-3,
            psi_pm_wb: 0.1989,
            pole_pairs: 4.0,
            inertia_kg_m2: 0.04,
            friction_nm_s_per_rad: 0.0,
            park_constant: 1.5,
        }
    }
}

impl MotorParams {
    /// Checks every field; `prefix` is prepended to field names in errors (e.g. `"motor"`).
    pub fn validate(&self, prefix: &str) -> Result<(), SlipError> {
        let f = |name: &str| format!("{prefix}.{name}");
        check_positive(&f("r_s_ohm"), self.r_s_ohm)?;
        check_positive(&f("l_s_h"), self.l_s_h)?;
        check_positive(&f("psi_pm_wb"), self.psi_pm_wb)?;
        check_positive(&f("pole_pairs"), self.pole_pairs)?;
        check_positive(&f("inertia_kg_m2"), self.inertia_kg_m2)?;
        check_non_negative(&f("friction_nm_s_per_rad"), self.friction_nm_s_per_rad)?;
        check_positive(&f("park_constant"), self.park_constant)?;
        Ok(())
    }

    /// Torque per quadrature ampere, `k_p p_p Psi_pm` (N m / A): `T_e = k_t i_q`.
    pub fn torque_constant_nm_per_a(&self) -> f64 {
        self.park_constant * self.pole_pairs * self.psi_pm_wb
    }
}

/// The discrete model (11) with its coefficients (12)-(13) precomputed for one `dt`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DriveModel {
    pub params: MotorParams,
    pub dt_s: f64,
    /// `theta_a = 1 - R_s dt / L_s` (12).
    pub theta_a: f64,
    /// `theta_b = Psi_pm dt / L_s` (12).
    pub theta_b: f64,
    /// `dt / L_s`, the voltage gain in (11).
    pub theta_c: f64,
    /// `theta_d = 1 - B dt / J` (13).
    pub theta_d: f64,
    /// `theta_e = k_p p_p^2 Psi_pm dt / J` (13).
    pub theta_e: f64,
    /// `p_p dt / J`, the load-torque gain of the speed row of (11).
    pub theta_l: f64,
}

impl DriveModel {
    /// Builds the model; validates the parameters and the step.
    pub fn new(params: MotorParams, dt_s: f64) -> Result<Self, SlipError> {
        params.validate("motor")?;
        check_positive("dt_s", dt_s)?;
        let p = params;
        Ok(DriveModel {
            params,
            dt_s,
            theta_a: 1.0 - p.r_s_ohm / p.l_s_h * dt_s,
            theta_b: p.psi_pm_wb / p.l_s_h * dt_s,
            theta_c: dt_s / p.l_s_h,
            theta_d: 1.0 - p.friction_nm_s_per_rad / p.inertia_kg_m2 * dt_s,
            theta_e: p.park_constant * p.pole_pairs * p.pole_pairs * p.psi_pm_wb / p.inertia_kg_m2
                * dt_s,
            theta_l: p.pole_pairs / p.inertia_kg_m2 * dt_s,
        })
    }

    /// `f(x, u)` of eq. (11) without noise; the angle is left unwrapped (callers wrap).
    pub fn transition(&self, x: &DriveState, u: &Vector2<f64>) -> DriveState {
        self.transition_with(x, u, x[idx::THETA].sin_cos())
    }

    /// [`DriveModel::transition`] and [`DriveModel::jacobian`] at the same state, with one
    /// `sin_cos` of the angle for both (the EKF's prediction needs both).
    pub fn transition_and_jacobian(
        &self,
        x: &DriveState,
        u: &Vector2<f64>,
    ) -> (DriveState, DriveMatrix) {
        let sin_cos = x[idx::THETA].sin_cos();
        (
            self.transition_with(x, u, sin_cos),
            self.jacobian_with(x, sin_cos),
        )
    }

    fn transition_with(&self, x: &DriveState, u: &Vector2<f64>, (s, c): (f64, f64)) -> DriveState {
        let (i_a, i_b, w) = (x[idx::I_ALPHA], x[idx::I_BETA], x[idx::OMEGA]);
        DriveState::new(
            self.theta_a * i_a + self.theta_b * w * s + self.theta_c * u[0],
            self.theta_a * i_b - self.theta_b * w * c + self.theta_c * u[1],
            self.theta_d * w + self.theta_e * (i_b * c - i_a * s) - self.theta_l * x[idx::TORQUE],
            x[idx::THETA] + w * self.dt_s,
            x[idx::TORQUE],
        )
    }

    /// Full Jacobian `A = df/dx` at `x` (eq. 8).
    ///
    /// Erratum (seed-notes): the printed speed row reads `[theta_e sin, theta_e cos, ...]` and
    /// its "simplified" form drops the coupling altogether. Differentiating (11):
    /// `d omega+/d i_alpha = -theta_e sin(theta)`, `d omega+/d i_beta = theta_e cos(theta)`,
    /// `d omega+/d theta = -theta_e (i_beta sin + i_alpha cos)`, `d omega+/d T_L = -p_p dt / J`.
    /// The test `jacobian_matches_finite_differences` proves it.
    pub fn jacobian(&self, x: &DriveState) -> DriveMatrix {
        self.jacobian_with(x, x[idx::THETA].sin_cos())
    }

    fn jacobian_with(&self, x: &DriveState, (s, c): (f64, f64)) -> DriveMatrix {
        let (i_a, i_b, w) = (x[idx::I_ALPHA], x[idx::I_BETA], x[idx::OMEGA]);
        let (ta, tb, td, te) = (self.theta_a, self.theta_b, self.theta_d, self.theta_e);
        #[rustfmt::skip]
        let a = DriveMatrix::new(
            ta,       0.0,     tb * s,   tb * w * c,                   0.0,
            0.0,      ta,      -tb * c,  tb * w * s,                   0.0,
            -te * s,  te * c,  td,       -te * (i_b * s + i_a * c),    -self.theta_l,
            0.0,      0.0,     self.dt_s, 1.0,                          0.0,
            0.0,      0.0,     0.0,      0.0,                          1.0,
        );
        a
    }
}

/// Wraps an angle to `(-pi, pi]`.
pub fn wrap_angle(theta_rad: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    // Nearly every call (the EKF's angle after one step) is already in range: skip the
    // `fmod`, which returns such an angle unchanged anyway.
    if theta_rad > -PI && theta_rad <= PI {
        return theta_rad;
    }
    let mut t = theta_rad % TAU;
    if t > PI {
        t -= TAU;
    } else if t <= -PI {
        t += TAU;
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model() -> DriveModel {
        DriveModel::new(MotorParams::default(), 125e-6).unwrap()
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        let m = model();
        let u = Vector2::new(12.0, -30.0);
        for x in [
            DriveState::new(3.0, -7.0, 150.0, 0.7, 20.0),
            DriveState::new(-12.0, 4.0, -80.0, 2.9, -5.0),
            DriveState::new(0.5, 25.0, 300.0, -2.2, 30.0),
        ] {
            let a = m.jacobian(&x);
            for j in 0..5 {
                let h = 1e-6 * x[j].abs().max(1.0);
                let mut xp = x;
                let mut xm = x;
                xp[j] += h;
                xm[j] -= h;
                let col = (m.transition(&xp, &u) - m.transition(&xm, &u)) / (2.0 * h);
                for i in 0..5 {
                    let err = (col[i] - a[(i, j)]).abs();
                    assert!(
                        err < 1e-7 * (1.0 + a[(i, j)].abs()),
                        "A[{i},{j}]: fd {} vs {}",
                        col[i],
                        a[(i, j)]
                    );
                }
            }
        }
    }

    #[test]
    fn printed_speed_row_is_wrong() {
        // The paper's printed d omega+/d i_alpha is +theta_e sin(theta); at theta = 0.7 the
        // finite difference has the opposite sign, which is the erratum.
        let m = model();
        let x = DriveState::new(3.0, -7.0, 150.0, 0.7, 20.0);
        let u = Vector2::zeros();
        let h = 1e-6;
        let mut xp = x;
        xp[0] += h;
        let fd = (m.transition(&xp, &u)[2] - m.transition(&x, &u)[2]) / h;
        let printed = m.theta_e * x[3].sin();
        assert!(fd < 0.0 && printed > 0.0);
        assert!((fd + printed).abs() < 1e-6);
    }

    #[test]
    fn steady_state_torque_balance() {
        // With i_q = T_L / k_t and B = 0 the speed does not change (eq. 11, third row).
        let m = model();
        let torque = 20.0;
        let i_q = torque / m.params.torque_constant_nm_per_a();
        let theta = 1.1_f64;
        // i_alpha = -i_q sin(theta), i_beta = i_q cos(theta) for i_d = 0.
        let x = DriveState::new(-i_q * theta.sin(), i_q * theta.cos(), 200.0, theta, torque);
        let next = m.transition(&x, &Vector2::zeros());
        assert!((next[2] - 200.0).abs() < 1e-12);
    }

    #[test]
    fn wrap_angle_range() {
        use std::f64::consts::PI;
        assert!((wrap_angle(3.0 * PI) - PI).abs() < 1e-12);
        assert!((wrap_angle(-3.0 * PI) - PI).abs() < 1e-12);
        assert!((wrap_angle(0.5) - 0.5).abs() < 1e-15);
        assert!((wrap_angle(-7.0) - (-7.0 + 2.0 * PI)).abs() < 1e-12);
    }

    fn invalid(mutate: impl Fn(&mut MotorParams), field: &str) {
        let mut p = MotorParams::default();
        mutate(&mut p);
        let err = p.validate("motor").unwrap_err();
        assert!(err.to_string().contains(field), "{err}");
    }

    #[test]
    fn each_invalid_motor_parameter_is_rejected() {
        invalid(|p| p.r_s_ohm = 0.0, "motor.r_s_ohm");
        invalid(|p| p.l_s_h = -1.0, "motor.l_s_h");
        invalid(|p| p.psi_pm_wb = f64::NAN, "motor.psi_pm_wb");
        invalid(|p| p.pole_pairs = 0.0, "motor.pole_pairs");
        invalid(|p| p.inertia_kg_m2 = f64::INFINITY, "motor.inertia_kg_m2");
        invalid(
            |p| p.friction_nm_s_per_rad = -0.1,
            "motor.friction_nm_s_per_rad",
        );
        invalid(|p| p.park_constant = 0.0, "motor.park_constant");
        assert!(DriveModel::new(MotorParams::default(), 0.0).is_err());
    }
}
