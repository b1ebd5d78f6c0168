//! The plan-view half vehicle of section 2: 17 states, 2 track inputs, 5 sensors.
//!
//! Built from the equations of motion (1), not from the rearranged (2), whose bogie-yaw line
//! has `a K_x / I_b` on the wheelset displacements where (1) gives `a K_y / I_b` (seed notes;
//! the test `a_matches_hand_derivation_from_equations_of_motion` checks the `a K_y` entries).
//!
//! State (paper, after eq. 3):
//! `x = [y_w1', y_w1, psi_w1', psi_w1, y_w2', y_w2, psi_w2', psi_w2, y_b', y_b, psi_b', psi_b,
//!       y_bd', y_bd, y_sr, d_1, d_2]`, input `beta = [y_t1', y_t2']`,
//! output `y = [y_w1'', y_w2'', y_b'', psi_b', y_bd'']`.
//!
//! ## The two zero eigenvalues (unobservable drift)
//! `A` has a two-dimensional null space (rank 15). Its left null vectors are
//! `W = [e_yw1 - e_d1; e_yw2 - e_d2]`: the track positions `y_t1 = y_w1 - d_1` and
//! `y_t2 = y_w2 - d_2`, which the model integrates from the track velocities (random walks).
//! The right null vectors `V` (with `W V = I`) are the static deflections of the vehicle on a
//! track displaced by `y_t1` and `y_t2`: for equal inputs, every lateral displacement shifts
//! together (the rigid drift). No force changes along `V`, so no sensor sees it (`H V = 0`,
//! `H` being rows of `A`), while the track input drives it: a Kalman covariance grows without
//! bound along `V`, and the filter Riccati equation has no stabilising solution.
//!
//! The filters therefore use `A_f = A - eps V W`: the track positions become mean-reverting
//! (`y_t' = beta - eps y_t`, time constant `1 / eps`) instead of random walks. Because `W` holds
//! left null vectors, every other eigenvalue and eigenvector of `A` is unchanged, and because
//! `A_f x = A x (mod V)` and `H V = 0`, the law of the measurements is exactly the same for
//! every `eps`: the leak only pins the invisible absolute position. `A V W = V W A = 0`, so
//! `expm(A_f T) = expm(A T) (I + (exp(-eps T) - 1) V W)`. The test
//! `drift_leak_changes_nothing_observable` checks the likelihood; the simulator (the plant)
//! uses `eps = 0`.

use nalgebra::{SMatrix, SVector};

use crate::params::{positive, BogieParams, Dampers};
use crate::DamperError;

pub const N_STATES: usize = 17;
pub const N_INPUTS: usize = 2;
pub const N_OUTPUTS: usize = 5;

pub type Matrix17 = SMatrix<f64, N_STATES, N_STATES>;
pub type Matrix17x2 = SMatrix<f64, N_STATES, N_INPUTS>;
pub type Matrix5x17 = SMatrix<f64, N_OUTPUTS, N_STATES>;
pub type Matrix5 = SMatrix<f64, N_OUTPUTS, N_OUTPUTS>;
pub type Vector17 = SVector<f64, N_STATES>;
pub type Vector5 = SVector<f64, N_OUTPUTS>;

/// Indices into the state vector.
pub mod state {
    pub const YW1_DOT: usize = 0;
    pub const YW1: usize = 1;
    pub const PSIW1_DOT: usize = 2;
    pub const PSIW1: usize = 3;
    pub const YW2_DOT: usize = 4;
    pub const YW2: usize = 5;
    pub const PSIW2_DOT: usize = 6;
    pub const PSIW2: usize = 7;
    pub const YB_DOT: usize = 8;
    pub const YB: usize = 9;
    pub const PSIB_DOT: usize = 10;
    pub const PSIB: usize = 11;
    pub const YBD_DOT: usize = 12;
    pub const YBD: usize = 13;
    pub const YSR: usize = 14;
    pub const D1: usize = 15;
    pub const D2: usize = 16;
}

/// Rows of `A` that are the measured accelerations, and the yaw-rate state, in output order
/// (eq. 5: rows 1, 5, 9, 12, 13 of `A`, 1-based; row 12 of `A` is `psi_b' `, the gyro).
pub const OUTPUT_ROWS: [usize; N_OUTPUTS] = [
    state::YW1_DOT,
    state::YW2_DOT,
    state::YB_DOT,
    state::PSIB,
    state::YBD_DOT,
];

/// Names of the five sensors, in output order.
pub const OUTPUT_NAMES: [&str; N_OUTPUTS] = [
    "wheelset1_accel_m_s2",
    "wheelset2_accel_m_s2",
    "bogie_accel_m_s2",
    "bogie_yaw_rate_rad_s",
    "body_accel_m_s2",
];

/// `A(theta)`, `G`, `H` for given physical parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct BogieModel {
    params: BogieParams,
    /// `A` with both damper terms zero and the drift leak applied.
    base: Matrix17,
    /// `d A[psib', psib'] / d C_say = -l_bw^2 / I_b`.
    csay_gain: f64,
    /// `K_sry`: `A[ysr, yb] = -A[ysr, ysr] = K_sry / C_sy`.
    end_stiffness: f64,
    drift_leak_per_s: f64,
    /// `V`: static deflections for unit track displacements (right null vectors of `A`).
    drift_basis: Matrix17x2,
    /// `H`, taken from the plant rows (before the leak, which changes the `psi_b` row).
    h: Matrix5x17,
}

/// `W`: the track positions `y_t1 = y_w1 - d_1`, `y_t2 = y_w2 - d_2` (left null vectors of `A`).
pub fn track_position_rows() -> SMatrix<f64, N_INPUTS, N_STATES> {
    let mut w = SMatrix::<f64, N_INPUTS, N_STATES>::zeros();
    w[(0, state::YW1)] = 1.0;
    w[(0, state::D1)] = -1.0;
    w[(1, state::YW2)] = 1.0;
    w[(1, state::D2)] = -1.0;
    w
}

impl BogieModel {
    /// Model with the given rigid-drift leak `eps` (1/s); `0` is the physical plant.
    pub fn new(params: &BogieParams, drift_leak_per_s: f64) -> Result<Self, DamperError> {
        params.validate()?;
        crate::params::non_negative("drift_leak_per_s", drift_leak_per_s)?;
        let p = params;
        let mw = p.wheelset_mass_kg;
        let iw = p.wheelset_yaw_inertia_kg_m2;
        let (ky, kx) = (
            p.primary_lateral_stiffness_n_per_m,
            p.primary_longitudinal_stiffness_n_per_m,
        );
        let (ksy, ksry) = (
            p.secondary_lateral_stiffness_n_per_m,
            p.secondary_end_stiffness_n_per_m,
        );
        let (f11, f22) = (p.longitudinal_creep_n, p.lateral_creep_n);
        let (a, l, r0) = (p.semi_wheelbase_m, p.half_gauge_m, p.wheel_radius_m);
        let lambda = p.conicity;
        let (mb, ib) = (p.bogie_mass_kg, p.bogie_yaw_inertia_kg_m2);
        use state::*;
        let mut m = Matrix17::zeros();
        // Kinematic rows: position' = velocity.
        for (pos, vel) in [
            (YW1, YW1_DOT),
            (PSIW1, PSIW1_DOT),
            (YW2, YW2_DOT),
            (PSIW2, PSIW2_DOT),
            (YB, YB_DOT),
            (PSIB, PSIB_DOT),
            (YBD, YBD_DOT),
        ] {
            m[(pos, vel)] = 1.0;
        }
        // Wheelsets, lines 1-4 of (1); `sign` is +1 for the leading wheelset (ahead of the
        // bogie centre by `a`), -1 for the trailing one.
        let creep_yaw = 2.0 * f11 * lambda * l / r0;
        for (y_dot, y, psi_dot, psi, d, sign) in [
            (YW1_DOT, YW1, PSIW1_DOT, PSIW1, D1, 1.0),
            (YW2_DOT, YW2, PSIW2_DOT, PSIW2, D2, -1.0),
        ] {
            m[(y_dot, y)] = -ky / mw;
            m[(y_dot, psi)] = 2.0 * f22 / mw;
            m[(y_dot, YB)] = ky / mw;
            m[(y_dot, PSIB)] = sign * a * ky / mw;
            m[(psi_dot, psi)] = -kx * l * l / iw;
            m[(psi_dot, PSIB)] = kx * l * l / iw;
            // (1) has `2 f11 lambda l / r0 (y_w - y_t)` = `... d`.
            m[(psi_dot, d)] = -creep_yaw / iw;
            // d' = y_w' - y_t' (the input enters through G).
            m[(d, y_dot)] = 1.0;
        }
        // Bogie lateral, line 5.
        m[(YB_DOT, YW1)] = ky / mb;
        m[(YB_DOT, YW2)] = ky / mb;
        m[(YB_DOT, YB)] = -(2.0 * ky + ksy + ksry) / mb;
        m[(YB_DOT, YBD)] = ksy / mb;
        m[(YB_DOT, YSR)] = ksry / mb;
        // Bogie yaw, line 6 of (1): `a K_y` on the wheelset displacements (erratum to (2)).
        m[(PSIB_DOT, YW1)] = a * ky / ib;
        m[(PSIB_DOT, YW2)] = -a * ky / ib;
        m[(PSIB_DOT, PSIW1)] = kx * l * l / ib;
        m[(PSIB_DOT, PSIW2)] = kx * l * l / ib;
        m[(PSIB_DOT, PSIB)] = -(2.0 * a * a * ky + 2.0 * kx * l * l) / ib;
        // Body, line 8 with line 7 substituted: C_sy (y_sr' - y_bd') = K_sry (y_b - y_sr).
        for (r, c, value) in mass_entries(p) {
            m[(r, c)] = value;
        }
        // Series node, line 7: y_sr' = y_bd' + K_sry / C_sy (y_b - y_sr).
        m[(YSR, YBD_DOT)] = 1.0;
        // The creep damping of the wheelsets, the only place the speed enters.
        for (r, c, value) in speed_entries(p) {
            m[(r, c)] = value;
        }
        let mut model = BogieModel {
            params: *params,
            base: m,
            csay_gain: -p.semi_bogie_width_m.powi(2) / ib,
            end_stiffness: ksry,
            drift_leak_per_s: 0.0,
            drift_basis: Matrix17x2::zeros(),
            h: Matrix5x17::zeros(),
        };
        let plant = model.a_matrix(&Dampers::NOMINAL);
        for (row, &r) in OUTPUT_ROWS.iter().enumerate() {
            model.h.set_row(row, &plant.row(r));
        }
        // The null space with any positive dampers (with both zero the series node would add
        // a third conserved quantity, y_sr - y_bd).
        model.drift_basis = null_basis(&model.a_matrix(&Dampers::NOMINAL))?;
        // Drift leak: A_f = A - eps V W (see module docs).
        model.base -= model.drift_basis * track_position_rows() * drift_leak_per_s;
        model.drift_leak_per_s = drift_leak_per_s;
        Ok(model)
    }

    /// The same vehicle at another forward speed: only the creep damping entries of `A`
    /// ([`SPEED_ENTRIES`], `-2 f_22 / (m_w v)` and `-2 f_11 l^2 / (I_w v)`) and their copies in
    /// `H` (the wheelset accelerometers' rows) change. `V` does not: the null vectors are
    /// static deflections, on which the velocity terms vanish, and the leak `eps V W` touches
    /// only position rows and columns. Cheap (no factorisation): the filters call it whenever
    /// the measured speed changes.
    pub fn set_speed(&mut self, speed_m_s: f64) -> Result<(), DamperError> {
        positive("speed_m_s", speed_m_s)?;
        self.params.speed_m_s = speed_m_s;
        for (r, c, value) in speed_entries(&self.params) {
            self.base[(r, c)] = value;
            if let Some(row) = OUTPUT_ROWS.iter().position(|&o| o == r) {
                self.h[(row, c)] = value;
            }
        }
        Ok(())
    }

    /// The same vehicle with another body mass above the bogie (`m_bd`, kg: the measured
    /// load, [`crate::BogieSample::half_body_mass_kg`]): only the body's acceleration row
    /// ([`MASS_ENTRIES`], `(K_sy + K_sry) / m_bd`, `-K_sy / m_bd`, `-K_sry / m_bd`) and its
    /// copy in `H` (the body accelerometer) change. `V` does not: `A V = 0` holds row by row,
    /// and scaling a row keeps its null space; the leak `eps V W` has no term in a velocity
    /// row's mass columns. Cheap (no factorisation), as [`BogieModel::set_speed`].
    pub fn set_half_body_mass_kg(&mut self, half_body_mass_kg: f64) -> Result<(), DamperError> {
        positive("half_body_mass_kg", half_body_mass_kg)?;
        self.params.half_body_mass_kg = half_body_mass_kg;
        for (r, c, value) in mass_entries(&self.params) {
            self.base[(r, c)] = value;
            if let Some(row) = OUTPUT_ROWS.iter().position(|&o| o == r) {
                self.h[(row, c)] = value;
            }
        }
        Ok(())
    }

    /// Everything of the model the gain grid's solution reads (`A(theta)`, `G`, `H`) into a
    /// fingerprint (`GainTable::fingerprint`).
    pub(crate) fn hash_solver_inputs(&self, h: &mut crate::fingerprint::Fnv128) {
        h.f64s(self.base.iter())
            .f64(self.csay_gain)
            .f64(self.end_stiffness)
            .f64s(self.g_matrix().iter())
            .f64s(self.h.iter());
    }

    /// `V` with `W V = I` (see module docs).
    pub fn drift_basis(&self) -> &Matrix17x2 {
        &self.drift_basis
    }

    pub fn params(&self) -> &BogieParams {
        &self.params
    }

    pub fn drift_leak_per_s(&self) -> f64 {
        self.drift_leak_per_s
    }

    /// The three entries of `A` that depend on the dampers: `A[psib', psib'] = -C_say l_bw^2 /
    /// I_b` and `A[ysr, yb] = -A[ysr, ysr] = K_sry / C_sy` (seed notes: `C_sy` enters only
    /// through the series node).
    pub fn damper_entries(&self, d: &Dampers) -> DamperEntries {
        DamperEntries {
            yaw_damping_per_s: self.csay_gain * d.csay_ns_per_m,
            series_rate_per_s: self.end_stiffness / d.csy_ns_per_m,
        }
    }

    /// `A(theta)` (with the drift leak the model was built with).
    pub fn a_matrix(&self, d: &Dampers) -> Matrix17 {
        let e = self.damper_entries(d);
        let mut a = self.base;
        a[(state::PSIB_DOT, state::PSIB_DOT)] += e.yaw_damping_per_s;
        a[(state::YSR, state::YB)] += e.series_rate_per_s;
        a[(state::YSR, state::YSR)] -= e.series_rate_per_s;
        a
    }

    /// `d A / d C_sy` and `d A / d C_say` applied to `x`: the columns of `d (A x) / d theta`
    /// in the EKF Jacobian (eq. 18).
    pub fn a_x_parameter_jacobian(&self, d: &Dampers, x: &Vector17) -> Matrix17x2 {
        let mut j = Matrix17x2::zeros();
        j[(state::YSR, 0)] =
            -self.end_stiffness / d.csy_ns_per_m.powi(2) * (x[state::YB] - x[state::YSR]);
        j[(state::PSIB_DOT, 1)] = self.csay_gain * x[state::PSIB_DOT];
        j
    }

    /// `G`: the track velocities enter only `d_1' = y_w1' - y_t1'`, `d_2' = y_w2' - y_t2'`.
    pub fn g_matrix(&self) -> Matrix17x2 {
        let mut g = Matrix17x2::zeros();
        g[(state::D1, 0)] = -1.0;
        g[(state::D2, 1)] = -1.0;
        g
    }

    /// `H` (eq. 5): rows of the plant's `A` for the four accelerometers, `e_psib'` for the
    /// gyro. None of these rows holds a damper term, so `H` does not depend on `theta`. It is
    /// taken before the drift leak: the leak alters the `psi_b` row of `A` (the static yaw of
    /// a displaced track), which is not what the gyro measures.
    pub fn h_matrix(&self) -> Matrix5x17 {
        self.h
    }
}

/// The entries of `A` that depend on the forward speed `v`, as `(row, column)`: the creep
/// damping of each wheelset's lateral and yaw velocity (lines 1-4 of (1)), all `~ 1 / v`.
pub const SPEED_ENTRIES: [(usize, usize); 4] = [
    (state::YW1_DOT, state::YW1_DOT),
    (state::PSIW1_DOT, state::PSIW1_DOT),
    (state::YW2_DOT, state::YW2_DOT),
    (state::PSIW2_DOT, state::PSIW2_DOT),
];

/// [`SPEED_ENTRIES`] with their values at `p.speed_m_s`: `-2 f_22 / (m_w v)` (lateral) and
/// `-2 f_11 l^2 / (I_w v)` (yaw).
fn speed_entries(p: &BogieParams) -> [(usize, usize, f64); 4] {
    let v = p.speed_m_s;
    let lateral = -2.0 * p.lateral_creep_n / (p.wheelset_mass_kg * v);
    let l = p.half_gauge_m;
    // In this order, as the model was always built (the default path stays bit for bit).
    let yaw = -2.0 * p.longitudinal_creep_n * l * l / (p.wheelset_yaw_inertia_kg_m2 * v);
    let value = [lateral, yaw, lateral, yaw];
    std::array::from_fn(|k| (SPEED_ENTRIES[k].0, SPEED_ENTRIES[k].1, value[k]))
}

/// The entries of `A` that depend on the body mass `m_bd`, as `(row, column)`: the body's
/// lateral acceleration (line 8 of (1) with line 7 substituted), all `~ 1 / m_bd`.
pub const MASS_ENTRIES: [(usize, usize); 3] = [
    (state::YBD_DOT, state::YB),
    (state::YBD_DOT, state::YBD),
    (state::YBD_DOT, state::YSR),
];

/// [`MASS_ENTRIES`] with their values at `p.half_body_mass_kg`.
fn mass_entries(p: &BogieParams) -> [(usize, usize, f64); 3] {
    let mbd = p.half_body_mass_kg;
    let (ksy, ksry) = (
        p.secondary_lateral_stiffness_n_per_m,
        p.secondary_end_stiffness_n_per_m,
    );
    // The expressions the model was always built with (the default path stays bit for bit).
    let value = [(ksy + ksry) / mbd, -ksy / mbd, -ksry / mbd];
    std::array::from_fn(|k| (MASS_ENTRIES[k].0, MASS_ENTRIES[k].1, value[k]))
}

/// The right null space of `a` (without damper terms: they vanish on static states, so the
/// null space does not depend on the dampers), normalised so that `W V = I`.
fn null_basis(a: &Matrix17) -> Result<Matrix17x2, DamperError> {
    // Solve the consistent, full-column-rank system [A; W] V = [0; I] in the least-squares
    // sense (normal equations would square the condition number; use the SVD).
    let mut stacked = SMatrix::<f64, { N_STATES + N_INPUTS }, N_STATES>::zeros();
    stacked
        .fixed_view_mut::<N_STATES, N_STATES>(0, 0)
        .copy_from(a);
    stacked
        .fixed_view_mut::<N_INPUTS, N_STATES>(N_STATES, 0)
        .copy_from(&track_position_rows());
    let mut rhs = SMatrix::<f64, { N_STATES + N_INPUTS }, N_INPUTS>::zeros();
    rhs[(N_STATES, 0)] = 1.0;
    rhs[(N_STATES + 1, 1)] = 1.0;
    let err = || DamperError::NonFinite { what: "null space" };
    let v = stacked
        .svd(true, true)
        .solve(&rhs, 1e-12)
        .map_err(|_| err())?;
    // Rescale so that W V = I holds to roundoff (the solve balances it against A V = 0).
    let wv_inv = (track_position_rows() * v).try_inverse().ok_or_else(err)?;
    Ok(v * wv_inv)
}

/// The damper-dependent entries of `A` for one parameter value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DamperEntries {
    /// `-C_say l_bw^2 / I_b`, added to `A[psib', psib']` (1/s).
    pub yaw_damping_per_s: f64,
    /// `K_sry / C_sy`, added to `A[ysr, yb]` and subtracted from `A[ysr, ysr]` (1/s).
    pub series_rate_per_s: f64,
}

#[cfg(test)]
mod tests {
    use super::state::*;
    use super::*;
    use crate::expm::{discretize, expm};

    fn nominal(leak: f64) -> BogieModel {
        BogieModel::new(&BogieParams::default(), leak).unwrap()
    }

    /// Entries of A computed by hand from (1) with the appendix values and lambda = 0.15.
    #[test]
    fn a_matches_hand_derivation_from_equations_of_motion() {
        let a = nominal(0.0).a_matrix(&Dampers::NOMINAL);
        let close = |i: usize, j: usize, want: f64| {
            let got = a[(i, j)];
            assert!(
                (got - want).abs() <= 1e-9 * want.abs().max(1.0),
                "A[{i},{j}] = {got}, hand-derived {want}"
            );
        };
        // Leading wheelset lateral: 2 f22 / (m_w v) = 2e7 / (1250 * 45.3) = 353.19...
        close(YW1_DOT, YW1_DOT, -20e6 / (1250.0 * 45.3));
        close(YW1_DOT, YW1, -4000.0); // K_y / m_w = 5e6 / 1250
        close(YW1_DOT, PSIW1, 16000.0); // 2 f22 / m_w
        close(YW1_DOT, YB, 4000.0);
        close(YW1_DOT, PSIB, 5200.0); // a K_y / m_w = 1.3 * 4000
        close(YW2_DOT, PSIB, -5200.0);
        // Wheelset yaw: K_x l^2 / I_w = 9.726e6 * 0.514089 / 700 = 7142.9...
        close(PSIW1_DOT, PSIW1, -9.726e6 * 0.717 * 0.717 / 700.0);
        close(
            PSIW1_DOT,
            PSIW1_DOT,
            -2.0 * 10e6 * 0.514_089 / (700.0 * 45.3),
        );
        // 2 f11 lambda l / (r0 I_w) = 2e7 * 0.15 * 0.717 / (0.455 * 700) = 6753.3...
        close(PSIW1_DOT, D1, -2e7 * 0.15 * 0.717 / (0.455 * 700.0));
        // Bogie lateral: (2 K_y + K_sy + K_sry) / m_b = 12.662e6 / 2580
        close(YB_DOT, YB, -12.662e6 / 2580.0);
        close(YB_DOT, YSR, 2.42e6 / 2580.0);
        // Bogie yaw from (1): a K_y / I_b = 6.5e6 / 2160 (not a K_x / I_b as in (2)).
        close(PSIB_DOT, YW1, 6.5e6 / 2160.0);
        close(PSIB_DOT, YW2, -6.5e6 / 2160.0);
        close(PSIB_DOT, PSIB_DOT, -160e3 * 1.69 / 2160.0);
        close(
            PSIB_DOT,
            PSIB,
            -(2.0 * 1.69 * 5e6 + 2.0 * 9.726e6 * 0.514_089) / 2160.0,
        );
        // Body and series node: K_sry / C_sy = 2420 / 16 = 151.25.
        close(YBD_DOT, YB, 2.662e6 / 13000.0);
        close(YBD_DOT, YSR, -2.42e6 / 13000.0);
        close(YSR, YB, 151.25);
        close(YSR, YSR, -151.25);
        close(YSR, YBD_DOT, 1.0);
        close(D1, YW1_DOT, 1.0);
        // Only rows psib' and ysr depend on the dampers; nothing else changes.
        let other = nominal(0.0).a_matrix(&Dampers {
            csy_ns_per_m: 5e3,
            csay_ns_per_m: 40e3,
        });
        for i in 0..N_STATES {
            for j in 0..N_STATES {
                if i != PSIB_DOT && i != YSR {
                    assert_eq!(a[(i, j)], other[(i, j)]);
                }
            }
        }
        // 44 structural non-zeros, as the issue says.
        assert_eq!(a.iter().filter(|v| **v != 0.0).count(), 44);
    }

    #[test]
    fn h_is_rows_of_a_and_independent_of_the_dampers() {
        let m = nominal(0.0);
        let h = m.h_matrix();
        for d in [
            Dampers::NOMINAL,
            Dampers {
                csy_ns_per_m: 3e3,
                csay_ns_per_m: 20e3,
            },
        ] {
            let a = m.a_matrix(&d);
            for (row, &r) in OUTPUT_ROWS.iter().enumerate() {
                assert_eq!(h.row(row), a.row(r));
            }
        }
        assert_eq!(h[(3, PSIB_DOT)], 1.0);
        assert_eq!(nominal(0.3).h_matrix(), h);
    }

    /// Seed notes: two zero eigenvalues. They are the track positions (left null vectors `W`);
    /// `A V = 0`, `H V = 0`, and with the leak the zeros move to `-eps` while every other
    /// eigenvalue stays put; the rigid drift (all displacements equal) is `V [1, 1]'`.
    #[test]
    fn drift_is_the_null_space_and_the_leak_only_moves_its_eigenvalues() {
        let plant = nominal(0.0);
        let v = *plant.drift_basis();
        let w = track_position_rows();
        for d in [
            Dampers::NOMINAL,
            Dampers {
                csy_ns_per_m: 4e3,
                csay_ns_per_m: 30e3,
            },
        ] {
            let a = plant.a_matrix(&d);
            let scale = a.amax() * v.amax();
            assert!((a * v).amax() < 1e-13 * scale, "{}", (a * v).amax() / scale);
            assert!((w * a).amax() < 1e-12);
        }
        assert!((plant.h_matrix() * v).amax() < 1e-9);
        assert!((w * v - nalgebra::Matrix2::identity()).amax() < 1e-12);
        let rigid = v * nalgebra::Vector2::new(1.0, 1.0);
        for i in [YW1, YW2, YB, YBD, YSR] {
            assert!((rigid[i] - 1.0).abs() < 1e-9, "{rigid}");
        }
        let eps = 0.05;
        let a = plant.a_matrix(&Dampers::NOMINAL);
        let leaky = nominal(eps).a_matrix(&Dampers::NOMINAL);
        assert!((leaky * v + v * eps).amax() < 1e-9);
        let sorted = |m: &Matrix17| {
            let mut ev: Vec<_> = m.complex_eigenvalues().iter().copied().collect();
            ev.sort_by(|x, y| x.re.total_cmp(&y.re).then(x.im.total_cmp(&y.im)));
            ev
        };
        let (ev0, ev1) = (sorted(&a), sorted(&leaky));
        assert_eq!(ev0.iter().filter(|c| c.norm() < 1e-6).count(), 2, "{ev0:?}");
        assert_eq!(ev1.iter().filter(|c| c.norm() < 1e-6).count(), 0, "{ev1:?}");
        assert_eq!(ev1.iter().filter(|c| (c.re + eps).abs() < 1e-6).count(), 2);
        for c in ev0.iter().filter(|c| c.norm() > 1e-6) {
            assert!(ev1.iter().any(|e| (e - c).norm() < 1e-6 * c.norm()), "{c}");
            // Stable at 45.3 m/s with lambda = 0.15.
            assert!(c.re < 0.0);
        }
    }

    /// A model moved to another body mass is the model built with it (the mass enters only
    /// the body row of `A` and `H`), and moved back it is the design model to the bit.
    #[test]
    fn set_half_body_mass_is_the_model_built_with_that_mass() {
        let design = nominal(0.05);
        let heavy_params = BogieParams {
            half_body_mass_kg: 1.3 * 13000.0,
            ..BogieParams::default()
        };
        let built = BogieModel::new(&heavy_params, 0.05).unwrap();
        let mut moved = design.clone();
        moved.set_half_body_mass_kg(1.3 * 13000.0).unwrap();
        let d = Dampers::NOMINAL;
        assert!((moved.a_matrix(&d) - built.a_matrix(&d)).amax() < 1e-9);
        assert_eq!(moved.h_matrix(), built.h_matrix());
        assert_ne!(moved.h_matrix(), design.h_matrix());
        assert!((moved.drift_basis() - built.drift_basis()).amax() < 1e-9);
        moved.set_half_body_mass_kg(13000.0).unwrap();
        assert_eq!(moved, design);
        assert!(moved.set_half_body_mass_kg(-1.0).is_err());
    }

    /// `Phi`, `Gamma` against a fine-step (RK4, 1 us) integration of `x' = A x + G beta` over
    /// one 1 ms step with `beta` held.
    #[test]
    fn discretisation_matches_fine_step_integration() {
        let m = nominal(0.0);
        let a = m.a_matrix(&Dampers {
            csy_ns_per_m: 9e3,
            csay_ns_per_m: 210e3,
        });
        let g = m.g_matrix();
        let dt = 1e-3;
        let disc = discretize(&a, &g, dt).unwrap();
        let x0 = Vector17::from_fn(|i, _| ((i * 7 + 3) % 11) as f64 * 1e-3 - 5e-3);
        let beta = nalgebra::Vector2::new(0.02, -0.01);
        let f = |x: &Vector17| a * x + g * beta;
        let mut x = x0;
        let n = 1000;
        let h = dt / n as f64;
        for _ in 0..n {
            let k1 = f(&x);
            let k2 = f(&(x + k1 * (h / 2.0)));
            let k3 = f(&(x + k2 * (h / 2.0)));
            let k4 = f(&(x + k3 * h));
            x += (k1 + k2 * 2.0 + k3 * 2.0 + k4) * (h / 6.0);
        }
        let exact = disc.phi * x0 + disc.gamma * beta;
        let err = (exact - x).amax() / x.amax();
        assert!(err < 1e-10, "relative error {err}");
        // And Phi is expm(A T) itself.
        assert!((disc.phi - expm(&(a * dt)).unwrap()).amax() < 1e-12);
    }
}
