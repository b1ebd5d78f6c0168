//! Steady-state Kalman gains on a grid of `(ln C_sy, ln C_say)`, interpolated bilinearly,
//! one grid per node of a geometric grid of forward speeds (nearest node).
//!
//! Once a particle's Kalman filter has run for a few seconds with (nearly) fixed parameters,
//! its covariance is the Riccati solution of its `theta` (`kalman::steady_state`); the
//! parameters move only by the small Liu-West kernel steps, so the gain, `S^-1` and `ln det S`
//! are smooth functions of `theta` that can be tabulated once. The fast filter then carries
//! only the 17-vector state per particle.

use std::sync::{Arc, Mutex, TryLockError};

use serde::{Deserialize, Serialize};

use crate::expm::discretize;
use crate::filter_model::FilterModel;
use crate::kalman::{steady_state, NoiseCovariances};
use crate::model::{BogieModel, N_OUTPUTS, N_STATES};
use crate::params::{positive, Dampers};
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
        let nom = nominal.ln();
        let ln_min = [nom[0] + grid.min_ratio.ln(), nom[1] + grid.min_ratio.ln()];
        let span = (grid.max_ratio / grid.min_ratio).ln();
        let ln_step = [span / (n - 1) as f64; 2];
        let h = model.h_matrix();
        let g = model.g_matrix();
        let mut data = vec![0.0; n * n * NODE_LEN];
        for i in 0..n {
            for j in 0..n {
                let d = Dampers::from_ln([
                    ln_min[0] + i as f64 * ln_step[0],
                    ln_min[1] + j as f64 * ln_step[1],
                ]);
                let disc = discretize(&model.a_matrix(&d), &g, dt_s)?;
                let ss = steady_state(&disc, &h, noise)?;
                let node = &mut data[(i * n + j) * NODE_LEN..(i * n + j + 1) * NODE_LEN];
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
            }
        }
        Ok(Arc::new(GainGrid {
            ln_min,
            ln_step,
            n,
            data,
        }))
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

/// The gain grids of one vehicle over its speed range, built on first use and shared by
/// every filter of that vehicle (`Arc`, thread-safe).
///
/// The creep forces make the model depend on `1 / v` (`model::SPEED_ENTRIES`), so the speed
/// nodes are geometric, `v_k = v_0 r^k` about the configured speed `v_0`
/// (`speed.grid_ratio = r`), covering `[speed.min_m_s, speed.max_m_s]`. A filter uses the
/// grid of the node nearest in `ln v` (a relative speed error of at most `sqrt(r) - 1`):
/// it changes only when the speed crosses into another node's cell, and at the configured
/// speed itself it is that speed's own grid. The propagation and `H` always use the exact
/// measured speed; only the gain, `S^-1` and `ln det S` come from the node (their error in
/// likelihood is measured in `docs/damper.md`).
#[derive(Debug)]
pub struct GainTable {
    model: BogieModel,
    noise: NoiseCovariances,
    nominal: Dampers,
    grid: GainGridConfig,
    dt_s: f64,
    ln_ratio: f64,
    /// `k` of the first node (`v_0 r^k_min`).
    k_min: i32,
    /// Each speed node's grid once solved. One lock per node, held while the node is being
    /// solved: a second filter (or a warming thread, [`GainTable::missing_near`]) asking for
    /// the same node waits for that solution instead of solving it again.
    nodes: Vec<Mutex<Option<Arc<GainGrid>>>>,
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
        let v0 = model.params().speed_m_s;
        let ln_ratio = speed.grid_ratio.ln();
        let k_of = |v: f64| ((v / v0).ln() / ln_ratio).round() as i32;
        let k_min = k_of(speed.min_m_s).min(0);
        let k_max = k_of(speed.max_m_s).max(0);
        let table = GainTable {
            model: model.clone(),
            noise: *noise,
            nominal: *nominal,
            grid: *grid,
            dt_s,
            ln_ratio,
            k_min,
            nodes: (k_min..=k_max).map(|_| Mutex::new(None)).collect(),
        };
        table.grid_at(table.node_of(v0))?;
        Ok(Arc::new(table))
    }

    /// The node whose cell holds `speed_m_s` (clamped to the table).
    pub fn node_of(&self, speed_m_s: f64) -> usize {
        let v0 = self.model.params().speed_m_s;
        let k = ((speed_m_s / v0).ln() / self.ln_ratio).round();
        let last = (self.nodes.len() - 1) as f64;
        (k - self.k_min as f64).clamp(0.0, last) as usize
    }

    /// The speed of node `node` (m/s).
    pub fn node_speed_m_s(&self, node: usize) -> f64 {
        let k = node as i32 + self.k_min;
        self.model.params().speed_m_s * (self.ln_ratio * k as f64).exp()
    }

    pub fn n_nodes(&self) -> usize {
        self.nodes.len()
    }

    /// The grid of node `node`, solved on first use (about 0.3 s for 33 x 33 in a release
    /// build, `cargo bench -p railmon-damper --bench rbpf_variants`); meanwhile other callers
    /// for the same node wait.
    pub fn grid_at(&self, node: usize) -> Result<Arc<GainGrid>, DamperError> {
        // A panic while solving leaves the node unsolved, not the lock unusable.
        let mut cell = self.nodes[node]
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        if let Some(g) = cell.as_ref() {
            return Ok(g.clone());
        }
        let mut model = self.model.clone();
        model.set_speed(self.node_speed_m_s(node))?;
        let built = GainGrid::build(&model, &self.noise, &self.nominal, &self.grid, self.dt_s)?;
        *cell = Some(built.clone());
        Ok(built)
    }

    /// The node nearest to `speed_m_s`'s own within `reach` nodes either side that is neither
    /// solved nor being solved (nearest first, the slower side first on a tie), if any. For a
    /// caller that solves nodes ahead of the filters ([`GainTable::grid_at`] on another
    /// thread), so that a filter reaching a new speed does not stall for the solution.
    pub fn missing_near(&self, speed_m_s: f64, reach: usize) -> Option<usize> {
        let centre = self.node_of(speed_m_s);
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
                .filter(|&node| node < self.nodes.len())
                .find(|&node| unsolved(node))
        })
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
