//! Steady-state Kalman gains on a grid of `(ln C_sy, ln C_say)`, interpolated bilinearly,
//! one grid per node of a geometric grid of forward speeds (nearest node).
//!
//! Once a particle's Kalman filter has run for a few seconds with (nearly) fixed parameters,
//! its covariance is the Riccati solution of its `theta` (`kalman::steady_state`); the
//! parameters move only by the small Liu-West kernel steps, so the gain, `S^-1` and `ln det S`
//! are smooth functions of `theta` that can be tabulated once. The fast filter then carries
//! only the 17-vector state per particle.

use std::ops::RangeInclusive;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock, TryLockError};

use serde::{Deserialize, Serialize};

use crate::expm::discretize;
use crate::filter_model::FilterModel;
use crate::fingerprint::Fnv128;
use crate::kalman::{steady_state, NoiseCovariances};
use crate::model::{BogieModel, N_OUTPUTS, N_STATES};
use crate::params::{positive, Dampers, HALF_BODY_MASS_RATIO};
use crate::speed::SpeedConfig;
use crate::DamperError;

/// Bounds of `points_per_axis` (declared to the settings reference and checked): a speed node
/// solves `points_per_axis^2` Riccati equations (33^2 took 0.28-0.53 s), so 129 already costs
/// several seconds per node and minutes for a speed table.
const POINTS_PER_AXIS: std::ops::RangeInclusive<usize> = 2..=129;

/// Grid of steady-state Riccati solutions over `(ln C_sy, ln C_say)`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct GainGridConfig {
    /// Nodes per axis (`points_per_axis^2` Riccati solutions per speed node).
    #[schemars(range(min = *POINTS_PER_AXIS.start(), max = *POINTS_PER_AXIS.end()))]
    pub points_per_axis: usize,
    /// Lower end of the grid as a ratio of the nominal coefficients (both axes); particles
    /// outside use the edge gain (their own `Phi` stays exact).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub min_ratio: f64,
    /// Upper end of the grid as a ratio of the nominal coefficients (both axes).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub max_ratio: f64,
}

impl Default for GainGridConfig {
    fn default() -> Self {
        GainGridConfig {
            points_per_axis: 33,
            min_ratio: 0.1,
            max_ratio: 3.0,
        }
    }
}

impl GainGridConfig {
    /// Errors name the field by its place in the settings (`rbpf.gain_grid`), where the
    /// grid is configured.
    pub fn validate(&self) -> Result<(), DamperError> {
        if !POINTS_PER_AXIS.contains(&self.points_per_axis) {
            return Err(DamperError::InvalidParameter {
                field: "rbpf.gain_grid.points_per_axis",
                value: self.points_per_axis as f64,
                reason: "must be in 2..=129",
            });
        }
        positive("rbpf.gain_grid.min_ratio", self.min_ratio)?;
        positive("rbpf.gain_grid.max_ratio", self.max_ratio)?;
        if self.max_ratio <= self.min_ratio {
            return Err(DamperError::InvalidParameter {
                field: "rbpf.gain_grid.max_ratio",
                value: self.max_ratio,
                reason: "must exceed min_ratio",
            });
        }
        Ok(())
    }
}

/// Values stored per node: gain (17 x 5, row-major), `S^-1` (5 x 5, row-major), `ln det S`,
/// `1 / S_ii` (5: the normalisers of the noise-scale estimate, `crate::noise_scale`).
pub const GAIN_LEN: usize = N_STATES * N_OUTPUTS;
pub const S_INV_OFFSET: usize = GAIN_LEN;
pub const LN_DET_OFFSET: usize = GAIN_LEN + N_OUTPUTS * N_OUTPUTS;
pub const INV_S_DIAG_OFFSET: usize = LN_DET_OFFSET + 1;
pub const NODE_LEN: usize = INV_S_DIAG_OFFSET + N_OUTPUTS;

/// The tabulated steady states at one speed.
#[derive(Debug, Clone, PartialEq)]
pub struct GainGrid {
    ln_min: [f64; 2],
    ln_step: [f64; 2],
    n: usize,
    /// Node `(i, j)` (i along `C_sy`, j along `C_say`) at `(i * n + j) * NODE_LEN`.
    data: Vec<f64>,
}

/// Where a parameter falls in the table: the lower-left node and the bilinear weights.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cell {
    pub node: usize,
    pub frac: [f64; 2],
}

impl GainGrid {
    /// Solves the Riccati equation at every node: `points_per_axis^2` solutions, at the
    /// model's speed.
    pub fn build(
        model: &BogieModel,
        noise: &NoiseCovariances,
        nominal: &Dampers,
        grid: &GainGridConfig,
        dt_s: f64,
    ) -> Result<Arc<Self>, DamperError> {
        let n = grid.points_per_axis;
        let (ln_min, ln_step) = geometry(nominal, grid);
        let mut data = vec![0.0; n * n * NODE_LEN];
        for i in 0..n {
            for j in 0..n {
                let node = &mut data[(i * n + j) * NODE_LEN..(i * n + j + 1) * NODE_LEN];
                solve_point(model, noise, dt_s, ln_min, ln_step, [i, j], node)?;
            }
        }
        Ok(Arc::new(GainGrid {
            ln_min,
            ln_step,
            n,
            data,
        }))
    }

    /// The stored values, node `(i, j)` at `(i * n + j) * NODE_LEN` (for a cache:
    /// [`GainTable::import`] takes them back).
    pub fn values(&self) -> &[f64] {
        &self.data
    }

    /// The cell of `ln theta`, clamped to the table (outside it the edge value holds).
    #[inline]
    pub fn cell(&self, ln_theta: [f64; 2]) -> Cell {
        let mut idx = [0usize; 2];
        let mut frac = [0.0; 2];
        for k in 0..2 {
            let u =
                ((ln_theta[k] - self.ln_min[k]) / self.ln_step[k]).clamp(0.0, (self.n - 1) as f64);
            let i = (u.floor() as usize).min(self.n - 2);
            idx[k] = i;
            frac[k] = u - i as f64;
        }
        Cell {
            node: idx[0] * self.n + idx[1],
            frac,
        }
    }

    /// Bilinear blend of the four nodes around `cell` into `out` (length `NODE_LEN`).
    #[inline]
    pub fn interpolate(&self, cell: &Cell, out: &mut [f64; NODE_LEN]) {
        let [f0, f1] = cell.frac;
        let w = [
            (1.0 - f0) * (1.0 - f1),
            (1.0 - f0) * f1,
            f0 * (1.0 - f1),
            f0 * f1,
        ];
        let base = cell.node * NODE_LEN;
        let row = self.n * NODE_LEN;
        let c00 = &self.data[base..base + NODE_LEN];
        let c01 = &self.data[base + NODE_LEN..base + 2 * NODE_LEN];
        let c10 = &self.data[base + row..base + row + NODE_LEN];
        let c11 = &self.data[base + row + NODE_LEN..base + row + 2 * NODE_LEN];
        for k in 0..NODE_LEN {
            out[k] = w[0] * c00[k] + w[1] * c01[k] + w[2] * c10[k] + w[3] * c11[k];
        }
    }
}

/// The grid's lower corner and steps in `ln theta`.
fn geometry(nominal: &Dampers, grid: &GainGridConfig) -> ([f64; 2], [f64; 2]) {
    let n = grid.points_per_axis;
    let nom = nominal.ln();
    let ln_min = [nom[0] + grid.min_ratio.ln(), nom[1] + grid.min_ratio.ln()];
    let span = (grid.max_ratio / grid.min_ratio).ln();
    (ln_min, [span / (n - 1) as f64; 2])
}

/// The steady state at grid point `(i, j)` into `node` (length `NODE_LEN`).
fn solve_point(
    model: &BogieModel,
    noise: &NoiseCovariances,
    dt_s: f64,
    ln_min: [f64; 2],
    ln_step: [f64; 2],
    [i, j]: [usize; 2],
    node: &mut [f64],
) -> Result<(), DamperError> {
    let d = Dampers::from_ln([
        ln_min[0] + i as f64 * ln_step[0],
        ln_min[1] + j as f64 * ln_step[1],
    ]);
    let disc = discretize(&model.a_matrix(&d), &model.g_matrix(), dt_s)?;
    let ss = steady_state(&disc, &model.h_matrix(), noise)?;
    for r in 0..N_STATES {
        for c in 0..N_OUTPUTS {
            node[r * N_OUTPUTS + c] = ss.gain[(r, c)];
        }
    }
    for r in 0..N_OUTPUTS {
        for c in 0..N_OUTPUTS {
            node[S_INV_OFFSET + r * N_OUTPUTS + c] = ss.s_inv[(r, c)];
        }
    }
    node[LN_DET_OFFSET] = ss.ln_det_s;
    for (r, v) in ss.s_diag.iter().enumerate() {
        node[INV_S_DIAG_OFFSET + r] = 1.0 / v;
    }
    Ok(())
}

/// Version of the solution a [`GainTable::fingerprint`] names: raise it whenever the solver
/// (`expm::discretize`, `kalman::steady_state`, [`GainGrid::build`]) or the layout of
/// [`GainGrid::values`] changes, so that a cache of the old solutions is not used. (A cached
/// node is also checked against a fresh solution of one of its points on import.)
pub const GAIN_SOLUTION_VERSION: u32 = 1;

/// Ratio of neighbouring body-mass nodes of the gain table (geometric grid about the design
/// mass over [`HALF_BODY_MASS_RATIO`]): a filter's gains are those of a mass within
/// `sqrt(1.05) - 1 = 2.5 %` of the measured one (its propagation and `H` use the measured
/// mass exactly). Not a setting: the load signal's own error is of that order.
pub const MASS_GRID_RATIO: f64 = 1.05;

/// Where a table takes a node's solution from before solving it: the solved nodes stored at
/// the edge (the gain cache on disk, `railmon_records::gain_cache`), imported with
/// [`GainTable::import`] and its checks. The maths stays here, the files there.
pub trait NodeSource: Send + Sync + std::fmt::Debug {
    /// Imports node `node` into `table` if the source holds it; a stored node refused is the
    /// source's to report (the table then solves the node).
    fn fill(&self, table: &GainTable, node: usize);
}

/// The gain grids of one vehicle over its speed range and body-mass range, built on first
/// use and shared by every filter of that vehicle (`Arc`, thread-safe).
///
/// The creep forces make the model depend on `1 / v` (`model::SPEED_ENTRIES`), so the speed
/// nodes are geometric, `v_k = v_0 r^k` about the configured speed `v_0`
/// (`speed.grid_ratio = r`), covering `[speed.min_m_s, speed.max_m_s]`. A filter uses the
/// grid of the node nearest in `ln v` (a relative speed error of at most `sqrt(r) - 1`):
/// it changes only when the speed crosses into another node's cell, and at the configured
/// speed itself it is that speed's own grid. The propagation and `H` always use the exact
/// measured speed; only the gain, `S^-1` and `ln det S` come from the node (their error in
/// likelihood is measured in `docs/damper.md`).
///
/// The body mass above the bogie (`m_bd`, measured: `BogieSample::half_body_mass_kg`) is
/// scheduled the same way, on a second axis: mass nodes `m_j = m_0 MASS_GRID_RATIO^j` about
/// the design mass `m_0` over [`HALF_BODY_MASS_RATIO`], the node nearest in `ln m`. A node
/// index names a (speed, mass) pair: `layer * n_nodes() + speed node`, where layer 0 is the
/// design mass, so that the nodes `0..n_nodes()` are the design-mass speed nodes they always
/// were (what a service without a load signal warms and caches); the other layers
/// (`n_mass_nodes()` in all) are solved when a filter first reaches their mass.
#[derive(Debug)]
pub struct GainTable {
    /// Where a node not solved yet is looked for first ([`GainTable::set_source`]).
    source: OnceLock<Box<dyn NodeSource>>,
    model: BogieModel,
    noise: NoiseCovariances,
    nominal: Dampers,
    grid: GainGridConfig,
    dt_s: f64,
    ln_ratio: f64,
    /// `k` of the first node (`v_0 r^k_min`).
    k_min: i32,
    /// Speed nodes per mass layer.
    n_speed: usize,
    /// `j` of the lightest and heaviest mass nodes (`m_0 MASS_GRID_RATIO^j`, `j_min <= 0 <=
    /// j_max`).
    j_range: (i32, i32),
    /// Each speed node's grid once solved. One lock per node, held while the node is being
    /// solved: a second filter (or a warming thread, [`GainTable::missing_near`]) asking for
    /// the same node waits for that solution instead of solving it again.
    nodes: Vec<Mutex<Option<Arc<GainGrid>>>>,
    /// Time filters spent waiting for or solving a node they reached unsolved
    /// ([`GainTable::filter_stall_ns`]), summed over the threads.
    filter_stall_ns: AtomicU64,
}

impl GainTable {
    /// The table of the filters' model `model` (unvalidated: the caller checks `model`,
    /// `grid` and `speed`).
    pub fn for_model(
        model: &FilterModel,
        grid: &GainGridConfig,
        speed: &SpeedConfig,
    ) -> Result<Arc<Self>, DamperError> {
        GainTable::build(
            &model.bogie_model()?,
            &model.noise(),
            &model.nominal,
            grid,
            speed,
            model.dt_s,
        )
    }

    /// The table of `model`'s vehicle; builds the grid of the model's (configured) speed now,
    /// the others when first asked for.
    pub fn build(
        model: &BogieModel,
        noise: &NoiseCovariances,
        nominal: &Dampers,
        grid: &GainGridConfig,
        speed: &SpeedConfig,
        dt_s: f64,
    ) -> Result<Arc<Self>, DamperError> {
        let table = GainTable::unsolved(model, noise, nominal, grid, speed, dt_s);
        table.grid_at(table.configured_node())?;
        Ok(Arc::new(table))
    }

    /// The table with no node solved.
    fn unsolved(
        model: &BogieModel,
        noise: &NoiseCovariances,
        nominal: &Dampers,
        grid: &GainGridConfig,
        speed: &SpeedConfig,
        dt_s: f64,
    ) -> GainTable {
        let v0 = model.params().speed_m_s;
        let ln_ratio = speed.grid_ratio.ln();
        let k_of = |v: f64| ((v / v0).ln() / ln_ratio).round() as i32;
        let k_min = k_of(speed.min_m_s).min(0);
        let k_max = k_of(speed.max_m_s).max(0);
        let n_speed = (k_max - k_min + 1) as usize;
        let j_of = |ratio: f64| (ratio.ln() / MASS_GRID_RATIO.ln()).round() as i32;
        let j_range = (
            j_of(*HALF_BODY_MASS_RATIO.start()).min(0),
            j_of(*HALF_BODY_MASS_RATIO.end()).max(0),
        );
        let n_mass = (j_range.1 - j_range.0 + 1) as usize;
        GainTable {
            source: OnceLock::new(),
            model: model.clone(),
            noise: *noise,
            nominal: *nominal,
            grid: *grid,
            dt_s,
            ln_ratio,
            k_min,
            n_speed,
            j_range,
            nodes: (0..n_speed * n_mass).map(|_| Mutex::new(None)).collect(),
            filter_stall_ns: AtomicU64::new(0),
        }
    }

    /// As [`GainTable::for_model`] without solving any node yet: for a caller that first
    /// imports stored nodes ([`GainTable::import`]).
    pub fn unsolved_for_model(
        model: &FilterModel,
        grid: &GainGridConfig,
        speed: &SpeedConfig,
    ) -> Result<Arc<Self>, DamperError> {
        Ok(Arc::new(GainTable::unsolved(
            &model.bogie_model()?,
            &model.noise(),
            &model.nominal,
            grid,
            speed,
            model.dt_s,
        )))
    }

    /// How many values a node's grid holds ([`GainGrid::values`]).
    pub fn values_per_node(&self) -> usize {
        self.grid.points_per_axis * self.grid.points_per_axis * NODE_LEN
    }

    /// The node of the vehicle's configured speed (solved first by [`GainTable::build`]).
    pub fn configured_node(&self) -> usize {
        self.node_of(self.model.params().speed_m_s)
    }

    /// The model at node `node`'s speed and body mass (the design mass's layer: the model
    /// as configured, bit for bit).
    fn model_at(&self, node: usize) -> Result<BogieModel, DamperError> {
        let mut model = self.model.clone();
        model.set_speed(self.node_speed_m_s(node))?;
        if node >= self.n_speed {
            model.set_half_body_mass_kg(self.node_half_body_mass_kg(node))?;
        }
        Ok(model)
    }

    /// A stable hash of everything node `node`'s solution is computed from (the model's
    /// matrices at the node's speed and body mass, the noise, the grid, the sample period) and of
    /// [`GAIN_SOLUTION_VERSION`]: the same on every platform and build, different (but for
    /// a 2^-128 chance) whenever the solution would be. The key of a stored node.
    pub fn fingerprint(&self, node: usize) -> Result<u128, DamperError> {
        let model = self.model_at(node)?;
        let (ln_min, ln_step) = geometry(&self.nominal, &self.grid);
        let mut h = Fnv128::default();
        h.bytes(b"railmon gain grid")
            .u64(GAIN_SOLUTION_VERSION as u64)
            .u64(NODE_LEN as u64)
            .u64(self.grid.points_per_axis as u64)
            .f64s(&ln_min)
            .f64s(&ln_step)
            .f64(self.dt_s);
        model.hash_solver_inputs(&mut h);
        h.f64s(self.noise.q_w.iter())
            .f64s(self.noise.q_v.iter())
            .f64(self.noise.q_floor);
        Ok(h.finish())
    }

    /// Has every node not solved yet looked for in `source` before it is solved, when a
    /// filter (or anyone) first asks for it ([`GainTable::grid_at`]): a run reads the nodes
    /// it reaches instead of all of them ahead. One source per table: `false` if one was set.
    pub fn set_source(&self, source: Box<dyn NodeSource>) -> bool {
        self.source.set(source).is_ok()
    }

    /// Takes node `node`'s grid from stored `values` ([`GainGrid::values`] of a grid solved
    /// for the same [`GainTable::fingerprint`]), exactly: the filters then compute what they
    /// would with the node solved here. Checked first: the length, every value finite, and one
    /// grid point (the centre) solved afresh must match to the bit; an error says which check
    /// failed and leaves the node as it was. `Ok(false)`: the node was already solved (kept).
    pub fn import(&self, node: usize, values: Vec<f64>) -> Result<bool, DamperError> {
        let n = self.grid.points_per_axis;
        let invalid = |reason: &'static str| DamperError::InvalidParameter {
            field: "gain grid",
            value: node as f64,
            reason,
        };
        if values.len() != n * n * NODE_LEN {
            return Err(invalid("stored grid has the wrong number of values"));
        }
        if values.iter().any(|v| !v.is_finite()) {
            return Err(invalid("stored grid has a non-finite value"));
        }
        let (ln_min, ln_step) = geometry(&self.nominal, &self.grid);
        let (i, j) = (n / 2, n / 2);
        let at = (i * n + j) * NODE_LEN;
        let mut fresh = [0.0; NODE_LEN];
        solve_point(
            &self.model_at(node)?,
            &self.noise,
            self.dt_s,
            ln_min,
            ln_step,
            [i, j],
            &mut fresh,
        )?;
        let stored = &values[at..at + NODE_LEN];
        if fresh
            .iter()
            .zip(stored)
            .any(|(a, b)| a.to_bits() != b.to_bits())
        {
            return Err(invalid(
                "stored grid differs from a fresh solution of its centre point",
            ));
        }
        let mut cell = self.nodes[node]
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        if cell.is_some() {
            return Ok(false);
        }
        *cell = Some(Arc::new(GainGrid {
            ln_min,
            ln_step,
            n,
            data: values,
        }));
        Ok(true)
    }

    /// Node `node`'s grid if it has been solved (waits for a solution under way).
    pub fn solved_grid(&self, node: usize) -> Option<Arc<GainGrid>> {
        self.nodes[node]
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
            .clone()
    }

    /// The design-mass node whose cell holds `speed_m_s` (clamped to the table).
    pub fn node_of(&self, speed_m_s: f64) -> usize {
        let v0 = self.model.params().speed_m_s;
        let k = ((speed_m_s / v0).ln() / self.ln_ratio).round();
        let last = (self.n_speed - 1) as f64;
        (k - self.k_min as f64).clamp(0.0, last) as usize
    }

    /// The node whose cell holds `speed_m_s` and `half_body_mass_kg` (each clamped to the
    /// table): [`GainTable::node_of`] itself at the design mass.
    pub fn node_at(&self, speed_m_s: f64, half_body_mass_kg: f64) -> usize {
        let j = *self
            .mass_node_js(half_body_mass_kg..=half_body_mass_kg)
            .start();
        self.layer_of(j) * self.n_speed + self.node_of(speed_m_s)
    }

    /// The layer of mass node `j`: 0 for the design mass, then the lighter nodes from the
    /// lightest, then the heavier ones.
    fn layer_of(&self, j: i32) -> usize {
        let below = -self.j_range.0;
        match j {
            0 => 0,
            j if j < 0 => (j + below + 1) as usize,
            j => (j + below) as usize,
        }
    }

    /// `j` of layer `layer` (inverse of `layer_of`).
    fn j_of_layer(&self, layer: usize) -> i32 {
        let below = -self.j_range.0;
        match layer as i32 {
            0 => 0,
            l if l <= below => l - below - 1,
            l => l - below,
        }
    }

    /// The speed of node `node` (m/s).
    pub fn node_speed_m_s(&self, node: usize) -> f64 {
        let k = (node % self.n_speed) as i32 + self.k_min;
        self.model.params().speed_m_s * (self.ln_ratio * k as f64).exp()
    }

    /// The body mass above the bogie of node `node` (kg).
    pub fn node_half_body_mass_kg(&self, node: usize) -> f64 {
        let j = self.j_of_layer(node / self.n_speed);
        self.model.params().half_body_mass_kg * (MASS_GRID_RATIO.ln() * j as f64).exp()
    }

    /// The design-mass speed nodes: `0..n_nodes()` (the layer a service without a load
    /// signal uses, warms and caches).
    pub fn n_nodes(&self) -> usize {
        self.n_speed
    }

    /// The mass nodes (layers of `n_nodes()` speed nodes each).
    pub fn n_mass_nodes(&self) -> usize {
        self.nodes.len() / self.n_speed
    }

    /// The grid of node `node`, solved on first use (about 0.3 s for 33 x 33 in a release
    /// build, `cargo bench -p railmon-damper --bench rbpf_variants`); meanwhile other callers
    /// for the same node wait.
    pub fn grid_at(&self, node: usize) -> Result<Arc<GainGrid>, DamperError> {
        // Outside the node's lock: the source imports through it (`GainTable::import`); two
        // callers filling the same node at once both read it, one import is kept.
        if let Some(source) = self.source.get() {
            if !self.is_solved(node) {
                source.fill(self, node);
            }
        }
        // A panic while solving leaves the node unsolved, not the lock unusable.
        let mut cell = self.nodes[node]
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        if let Some(g) = cell.as_ref() {
            return Ok(g.clone());
        }
        let model = self.model_at(node)?;
        let built = GainGrid::build(&model, &self.noise, &self.nominal, &self.grid, self.dt_s)?;
        *cell = Some(built.clone());
        Ok(built)
    }

    /// The node nearest to `speed_m_s`'s own within `reach` speed nodes either side, at a mass
    /// node within `half_body_masses_kg` (kg; the masses the filters run at: the measured one,
    /// the span of the particles' own, or the design mass), that is neither solved nor being
    /// solved, if any: nearest in speed first (the slower side first on a tie), then the
    /// lightest mass. For a caller that solves nodes ahead of the filters
    /// ([`GainTable::grid_at`] on another thread), so that a filter reaching a new speed or
    /// mass does not stall for the solution.
    pub fn missing_near(
        &self,
        speed_m_s: f64,
        half_body_masses_kg: RangeInclusive<f64>,
        reach: usize,
    ) -> Option<usize> {
        let centre = self.node_of(speed_m_s);
        let layer_nodes: Vec<usize> = self
            .mass_node_js(half_body_masses_kg)
            .map(|j| self.layer_of(j) * self.n_speed)
            .collect();
        let unsolved = |node: usize| match self.nodes[node].try_lock() {
            Ok(cell) => cell.is_none(),
            Err(TryLockError::Poisoned(p)) => p.into_inner().is_none(),
            // Being solved (or looked up) right now.
            Err(TryLockError::WouldBlock) => false,
        };
        (0..=reach).find_map(|d| {
            [centre.checked_sub(d), Some(centre + d)]
                .into_iter()
                .flatten()
                .filter(|&speed_node| speed_node < self.n_speed)
                .flat_map(|speed_node| layer_nodes.iter().map(move |&l| l + speed_node))
                .find(|&node| unsolved(node))
        })
    }

    /// Every node (every speed) of the mass nodes whose cells meet `half_body_masses_kg`
    /// (kg; clamped to the table), the lightest mass's first.
    pub fn nodes_of_masses(&self, half_body_masses_kg: RangeInclusive<f64>) -> Vec<usize> {
        self.mass_node_js(half_body_masses_kg)
            .flat_map(|j| {
                let first = self.layer_of(j) * self.n_speed;
                first..first + self.n_speed
            })
            .collect()
    }

    /// `j` of the mass nodes whose cells meet `half_body_masses_kg` (clamped to the table).
    fn mass_node_js(&self, half_body_masses_kg: RangeInclusive<f64>) -> RangeInclusive<i32> {
        let m0 = self.model.params().half_body_mass_kg;
        let j = |m: f64| {
            let j = ((m / m0).ln() / MASS_GRID_RATIO.ln()).round();
            j.clamp(self.j_range.0 as f64, self.j_range.1 as f64) as i32
        };
        j(*half_body_masses_kg.start())..=j(*half_body_masses_kg.end())
    }

    /// [`GainTable::grid_at`] for a filter's step: the time it stalls on a node not yet
    /// solved (solving it, or waiting for the thread solving it) is added to
    /// [`GainTable::filter_stall_ns`]. A solved node costs what it did.
    pub fn grid_for_filter(&self, node: usize) -> Result<Arc<GainGrid>, DamperError> {
        // Not blocking: a node being solved is a stall too.
        let solved = match self.nodes[node].try_lock() {
            Ok(cell) => cell.clone(),
            Err(TryLockError::Poisoned(p)) => p.into_inner().clone(),
            Err(TryLockError::WouldBlock) => None,
        };
        if let Some(grid) = solved {
            return Ok(grid);
        }
        let start = std::time::Instant::now();
        let grid = self.grid_at(node);
        let stalled = u64::try_from(start.elapsed().as_nanos()).unwrap_or(u64::MAX);
        self.filter_stall_ns.fetch_add(stalled, Ordering::Relaxed);
        grid
    }

    /// The time (ns, summed over threads) filters stalled on nodes not yet solved
    /// ([`GainTable::grid_for_filter`]): a one-off of reaching a new speed or mass, which a
    /// caller measuring the steps' cost keeps apart from it.
    pub fn filter_stall_ns(&self) -> u64 {
        self.filter_stall_ns.load(Ordering::Relaxed)
    }

    /// Whether node `node`'s grid has been solved (false while it is being solved).
    pub fn is_solved(&self, node: usize) -> bool {
        match self.nodes[node].try_lock() {
            Ok(cell) => cell.is_some(),
            Err(TryLockError::Poisoned(p)) => p.into_inner().is_some(),
            Err(TryLockError::WouldBlock) => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{DamperMonitorConfig, Rbpf};

    fn small() -> DamperMonitorConfig {
        let mut c = DamperMonitorConfig::default();
        c.rbpf.gain_grid.points_per_axis = 5;
        c
    }

    /// A node taken from another table's values is the node solved here, to the bit, and
    /// gives the same interpolated gains.
    #[test]
    fn an_imported_node_is_the_solved_node_to_the_bit() {
        let c = small();
        let solved = Rbpf::gain_table(&c.filter_model(), &c.rbpf, &c.speed).unwrap();
        let node = solved.configured_node() + 3;
        let grid = solved.grid_at(node).unwrap();
        let values = grid.values().to_vec();
        let stored: Vec<u64> = values.iter().map(|v| v.to_bits()).collect();
        // As a cache would: bits out, bits in.
        let loaded = Rbpf::unsolved_gain_table(&c.filter_model(), &c.rbpf, &c.speed).unwrap();
        assert_eq!(
            loaded.fingerprint(node).unwrap(),
            solved.fingerprint(node).unwrap()
        );
        assert!(!loaded.is_solved(node));
        let back = stored.iter().map(|&b| f64::from_bits(b)).collect();
        assert!(loaded.import(node, back).unwrap());
        let imported = loaded.solved_grid(node).unwrap();
        assert_eq!(*imported, *grid);
        let (mut a, mut b) = ([0.0; NODE_LEN], [0.0; NODE_LEN]);
        for ln in [[10.0, 11.0], [9.3, 12.7], [0.0, 0.0]] {
            let cell = grid.cell(ln);
            assert_eq!(cell, imported.cell(ln));
            grid.interpolate(&cell, &mut a);
            imported.interpolate(&cell, &mut b);
            assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
        }
        // Once solved a node stays as it is.
        assert!(!loaded.import(node, values).unwrap());
    }

    /// A table with a source asks it for a node when the node is first reached, and only
    /// then: what the source holds is used to the bit, what it does not is solved here.
    #[test]
    fn a_node_is_taken_from_the_source_when_first_reached() {
        #[derive(Debug)]
        struct Held {
            node: usize,
            values: Vec<f64>,
            asked: Mutex<Vec<usize>>,
        }
        impl NodeSource for Arc<Held> {
            fn fill(&self, table: &GainTable, node: usize) {
                self.asked.lock().unwrap().push(node);
                if node == self.node {
                    assert!(table.import(node, self.values.clone()).unwrap());
                }
            }
        }
        let c = small();
        let solved = Rbpf::gain_table(&c.filter_model(), &c.rbpf, &c.speed).unwrap();
        let node = solved.configured_node() + 2;
        let held = Arc::new(Held {
            node,
            values: solved.grid_at(node).unwrap().values().to_vec(),
            asked: Mutex::new(vec![]),
        });
        let t = Rbpf::unsolved_gain_table(&c.filter_model(), &c.rbpf, &c.speed).unwrap();
        assert!(t.set_source(Box::new(held.clone())));
        assert!(
            !t.set_source(Box::new(held.clone())),
            "one source per table"
        );
        assert!(held.asked.lock().unwrap().is_empty(), "nothing read ahead");
        let grid = t.grid_for_filter(node).unwrap();
        assert_eq!(*grid, *solved.grid_at(node).unwrap());
        let other = t.grid_at(node + 1).unwrap();
        assert_eq!(*other, *solved.grid_at(node + 1).unwrap());
        t.grid_at(node).unwrap();
        t.grid_at(node + 1).unwrap();
        assert_eq!(*held.asked.lock().unwrap(), vec![node, node + 1]);
    }

    /// A filter that reaches an unsolved node stalls, and says so; on a solved node it does
    /// not (the service keeps the stalls out of its compute load).
    #[test]
    fn a_filter_stalls_only_on_a_node_not_yet_solved() {
        let c = small();
        let t = Rbpf::gain_table(&c.filter_model(), &c.rbpf, &c.speed).unwrap();
        let node = t.configured_node();
        t.grid_for_filter(node).unwrap();
        assert_eq!(
            t.filter_stall_ns(),
            0,
            "the configured node is solved with the table"
        );
        let first = t.grid_for_filter(node + 1).unwrap();
        let stalled = t.filter_stall_ns();
        assert!(stalled > 0);
        let again = t.grid_for_filter(node + 1).unwrap();
        assert!(Arc::ptr_eq(&first, &again));
        assert_eq!(t.filter_stall_ns(), stalled);
    }

    /// The mass axis: the design mass's nodes are the speed nodes as they were (index and
    /// fingerprint), every other mass node is its own solution with its own key, nearest in
    /// `ln m`, clamped to the range.
    #[test]
    fn mass_nodes_are_scheduled_like_the_speed_nodes() {
        let c = small();
        let t = Rbpf::unsolved_gain_table(&c.filter_model(), &c.rbpf, &c.speed).unwrap();
        let (v0, m0) = (c.vehicle.speed_m_s, c.vehicle.half_body_mass_kg);
        let k = t.configured_node();
        assert_eq!(t.node_at(v0, m0), k);
        assert_eq!(t.node_at(v0, m0 * 1.02), k);
        assert_eq!(t.n_mass_nodes(), 18, "0.71-1.63 x design in steps of 5 %");
        let mut seen = std::collections::HashSet::new();
        for ratio in [0.7, 0.85, 1.0, 1.3, 1.6] {
            let node = t.node_at(v0, m0 * ratio);
            let m = t.node_half_body_mass_kg(node);
            assert!((m / (m0 * ratio)).ln().abs() <= 0.5 * MASS_GRID_RATIO.ln() + 1e-12);
            assert_eq!(t.node_speed_m_s(node), t.node_speed_m_s(k));
            assert!(seen.insert(t.fingerprint(node).unwrap()), "{ratio}");
        }
        let all = t.n_nodes() * t.n_mass_nodes();
        let nodes: std::collections::HashSet<_> = (0..all)
            .map(|n| {
                (
                    n % t.n_nodes(),
                    t.node_at(t.node_speed_m_s(n), t.node_half_body_mass_kg(n)),
                )
            })
            .map(|(_, n)| n)
            .collect();
        assert_eq!(
            nodes.len(),
            all,
            "every node is reached by its own speed and mass"
        );
        let lightest = t.node_at(v0, m0 * 0.1);
        assert_eq!(lightest, t.node_at(v0, m0 * 0.7));
        // The heavy node's grid differs from the design one.
        let table = Rbpf::gain_table(&c.filter_model(), &c.rbpf, &c.speed).unwrap();
        let heavy = table.node_at(v0, m0 * 1.3);
        assert_ne!(
            table.grid_at(heavy).unwrap().values(),
            table.grid_at(k).unwrap().values()
        );
    }

    /// Wrong length, non-finite values and values of another solution are refused, and the
    /// node stays unsolved.
    #[test]
    fn a_stored_grid_that_does_not_match_is_refused() {
        let c = small();
        let table = Rbpf::gain_table(&c.filter_model(), &c.rbpf, &c.speed).unwrap();
        let node = table.configured_node();
        let good = table.grid_at(node).unwrap().values().to_vec();
        let fresh = Rbpf::unsolved_gain_table(&c.filter_model(), &c.rbpf, &c.speed).unwrap();
        assert!(fresh.import(node, good[1..].to_vec()).is_err());
        let mut nan = good.clone();
        nan[7] = f64::NAN;
        assert!(fresh.import(node, nan).is_err());
        // Another node's solution under this node's key.
        let other = table.grid_at(node + 1).unwrap().values().to_vec();
        let e = fresh.import(node, other).unwrap_err();
        assert!(e.to_string().contains("fresh solution"), "{e}");
        assert!(!fresh.is_solved(node));
    }

    /// The fingerprint tells apart nodes, grids and models, and is stable: the value of the
    /// default settings is pinned, so that a change of what it covers is a decision
    /// (raise `GAIN_SOLUTION_VERSION` if the solution changes).
    #[test]
    fn the_fingerprint_names_what_the_solution_depends_on() {
        let c = DamperMonitorConfig::default();
        let t = Rbpf::unsolved_gain_table(&c.filter_model(), &c.rbpf, &c.speed).unwrap();
        let k = t.configured_node();
        let fp = t.fingerprint(k).unwrap();
        assert_ne!(fp, t.fingerprint(k + 1).unwrap());
        let mut g = c;
        g.rbpf.gain_grid.points_per_axis = 32;
        let tg = Rbpf::unsolved_gain_table(&g.filter_model(), &g.rbpf, &g.speed).unwrap();
        assert_ne!(fp, tg.fingerprint(tg.configured_node()).unwrap());
        let mut m = c;
        m.vehicle.bogie_mass_kg *= 1.0 + 1e-12;
        let tm = Rbpf::unsolved_gain_table(&m.filter_model(), &m.rbpf, &m.speed).unwrap();
        assert_ne!(fp, tm.fingerprint(tm.configured_node()).unwrap());
        // A wider speed range adds nodes but leaves the configured speed's node as it is.
        let mut s = c;
        s.speed.min_m_s = 2.0;
        let ts = Rbpf::unsolved_gain_table(&s.filter_model(), &s.rbpf, &s.speed).unwrap();
        assert_eq!(fp, ts.fingerprint(ts.configured_node()).unwrap());
        assert_eq!(format!("{fp:032x}"), "c9b090ed367aef3523db26d410d00223");
    }
}
