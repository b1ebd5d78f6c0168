//! The Rao-Blackwellised particle filter of section 4: particles carry only the log damping
//! coefficients; each has a Kalman filter for the 17 states (marginalised analytically), whose
//! predictive likelihood weights it (eq. 22). Parameters move by the Liu-West kernel (eq. 24)
//! on their logarithms; systematic resampling when the effective sample size drops.
//!
//! Two ways to run the per-particle filters (`Propagation`):
//! - `Exact`: `Phi(theta_i), Gamma(theta_i)` by the matrix exponential, full covariance,
//!   Joseph update: the paper's algorithm as written.
//! - `SteadyState`: the state is propagated exactly (`Phi(theta_i) x` by a Taylor series of the
//!   sparse `A(theta_i)`: 44 non-zeros, two damper rows), the gain and innovation covariance
//!   are the Riccati steady state of `theta_i`, interpolated from a `GainTable`. Particles are
//!   stored structure-of-arrays (`x[state * N + particle]`) so the propagation runs as long
//!   vectorisable loops over particles.

use std::sync::Arc;

use nalgebra::Matrix2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use crate::config::{DamperMonitorConfig, KernelSchedule, Propagation, RbpfConfig};
use crate::expm::discretize;
use crate::gain_table::{GainTable, LN_DET_OFFSET, NODE_LEN, S_INV_OFFSET};
use crate::kalman::{self, NoiseCovariances, StateEstimate};
use crate::model::{
    state, BogieModel, Matrix17, Matrix17x2, Matrix5x17, Vector17, Vector5, N_OUTPUTS, N_STATES,
};
use crate::params::Dampers;
use crate::DamperError;
use railmon_filter::kalman::LN_2PI;
use railmon_filter::logspace::{effective_sample_size, normalize_log_weights};
use railmon_filter::resample::systematic_resample;

/// Posterior summary of one damper coefficient.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DamperPosterior {
    /// Posterior mean (N s/m).
    pub mean_ns_per_m: f64,
    /// 5% and 95% quantiles (N s/m).
    pub q05_ns_per_m: f64,
    pub q95_ns_per_m: f64,
    /// Mean / nominal.
    pub health_ratio: f64,
}

/// What the RBPF says after a step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RbpfEstimate {
    pub csy: DamperPosterior,
    pub csay: DamperPosterior,
    pub effective_sample_size: f64,
}

/// `A(theta) x` with `A` sparse, plus `H x`: the structure the fast filter exploits.
#[derive(Debug, Clone)]
pub struct SparsePropagator {
    /// Non-zeros of the plant `A` without its damper terms and without the drift leak.
    entries: Vec<(usize, usize, f64)>,
    /// Non-zeros of `H` as `(output, state, value)`.
    h_entries: Vec<(usize, usize, f64)>,
    dt_s: f64,
    order: usize,
    /// `exp(-eps T) - 1`: the leak as a projector update (model docs).
    leak: f64,
    drift_basis: Matrix17x2,
    /// Rows where the drift basis is non-zero.
    drift_rows: Vec<usize>,
}

impl SparsePropagator {
    pub fn new(model: &BogieModel, dt_s: f64, order: usize) -> Result<Self, DamperError> {
        let plant = BogieModel::new(model.params(), 0.0)?;
        let mut a = plant.a_matrix(&Dampers::NOMINAL);
        a[(state::PSIB_DOT, state::PSIB_DOT)] = 0.0;
        a[(state::YSR, state::YB)] = 0.0;
        a[(state::YSR, state::YSR)] = 0.0;
        let sparse = |m: &[(usize, usize)], get: &dyn Fn(usize, usize) -> f64| {
            m.iter()
                .map(|&(r, c)| (r, c, get(r, c)))
                .filter(|e| e.2 != 0.0)
                .collect::<Vec<_>>()
        };
        let all: Vec<(usize, usize)> = (0..N_STATES)
            .flat_map(|r| (0..N_STATES).map(move |c| (r, c)))
            .collect();
        let h = model.h_matrix();
        let h_all: Vec<(usize, usize)> = (0..N_OUTPUTS)
            .flat_map(|r| (0..N_STATES).map(move |c| (r, c)))
            .collect();
        let drift_basis = *model.drift_basis();
        Ok(SparsePropagator {
            entries: sparse(&all, &|r, c| a[(r, c)]),
            h_entries: sparse(&h_all, &|r, c| h[(r, c)]),
            dt_s,
            order,
            leak: (-model.drift_leak_per_s() * dt_s).exp_m1(),
            drift_rows: (0..N_STATES)
                .filter(|&r| drift_basis.row(r).amax() > 0.0)
                .collect(),
            drift_basis,
        })
    }

    /// `out = Phi_f(theta_i) x` for all `n` particles (structure-of-arrays), where
    /// `yaw[i]`, `series[i]` are the damper entries of particle `i` (`DamperEntries`).
    /// `term`, `next` are scratch of the same length as `x`.
    #[allow(clippy::too_many_arguments)]
    pub fn propagate(
        &self,
        n: usize,
        x: &[f64],
        yaw: &[f64],
        series: &[f64],
        out: &mut [f64],
        term: &mut [f64],
        next: &mut [f64],
    ) {
        let (mut term, mut next) = (term, next);
        out.copy_from_slice(x);
        term.copy_from_slice(x);
        for k in 1..=self.order {
            let s = self.dt_s / k as f64;
            next.fill(0.0);
            for &(r, c, v) in &self.entries {
                let sv = s * v;
                let dst = &mut next[r * n..(r + 1) * n];
                let src = &term[c * n..(c + 1) * n];
                for (d, t) in dst.iter_mut().zip(src) {
                    *d += sv * t;
                }
            }
            // The two damper rows, per particle.
            let (head, tail) = next.split_at_mut(state::YSR * n);
            let yaw_row = &mut head[state::PSIB_DOT * n..(state::PSIB_DOT + 1) * n];
            let psib_dot = &term[state::PSIB_DOT * n..(state::PSIB_DOT + 1) * n];
            for i in 0..n {
                yaw_row[i] += s * yaw[i] * psib_dot[i];
            }
            let ysr_row = &mut tail[..n];
            let yb = &term[state::YB * n..(state::YB + 1) * n];
            let ysr = &term[state::YSR * n..(state::YSR + 1) * n];
            for i in 0..n {
                ysr_row[i] += s * series[i] * (yb[i] - ysr[i]);
            }
            for (o, v) in out.iter_mut().zip(next.iter()) {
                *o += v;
            }
            std::mem::swap(&mut term, &mut next);
        }
        // Drift leak: out += (exp(-eps T) - 1) V W out (A and V W commute).
        for i in 0..n {
            let w0 = out[state::YW1 * n + i] - out[state::D1 * n + i];
            let w1 = out[state::YW2 * n + i] - out[state::D2 * n + i];
            for &r in &self.drift_rows {
                out[r * n + i] +=
                    self.leak * (self.drift_basis[(r, 0)] * w0 + self.drift_basis[(r, 1)] * w1);
            }
        }
    }

    /// `y - H x` of particle `i`.
    #[inline]
    pub fn innovation(&self, n: usize, x: &[f64], i: usize, y: &Vector5) -> Vector5 {
        let mut e = *y;
        for &(m, c, v) in &self.h_entries {
            e[m] -= v * x[c * n + i];
        }
        e
    }
}

/// Per-particle filters, exact or steady-state.
#[derive(Debug, Clone)]
enum Bank {
    Exact(Box<ExactBank>),
    Steady(Box<SteadyBank>),
}

#[derive(Debug, Clone)]
struct ExactBank {
    model: BogieModel,
    h: Matrix5x17,
    noise: NoiseCovariances,
    dt_s: f64,
    est: Vec<StateEstimate>,
    next: Vec<StateEstimate>,
}

#[derive(Debug, Clone)]
struct SteadyBank {
    n: usize,
    prop: SparsePropagator,
    table: Arc<GainTable>,
    csay_gain: f64,
    end_stiffness: f64,
    /// Posterior states, structure-of-arrays.
    x: Vec<f64>,
    /// The step's new posterior states (committed by swapping with `x`).
    next: Vec<f64>,
    term: Vec<f64>,
    scratch: Vec<f64>,
    yaw: Vec<f64>,
    series: Vec<f64>,
    /// Per particle: the interpolated gain node and the `ln theta` it was computed for
    /// (recomputed only when the particle's parameters changed).
    nodes: Vec<[f64; NODE_LEN]>,
    node_theta: Vec<[f64; 2]>,
}

impl Bank {
    /// Runs predict + update of every particle with its new parameters; writes the
    /// log-likelihoods. Nothing is committed (see `commit`).
    fn step(
        &mut self,
        ln_theta: &[[f64; 2]],
        y: &Vector5,
        ll: &mut [f64],
    ) -> Result<(), DamperError> {
        match self {
            Bank::Exact(b) => {
                let g = b.model.g_matrix();
                for (i, th) in ln_theta.iter().enumerate() {
                    let d = Dampers::from_ln(*th);
                    let disc = discretize(&b.model.a_matrix(&d), &g, b.dt_s)?;
                    let pred = kalman::predict(&b.est[i], &disc, &b.noise);
                    let (post, l) = kalman::update(&pred, y, &b.h, &b.noise.q_v)?;
                    b.next[i] = post;
                    ll[i] = l;
                }
                Ok(())
            }
            Bank::Steady(b) => b.step(ln_theta, y, ll),
        }
    }

    fn commit(&mut self) {
        match self {
            Bank::Exact(b) => std::mem::swap(&mut b.est, &mut b.next),
            Bank::Steady(b) => std::mem::swap(&mut b.x, &mut b.next),
        }
    }

    /// Replaces particle `j` by particle `indices[j]`.
    fn resample(&mut self, indices: &[usize]) {
        match self {
            Bank::Exact(b) => {
                for (j, &i) in indices.iter().enumerate() {
                    b.next[j].clone_from(&b.est[i]);
                }
                std::mem::swap(&mut b.est, &mut b.next);
            }
            Bank::Steady(b) => {
                let n = b.n;
                for s in 0..N_STATES {
                    let src = &b.x[s * n..(s + 1) * n];
                    let dst = &mut b.next[s * n..(s + 1) * n];
                    for (d, &i) in dst.iter_mut().zip(indices) {
                        *d = src[i];
                    }
                }
                std::mem::swap(&mut b.x, &mut b.next);
            }
        }
    }

    /// Posterior state mean of particle `i` (for tests and diagnostics).
    fn state(&self, i: usize) -> Vector17 {
        match self {
            Bank::Exact(b) => b.est[i].x,
            Bank::Steady(b) => Vector17::from_fn(|s, _| b.x[s * b.n + i]),
        }
    }

    /// Posterior covariance of particle `i`; the steady-state filter's is the Riccati
    /// solution `(I - K H) P-` of its parameters, not stored per particle.
    fn covariance(&self, i: usize) -> Option<Matrix17> {
        match self {
            Bank::Exact(b) => Some(b.est[i].p),
            Bank::Steady(_) => None,
        }
    }
}

impl SteadyBank {
    fn step(
        &mut self,
        ln_theta: &[[f64; 2]],
        y: &Vector5,
        ll: &mut [f64],
    ) -> Result<(), DamperError> {
        let n = self.n;
        // Parameters change only at kernel moves (or every step with `EveryStep`): refresh the
        // damper entries and the interpolated gain of the particles that moved.
        for (i, th) in ln_theta.iter().enumerate() {
            if self.node_theta[i] != *th {
                self.yaw[i] = self.csay_gain * th[1].exp();
                self.series[i] = self.end_stiffness * (-th[0]).exp();
                self.table
                    .interpolate(&self.table.cell(*th), &mut self.nodes[i]);
                self.node_theta[i] = *th;
            }
        }
        self.prop.propagate(
            n,
            &self.x,
            &self.yaw,
            &self.series,
            &mut self.next,
            &mut self.term,
            &mut self.scratch,
        );
        let const_term = N_OUTPUTS as f64 * LN_2PI;
        for (i, ll_i) in ll.iter_mut().enumerate() {
            let e = self.prop.innovation(n, &self.next, i, y);
            let node = &self.nodes[i];
            let s_inv = &node[S_INV_OFFSET..S_INV_OFFSET + N_OUTPUTS * N_OUTPUTS];
            let mut mahalanobis = 0.0;
            for r in 0..N_OUTPUTS {
                let mut acc = 0.0;
                for c in 0..N_OUTPUTS {
                    acc += s_inv[r * N_OUTPUTS + c] * e[c];
                }
                mahalanobis += e[r] * acc;
            }
            *ll_i = -0.5 * (const_term + node[LN_DET_OFFSET] + mahalanobis);
            for s in 0..N_STATES {
                let k = &node[s * N_OUTPUTS..(s + 1) * N_OUTPUTS];
                let mut dx = 0.0;
                for m in 0..N_OUTPUTS {
                    dx += k[m] * e[m];
                }
                self.next[s * n + i] += dx;
            }
        }
        if ll.iter().any(|v| !v.is_finite()) {
            return Err(DamperError::NonFinite {
                what: "particle likelihood",
            });
        }
        Ok(())
    }
}

/// The filter.
#[derive(Debug, Clone)]
pub struct Rbpf {
    config: RbpfConfig,
    nominal: Dampers,
    kernel_a: f64,
    kernel_h: f64,
    dt_s: f64,
    steps_since_move: u64,
    ln_theta: Vec<[f64; 2]>,
    ln_theta_next: Vec<[f64; 2]>,
    log_w: Vec<f64>,
    log_w_next: Vec<f64>,
    ll: Vec<f64>,
    indices: Vec<usize>,
    bank: Bank,
    rng: ChaCha8Rng,
    ess: f64,
    log_evidence: f64,
    resamples: u64,
}

impl Rbpf {
    /// Builds the filter; with `SteadyState` propagation this solves the Riccati equation on
    /// the whole gain grid (about a second for 33 x 33): share the table with
    /// [`Rbpf::with_gain_table`] when running several filters on the same vehicle.
    pub fn new(config: &DamperMonitorConfig) -> Result<Self, DamperError> {
        config.validate()?;
        let table = match config.rbpf.propagation {
            Propagation::SteadyState => Some(Self::gain_table(config)?),
            Propagation::Exact => None,
        };
        Self::with_gain_table(config, table)
    }

    /// The gain table `config` needs (steady-state propagation).
    pub fn gain_table(config: &DamperMonitorConfig) -> Result<Arc<GainTable>, DamperError> {
        config.validate()?;
        let model = BogieModel::new(&config.vehicle, config.drift_leak_per_s)?;
        GainTable::build(
            &model,
            &config.noise(),
            &config.nominal,
            &config.rbpf.gain_grid,
            config.dt_s,
        )
    }

    /// As [`Rbpf::new`] with a prebuilt table (ignored for `Exact`).
    pub fn with_gain_table(
        config: &DamperMonitorConfig,
        table: Option<Arc<GainTable>>,
    ) -> Result<Self, DamperError> {
        config.validate()?;
        let cfg = config.rbpf;
        let n = cfg.particles;
        let model = BogieModel::new(&config.vehicle, config.drift_leak_per_s)?;
        let bank = match (cfg.propagation, table) {
            (Propagation::Exact, _) => {
                // x0 = 0 (vehicle at rest on the track centre line), P0 = the prior's
                // stationary spread is unknown: a diffuse-enough start, refined in a second.
                let est0 = StateEstimate {
                    x: Vector17::zeros(),
                    p: initial_covariance(),
                };
                Bank::Exact(Box::new(ExactBank {
                    h: model.h_matrix(),
                    noise: config.noise(),
                    dt_s: config.dt_s,
                    est: vec![est0.clone(); n],
                    next: vec![est0; n],
                    model,
                }))
            }
            (Propagation::SteadyState, table) => {
                let table = match table {
                    Some(t) => t,
                    None => Self::gain_table(config)?,
                };
                let entries = model.damper_entries(&Dampers {
                    csy_ns_per_m: 1.0,
                    csay_ns_per_m: 1.0,
                });
                Bank::Steady(Box::new(SteadyBank {
                    n,
                    prop: SparsePropagator::new(&model, config.dt_s, cfg.taylor_order)?,
                    table,
                    csay_gain: entries.yaw_damping_per_s,
                    end_stiffness: entries.series_rate_per_s,
                    x: vec![0.0; N_STATES * n],
                    next: vec![0.0; N_STATES * n],
                    term: vec![0.0; N_STATES * n],
                    scratch: vec![0.0; N_STATES * n],
                    yaw: vec![0.0; n],
                    series: vec![0.0; n],
                    nodes: vec![[0.0; NODE_LEN]; n],
                    node_theta: vec![[f64::NAN; 2]; n],
                }))
            }
        };
        let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
        let centre = Dampers {
            csy_ns_per_m: config.nominal.csy_ns_per_m * cfg.prior_ratio,
            csay_ns_per_m: config.nominal.csay_ns_per_m * cfg.prior_ratio,
        }
        .ln();
        let ln_theta: Vec<[f64; 2]> = (0..n)
            .map(|_| {
                [
                    centre[0] + cfg.prior_ln_std * rng.sample::<f64, _>(StandardNormal),
                    centre[1] + cfg.prior_ln_std * rng.sample::<f64, _>(StandardNormal),
                ]
            })
            .collect();
        let (a, h2) = cfg.liu_west();
        Ok(Rbpf {
            config: cfg,
            nominal: config.nominal,
            kernel_a: a,
            kernel_h: h2.sqrt(),
            dt_s: config.dt_s,
            steps_since_move: 0,
            ln_theta_next: ln_theta.clone(),
            ln_theta,
            log_w: vec![-(n as f64).ln(); n],
            log_w_next: vec![0.0; n],
            ll: vec![0.0; n],
            indices: vec![0; n],
            bank,
            rng,
            ess: n as f64,
            log_evidence: 0.0,
            resamples: 0,
        })
    }

    pub fn n_particles(&self) -> usize {
        self.ln_theta.len()
    }

    /// One step with measurement `y` (validated by the caller: must be finite). On error the
    /// filter is unchanged except for its random-number stream.
    pub fn step(&mut self, y: &Vector5) -> Result<(), DamperError> {
        if y.iter().any(|v| !v.is_finite()) {
            return Err(DamperError::NonFinite {
                what: "measurement",
            });
        }
        self.steps_since_move += 1;
        match self.config.kernel {
            KernelSchedule::EveryStep => self.kernel_move(),
            KernelSchedule::AtResampling => self.ln_theta_next.clone_from(&self.ln_theta),
        }
        self.bank.step(&self.ln_theta_next, y, &mut self.ll)?;
        for ((next, w), l) in self.log_w_next.iter_mut().zip(&self.log_w).zip(&self.ll) {
            *next = w + l;
        }
        let log_increment = normalize_log_weights(&mut self.log_w_next)?;
        // Commit.
        self.bank.commit();
        std::mem::swap(&mut self.ln_theta, &mut self.ln_theta_next);
        std::mem::swap(&mut self.log_w, &mut self.log_w_next);
        self.log_evidence += log_increment;
        self.ess = effective_sample_size(&self.log_w);
        let n = self.n_particles();
        if self.ess < self.config.resample_ess_fraction * n as f64 {
            systematic_resample(&self.log_w, &mut self.indices, &mut self.rng);
            self.bank.resample(&self.indices);
            for (dst, &i) in self.ln_theta_next.iter_mut().zip(&self.indices) {
                *dst = self.ln_theta[i];
            }
            std::mem::swap(&mut self.ln_theta, &mut self.ln_theta_next);
            self.log_w.fill(-(n as f64).ln());
            self.resamples += 1;
            if self.config.kernel == KernelSchedule::AtResampling {
                self.kernel_move();
                std::mem::swap(&mut self.ln_theta, &mut self.ln_theta_next);
            }
        }
        Ok(())
    }

    /// Liu-West (eq. 24) on `ln theta`: `m_i = a theta_i + (1 - a) theta_bar`,
    /// `theta_i' ~ N(m_i, h^2 V)`, with `theta_bar`, `V` the weighted mean and covariance;
    /// plus the optional random walk over the time since the last move and the optional
    /// regeneration from the prior. Writes `ln_theta_next`.
    fn kernel_move(&mut self) {
        let dif =
            self.config.ln_diffusion_per_sqrt_s * (self.steps_since_move as f64 * self.dt_s).sqrt();
        self.steps_since_move = 0;
        let regen = self.config.regeneration_fraction;
        let (lo, hi) = (
            self.config.gain_grid.min_ratio.ln(),
            self.config.gain_grid.max_ratio.ln(),
        );
        let nominal = self.nominal.ln();
        let (mean, cov) = self.ln_moments();
        // A collapsed cloud (all particles equal) has V = 0: then there is nothing to smooth.
        let chol = (cov + Matrix2::identity() * 1e-300)
            .cholesky()
            .map(|c| c.l())
            .unwrap_or_else(Matrix2::zeros);
        let (a, h) = (self.kernel_a, self.kernel_h);
        for (dst, th) in self.ln_theta_next.iter_mut().zip(&self.ln_theta) {
            let z0: f64 = self.rng.sample(StandardNormal);
            let z1: f64 = self.rng.sample(StandardNormal);
            for k in 0..2 {
                let jitter = h * (chol[(k, 0)] * z0 + chol[(k, 1)] * z1);
                dst[k] = a * th[k] + (1.0 - a) * mean[k] + jitter;
            }
            if dif > 0.0 {
                dst[0] += dif * self.rng.sample::<f64, _>(StandardNormal);
                dst[1] += dif * self.rng.sample::<f64, _>(StandardNormal);
            }
            // Regeneration, one coefficient at a time (the other is usually known to a fraction
            // of a percent: redrawing both would almost never land near the truth), uniform
            // in log over the gain grid's range.
            for k in 0..2 {
                if regen > 0.0 && self.rng.random::<f64>() < regen {
                    dst[k] = nominal[k] + lo + (hi - lo) * self.rng.random::<f64>();
                }
            }
        }
    }

    /// Weighted mean and covariance of `ln theta`, accumulated about the first particle so
    /// that a collapsed cloud (all particles equal) has exactly zero spread.
    fn ln_moments(&self) -> ([f64; 2], Matrix2<f64>) {
        let origin = self.ln_theta[0];
        let mut shift = [0.0; 2];
        for (th, lw) in self.ln_theta.iter().zip(&self.log_w) {
            let w = lw.exp();
            shift[0] += w * (th[0] - origin[0]);
            shift[1] += w * (th[1] - origin[1]);
        }
        let mut cov = Matrix2::zeros();
        for (th, lw) in self.ln_theta.iter().zip(&self.log_w) {
            let w = lw.exp();
            let d = [th[0] - origin[0] - shift[0], th[1] - origin[1] - shift[1]];
            for r in 0..2 {
                for c in 0..2 {
                    cov[(r, c)] += w * d[r] * d[c];
                }
            }
        }
        ([origin[0] + shift[0], origin[1] + shift[1]], cov)
    }

    /// Posterior summary (mean, 5%/95% quantiles, health ratio) and effective sample size.
    /// Sorts the particles: O(N log N).
    pub fn estimate(&self) -> RbpfEstimate {
        let w: Vec<f64> = self.log_w.iter().map(|v| v.exp()).collect();
        let post = |k: usize, nominal: f64| {
            let mut order: Vec<usize> = (0..w.len()).collect();
            order.sort_unstable_by(|&i, &j| self.ln_theta[i][k].total_cmp(&self.ln_theta[j][k]));
            let mean: f64 = self
                .ln_theta
                .iter()
                .zip(&w)
                .map(|(th, wi)| wi * th[k].exp())
                .sum();
            let quantile = |q: f64| {
                let mut cum = 0.0;
                for &i in &order {
                    cum += w[i];
                    if cum >= q {
                        return self.ln_theta[i][k].exp();
                    }
                }
                self.ln_theta[order[order.len() - 1]][k].exp()
            };
            DamperPosterior {
                mean_ns_per_m: mean,
                q05_ns_per_m: quantile(0.05),
                q95_ns_per_m: quantile(0.95),
                health_ratio: mean / nominal,
            }
        };
        RbpfEstimate {
            csy: post(0, self.nominal.csy_ns_per_m),
            csay: post(1, self.nominal.csay_ns_per_m),
            effective_sample_size: self.ess,
        }
    }

    /// Posterior mean of the coefficients (O(N), no sorting).
    pub fn mean(&self) -> Dampers {
        let mut m = [0.0; 2];
        for (th, lw) in self.ln_theta.iter().zip(&self.log_w) {
            let w = lw.exp();
            m[0] += w * th[0].exp();
            m[1] += w * th[1].exp();
        }
        Dampers {
            csy_ns_per_m: m[0],
            csay_ns_per_m: m[1],
        }
    }

    pub fn effective_sample_size(&self) -> f64 {
        self.ess
    }

    /// `ln p(y_1..y_k)` estimated by the filter (sum of the weight normalisers).
    pub fn log_evidence(&self) -> f64 {
        self.log_evidence
    }

    pub fn resample_count(&self) -> u64 {
        self.resamples
    }

    /// Particle `i`: its `ln theta`, normalised log-weight, state mean and (exact filter only)
    /// covariance.
    pub fn particle(&self, i: usize) -> ([f64; 2], f64, Vector17, Option<Matrix17>) {
        (
            self.ln_theta[i],
            self.log_w[i],
            self.bank.state(i),
            self.bank.covariance(i),
        )
    }
}

/// Initial state covariance of the exact filter: the vehicle starts near rest; standard
/// deviations 1 cm (displacements, track), 1 mrad, 1 cm/s, 10 mrad/s.
pub fn initial_covariance() -> Matrix17 {
    let mut d = Vector17::repeat(1e-2f64.powi(2));
    for i in [state::PSIW1, state::PSIW2, state::PSIB] {
        d[i] = 1e-3f64.powi(2);
    }
    for i in [state::PSIW1_DOT, state::PSIW2_DOT, state::PSIB_DOT] {
        d[i] = 1e-2f64.powi(2);
    }
    Matrix17::from_diagonal(&d)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::expm::expm;
    use crate::params::BogieParams;

    /// The sparse Taylor propagation with the leak projector equals `expm(A_f T) x`.
    #[test]
    fn sparse_propagation_equals_the_matrix_exponential() {
        let model = BogieModel::new(&BogieParams::default(), 0.1).unwrap();
        let dt = 1e-3;
        let thetas = [
            Dampers::NOMINAL,
            Dampers {
                csy_ns_per_m: 3e3,
                csay_ns_per_m: 400e3,
            },
            Dampers {
                csy_ns_per_m: 40e3,
                csay_ns_per_m: 20e3,
            },
        ];
        let n = thetas.len();
        let xs: Vec<Vector17> = (0..n)
            .map(|i| Vector17::from_fn(|s, _| ((s * 5 + i * 3) % 7) as f64 * 1e-3 - 3e-3))
            .collect();
        let mut soa = vec![0.0; N_STATES * n];
        for (i, x) in xs.iter().enumerate() {
            for s in 0..N_STATES {
                soa[s * n + i] = x[s];
            }
        }
        let unit = model.damper_entries(&Dampers {
            csy_ns_per_m: 1.0,
            csay_ns_per_m: 1.0,
        });
        let yaw: Vec<f64> = thetas
            .iter()
            .map(|d| unit.yaw_damping_per_s * d.csay_ns_per_m)
            .collect();
        let series: Vec<f64> = thetas
            .iter()
            .map(|d| unit.series_rate_per_s / d.csy_ns_per_m)
            .collect();
        let exact: Vec<Vector17> = thetas
            .iter()
            .zip(&xs)
            .map(|(d, x)| expm(&(model.a_matrix(d) * dt)).unwrap() * x)
            .collect();
        // Truncation error (relative, worst particle) falls with the order as (rho T)^k / k!.
        let mut errors = vec![];
        for order in [4, 6, 8, 10, 12] {
            let prop = SparsePropagator::new(&model, dt, order).unwrap();
            let (mut out, mut t1, mut t2) = (soa.clone(), soa.clone(), soa.clone());
            prop.propagate(n, &soa, &yaw, &series, &mut out, &mut t1, &mut t2);
            let err = (0..n)
                .map(|i| {
                    let got = Vector17::from_fn(|s, _| out[s * n + i]);
                    (got - exact[i]).amax() / exact[i].amax()
                })
                .fold(0.0, f64::max);
            errors.push(err);
        }
        assert!(errors.windows(2).all(|w| w[1] < w[0] * 0.1), "{errors:?}");
        // Measured: [3e-4, 5e-6, 5e-8, 3e-10, 1.2e-12]; the worst case is the stiff series
        // node of C_sy = 3 kN s/m (K_sry T / C_sy = 0.8).
        assert!(errors[3] < 1e-9, "order 10: {errors:?}");
        assert!(errors[4] < 1e-11, "order 12: {errors:?}");
    }
}
