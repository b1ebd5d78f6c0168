//! Sensorless EKF of one PMSM drive (paper section 3.1-3.2), and the bank of N independent
//! filters of section 3.3.
//!
//! Eq. (16)-(17) stack the drives into one block-diagonal filter. Because every matrix is
//! block diagonal, the stacked filter is exactly N independent 5-state filters; we run them as
//! such (O(N) work and memory, never a dense 5N x 5N matrix).

use nalgebra::{Matrix2, SMatrix, Vector2};
use serde::{Deserialize, Serialize};

use railmon_filter::kalman::{symmetrize, update_joseph, LN_2PI};

use crate::error::{check_finite, check_positive, SlipError};
use crate::model::{idx, wrap_angle, DriveMatrix, DriveModel, DriveState};
use crate::sample::{validate_frame, DriveSample};

/// Noise and initialisation of the per-drive EKF.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct EkfConfig {
    /// Diagonal of the process-noise covariance `Q` for
    /// `[i_alpha, i_beta, omega, theta, T_L]` (section 3.2.1).
    #[schemars(transform = railmon_settings::items_above(0.0))]
    pub process_noise_diag: [f64; 5],
    /// Variance of each current measurement, `R = r I` (section 3.2.1), in A^2.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub measurement_noise_a2: f64,
    /// Diagonal of the initial covariance `P_0` ("low integers", section 3.2.1).
    #[schemars(transform = railmon_settings::items_above(0.0))]
    pub initial_covariance_diag: [f64; 5],
    /// Initial electrical speed guess; a drive controller knows its speed reference.
    pub initial_speed_rad_s: f64,
    /// Initial electrical angle guess.
    pub initial_angle_rad: f64,
    /// Initial load-torque guess.
    pub initial_torque_nm: f64,
    /// Replace the speed and angle guesses by the back-EMF seen between the first two frames
    /// (see [`back_emf_speed_angle`]); the direction of rotation is the sign of
    /// `initial_speed_rad_s` (forward when 0). Without it a filter started far from the true
    /// speed may lock on the mirrored solution `(-omega, theta + pi)`.
    pub start_from_back_emf: bool,
}

/// The validated setting (docs/adhesion.md, "EKF process noise"): the paper's measurement
/// noise `R = 0.01 A^2`, but a small process noise on the electrical states and a fast one on
/// the torque. The paper's `Q` on the currents (0.05 A^2 per step) tells the filter that the
/// current equations are wrong by 0.2 A every 125 us; it then explains the back-EMF signal
/// away as process noise and its torque estimate lags a load step by 70-200 steps. With this
/// `Q` the torque follows a step in about 20 steps at the 10 % level. The paper's values are
/// [`EkfConfig::paper`].
impl Default for EkfConfig {
    fn default() -> Self {
        EkfConfig {
            process_noise_diag: [1e-5, 1e-5, 1e-4, 1e-6, 1.0],
            measurement_noise_a2: 0.01,
            // Wide on the torque: the load at start is unknown to tens of N m.
            initial_covariance_diag: [1.0, 1.0, 1.0, 1.0, 100.0],
            // The direction of rotation (see `start_from_back_emf`) and the speed the
            // drive controllers hold in our scenarios.
            initial_speed_rad_s: 200.0,
            initial_angle_rad: 0.0,
            initial_torque_nm: 0.0,
            start_from_back_emf: true,
        }
    }
}

impl EkfConfig {
    /// The paper's setting (section 3.2.1): `diag Q = [0.05, 0.05, 0.001, 0.0001, 0.1]`,
    /// `R = 0.01`, `P_0 = I` ("low integers"); it gives no initial state, so the guesses are
    /// 0 (forward rotation) and the back-EMF start is kept.
    pub fn paper() -> Self {
        EkfConfig {
            process_noise_diag: [0.05, 0.05, 0.001, 0.0001, 0.1],
            measurement_noise_a2: 0.01,
            initial_covariance_diag: [1.0; 5],
            initial_speed_rad_s: 0.0,
            ..EkfConfig::default()
        }
    }

    pub fn validate(&self, prefix: &str) -> Result<(), SlipError> {
        for (k, v) in self.process_noise_diag.iter().enumerate() {
            check_positive(&format!("{prefix}.process_noise_diag[{k}]"), *v)?;
        }
        check_positive(
            &format!("{prefix}.measurement_noise_a2"),
            self.measurement_noise_a2,
        )?;
        for (k, v) in self.initial_covariance_diag.iter().enumerate() {
            check_positive(&format!("{prefix}.initial_covariance_diag[{k}]"), *v)?;
        }
        check_finite(
            &format!("{prefix}.initial_speed_rad_s"),
            self.initial_speed_rad_s,
        )?;
        check_finite(
            &format!("{prefix}.initial_angle_rad"),
            self.initial_angle_rad,
        )?;
        check_finite(
            &format!("{prefix}.initial_torque_nm"),
            self.initial_torque_nm,
        )
    }

    fn q(&self) -> DriveMatrix {
        DriveMatrix::from_diagonal(&self.process_noise_diag.into())
    }
}

/// Mean and covariance of one drive's state, plus the voltage it applies over the coming step.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DriveFilter {
    pub x: DriveState,
    pub p: DriveMatrix,
    /// Voltage applied since the last measurement (input of the next prediction); `None`
    /// before the first frame.
    pub u_prev: Option<Vector2<f64>>,
    /// Log-likelihood of the last measurement under `N(C x-, C P- C' + R)` (eq. 10 with the
    /// erratum: the predictive covariance is `C P- C' + R`, not `R`).
    pub log_likelihood: f64,
    /// Frames processed.
    pub frames: u64,
}

impl DriveFilter {
    fn initial(config: &EkfConfig) -> Self {
        DriveFilter {
            x: DriveState::new(
                0.0,
                0.0,
                config.initial_speed_rad_s,
                wrap_angle(config.initial_angle_rad),
                config.initial_torque_nm,
            ),
            p: DriveMatrix::from_diagonal(&config.initial_covariance_diag.into()),
            u_prev: None,
            log_likelihood: 0.0,
            frames: 0,
        }
    }

    pub fn torque_nm(&self) -> f64 {
        self.x[idx::TORQUE]
    }
    pub fn torque_var_nm2(&self) -> f64 {
        self.p[(idx::TORQUE, idx::TORQUE)]
    }
    pub fn speed_rad_s(&self) -> f64 {
        self.x[idx::OMEGA]
    }
    pub fn angle_rad(&self) -> f64 {
        self.x[idx::THETA]
    }
}

/// Measurement matrix `C` of eq. (15): the two currents.
fn measurement_matrix() -> SMatrix<f64, 2, 5> {
    let mut c = SMatrix::<f64, 2, 5>::zeros();
    c[(0, idx::I_ALPHA)] = 1.0;
    c[(1, idx::I_BETA)] = 1.0;
    c
}

/// One EKF step (eq. 3-9) of one drive; returns the new filter, leaving `f` untouched.
///
/// The prediction skips the zeros of the Jacobian `A` (14 non-zeros of 25), the update those
/// of `I - K C` (`C` selects the two currents: 2 x 5 x 5 products instead of 5 x 5 x 5,
/// twice) and factors the 2 x 2 innovation covariance by hand, but every sum adds the
/// remaining terms in the order of the dense products of [`ekf_step_dense`], so the result is
/// the same to the bit (test `sparse_step_equals_the_dense_one_bit_for_bit` compares the
/// bits); speed ratio in `cargo bench -p railmon-slip --bench sections`.
pub fn ekf_step(
    model: &DriveModel,
    q: &DriveMatrix,
    r: &Matrix2<f64>,
    f: &DriveFilter,
    sample: &DriveSample,
) -> Result<DriveFilter, railmon_filter::FilterError> {
    let mut out = *f;
    ekf_step_into(model, q, r, f, sample, &mut out)?;
    Ok(out)
}

/// [`ekf_step`] writing the new filter into `out` (unspecified on error): the bank steps into
/// its scratch space without moving a `DriveFilter` (288 bytes) through a `Result`.
pub fn ekf_step_into(
    model: &DriveModel,
    q: &DriveMatrix,
    r: &Matrix2<f64>,
    f: &DriveFilter,
    sample: &DriveSample,
    out: &mut DriveFilter,
) -> Result<(), railmon_filter::FilterError> {
    // Prediction (3)-(4), with the Jacobian at the previous posterior (8).
    let (x_pred, p_pred) = match f.u_prev {
        Some(u) => {
            let (x_pred, a) = model.transition_and_jacobian(&f.x, &u);
            let mut p = predicted_covariance(&a, &f.p, q);
            symmetrize(&mut p);
            (x_pred, p)
        }
        None => (f.x, f.p),
    };
    // Update (5)-(7) in Joseph form; h(x) = C x is linear (14).
    let innovation = Vector2::new(
        sample.i_alpha_a - x_pred[idx::I_ALPHA],
        sample.i_beta_a - x_pred[idx::I_BETA],
    );
    let upd = update_currents(&x_pred, &p_pred, &innovation, r)?;
    out.x = upd.x;
    out.x[idx::THETA] = wrap_angle(out.x[idx::THETA]);
    out.p = upd.p;
    out.u_prev = Some(Vector2::new(sample.u_alpha_v, sample.u_beta_v));
    out.log_likelihood = upd.log_likelihood;
    out.frames = f.frames + 1;
    Ok(())
}

/// Row `i` of the Jacobian `A` (eq. 8, [`DriveModel::jacobian`]) times `v`, over the
/// entries of that row that are not structurally zero (14 of the 25), in increasing column
/// order.
#[inline(always)]
fn a_row_times(a: &DriveMatrix, i: usize, v: &[f64; 5]) -> f64 {
    match i {
        0 => a[(0, 0)] * v[0] + a[(0, 2)] * v[2] + a[(0, 3)] * v[3],
        1 => a[(1, 1)] * v[1] + a[(1, 2)] * v[2] + a[(1, 3)] * v[3],
        2 => {
            a[(2, 0)] * v[0]
                + a[(2, 1)] * v[1]
                + a[(2, 2)] * v[2]
                + a[(2, 3)] * v[3]
                + a[(2, 4)] * v[4]
        }
        3 => a[(3, 2)] * v[2] + a[(3, 3)] * v[3],
        _ => a[(4, 4)] * v[4],
    }
}

/// `A P A' + Q` of eq. (4) over the non-zeros of `A` only (2 x 14 x 5 products instead of
/// 2 x 125). nalgebra's dense product sums `a_ik b_kj` over `k` in increasing order starting
/// from the first term; this sums the same terms in the same order without the zero ones, and
/// adding a product `0 * b` (`b` finite) to a sum changes at most the sign of a zero sum: the
/// same bits as `a * p * a.transpose() + q` (test `sparse_step_equals_the_dense_one_bit_for_bit`
/// compares the bits).
fn predicted_covariance(a: &DriveMatrix, p: &DriveMatrix, q: &DriveMatrix) -> DriveMatrix {
    debug_assert!((0..5).all(|i| (0..5).all(|k| {
        let mut e = [0.0; 5];
        e[k] = 1.0;
        a_row_times(a, i, &e) == a[(i, k)]
    })));
    // The rows of `A P`: entry (i, j) is row i of `A` times column j of `P`.
    let mut ap = [[0.0; 5]; 5];
    for j in 0..5 {
        let p_col: [f64; 5] = p.fixed_columns::<1>(j).into_owned().into();
        for (i, row) in ap.iter_mut().enumerate() {
            row[j] = a_row_times(a, i, &p_col);
        }
    }
    // `(A P) A'`: entry (i, j) is row j of `A` times row i of `A P`.
    let mut apa = DriveMatrix::zeros();
    for (i, ap_row) in ap.iter().enumerate() {
        for j in 0..5 {
            apa[(i, j)] = a_row_times(a, j, ap_row);
        }
    }
    // All of `Q`, its zeros too, as the dense sum does (`-0 + 0` is `+0`).
    apa + q
}

/// The Cholesky factor `L = [l00 0; l10 l11]` of a 2 x 2 innovation covariance, with the
/// solves `S z = b` the update needs. The same operations in the same order as nalgebra's
/// `Cholesky::new` and `Cholesky::solve` for a 2 x 2 matrix (the same bits, test
/// `sparse_step_equals_the_dense_one_bit_for_bit`), written out: nalgebra's generic solves are
/// not inlined and cost as much as the rest of the update.
#[derive(Clone, Copy)]
struct Cholesky2 {
    l00: f64,
    l10: f64,
    l11: f64,
}

impl Cholesky2 {
    /// `None` unless `S` is positive definite (a diagonal pivot not `> 0`, NaN included).
    fn new(s: &Matrix2<f64>) -> Option<Self> {
        let s00 = s[(0, 0)];
        if s00.is_nan() || s00 <= 0.0 {
            return None;
        }
        let l00 = s00.sqrt();
        let l10 = s[(1, 0)] / l00;
        let d1 = s[(1, 1)] - l10 * l10;
        if d1.is_nan() || d1 <= 0.0 {
            return None;
        }
        Some(Cholesky2 {
            l00,
            l10,
            l11: d1.sqrt(),
        })
    }

    /// `S^-1 b`: `L y = b` forward, then `L' z = y` backward.
    fn solve(&self, b0: f64, b1: f64) -> (f64, f64) {
        let y0 = b0 / self.l00;
        let y1 = (b1 - y0 * self.l10) / self.l11;
        let z1 = y1 / self.l11;
        // nalgebra's dot product starts from +0 (`+0 + -0` is `+0`).
        let dot = 0.0 + self.l10 * z1;
        let z0 = (y0 - dot) / self.l00;
        (z0, z1)
    }

    /// `log det S = 2 (log l00 + log l11)`.
    fn log_det(&self) -> f64 {
        2.0 * (self.l00.ln() + self.l11.ln())
    }
}

/// The posterior and likelihood of the update with `C = [I_2 0]`.
struct CurrentUpdate {
    x: DriveState,
    p: DriveMatrix,
    log_likelihood: f64,
}

#[inline(always)]
/// `railmon_filter::kalman::update_joseph` for `C = [I_2 0]`: `P C'` is the first two columns
/// of `P`, and `I - K C` differs from `I` in its first two columns only.
fn update_currents(
    x: &DriveState,
    p: &DriveMatrix,
    innovation: &Vector2<f64>,
    r: &Matrix2<f64>,
) -> Result<CurrentUpdate, railmon_filter::FilterError> {
    use railmon_filter::FilterError;
    let ph_t = p.fixed_columns::<2>(idx::I_ALPHA).into_owned();
    let mut s = ph_t.fixed_rows::<2>(idx::I_ALPHA).into_owned() + r;
    symmetrize(&mut s);
    let chol = Cholesky2::new(&s).ok_or(FilterError::InnovationNotPositiveDefinite)?;
    // K = P C' S^-1, row by row: S^-1 times each row of P C' (S is symmetric).
    let mut k = SMatrix::<f64, 5, 2>::zeros();
    for j in 0..5 {
        let (k0, k1) = chol.solve(ph_t[(j, 0)], ph_t[(j, 1)]);
        k[(j, 0)] = k0;
        k[(j, 1)] = k1;
    }
    let x_post = x + k * innovation;
    // The first two columns of I - K C (the others are those of I).
    let mut i_kh = -k;
    i_kh[(0, 0)] += 1.0;
    i_kh[(1, 1)] += 1.0;
    // (I - K C) P: the first two columns of I - K C times the first two rows of P, plus the
    // rows 2-4 of P (the identity's part), term for term the dense product's sum.
    let mut t = i_kh * p.fixed_rows::<2>(idx::I_ALPHA);
    t.fixed_rows_mut::<3>(idx::OMEGA)
        .iter_mut()
        .zip(p.fixed_rows::<3>(idx::OMEGA).iter())
        .for_each(|(t, p)| *t += p);
    // ((I - K C) P) (I - K C)', the same way.
    let mut p_post = t.fixed_columns::<2>(idx::I_ALPHA) * i_kh.transpose();
    p_post
        .fixed_columns_mut::<3>(idx::OMEGA)
        .iter_mut()
        .zip(t.fixed_columns::<3>(idx::OMEGA).iter())
        .for_each(|(q, t)| *q += t);
    p_post += k * r * k.transpose();
    symmetrize(&mut p_post);

    let (z0, z1) = chol.solve(innovation[0], innovation[1]);
    let mahalanobis = innovation[0] * z0 + innovation[1] * z1;
    let log_likelihood = -0.5 * (2.0 * LN_2PI + chol.log_det() + mahalanobis);
    if !log_likelihood.is_finite() || x_post.iter().any(|v| !v.is_finite()) {
        return Err(FilterError::NonFinite {
            what: "Kalman update",
        });
    }
    Ok(CurrentUpdate {
        x: x_post,
        p: p_post,
        log_likelihood,
    })
}

/// The same step with dense products and the general Joseph update
/// (`railmon_filter::kalman::update_joseph`): the textbook form, kept as the reference the
/// fast [`ekf_step`] is tested and benchmarked against.
pub fn ekf_step_dense(
    model: &DriveModel,
    q: &DriveMatrix,
    r: &Matrix2<f64>,
    f: &DriveFilter,
    sample: &DriveSample,
) -> Result<DriveFilter, railmon_filter::FilterError> {
    let (x_pred, p_pred) = match f.u_prev {
        Some(u) => {
            let a = model.jacobian(&f.x);
            let mut p = a * f.p * a.transpose() + q;
            symmetrize(&mut p);
            (model.transition(&f.x, &u), p)
        }
        None => (f.x, f.p),
    };
    let innovation = Vector2::new(
        sample.i_alpha_a - x_pred[idx::I_ALPHA],
        sample.i_beta_a - x_pred[idx::I_BETA],
    );
    let upd = update_joseph(&x_pred, &p_pred, &innovation, &measurement_matrix(), r)?;
    let mut x = upd.x;
    x[idx::THETA] = wrap_angle(x[idx::THETA]);
    Ok(DriveFilter {
        x,
        p: upd.p,
        u_prev: Some(Vector2::new(sample.u_alpha_v, sample.u_beta_v)),
        log_likelihood: upd.log_likelihood,
        frames: f.frames + 1,
    })
}

/// Electrical speed and angle at step t from the currents at t and t+1 and the voltage over
/// the step: rows 1-2 of eq. (11) give `theta_b omega [sin theta, -cos theta] = i(t+1) -
/// theta_a i(t) - (dt / L_s) u(t)`. The back-EMF does not tell the direction of rotation:
/// `(omega, theta)` and `(-omega, theta + pi)` give the same currents, so `forward` picks it.
pub fn back_emf_speed_angle(
    model: &DriveModel,
    i_now: &Vector2<f64>,
    u_now: &Vector2<f64>,
    i_next: &Vector2<f64>,
    forward: bool,
) -> (f64, f64) {
    let d = (i_next - i_now * model.theta_a - u_now * model.theta_c) / model.theta_b;
    let speed = d.norm();
    if forward {
        (speed, d[0].atan2(-d[1]))
    } else {
        (-speed, (-d[0]).atan2(d[1]))
    }
}

/// The filter after its first frame, with speed and angle replaced by the back-EMF estimate
/// from that frame and `next` (the covariance keeps its initial values).
fn start_from_back_emf(
    model: &DriveModel,
    f: &DriveFilter,
    next: &DriveSample,
    forward: bool,
) -> DriveFilter {
    let Some(u) = f.u_prev else { return *f };
    let i_now = Vector2::new(f.x[idx::I_ALPHA], f.x[idx::I_BETA]);
    let i_next = Vector2::new(next.i_alpha_a, next.i_beta_a);
    let (speed, angle) = back_emf_speed_angle(model, &i_now, &u, &i_next, forward);
    let mut started = *f;
    started.x[idx::OMEGA] = speed;
    started.x[idx::THETA] = wrap_angle(angle);
    started
}

/// N independent drive EKFs (the block-diagonal filter of eq. 16-17).
#[derive(Debug, Serialize, Deserialize)]
pub struct EkfBank {
    model: DriveModel,
    q: DriveMatrix,
    r: Matrix2<f64>,
    filters: Vec<DriveFilter>,
    scratch: Vec<DriveFilter>,
    /// `Some(forward)` when the second frame restarts speed and angle from the back-EMF.
    back_emf_start: Option<bool>,
    /// Every drive's filter before its first frame (the configured guesses), for
    /// [`EkfBank::relock`].
    initial: DriveFilter,
}

/// The longest gap (s) without frames that [`EkfBank::bridge`] predicts the filters through;
/// after a longer one they relock from the back-EMF as at start. Over a gap `T` the prediction
/// holds the speed, so a rotor accelerating at `a` (electrical rad/s^2) ends `a T^2 / 2` off in
/// angle: at 0.05 s and ~70 rad/s^2 (a motor of 4 pole pairs behind a 5:1 gear, the train at
/// 1.5 m/s^2) 0.09 rad, well inside what the update corrects; at 1 s (a restart of the
/// service) radians, and the filter can lock onto the wrong direction of rotation.
pub const MAX_PREDICTED_GAP_S: f64 = 0.0005;

impl Clone for EkfBank {
    fn clone(&self) -> Self {
        EkfBank {
            model: self.model,
            q: self.q,
            r: self.r,
            filters: self.filters.clone(),
            scratch: self.scratch.clone(),
            back_emf_start: self.back_emf_start,
            initial: self.initial,
        }
    }

    /// Copies without allocating when the sizes match (the monitor's per-frame backup). The
    /// scratch space is written before it is read at every step, so only its size is copied.
    fn clone_from(&mut self, source: &Self) {
        self.model = source.model;
        self.q = source.q;
        self.r = source.r;
        self.filters.clone_from(&source.filters);
        if self.scratch.len() != source.scratch.len() {
            self.scratch.clone_from(&source.scratch);
        }
        self.back_emf_start = source.back_emf_start;
        self.initial = source.initial;
    }
}

impl EkfBank {
    pub fn new(model: DriveModel, config: &EkfConfig, n_drives: usize) -> Result<Self, SlipError> {
        config.validate("ekf")?;
        if n_drives == 0 {
            return Err(SlipError::invalid("n_drives", 0, "must be >= 1"));
        }
        let initial = DriveFilter::initial(config);
        let filters = vec![initial; n_drives];
        Ok(EkfBank {
            initial,
            model,
            q: config.q(),
            r: Matrix2::identity() * config.measurement_noise_a2,
            scratch: filters.clone(),
            filters,
            back_emf_start: config
                .start_from_back_emf
                .then_some(config.initial_speed_rad_s >= 0.0),
        })
    }

    pub fn n_drives(&self) -> usize {
        self.filters.len()
    }

    pub fn filters(&self) -> &[DriveFilter] {
        &self.filters
    }

    pub fn model(&self) -> &DriveModel {
        &self.model
    }

    /// Whether [`EkfBank::bridge`] over `missing_steps` relocks the filters (longer than
    /// [`MAX_PREDICTED_GAP_S`]).
    pub fn relocks_after(&self, missing_steps: u64) -> bool {
        missing_steps as f64 * self.model.dt_s > MAX_PREDICTED_GAP_S
    }

    /// Carries every filter over `missing_steps` sample periods that no frame covered (a
    /// sample lost at the source, a restart of the service): predicted through them (eq. 3-4,
    /// the voltage held in the rotor's frame) up to [`MAX_PREDICTED_GAP_S`], else relocked
    /// ([`EkfBank::relock`]). Returns whether the filters relocked.
    pub fn bridge(&mut self, missing_steps: u64) -> bool {
        if self.relocks_after(missing_steps) {
            self.relock();
            return true;
        }
        for f in &mut self.filters {
            let Some(u_last) = f.u_prev else { continue };
            let angle_last = f.x[idx::THETA];
            for _ in 0..missing_steps {
                // The inverter holds its voltage in the rotor's frame, not in the stator's
                // (alpha, beta), where it turns with the rotor: hold it in the rotor's frame.
                let (sin, cos) = (f.x[idx::THETA] - angle_last).sin_cos();
                let u = Vector2::new(
                    cos * u_last[0] - sin * u_last[1],
                    sin * u_last[0] + cos * u_last[1],
                );
                let (mut x, a) = self.model.transition_and_jacobian(&f.x, &u);
                x[idx::THETA] = wrap_angle(x[idx::THETA]);
                f.p = a * f.p * a.transpose() + self.q;
                symmetrize(&mut f.p);
                f.x = x;
            }
        }
        false
    }

    /// Starts every filter again from its configured guesses, speed and angle found from the
    /// back-EMF of the next two frames (when `ekf.start_from_back_emf`), turning the way the
    /// drives turned (the sign of their median speed): after a gap the speed and angle
    /// cannot be predicted over.
    pub fn relock(&mut self) {
        let mut speeds: Vec<f64> = self.filters.iter().map(|f| f.speed_rad_s()).collect();
        speeds.sort_by(f64::total_cmp);
        let forward = speeds[speeds.len() / 2] >= 0.0;
        self.back_emf_start = self.back_emf_start.map(|_| forward);
        self.filters.fill(self.initial);
    }

    /// One step of every drive. The frame is validated first and all filters are computed
    /// before any is committed: on error the bank is unchanged.
    pub fn step(&mut self, samples: &[DriveSample]) -> Result<(), SlipError> {
        validate_frame(samples, self.filters.len())?;
        for (k, ((f, s), out)) in self
            .filters
            .iter()
            .zip(samples)
            .zip(self.scratch.iter_mut())
            .enumerate()
        {
            let start;
            let f = match self.back_emf_start {
                Some(forward) if f.frames == 1 => {
                    start = start_from_back_emf(&self.model, f, s, forward);
                    &start
                }
                _ => f,
            };
            ekf_step_into(&self.model, &self.q, &self.r, f, s, out).map_err(|source| {
                SlipError::Filter {
                    drive: k + 1,
                    source,
                }
            })?;
        }
        // Every update succeeded: only now is the bank changed.
        std::mem::swap(&mut self.filters, &mut self.scratch);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::MotorParams;

    #[test]
    fn each_invalid_ekf_parameter_is_rejected() {
        let bad = |m: fn(&mut EkfConfig), field: &str| {
            let mut c = EkfConfig::default();
            m(&mut c);
            let e = c.validate("ekf").unwrap_err().to_string();
            assert!(e.contains(field), "{e}");
        };
        bad(
            |c| c.process_noise_diag[2] = 0.0,
            "ekf.process_noise_diag[2]",
        );
        bad(
            |c| c.measurement_noise_a2 = -0.01,
            "ekf.measurement_noise_a2",
        );
        bad(
            |c| c.initial_covariance_diag[4] = f64::NAN,
            "ekf.initial_covariance_diag[4]",
        );
        bad(
            |c| c.initial_speed_rad_s = f64::INFINITY,
            "ekf.initial_speed_rad_s",
        );
        bad(|c| c.initial_angle_rad = f64::NAN, "ekf.initial_angle_rad");
        bad(
            |c| c.initial_torque_nm = f64::NEG_INFINITY,
            "ekf.initial_torque_nm",
        );
        let model = DriveModel::new(MotorParams::default(), 125e-6).unwrap();
        assert!(EkfBank::new(model, &EkfConfig::default(), 0).is_err());
    }

    #[test]
    fn back_emf_gives_speed_and_angle_and_both_directions() {
        let model = DriveModel::new(MotorParams::default(), 125e-6).unwrap();
        let u = Vector2::new(30.0, -12.0);
        for (speed, angle) in [(200.0, 0.7), (-150.0, -2.5), (80.0, 3.0)] {
            let x = DriveState::new(3.0, -4.0, speed, angle, 10.0);
            let next = model.transition(&x, &u);
            let i_now = Vector2::new(x[0], x[1]);
            let i_next = Vector2::new(next[0], next[1]);
            let forward = speed > 0.0;
            let (w, th) = back_emf_speed_angle(&model, &i_now, &u, &i_next, forward);
            assert!((w - speed).abs() < 1e-9, "{w} vs {speed}");
            assert!(wrap_angle(th - angle).abs() < 1e-9, "{th} vs {angle}");
            // The other direction is the mirrored solution.
            let (w2, th2) = back_emf_speed_angle(&model, &i_now, &u, &i_next, !forward);
            assert!((w2 + speed).abs() < 1e-9);
            assert!((wrap_angle(th2 - angle).abs() - std::f64::consts::PI).abs() < 1e-9);
        }
    }

    #[test]
    fn first_step_is_a_pure_update_and_covariance_stays_spd() {
        let model = DriveModel::new(MotorParams::default(), 125e-6).unwrap();
        let config = EkfConfig::default();
        let config = EkfConfig {
            start_from_back_emf: false,
            ..config
        };
        let mut bank = EkfBank::new(model, &config, 2).unwrap();
        let s = DriveSample {
            u_alpha_v: 10.0,
            u_beta_v: -5.0,
            i_alpha_a: 2.0,
            i_beta_a: -1.0,
        };
        bank.step(&[s, s]).unwrap();
        // Scalar update of i_alpha from prior N(0, 1) with R = 0.01: gain 1 / 1.01.
        let f = bank.filters()[0];
        assert!((f.x[idx::I_ALPHA] - 2.0 / 1.01).abs() < 1e-12);
        assert!((f.p[(0, 0)] - 0.01 / 1.01).abs() < 1e-12);
        assert_eq!(f.u_prev, Some(Vector2::new(10.0, -5.0)));
        for _ in 0..100 {
            bank.step(&[s, s]).unwrap();
            for f in bank.filters() {
                assert!(railmon_filter::kalman::is_symmetric_positive_definite(
                    &f.p, 1e-12
                ));
                assert!(
                    f.angle_rad() > -std::f64::consts::PI && f.angle_rad() <= std::f64::consts::PI
                );
            }
        }
    }
}
