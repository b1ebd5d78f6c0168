//! A per-drive test on the measured currents' innovations with the load *known* (issue 23
//! item 1, seventh round): the information bound's own filter (`bound.rs`,
//! [`crate::bound::LoadChangeInformation`]) run live. Each drive has a 4-state Kalman
//! filter (currents, electrical speed, angle; eq. 11 without the torque state) whose load is
//! an input, the drive's healthy level from the group (`M + b_i`). A loss of adhesion is a
//! departure `delta` of the true load from that input; it reaches the innovations through
//! the speed and its back-EMF, with mean `C eps_t`, `eps_(t+1) = A (I - K C) eps_t - theta_l
//! e_omega delta` (Willsky and Jones, IEEE TAC 21(1), 1976). The GLR over onsets kept in a
//! bank (one every `stride` steps, each followed for `window` steps) gives, per onset, the
//! departure's estimate `a / b` and its log-likelihood ratio `a^2 / (2 b)`, with
//! `a = sum m' S^-1 nu`, `b = sum m' S^-1 m`, `m = C eps`.

use nalgebra::{Matrix2, SMatrix, SVector, Vector2};

use crate::adhesion::TemporalEstimator;
use crate::ekf::{DriveFilter, EkfBank};
use crate::model::{idx, wrap_angle, DriveModel, DriveState};
use crate::sample::DriveSample;

type State4 = SVector<f64, 4>;
type Matrix4 = SMatrix<f64, 4, 4>;

/// One drive's known-load filter and its bank of onsets.
#[derive(Debug, Clone)]
pub struct KnownLoadFilter {
    x: State4,
    p: Matrix4,
    /// Per onset slot: signature `eps` (per N m of departure), `a`, `b`, age in steps.
    eps: Vec<State4>,
    a: Vec<f64>,
    b: Vec<f64>,
    age: Vec<usize>,
    /// Learnt variance of each current's innovation beyond `C P C'` (A^2): the sensor noise.
    r_a2: f64,
    u_prev: Option<Vector2<f64>>,
    load_prev_nm: f64,
    pub steps: usize,
}

/// Settings of the bank (temporary, the experiment's).
#[derive(Debug, Clone, Copy)]
pub struct InnovationConfig {
    pub q_diag: [f64; 4],
    pub initial_r_a2: f64,
    pub r_memory_steps: f64,
    pub window_steps: usize,
    pub stride_steps: usize,
}

impl Default for InnovationConfig {
    fn default() -> Self {
        InnovationConfig {
            q_diag: [1e-5, 1e-5, 1e-4, 1e-6],
            initial_r_a2: 1e-4,
            r_memory_steps: 2000.0,
            window_steps: 64,
            stride_steps: 4,
        }
    }
}

impl KnownLoadFilter {
    pub fn new(config: &InnovationConfig) -> Self {
        let slots = config.window_steps.div_ceil(config.stride_steps);
        KnownLoadFilter {
            x: State4::zeros(),
            p: Matrix4::identity(),
            eps: vec![State4::zeros(); slots],
            a: vec![0.0; slots],
            b: vec![0.0; slots],
            age: vec![usize::MAX; slots],
            r_a2: config.initial_r_a2,
            u_prev: None,
            load_prev_nm: 0.0,
            steps: 0,
        }
    }

    /// Restart from the EKF's state (currents, speed, angle and their covariance); the bank
    /// forgets every onset.
    pub fn sync(&mut self, f: &DriveFilter) {
        self.x = f.x.fixed_rows::<4>(0).into_owned();
        self.p = f.p.fixed_view::<4, 4>(0, 0).into_owned();
        self.u_prev = f.u_prev;
        self.age.fill(usize::MAX);
        self.steps = 0;
    }

    /// One step: `load_nm` the known load over the coming step, `current` the measured
    /// currents of this step, `u` the voltage applied from now, `flagged` whether the drive
    /// is judged slipping (the noise is then not learnt).
    #[allow(clippy::too_many_arguments)]
    pub fn step(
        &mut self,
        model: &DriveModel,
        config: &InnovationConfig,
        global_step: usize,
        current: Vector2<f64>,
        u: Vector2<f64>,
        load_nm: f64,
        learn: bool,
    ) {
        let g = -model.theta_l;
        if let Some(u_prev) = self.u_prev {
            let x5 = DriveState::new(
                self.x[0],
                self.x[1],
                self.x[2],
                self.x[3],
                self.load_prev_nm,
            );
            let (xp, a5) = model.transition_and_jacobian(&x5, &u_prev);
            let a: Matrix4 = a5.fixed_view::<4, 4>(0, 0).into_owned();
            self.x = xp.fixed_rows::<4>(0).into_owned();
            self.p =
                a * self.p * a.transpose() + Matrix4::from_diagonal(&State4::from(config.q_diag));
            for (e, age) in self.eps.iter_mut().zip(&mut self.age) {
                if *age != usize::MAX {
                    *e = a * *e;
                    e[idx::OMEGA] += g;
                    *age += 1;
                }
            }
        }
        let nu = Vector2::new(current[0] - self.x[0], current[1] - self.x[1]);
        let cpc = self.p.fixed_view::<2, 2>(0, 0).into_owned();
        let s = cpc + Matrix2::identity() * self.r_a2;
        let Some(s_inv) = s.try_inverse() else {
            return;
        };
        let s_inv_nu = s_inv * nu;
        for ((e, age), (a, b)) in self
            .eps
            .iter()
            .zip(&self.age)
            .zip(self.a.iter_mut().zip(self.b.iter_mut()))
        {
            if *age != usize::MAX {
                let m = Vector2::new(e[0], e[1]);
                *a += m.dot(&s_inv_nu);
                *b += m.dot(&(s_inv * m));
            }
        }
        let pc: SMatrix<f64, 4, 2> = self.p.fixed_view::<4, 2>(0, 0).into_owned();
        let k = pc * s_inv;
        self.x += k * nu;
        self.x[3] = wrap_angle(self.x[3]);
        let mut i_kc = Matrix4::identity();
        i_kc.fixed_view_mut::<4, 2>(0, 0).copy_from(&(-k));
        i_kc[(0, 0)] += 1.0;
        i_kc[(1, 1)] += 1.0;
        self.p =
            i_kc * self.p * i_kc.transpose() + k * Matrix2::identity() * self.r_a2 * k.transpose();
        self.p = (self.p + self.p.transpose()) * 0.5;
        for (e, age) in self.eps.iter_mut().zip(&self.age) {
            if *age != usize::MAX {
                *e = i_kc * *e;
            }
        }
        if learn {
            let excess = 0.5 * (nu.norm_squared() - cpc.trace());
            let rate = 1.0 / config.r_memory_steps;
            self.r_a2 = ((1.0 - rate) * self.r_a2 + rate * excess).max(1e-7);
        }
        // A new onset over the coming step, in the slot of the oldest.
        if global_step % config.stride_steps == 0 {
            let slot = (global_step / config.stride_steps) % self.eps.len();
            self.eps[slot] = State4::zeros();
            self.a[slot] = 0.0;
            self.b[slot] = 0.0;
            self.age[slot] = 0;
        }
        self.u_prev = Some(u);
        self.load_prev_nm = load_nm;
        self.steps += 1;
    }

    /// Per slot: the departure's estimate (N m) and the information `b` (None: no data yet).
    pub fn slot(&self, j: usize) -> Option<(f64, f64)> {
        (self.age[j] != usize::MAX && self.age[j] > 0 && self.b[j] > 0.0)
            .then(|| (self.a[j] / self.b[j], self.b[j]))
    }

    pub fn slots(&self) -> usize {
        self.eps.len()
    }
}

fn env_f64(name: &str, default: f64) -> f64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// The bank of every drive's known-load filter and the group's comparison of their
/// departures (experiment: `RAILMON_INNOV=1`).
#[derive(Debug, Clone)]
pub struct InnovationBank {
    config: InnovationConfig,
    filters: Vec<KnownLoadFilter>,
    quiet: Vec<usize>,
    step: usize,
    threshold: f64,
    min_steps: usize,
    hold_steps: usize,
    warmup_steps: usize,
    raised: f64,
    fired: Vec<bool>,
    reference: Vec<f64>,
    history: std::collections::VecDeque<f64>,
    lag: usize,
    plain: bool,
    debug: bool,
}

impl InnovationBank {
    pub fn from_env(n_drives: usize) -> Option<Self> {
        std::env::var("RAILMON_INNOV").ok()?;
        let mut config = InnovationConfig::default();
        config.window_steps = env_f64("RAILMON_INNOV_WINDOW", 64.0) as usize;
        config.stride_steps = env_f64("RAILMON_INNOV_STRIDE", 4.0) as usize;
        config.initial_r_a2 = env_f64("RAILMON_INNOV_R0", 1e-4);
        config.q_diag[2] = env_f64("RAILMON_INNOV_QW", 1e-4);
        let qi = env_f64("RAILMON_INNOV_QI", 1e-5);
        config.q_diag[0] = qi;
        config.q_diag[1] = qi;
        Some(InnovationBank {
            filters: vec![KnownLoadFilter::new(&config); n_drives],
            config,
            quiet: vec![0; n_drives],
            step: 0,
            threshold: env_f64("RAILMON_INNOV_H", 12.0),
            min_steps: env_f64("RAILMON_INNOV_MIN_STEPS", 200.0) as usize,
            hold_steps: env_f64("RAILMON_INNOV_HOLD", 100.0) as usize,
            warmup_steps: 600,
            raised: env_f64("RAILMON_INNOV_P", 0.99),
            fired: vec![false; n_drives],
            reference: Vec::new(),
            history: std::collections::VecDeque::new(),
            plain: std::env::var("RAILMON_INNOV_PLAIN").is_ok(),
            debug: std::env::var("RAILMON_INNOV_DEBUG").is_ok(),
            lag: env_f64("RAILMON_INNOV_LAG", 0.0) as usize,
        })
    }

    pub fn step(&mut self, bank: &EkfBank, samples: &[DriveSample], est: &mut TemporalEstimator) {
        let model = *bank.model();
        let out = est.output();
        let m = out.global_torque_nm;
        self.history.push_back(m);
        if self.history.len() > self.lag + 1 {
            self.history.pop_front();
        }
        let m_known = self.history[0];
        let warm = self.step >= self.warmup_steps;
        for (k, f) in self.filters.iter_mut().enumerate() {
            let p = out.slip_probability[k];
            if !warm || p > 0.5 || self.quiet[k] > 0 {
                f.sync(&bank.filters()[k]);
                self.quiet[k] = if p > 0.5 {
                    self.hold_steps
                } else {
                    self.quiet[k].saturating_sub(1)
                };
                continue;
            }
            let s = &samples[k];
            let load = m_known + est.offset_nm()[k];
            f.step(
                &model,
                &self.config,
                self.step,
                Vector2::new(s.i_alpha_a, s.i_beta_a),
                Vector2::new(s.u_alpha_v, s.u_beta_v),
                load,
                true,
            );
        }
        self.step += 1;
        let dir = if m.abs() > 0.5 { m.signum() } else { 0.0 };
        self.fired.fill(false);
        if dir == 0.0 {
            return;
        }
        let slots = self.filters[0].slots();
        self.reference.clear();
        for j in 0..slots {
            let top = self
                .filters
                .iter()
                .filter(|f| f.steps >= self.min_steps)
                .filter_map(|f| f.slot(j))
                .map(|(d, _)| dir * d)
                .fold(f64::NEG_INFINITY, f64::max);
            self.reference.push(top.min(0.0).max(f64::NEG_INFINITY));
        }
        let mut raise = Vec::new();
        for (k, f) in self.filters.iter().enumerate() {
            if f.steps < self.min_steps {
                continue;
            }
            let tol = (0.1 * (m + est.offset_nm()[k]).abs()).max(0.5);
            for j in 0..slots {
                let (Some((d, b)), r) = (f.slot(j), self.reference[j]) else {
                    continue;
                };
                if !r.is_finite() {
                    continue;
                }
                let rel = dir * d - r;
                let margin = if self.plain { 0.0 } else { tol };
                if rel < -tol && 0.5 * b * (rel + margin).powi(2) > self.threshold {
                    if self.debug {
                        eprintln!(
                            "fire step {} drive {} slot {} rel {:.2} b {:.3} r {:.2e} m {:.2}",
                            self.step,
                            k + 1,
                            j,
                            rel,
                            b,
                            f.r_a2,
                            m
                        );
                    }
                    raise.push(k);
                    break;
                }
            }
        }
        for k in raise {
            self.fired[k] = true;
            est.raise_probability(k, self.raised);
        }
    }
}
