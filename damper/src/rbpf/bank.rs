//! The per-particle Kalman filters of the RBPF, exact or steady-state (see the module docs of
//! [`super`]), run for every particle at once.

use std::sync::Arc;

use serde::{Deserialize, Serialize};

use crate::expm::discretize;
use crate::filter_model::FilterModel;
use crate::gain_table::{
    GainGrid, GainTable, INV_S_DIAG_OFFSET, LN_DET_OFFSET, NODE_LEN, S_INV_OFFSET,
};
use crate::kalman::{self, initial_covariance, NoiseCovariances, StateEstimate};
use crate::model::{BogieModel, Matrix17, Matrix5x17, Vector17, Vector5, N_OUTPUTS, N_STATES};
use crate::params::{positive, Dampers};
use crate::DamperError;
use railmon_filter::kalman::LN_2PI;

use super::propagator::{Block, Row, SparsePropagator, BLOCK};

/// How each particle's Kalman filter propagates (section 4.3 and the speed/accuracy study in
/// `docs/damper.md`).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum Propagation {
    /// Per particle and step: `Phi, Gamma` by the matrix exponential of its own `A(theta)`,
    /// full covariance predict and Joseph update. The reference; ~100x too slow for 1 kHz.
    Exact,
    /// Per particle: `Phi(theta) x` by a Taylor series of the sparse `A(theta)` (exact to
    /// `taylor_truncation`), and the steady-state gain and innovation covariance of its `theta`,
    /// interpolated bilinearly on a log-parameter grid of Riccati solutions.
    #[default]
    SteadyState,
}

/// The per-particle filters' states, for a snapshot ([`Bank::save`], [`Bank::restore`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum BankState {
    /// Per particle: state mean and covariance.
    Exact(Vec<(Vector17, Matrix17)>),
    /// The posterior states, structure-of-arrays `x[state * n + particle]` (the gains are the
    /// table's, recomputed from the parameters).
    Steady(Vec<f64>),
}

impl Bank {
    pub(super) fn save(&self) -> BankState {
        match self {
            Bank::Exact(b) => BankState::Exact(b.est.iter().map(|e| (e.x, e.p)).collect()),
            Bank::Steady(b) => {
                let n = b.n;
                let mut x = vec![0.0; N_STATES * n];
                for s in 0..N_STATES {
                    for (i, v) in x[s * n..(s + 1) * n].iter_mut().enumerate() {
                        *v = at(&b.x, N_STATES, s, i);
                    }
                }
                BankState::Steady(x)
            }
        }
    }

    /// Takes the states of `state` (of the same propagation and particle count).
    pub(super) fn restore(&mut self, state: BankState) -> Result<(), DamperError> {
        let mismatch = |what: &str| DamperError::Config(format!("snapshot: {what}"));
        match (self, state) {
            (Bank::Exact(b), BankState::Exact(est)) => {
                if est.len() != b.est.len() {
                    return Err(mismatch("another particle count"));
                }
                for (dst, (x, p)) in b.est.iter_mut().zip(est) {
                    *dst = StateEstimate { x, p };
                }
                Ok(())
            }
            (Bank::Steady(b), BankState::Steady(x)) => {
                let n = b.n;
                if x.len() != N_STATES * n {
                    return Err(mismatch("another particle count"));
                }
                for s in 0..N_STATES {
                    for (i, v) in x[s * n..(s + 1) * n].iter().enumerate() {
                        *at_mut(&mut b.x, N_STATES, s, i) = *v;
                    }
                }
                Ok(())
            }
            _ => Err(mismatch("another propagation")),
        }
    }

    /// `n` per-particle filters of `filter_model`, every state at rest (`x0 = 0`),
    /// propagated as `propagation` says: steady-state needs the gain table `table` (the
    /// caller builds it when it was not given one) and the Taylor series' `taylor_truncation`.
    pub(super) fn new(
        filter_model: &FilterModel,
        n: usize,
        propagation: Propagation,
        taylor_truncation: f64,
        table: Option<Arc<GainTable>>,
    ) -> Result<Self, DamperError> {
        let model = filter_model.bogie_model()?;
        Ok(match (propagation, table) {
            (Propagation::Exact, _) => {
                // x0 = 0 (vehicle at rest on the track centre line), P0 = the prior's
                // stationary spread is unknown: a diffuse-enough start, refined in a second.
                let est0 = StateEstimate {
                    x: Vector17::zeros(),
                    p: initial_covariance(),
                };
                Bank::Exact(Box::new(ExactBank {
                    h: model.h_matrix(),
                    noise: filter_model.noise(),
                    dt_s: filter_model.dt_s,
                    est: vec![est0.clone(); n],
                    next: vec![est0; n],
                    model,
                }))
            }
            (Propagation::SteadyState, None) => {
                return Err(DamperError::Config(
                    "steady-state propagation without a gain table".into(),
                ))
            }
            (Propagation::SteadyState, Some(table)) => {
                let entries = model.damper_entries(&Dampers {
                    csy_ns_per_m: 1.0,
                    csay_ns_per_m: 1.0,
                });
                let grid_node = table.node_of(model.params().speed_m_s);
                // Whole blocks: the padding particles stay at zero and are never output.
                let blocks = n.div_ceil(BLOCK);
                Bank::Steady(Box::new(SteadyBank {
                    n,
                    prop: SparsePropagator::new(&model, filter_model.dt_s, taylor_truncation)?,
                    grid: table.grid_at(grid_node)?,
                    grid_node,
                    table,
                    model,
                    csay_gain: entries.yaw_damping_per_s,
                    end_stiffness: entries.series_rate_per_s,
                    x: vec![Row::ZERO; N_STATES * blocks],
                    next: vec![Row::ZERO; N_STATES * blocks],
                    yaw: vec![Row::ZERO; blocks],
                    series: vec![Row::ZERO; blocks],
                    body: vec![Row::ONE; blocks],
                    nodes: vec![Row::ZERO; NODE_LEN * blocks],
                    node_theta: vec![[f64::NAN; 2]; n],
                    node_ln_mass: vec![0.0; n],
                    mass_grids: Vec::new(),
                    block: Block::new(),
                }))
            }
        })
    }
}

/// Per-particle filters, exact or steady-state.
#[derive(Debug, Clone)]
pub(super) enum Bank {
    Exact(Box<ExactBank>),
    Steady(Box<SteadyBank>),
}

#[derive(Debug, Clone)]
pub(super) struct ExactBank {
    model: BogieModel,
    h: Matrix5x17,
    noise: NoiseCovariances,
    dt_s: f64,
    est: Vec<StateEstimate>,
    next: Vec<StateEstimate>,
}

#[derive(Debug, Clone)]
pub(super) struct SteadyBank {
    n: usize,
    prop: SparsePropagator,
    /// The filter model at the current speed.
    model: BogieModel,
    table: Arc<GainTable>,
    /// The gain grid of the current speed's and mass's node, and that node.
    grid: Arc<GainGrid>,
    grid_node: usize,
    csay_gain: f64,
    end_stiffness: f64,
    /// Posterior states, blocked structure-of-arrays (`at(&x, N_STATES, state, particle)`:
    /// each block of [`BLOCK`] particles holds its states row by row, contiguous), the
    /// particle count rounded up to whole blocks.
    x: Vec<Row>,
    /// The step's new posterior states (committed by swapping with `x`).
    next: Vec<Row>,
    /// The damper entries (`DamperEntries`), one row per block.
    yaw: Vec<Row>,
    series: Vec<Row>,
    /// The scale of the body's acceleration row, `m_model / m_i`, one row per block (1: every
    /// particle at the model's mass).
    body: Vec<Row>,
    /// Per particle: the interpolated gain node, blocked like `x`
    /// (`at(&nodes, NODE_LEN, value, particle)`), and the `ln theta` and `ln (m_i / m_model)`
    /// it was computed for (recomputed only when the particle's parameters changed).
    nodes: Vec<Row>,
    node_theta: Vec<[f64; 2]>,
    node_ln_mass: Vec<f64>,
    /// The grids of the other mass nodes the particles' own masses fell in, at the current
    /// speed node (`(node, grid)`; emptied when the schedule's node changes).
    mass_grids: Vec<(usize, Arc<GainGrid>)>,
    block: Box<Block>,
}

/// The estimated noise scale as the particles use it: each innovation is weighed with
/// `D^1/2 S D^1/2` (`crate::noise_scale`), i.e. `e_i / sqrt(d_i)` against `S`, plus `ln det D`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Whitening {
    pub(super) inv_sqrt: [f64; N_OUTPUTS],
    pub(super) ln_det: f64,
}

impl Whitening {
    pub(super) fn new(variance_scale: &[f64; N_OUTPUTS]) -> Self {
        Whitening {
            inv_sqrt: variance_scale.map(|d| 1.0 / d.sqrt()),
            ln_det: variance_scale.iter().map(|d| d.ln()).sum(),
        }
    }
}

/// What a bank step writes per particle: the log-likelihoods, the (whitened) normalised
/// innovations squared `e' S^-1 e`, and `z[channel * n + particle] = e_i^2 / S_ii` (with the
/// configured noise, for the noise-scale estimate).
pub(super) struct StepOutput<'a> {
    pub(super) ll: &'a mut [f64],
    pub(super) nis: &'a mut [f64],
    pub(super) z: &'a mut [f64],
}

impl Bank {
    /// Runs predict + update of every particle with its new parameters, weighing the
    /// innovations with `whiten`. `ln_mass`: each particle's body mass as `ln (m_i /
    /// m_model)` (the model's: [`Bank::set_schedule`]); empty, every particle at the model's.
    /// Nothing is committed (see `commit`).
    pub(super) fn step(
        &mut self,
        ln_theta: &[[f64; 2]],
        ln_mass: &[f64],
        y: &Vector5,
        whiten: &Whitening,
        out: StepOutput<'_>,
    ) -> Result<(), DamperError> {
        match self {
            Bank::Exact(b) => {
                let n = ln_theta.len();
                let g = b.model.g_matrix();
                let w = Vector5::from(whiten.inv_sqrt);
                let mut own = b.model.clone();
                for (i, th) in ln_theta.iter().enumerate() {
                    let d = Dampers::from_ln(*th);
                    let (model, h) = match ln_mass.get(i) {
                        Some(lm) => {
                            let m = b.model.params().half_body_mass_kg * lm.exp();
                            own.set_half_body_mass_kg(m)?;
                            (&own, own.h_matrix())
                        }
                        None => (&b.model, b.h),
                    };
                    let disc = discretize(&model.a_matrix(&d), &g, b.dt_s)?;
                    let pred = kalman::predict(&b.est[i], &disc, &b.noise);
                    let e = y - h * pred.x;
                    let s_cov = h * pred.p * h.transpose() + b.noise.q_v;
                    let ew = e.component_mul(&w);
                    let (nis_raw, nis_w) = s_cov.cholesky().map_or((f64::NAN, f64::NAN), |c| {
                        (e.dot(&c.solve(&e)), ew.dot(&c.solve(&ew)))
                    });
                    for (ch, z) in out.z.iter_mut().skip(i).step_by(n).enumerate() {
                        *z = e[ch] * e[ch] / s_cov[(ch, ch)];
                    }
                    let (post, l) = kalman::update(&pred, y, &h, &b.noise.q_v)?;
                    b.next[i] = post;
                    // ln N(e; 0, D^1/2 S D^1/2) from the update's ln N(e; 0, S); the
                    // correction is exactly 0 at D = I.
                    out.ll[i] = l - 0.5 * (whiten.ln_det + nis_w - nis_raw);
                    out.nis[i] = nis_w;
                }
                check_finite(out.ll)
            }
            Bank::Steady(b) => b.step(ln_theta, ln_mass, y, whiten, out),
        }
    }

    /// The forward speed (m/s, positive) and body mass above the bogie (kg, positive) of
    /// the next steps: the model, `H` and the Taylor order at exactly these; the steady-state
    /// gains of the nearest (speed, mass) node (every particle's gain is looked up again when
    /// the node changes). Nothing is done when neither changed.
    pub(super) fn set_schedule(
        &mut self,
        speed_m_s: f64,
        half_body_mass_kg: f64,
    ) -> Result<(), DamperError> {
        let model = match self {
            Bank::Exact(b) => &mut b.model,
            Bank::Steady(b) => &mut b.model,
        };
        let p = model.params();
        if p.speed_m_s == speed_m_s && p.half_body_mass_kg == half_body_mass_kg {
            return Ok(());
        }
        // Both checked before either changes.
        positive("speed_m_s", speed_m_s)?;
        positive("half_body_mass_kg", half_body_mass_kg)?;
        if p.speed_m_s != speed_m_s {
            model.set_speed(speed_m_s)?;
        }
        if model.params().half_body_mass_kg != half_body_mass_kg {
            model.set_half_body_mass_kg(half_body_mass_kg)?;
        }
        match self {
            Bank::Exact(b) => {
                b.h = b.model.h_matrix();
                Ok(())
            }
            Bank::Steady(b) => {
                b.prop.set_speed(&b.model);
                let node = b.table.node_at(speed_m_s, half_body_mass_kg);
                if node != b.grid_node {
                    b.grid = b.table.grid_for_filter(node)?;
                    b.grid_node = node;
                    b.node_theta.fill([f64::NAN; 2]);
                    b.mass_grids.clear();
                }
                Ok(())
            }
        }
    }

    /// The speed (m/s) and body mass (kg) the bank runs at ([`Bank::set_schedule`]).
    pub(super) fn schedule(&self) -> (f64, f64) {
        let p = match self {
            Bank::Exact(b) => b.model.params(),
            Bank::Steady(b) => b.model.params(),
        };
        (p.speed_m_s, p.half_body_mass_kg)
    }

    pub(super) fn commit(&mut self) {
        match self {
            Bank::Exact(b) => std::mem::swap(&mut b.est, &mut b.next),
            Bank::Steady(b) => std::mem::swap(&mut b.x, &mut b.next),
        }
    }

    /// Replaces particle `j` by particle `indices[j]`.
    pub(super) fn resample(&mut self, indices: &[usize]) {
        match self {
            Bank::Exact(b) => {
                for (j, &i) in indices.iter().enumerate() {
                    b.next[j].clone_from(&b.est[i]);
                }
                std::mem::swap(&mut b.est, &mut b.next);
            }
            Bank::Steady(b) => {
                for (j, &i) in indices.iter().enumerate() {
                    for s in 0..N_STATES {
                        *at_mut(&mut b.next, N_STATES, s, j) = at(&b.x, N_STATES, s, i);
                    }
                }
                std::mem::swap(&mut b.x, &mut b.next);
            }
        }
    }

    /// `indices.len()` filters, filter `j` a copy of filter `indices[j]` (resampling to another
    /// particle count, `Rbpf::set_particles`). The steady-state bank recomputes each new
    /// particle's gain node at its next step.
    pub(super) fn resize(&mut self, indices: &[usize]) {
        let n = indices.len();
        match self {
            Bank::Exact(b) => {
                b.est = indices.iter().map(|&i| b.est[i].clone()).collect();
                b.next.clone_from(&b.est);
            }
            Bank::Steady(b) => {
                let blocks = n.div_ceil(BLOCK);
                // Whole blocks: the padding particles stay at zero, as in `Bank::new`.
                let mut x = vec![Row::ZERO; N_STATES * blocks];
                for (j, &i) in indices.iter().enumerate() {
                    for s in 0..N_STATES {
                        *at_mut(&mut x, N_STATES, s, j) = at(&b.x, N_STATES, s, i);
                    }
                }
                b.x = x;
                b.next = vec![Row::ZERO; N_STATES * blocks];
                b.yaw = vec![Row::ZERO; blocks];
                b.series = vec![Row::ZERO; blocks];
                b.body = vec![Row::ONE; blocks];
                b.nodes = vec![Row::ZERO; NODE_LEN * blocks];
                b.node_theta = vec![[f64::NAN; 2]; n];
                b.node_ln_mass = vec![0.0; n];
                b.n = n;
            }
        }
    }

    /// Every filter back at its start (`Bank::new`): the state at rest, and (exact) the
    /// start's covariance.
    pub(super) fn reset_states(&mut self) {
        match self {
            Bank::Exact(b) => {
                for e in &mut b.est {
                    e.x = Vector17::zeros();
                    e.p = initial_covariance();
                }
            }
            Bank::Steady(b) => b.x.fill(Row::ZERO),
        }
    }

    /// Every filter's state set to `x` (and, exact, its covariance to `p`): the common state
    /// estimated after a pause (`super::resume_init`).
    pub(super) fn set_all_states(&mut self, x: &Vector17, p: &Matrix17) {
        match self {
            Bank::Exact(b) => {
                for e in &mut b.est {
                    e.x = *x;
                    e.p = *p;
                }
            }
            Bank::Steady(b) => {
                // The real particles only: the padding stays at zero (`Bank::new`).
                for s in 0..N_STATES {
                    for i in 0..b.n {
                        *at_mut(&mut b.x, N_STATES, s, i) = x[s];
                    }
                }
            }
        }
    }

    /// Gives particle `dst` the filter state of particle `src` of `from` (a bank of the same
    /// propagation: the sentinels of `super::jump`).
    pub(super) fn copy_particle(&mut self, dst: usize, from: &Bank, src: usize) {
        match (self, from) {
            (Bank::Exact(b), Bank::Exact(f)) => b.est[dst].clone_from(&f.est[src]),
            (Bank::Steady(b), Bank::Steady(f)) => {
                for s in 0..N_STATES {
                    *at_mut(&mut b.x, N_STATES, s, dst) = at(&f.x, N_STATES, s, src);
                }
            }
            _ => unreachable!("the sentinels are built with the particles' propagation"),
        }
    }

    /// Posterior state mean of particle `i` (for tests and diagnostics).
    pub(super) fn state(&self, i: usize) -> Vector17 {
        match self {
            Bank::Exact(b) => b.est[i].x,
            Bank::Steady(b) => Vector17::from_fn(|s, _| at(&b.x, N_STATES, s, i)),
        }
    }

    /// Posterior covariance of particle `i`; the steady-state filter's is the Riccati
    /// solution `(I - K H) P-` of its parameters, not stored per particle.
    pub(super) fn covariance(&self, i: usize) -> Option<Matrix17> {
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
        ln_mass: &[f64],
        y: &Vector5,
        whiten: &Whitening,
        mut out: StepOutput<'_>,
    ) -> Result<(), DamperError> {
        // Parameters change only at kernel moves (or every step with `EveryStep`): refresh the
        // damper entries and the interpolated gain of the particles that moved.
        let mut node = [0.0; NODE_LEN];
        for (i, th) in ln_theta.iter().enumerate() {
            let lm = ln_mass.get(i).copied().unwrap_or(0.0);
            if self.node_theta[i] != *th || self.node_ln_mass[i] != lm {
                self.yaw[i / BLOCK][i % BLOCK] = self.csay_gain * th[1].exp();
                self.series[i / BLOCK][i % BLOCK] = self.end_stiffness * (-th[0]).exp();
                self.body[i / BLOCK][i % BLOCK] = (-lm).exp();
                let grid = self.grid_of_mass(lm)?;
                grid.interpolate(&grid.cell(*th), &mut node);
                for (k, v) in node.iter().enumerate() {
                    *at_mut(&mut self.nodes, NODE_LEN, k, i) = *v;
                }
                self.node_theta[i] = *th;
                self.node_ln_mass[i] = lm;
            }
        }
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                // SAFETY: the CPU supports AVX-512F, checked just above.
                unsafe { self.filter_all_avx512(y, whiten, &mut out) };
                return check_finite(out.ll);
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: the CPU supports AVX2, checked just above.
                unsafe { self.filter_all_avx2(y, whiten, &mut out) };
                return check_finite(out.ll);
            }
        }
        self.filter_all(y, whiten, &mut out);
        check_finite(out.ll)
    }

    /// The gain grid of the mass node nearest to `m_model exp(ln_mass)` at the current speed
    /// node: the schedule's own at the model's mass.
    fn grid_of_mass(&mut self, ln_mass: f64) -> Result<Arc<GainGrid>, DamperError> {
        if ln_mass == 0.0 {
            return Ok(self.grid.clone());
        }
        let p = self.model.params();
        let node = self
            .table
            .node_at(p.speed_m_s, p.half_body_mass_kg * ln_mass.exp());
        if node == self.grid_node {
            return Ok(self.grid.clone());
        }
        if let Some((_, g)) = self.mass_grids.iter().find(|(k, _)| *k == node) {
            return Ok(g.clone());
        }
        let g = self.table.grid_for_filter(node)?;
        self.mass_grids.push((node, g.clone()));
        Ok(g)
    }

    /// [`SteadyBank::filter_all`] compiled for AVX-512 (8-wide vectors). The particles are
    /// independent lanes and no sum runs across them, so every width gives the same bits.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn filter_all_avx512(&mut self, y: &Vector5, whiten: &Whitening, out: &mut StepOutput) {
        self.filter_all(y, whiten, out)
    }

    /// [`SteadyBank::filter_all`] compiled for AVX2 (4-wide vectors instead of SSE2's 2).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn filter_all_avx2(&mut self, y: &Vector5, whiten: &Whitening, out: &mut StepOutput) {
        self.filter_all(y, whiten, out)
    }

    /// Predict, innovation, log-likelihood and update of every particle, block by block,
    /// each sum in the order the per-particle formula gives it.
    #[inline(always)]
    fn filter_all(&mut self, y: &Vector5, whiten: &Whitening, out: &mut StepOutput) {
        let n = self.n;
        // ln det of D^1/2 S D^1/2 is ln det S + ln det D; exactly the old constant at D = I.
        let const_term = N_OUTPUTS as f64 * LN_2PI + whiten.ln_det;
        let blk = &mut self.block;
        for (b, i0) in (0..n).step_by(BLOCK).enumerate() {
            let len = BLOCK.min(n - i0);
            // Propagated and updated in place in the new posterior's rows.
            let states = b * N_STATES..(b + 1) * N_STATES;
            let x: &[Row; N_STATES] = self.x[states.clone()].try_into().expect("whole block");
            let acc: &mut [Row; N_STATES] =
                (&mut self.next[states]).try_into().expect("whole block");
            let body = &self.body[b];
            self.prop
                .propagate_block(x, &self.yaw[b], &self.series[b], body, acc, blk);
            self.prop.innovation_block(acc, body, &mut blk.e, y);
            let nodes = &self.nodes[b * NODE_LEN..(b + 1) * NODE_LEN];
            let node = |k: usize| &nodes[k].0;
            let e = &blk.e;
            // The whitened innovations e_i / sqrt(d_i) (bit for bit e at d = 1).
            let ew: [[f64; BLOCK]; N_OUTPUTS] =
                std::array::from_fn(|r| e[r].map(|v| v * whiten.inv_sqrt[r]));
            // ln N(e; 0, D^1/2 S D^1/2) with S^-1 and ln det S of each particle's parameters:
            // the quadratic form summed entry by entry in row-major order.
            let ln_det = node(LN_DET_OFFSET);
            let mut l: [f64; BLOCK] = std::array::from_fn(|j| const_term + ln_det[j]);
            for r in 0..N_OUTPUTS {
                for c in 0..N_OUTPUTS {
                    let s_inv = node(S_INV_OFFSET + r * N_OUTPUTS + c);
                    for j in 0..BLOCK {
                        l[j] += s_inv[j] * ew[r][j] * ew[c][j];
                    }
                }
            }
            // e' S^-1 e, for the filter's consistency check (taken from the sum so that the
            // likelihoods stay bit for bit what they were).
            let nis: [f64; BLOCK] = std::array::from_fn(|j| l[j] - (const_term + ln_det[j]));
            let ll = l.map(|v| -0.5 * v);
            // x+ = x- + K e, each state's corrections added in the order of the outputs.
            for (s, acc_row) in acc.iter_mut().enumerate() {
                let mut a = acc_row.0;
                for (m, e_m) in e.iter().enumerate() {
                    let k = node(s * N_OUTPUTS + m);
                    for j in 0..BLOCK {
                        a[j] += k[j] * e_m[j];
                    }
                }
                acc_row.0 = a;
            }
            // z_i = e_i^2 / S_ii, for the noise-scale estimate.
            for (r, e_row) in blk.e.iter().enumerate() {
                let zs = &mut out.z[r * n + i0..r * n + i0 + len];
                for ((z, e), inv_s) in zs
                    .iter_mut()
                    .zip(e_row.iter())
                    .zip(node(INV_S_DIAG_OFFSET + r))
                {
                    *z = e * e * inv_s;
                }
            }
            out.ll[i0..i0 + len].copy_from_slice(&ll[..len]);
            out.nis[i0..i0 + len].copy_from_slice(&nis[..len]);
        }
    }
}

/// Value `k` of particle `i` in a blocked structure-of-arrays of `values` values per
/// particle: each block of [`BLOCK`] particles holds its values as `values` rows, so a
/// block's data are one contiguous stretch (the prefetcher follows one stream, not one per
/// value) of cache-aligned rows.
#[inline(always)]
fn at(rows: &[Row], values: usize, k: usize, i: usize) -> f64 {
    rows[(i / BLOCK) * values + k][i % BLOCK]
}

#[inline(always)]
fn at_mut(rows: &mut [Row], values: usize, k: usize, i: usize) -> &mut f64 {
    &mut rows[(i / BLOCK) * values + k][i % BLOCK]
}

fn check_finite(ll: &[f64]) -> Result<(), DamperError> {
    if ll.iter().any(|v| !v.is_finite()) {
        return Err(DamperError::NonFinite {
            what: "particle likelihood",
        });
    }
    Ok(())
}
