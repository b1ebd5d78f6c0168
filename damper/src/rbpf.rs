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

    /// `out = Phi_f(theta_i) x` for all `n` particles (structure-of-arrays, `x[s * n + i]`),
    /// where `yaw[i]`, `series[i]` are the damper entries of particle `i`
    /// (`DamperEntries`); in blocks of [`BLOCK`] particles.
    pub fn propagate(&self, n: usize, x: &[f64], yaw: &[f64], series: &[f64], out: &mut [f64]) {
        let mut blk = Block::new();
        for i0 in (0..n).step_by(BLOCK) {
            let len = BLOCK.min(n - i0);
            blk.load(x, &yaw[i0..i0 + len], &series[i0..i0 + len], n, i0);
            self.propagate_block(&mut blk);
            blk.store(out, n, i0, len);
        }
    }

    /// `blk.acc = Phi_f(theta_j) blk.x` for the particles of one block, by the Taylor series
    /// `sum_k (A T)^k / k!` of the sparse `A(theta_j)`. Works on whole rows of [`BLOCK`]
    /// (padding columns hold zeros): fixed-length loops without bounds checks, which the
    /// compiler vectorises.
    #[inline(always)]
    fn propagate_block(&self, blk: &mut Block) {
        blk.acc = blk.x;
        blk.term = blk.x;
        for k in 1..=self.order {
            let s = self.dt_s / k as f64;
            for row in blk.next.iter_mut() {
                *row = [0.0; BLOCK];
            }
            for &(r, c, v) in &self.entries {
                let sv = s * v;
                let src = &blk.term[c];
                for (d, t) in blk.next[r].iter_mut().zip(src) {
                    *d += sv * t;
                }
            }
            // The two damper rows, per particle.
            let term = &blk.term;
            for ((d, y), t) in blk.next[state::PSIB_DOT]
                .iter_mut()
                .zip(&blk.yaw)
                .zip(&term[state::PSIB_DOT])
            {
                *d += s * y * t;
            }
            for (((d, g), yb), ysr) in blk.next[state::YSR]
                .iter_mut()
                .zip(&blk.series)
                .zip(&term[state::YB])
                .zip(&term[state::YSR])
            {
                *d += s * g * (yb - ysr);
            }
            for (acc_row, next_row) in blk.acc.iter_mut().zip(&blk.next) {
                for (a, v) in acc_row.iter_mut().zip(next_row) {
                    *a += v;
                }
            }
            std::mem::swap(&mut blk.term, &mut blk.next);
        }
        // Drift leak: acc += (exp(-eps T) - 1) V W acc (A and V W commute).
        let mut w0 = [0.0; BLOCK];
        let mut w1 = [0.0; BLOCK];
        for j in 0..BLOCK {
            w0[j] = self.leak * (blk.acc[state::YW1][j] - blk.acc[state::D1][j]);
            w1[j] = self.leak * (blk.acc[state::YW2][j] - blk.acc[state::D2][j]);
        }
        for &r in &self.drift_rows {
            let (v0, v1) = (self.drift_basis[(r, 0)], self.drift_basis[(r, 1)]);
            for ((a, p), q) in blk.acc[r].iter_mut().zip(&w0).zip(&w1) {
                *a += v0 * p + v1 * q;
            }
        }
    }

    /// `blk.e = y - H blk.acc` for one block.
    #[inline(always)]
    fn innovation_block(&self, blk: &mut Block, y: &Vector5) {
        for (m, row) in blk.e.iter_mut().enumerate() {
            *row = [y[m]; BLOCK];
        }
        for &(m, c, v) in &self.h_entries {
            for (e, a) in blk.e[m].iter_mut().zip(&blk.acc[c]) {
                *e -= v * a;
            }
        }
    }
}

/// Particles processed together: small enough for the level-1 cache (about 35 kB), long
/// enough for the inner loops to vectorise.
pub const BLOCK: usize = 64;

type Row = [f64; BLOCK];

/// Block-local working arrays, one row of [`BLOCK`] particles per state or output.
#[derive(Debug, Clone)]
struct Block {
    x: [Row; N_STATES],
    acc: [Row; N_STATES],
    term: [Row; N_STATES],
    next: [Row; N_STATES],
    e: [Row; N_OUTPUTS],
    /// The damper entries of the block's particles (`DamperEntries`).
    yaw: Row,
    series: Row,
}

impl Block {
    fn new() -> Box<Self> {
        Box::new(Block {
            x: [[0.0; BLOCK]; N_STATES],
            acc: [[0.0; BLOCK]; N_STATES],
            term: [[0.0; BLOCK]; N_STATES],
            next: [[0.0; BLOCK]; N_STATES],
            e: [[0.0; BLOCK]; N_OUTPUTS],
            yaw: [0.0; BLOCK],
            series: [0.0; BLOCK],
        })
    }

    /// Copies particles `i0..i0 + yaw.len()` of the structure-of-arrays `src` (stride `n`)
    /// and their damper entries in; zeros in the padding.
    fn load(&mut self, src: &[f64], yaw: &[f64], series: &[f64], n: usize, i0: usize) {
        let len = yaw.len();
        for (s, row) in self.x.iter_mut().enumerate() {
            row[..len].copy_from_slice(&src[s * n + i0..s * n + i0 + len]);
            row[len..].fill(0.0);
        }
        self.yaw[..len].copy_from_slice(yaw);
        self.yaw[len..].fill(0.0);
        self.series[..len].copy_from_slice(series);
        self.series[len..].fill(0.0);
    }

    /// Copies `acc` back into particles `i0..i0 + len` of `dst`.
    fn store(&self, dst: &mut [f64], n: usize, i0: usize, len: usize) {
        for (s, row) in self.acc.iter().enumerate() {
            dst[s * n + i0..s * n + i0 + len].copy_from_slice(&row[..len]);
        }
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
    /// Posterior states, structure-of-arrays `x[state * n + particle]`.
    x: Vec<f64>,
    /// The step's new posterior states (committed by swapping with `x`).
    next: Vec<f64>,
    yaw: Vec<f64>,
    series: Vec<f64>,
    /// Per particle: the interpolated gain node, structure-of-arrays
    /// `nodes[value * n + particle]`, and the `ln theta` it was computed for (recomputed
    /// only when the particle's parameters changed).
    nodes: Vec<f64>,
    node_theta: Vec<[f64; 2]>,
    block: Box<Block>,
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
        let mut node = [0.0; NODE_LEN];
        for (i, th) in ln_theta.iter().enumerate() {
            if self.node_theta[i] != *th {
                self.yaw[i] = self.csay_gain * th[1].exp();
                self.series[i] = self.end_stiffness * (-th[0]).exp();
                self.table.interpolate(&self.table.cell(*th), &mut node);
                for (k, v) in node.iter().enumerate() {
                    self.nodes[k * n + i] = *v;
                }
                self.node_theta[i] = *th;
            }
        }
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: the CPU supports AVX2, checked just above.
                unsafe { self.filter_all_avx2(y, ll) };
                return check_finite(ll);
            }
        }
        self.filter_all(y, ll);
        check_finite(ll)
    }

    /// [`SteadyBank::filter_all`] compiled for AVX2 (4-wide vectors instead of SSE2's 2).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn filter_all_avx2(&mut self, y: &Vector5, ll: &mut [f64]) {
        self.filter_all(y, ll)
    }

    /// Predict, innovation, log-likelihood and update of every particle, block by block.
    #[inline(always)]
    fn filter_all(&mut self, y: &Vector5, ll: &mut [f64]) {
        let n = self.n;
        let const_term = N_OUTPUTS as f64 * LN_2PI;
        let blk = &mut self.block;
        for i0 in (0..n).step_by(BLOCK) {
            let len = BLOCK.min(n - i0);
            blk.load(
                &self.x,
                &self.yaw[i0..i0 + len],
                &self.series[i0..i0 + len],
                n,
                i0,
            );
            self.prop.propagate_block(blk);
            self.prop.innovation_block(blk, y);
            let node = |k: usize| &self.nodes[k * n + i0..k * n + i0 + len];
            // ln N(e; 0, S) with S^-1 and ln det S of each particle's parameters.
            let lls = &mut ll[i0..i0 + len];
            for (l, d) in lls.iter_mut().zip(node(LN_DET_OFFSET)) {
                *l = const_term + d;
            }
            for r in 0..N_OUTPUTS {
                for c in 0..N_OUTPUTS {
                    let s_inv = node(S_INV_OFFSET + r * N_OUTPUTS + c);
                    for (((l, si), er), ec) in
                        lls.iter_mut().zip(s_inv).zip(&blk.e[r]).zip(&blk.e[c])
                    {
                        *l += si * er * ec;
                    }
                }
            }
            for l in lls.iter_mut() {
                *l *= -0.5;
            }
            // x+ = x- + K e.
            for (s, acc_row) in blk.acc.iter_mut().enumerate() {
                for (m, e_row) in blk.e.iter().enumerate() {
                    let k = node(s * N_OUTPUTS + m);
                    for ((a, kj), ej) in acc_row.iter_mut().zip(k).zip(e_row) {
                        *a += kj * ej;
                    }
                }
            }
            blk.store(&mut self.next, n, i0, len);
        }
    }
}

fn check_finite(ll: &[f64]) -> Result<(), DamperError> {
    if ll.iter().any(|v| !v.is_finite()) {
        return Err(DamperError::NonFinite {
            what: "particle likelihood",
        });
    }
    Ok(())
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
    regeneration_penalty: Vec<f64>,
    indices: Vec<usize>,
    bank: Bank,
    rng: ChaCha8Rng,
    ess: f64,
    log_evidence: f64,
    resamples: u64,
    sorted: SortedParticles,
}

/// Per coefficient: particle indices in increasing order of the coefficient, and the
/// coefficients (N s/m) in that order. Valid until the parameters move.
#[derive(Debug, Clone, Default)]
struct SortedParticles {
    stale: bool,
    order: [Vec<usize>; 2],
    values: [Vec<f64>; 2],
}

impl SortedParticles {
    fn refresh(&mut self, ln_theta: &[[f64; 2]]) {
        for k in 0..2 {
            let order = &mut self.order[k];
            order.clear();
            order.extend(0..ln_theta.len());
            order.sort_unstable_by(|&i, &j| ln_theta[i][k].total_cmp(&ln_theta[j][k]));
            self.values[k].clear();
            self.values[k].extend(order.iter().map(|&i| ln_theta[i][k].exp()));
        }
        self.stale = false;
    }
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
                    yaw: vec![0.0; n],
                    series: vec![0.0; n],
                    nodes: vec![0.0; NODE_LEN * n],
                    node_theta: vec![[f64::NAN; 2]; n],
                    block: Block::new(),
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
            regeneration_penalty: vec![0.0; n],
            indices: vec![0; n],
            bank,
            rng,
            ess: n as f64,
            log_evidence: 0.0,
            resamples: 0,
            sorted: SortedParticles {
                stale: true,
                ..SortedParticles::default()
            },
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
            KernelSchedule::AtResampling => {
                self.ln_theta_next.clone_from(&self.ln_theta);
                self.regeneration_penalty.fill(0.0);
            }
        }
        self.bank.step(&self.ln_theta_next, y, &mut self.ll)?;
        for (((next, w), l), pen) in self
            .log_w_next
            .iter_mut()
            .zip(&self.log_w)
            .zip(&self.ll)
            .zip(&self.regeneration_penalty)
        {
            *next = w + l + pen;
        }
        let log_increment = normalize_log_weights(&mut self.log_w_next)?;
        // Commit.
        self.bank.commit();
        if self.config.kernel == KernelSchedule::EveryStep {
            self.sorted.stale = true;
        }
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
            self.sorted.stale = true;
            if self.config.kernel == KernelSchedule::AtResampling {
                self.kernel_move();
                std::mem::swap(&mut self.ln_theta, &mut self.ln_theta_next);
                for (w, pen) in self.log_w.iter_mut().zip(&self.regeneration_penalty) {
                    *w += pen;
                }
                normalize_log_weights(&mut self.log_w)?;
                self.ess = effective_sample_size(&self.log_w);
            }
        }
        Ok(())
    }

    /// Liu-West (eq. 24) on `ln theta`: `m_i = a theta_i + (1 - a) theta_bar`,
    /// `theta_i' ~ N(m_i, h^2 V)`, with `theta_bar`, `V` the weighted mean and covariance;
    /// plus the optional random walk over the time since the last move and the optional
    /// regeneration. Writes `ln_theta_next`, and in `regeneration_penalty` the log-weight
    /// each particle's weight is to be scaled by (`ln regeneration_weight` for a regenerated
    /// one, else 0).
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
        let ln_regen_weight = self.config.regeneration_weight.ln();
        for ((dst, th), penalty) in self
            .ln_theta_next
            .iter_mut()
            .zip(&self.ln_theta)
            .zip(self.regeneration_penalty.iter_mut())
        {
            *penalty = 0.0;
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
            // in log over the gain grid's range. A newcomer starts with a reduced weight
            // (`regeneration_weight`): it barely moves the estimate, yet takes over when the
            // data favour it by more than ln(1 / regeneration_weight) nats (a failed damper).
            for k in 0..2 {
                if regen > 0.0 && self.rng.random::<f64>() < regen {
                    dst[k] = nominal[k] + lo + (hi - lo) * self.rng.random::<f64>();
                    *penalty = ln_regen_weight;
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
    /// O(N); the particles are sorted (O(N log N)) only after their parameters changed.
    pub fn estimate(&mut self) -> RbpfEstimate {
        if self.sorted.stale {
            self.sorted.refresh(&self.ln_theta);
        }
        let w: Vec<f64> = self.log_w.iter().map(|v| v.exp()).collect();
        let post = |k: usize, nominal: f64| {
            let (order, values) = (&self.sorted.order[k], &self.sorted.values[k]);
            let mean: f64 = order.iter().zip(values).map(|(&i, v)| w[i] * v).sum();
            let quantile = |q: f64| {
                let mut cum = 0.0;
                for (&i, v) in order.iter().zip(values) {
                    cum += w[i];
                    if cum >= q {
                        return *v;
                    }
                }
                values[values.len() - 1]
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
            let mut out = soa.clone();
            prop.propagate(n, &soa, &yaw, &series, &mut out);
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
