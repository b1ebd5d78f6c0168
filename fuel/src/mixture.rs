//! Algorithm 3.4: recursive quasi-Bayes estimation of a mixture of normal regression components
//! and categorical components with a data-dependent switching model, one pass, `O(m_c^2)` per
//! step. This module works on prepared vectors (`y_t`, `psi_t`, the categorical cell and the
//! switching configuration); [`crate::FuelMonitor`] builds them from vehicle samples.

use nalgebra::{DMatrix, DVector};
use railmon_filter::logspace::{log_sum_exp, normalize_log_weights};

use crate::counts::CountTable;
use crate::regression::{Prediction, RegressionStats};
use crate::FuelError;

/// Sizes and settings of a [`Mixture`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MixtureSpec {
    /// `m_c`.
    pub components: usize,
    /// Dimension of `y_t`.
    pub k_y: usize,
    /// Dimension of `psi_t`.
    pub k_psi: usize,
    /// Categories `m_z` of `z_t` (0: no categorical component).
    pub categories: usize,
    /// Configurations `m_psi` of the categorical condition `psi^z_{t-1}`.
    pub categorical_rows: usize,
    /// Configurations `m_phi` of the switching condition `phi_{t-1}`.
    pub switching_rows: usize,
    /// Forgetting factor in (0, 1].
    pub forgetting: f64,
    /// Proximities with the GiW predictive covariance `r (1 + zeta)` instead of `r`.
    pub parameter_uncertainty: bool,
    /// Prior statistics of every component.
    pub prior_information: f64,
    pub prior_kappa: f64,
    pub min_noise_variance: f64,
    pub dirichlet_prior: f64,
    pub switching_prior_stay: f64,
    pub switching_prior_move: f64,
    /// Non-empty: the pointer is weighed by levels (docs/fuel.md, "The pointer weighed by
    /// levels"): `ln N(x | c)` of the channels of `y` at these indices under a static
    /// Gauss-inverse-Wishart per component (regressor `[1]`, no lags: a mean and covariance),
    /// updated with the pointer's weights, plus, unless the fuel (index 0) is among them,
    /// `ln N(y_0 | y_1..k_y, psi)` (fuel given every other channel now and the lags: the
    /// regression, the other channels as regressors only). Empty: the paper's proximity of all
    /// of `y`.
    #[serde(default)]
    pub level_channels: Vec<usize>,
    /// Floor on the eigenvalues of the level statistics' covariance (standardised units; 0:
    /// `min_noise_variance`).
    #[serde(default)]
    pub level_min_variance: f64,
    /// With level channels, `Some(channels)`: a standing vehicle (`MixtureInput::standing`) is
    /// a state of its own, not a point of the levels' continuum. Its speed is exactly 0 (and
    /// so is every level derived from it): as a Gaussian level that point mass either costs a
    /// tuning floor or pulls a standing component onto the slow creep into a platform
    /// (docs/fuel.md). So at standstill the evidence is the density of these level channels
    /// (indices into `y`, those measured while standing: the fuel) under the standing
    /// component's own static statistics, updated only with standing samples; the left-out
    /// channels are point masses at 0, the same for every component, so they drop out of the
    /// pointer. Standstill is observed, so it is a regime given, not learned: component 0 is
    /// the standing one, every standing sample is its and no moving sample is
    /// (`ln P_i(standing)` is 0 or minus infinity). A learned share (a Beta-Bernoulli count
    /// per component) was measured first: a component that brakes to a stop and stands pays
    /// only `ln 2` a sample for mixing both, and on the loaded railcar route one did, its name
    /// flipping between `braking` and `idle` at every stop (docs/fuel.md). `None`: every
    /// sample under the one set of level statistics.
    #[serde(default)]
    pub standing_level_channels: Option<Vec<usize>>,
}

/// One step's data for the mixture.
#[derive(Clone, Debug)]
pub struct MixtureInput<'a> {
    /// `y_t`.
    pub y: &'a DVector<f64>,
    /// `psi_t` (data up to `t-1`).
    pub psi: &'a DVector<f64>,
    /// `(q, l)`: the configuration of `psi^z_{t-1}` and the category `z_t = l`.
    pub category: Option<(usize, usize)>,
    /// The configuration `k` of `phi_{t-1}`.
    pub switching_row: usize,
    /// The vehicle stands (only read with [`MixtureSpec::standing_level_channels`]).
    pub standing: bool,
    /// `ln P(c_t = i | what was measured besides y)`, one per component: the physical
    /// regime's probability (the monitor's `pointer_regimes`), 0 or minus infinity where it is
    /// certain, as for standstill. Added to each component's evidence. `None`: the components
    /// are learned alone.
    pub given: Option<&'a [f64]>,
}

/// Component `i`'s term of [`MixtureInput::given`] (0 without one).
pub(crate) fn log_given(given: Option<&[f64]>, i: usize) -> f64 {
    given.map_or(0.0, |g| g[i])
}

/// The estimator state: component statistics, categorical counts, switching counts, pointer.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Mixture {
    spec: MixtureSpec,
    v0: DMatrix<f64>,
    components: Vec<RegressionStats>,
    /// Per component: rows `q`, columns `l` (empty when there is no categorical channel).
    categorical: Vec<CountTable>,
    /// Rows `k * m_c + j` (`phi_{t-1} = k`, `c_{t-1} = j`), columns `i` (`c_t = i`).
    switching: CountTable,
    /// `ln w_{i;t}`, normalised.
    log_w: Vec<f64>,
    /// The last normalised joint `W_{i,j;t}` (eq. 9), row-major `i * m_c + j`.
    joint: Vec<f64>,
    /// `ln alpha` and `alpha` of every cell of `switching`, refreshed where the table changes.
    #[serde(skip)]
    alpha: AlphaCache,
    /// Per component, the static statistics of the level channels
    /// ([`MixtureSpec::level_channels`], `psi = [1]`); empty when those are.
    #[serde(default)]
    levels: Vec<RegressionStats>,
    /// The standing component's static statistics of the levels measured at standstill
    /// ([`MixtureSpec::standing_level_channels`]), updated with the standing samples (all its,
    /// and only they); `None` without them.
    #[serde(default)]
    standing_level: Option<RegressionStats>,
    /// The buffers a step updates the statistics in (the components of two steps ago; empty
    /// after a restore).
    #[serde(skip)]
    spare: Vec<RegressionStats>,
    /// Of the last step, per component `ln` of the pointer's posterior without the regime
    /// given, unnormalised: its evidence plus `ln sum_j alpha_(i|j) w_(j;t-1)`. What
    /// [`Mixture::weights_given`] weighs with another regime prior. Not in snapshots: empty
    /// after a restore until the next step.
    #[serde(skip)]
    log_ungiven: Vec<f64>,
}

/// `ln alpha_{i|j,k}` of every cell of the switching table, computed as
/// [`Mixture::log_alpha`] computes it (so the same bits), and its `exp`: the forecast reads
/// `m_c^2` of them at every step of its horizon, two logarithms and an exponential each, and
/// the table changes in `m_c` rows per sample. Not in snapshots: empty after a restore (the
/// values are then computed when asked) until the next step fills it.
#[derive(Clone, Debug, Default)]
struct AlphaCache {
    log: Vec<f64>,
    exp: Vec<f64>,
}

impl Mixture {
    /// A mixture at its prior: every component `V_0 = prior_information I`, uniform pointer.
    pub fn new(spec: MixtureSpec) -> Result<Self, FuelError> {
        if spec.components == 0 || spec.k_y == 0 || spec.k_psi == 0 || spec.switching_rows == 0 {
            return Err(FuelError::Numerical("mixture of zero size"));
        }
        if spec.categories > 0 && spec.categorical_rows == 0 {
            return Err(FuelError::invalid(
                "categorical_rows",
                0,
                "must be > 0 with categories",
            ));
        }
        if !(spec.forgetting > 0.0 && spec.forgetting <= 1.0) {
            return Err(FuelError::invalid(
                "forgetting",
                spec.forgetting,
                "must be in (0, 1]",
            ));
        }
        let positive = [
            ("prior_information", spec.prior_information),
            ("prior_kappa", spec.prior_kappa),
            ("min_noise_variance", spec.min_noise_variance),
            ("dirichlet_prior", spec.dirichlet_prior),
            ("switching_prior_stay", spec.switching_prior_stay),
            ("switching_prior_move", spec.switching_prior_move),
        ];
        if let Some((field, v)) = positive.iter().find(|(_, v)| !(v.is_finite() && *v > 0.0)) {
            return Err(FuelError::invalid(field, v, "must be finite and > 0"));
        }
        let d = spec.k_y + spec.k_psi;
        let v0 = DMatrix::identity(d, d) * spec.prior_information;
        let comp = RegressionStats::new(
            spec.k_y,
            v0.clone(),
            spec.prior_kappa,
            spec.min_noise_variance,
        )?;
        let m = spec.components;
        if spec.level_channels.iter().any(|&c| c >= spec.k_y) {
            return Err(FuelError::invalid(
                "level_channels",
                format!("{:?}", spec.level_channels),
                "must index channels of y",
            ));
        }
        let levels = match spec.level_channels.len() {
            0 => Vec::new(),
            n => vec![level_prior(&spec, n)?; m],
        };
        let standing_level = match &spec.standing_level_channels {
            None => None,
            Some(kept) => {
                if kept.is_empty() || kept.iter().any(|c| !spec.level_channels.contains(c)) {
                    return Err(FuelError::invalid(
                        "standing_level_channels",
                        format!("{kept:?}"),
                        "must be some of the level channels",
                    ));
                }
                Some(level_prior(&spec, kept.len())?)
            }
        };

        let categorical = if spec.categories > 0 {
            vec![
                CountTable::new(spec.categorical_rows, spec.categories, |_, _| spec
                    .dirichlet_prior);
                m
            ]
        } else {
            Vec::new()
        };
        let (stay, moves) = (spec.switching_prior_stay, spec.switching_prior_move);
        let switching = CountTable::new(spec.switching_rows * m, m, |row, i| {
            if row % m == i {
                stay
            } else {
                moves
            }
        });
        Ok(Mixture {
            components: vec![comp; m],
            levels,
            standing_level,
            categorical,
            switching,
            log_w: vec![-(m as f64).ln(); m],
            joint: vec![1.0 / (m * m) as f64; m * m],
            alpha: AlphaCache::default(),
            spare: Vec::new(),
            log_ungiven: Vec::new(),
            v0,
            spec,
        }
        .with_alpha_cache())
    }

    /// `self` with every row of the [`AlphaCache`] filled.
    fn with_alpha_cache(mut self) -> Self {
        self.refresh_alpha(0..self.switching.rows());
        self
    }

    /// Refreshes the [`AlphaCache`] rows `rows` of the switching table (all of them when the
    /// cache is not filled).
    fn refresh_alpha(&mut self, rows: std::ops::Range<usize>) {
        let cols = self.switching.cols();
        let cells = self.switching.rows() * cols;
        let rows = if self.alpha.log.len() == cells {
            rows
        } else {
            self.alpha.log.resize(cells, 0.0);
            self.alpha.exp.resize(cells, 0.0);
            0..self.switching.rows()
        };
        for row in rows {
            let cells = row * cols..(row + 1) * cols;
            self.switching
                .log_probabilities_into(row, &mut self.alpha.log[cells.clone()]);
            for (e, l) in self.alpha.exp[cells.clone()]
                .iter_mut()
                .zip(&self.alpha.log[cells])
            {
                *e = l.exp();
            }
        }
    }

    pub fn spec(&self) -> &MixtureSpec {
        &self.spec
    }

    pub fn components(&self) -> &[RegressionStats] {
        &self.components
    }

    /// Per component, the static statistics of the level channels (empty unless
    /// [`MixtureSpec::level_channels`] is set): `theta` their mean, `r` their covariance.
    pub fn levels(&self) -> &[RegressionStats] {
        &self.levels
    }

    pub fn categorical(&self) -> &[CountTable] {
        &self.categorical
    }

    pub fn switching(&self) -> &CountTable {
        &self.switching
    }

    /// `ln w_{i;t}` (normalised).
    pub fn log_weights(&self) -> &[f64] {
        &self.log_w
    }

    /// `w_{i;t}`, summing to 1.
    /// The pointer's posterior after the last step had the regime prior `log_given` (`ln P`
    /// per component) stood for the step's given one: the step's evidence and predicted
    /// pointer, another prior on which regime the sample is. Before the first step (and
    /// after a restore until the next), or if no component is possible, [`Mixture::weights`].
    pub fn weights_given(&self, log_given: &[f64]) -> Vec<f64> {
        if self.log_ungiven.len() != log_given.len() {
            return self.weights();
        }
        let mut log_w: Vec<f64> = self
            .log_ungiven
            .iter()
            .zip(log_given)
            .map(|(u, g)| u + g)
            .collect();
        match normalize_log_weights(&mut log_w) {
            Ok(_) => log_w.iter().map(|l| l.exp()).collect(),
            Err(_) => self.weights(),
        }
    }

    pub fn weights(&self) -> Vec<f64> {
        self.log_w.iter().map(|l| l.exp()).collect()
    }

    /// The joint posterior `W_{i,j;t} = f(c_t = i, c_{t-1} = j | data)` of the last step.
    pub fn joint(&self) -> &[f64] {
        &self.joint
    }

    /// The component with the largest weight: the point estimate of the pointer `c_t`.
    pub fn active(&self) -> usize {
        argmax(&self.log_w)
    }

    /// `ln alpha_{i|j,k}`, eq. (17).
    pub fn log_alpha(&self, k: usize, j: usize, i: usize) -> f64 {
        let m = self.spec.components;
        match self.alpha.log.get((k * m + j) * m + i) {
            Some(cached) => *cached,
            None => self.switching.log_probability(k * m + j, i),
        }
    }

    /// `alpha_{i|j,k} = exp(ln alpha_{i|j,k})` (the exponential of [`Self::log_alpha`]).
    pub fn alpha(&self, k: usize, j: usize, i: usize) -> f64 {
        let m = self.spec.components;
        match self.alpha.exp.get((k * m + j) * m + i) {
            Some(cached) => *cached,
            None => self.log_alpha(k, j, i).exp(),
        }
    }

    /// `ln alpha_{i|j,k}` (eq. 17) of every `j, i` for `phi = k`, at `j * m_c + i`: the kept
    /// values (`AlphaCache`), or after a restore one logarithm per count and per row sum.
    pub fn log_alpha_block(&self, k: usize) -> std::borrow::Cow<'_, [f64]> {
        let m = self.spec.components;
        if let Some(block) = self.alpha.log.get(k * m * m..(k + 1) * m * m) {
            return std::borrow::Cow::Borrowed(block);
        }
        let mut block = vec![0.0; m * m];
        for (j, row) in block.chunks_mut(m).enumerate() {
            self.switching.log_probabilities_into(k * m + j, row);
        }
        std::borrow::Cow::Owned(block)
    }

    /// The predicted pointer `f(c_{t+1} = i | data up to t) = sum_j alpha_{i|j,k} w_{j;t}` for
    /// `phi_t = k`, written into `out` as log-probabilities (from log weights `log_w`).
    pub fn predict_pointer_from(&self, log_w: &[f64], k: usize, out: &mut [f64]) {
        predict_pointer(&self.log_alpha_block(k), log_w, out);
    }

    /// Log-probability of category `l` under condition `q` for component `i` (0 without a
    /// categorical channel).
    pub fn log_category(&self, i: usize, category: Option<(usize, usize)>) -> f64 {
        match (category, self.categorical.get(i)) {
            (Some((q, l)), Some(t)) => t.log_probability(q, l),
            _ => 0.0,
        }
    }

    /// The evidence of the channels other than fuel for component `i` (the virtual sensor's
    /// weight of the component besides the predicted pointer and the category):
    /// `conditional.log_density` (their density under the regression, the paper's) or, with
    /// level channels, their levels' density under the component's level statistics (fuel's
    /// level left out: the virtual sensor must not see fuel now) -- the same evidence the
    /// pointer weighs, without fuel.
    pub fn log_evidence_without_fuel(
        &self,
        i: usize,
        y: &DVector<f64>,
        standing: bool,
        conditional: &crate::regression::Conditional,
    ) -> f64 {
        let Some(data) = LevelData::of(&self.spec, y, standing) else {
            return conditional.log_density;
        };
        // A standing sample is only the standing component's, a moving one never.
        let Some(level) = level_stats(&self.levels, self.standing_level.as_ref(), i, &data) else {
            return f64::NEG_INFINITY;
        };
        let pu = self.spec.parameter_uncertainty;
        match data.fuel {
            None => level.log_proximity(&data.x, &data.psi, pu),
            // Fuel the only level (at standstill): nothing else to weigh.
            Some(_) if data.x.len() == 1 => 0.0,
            // Fuel among the levels: the marginal of the others (drop fuel's row and column).
            Some(fuel) => {
                let others: Vec<usize> = (0..data.x.len()).filter(|&k| k != fuel).collect();
                level.log_marginal_density(&others, &data.x, &data.psi, pu)
            }
        }
    }

    /// Component `i`'s share of standing samples (`None` without standing levels): 1 for the
    /// standing component, 0 for the others.
    pub fn standing_share(&self, i: usize) -> Option<f64> {
        self.spec.standing_level_channels.as_ref().map(|_| {
            if i == STANDING_COMPONENT {
                1.0
            } else {
                0.0
            }
        })
    }

    fn check_input(&self, input: &MixtureInput) -> Result<(), FuelError> {
        let bad = input.y.len() != self.spec.k_y
            || input.psi.len() != self.spec.k_psi
            || input.switching_row >= self.spec.switching_rows
            || input
                .given
                .is_some_and(|g| g.len() != self.spec.components || g.iter().any(|v| v.is_nan()))
            || input
                .y
                .iter()
                .chain(input.psi.iter())
                .any(|v| !v.is_finite())
            || match input.category {
                Some((q, l)) => {
                    self.categorical.is_empty()
                        || q >= self.spec.categorical_rows
                        || l >= self.spec.categories
                }
                None => !self.categorical.is_empty(),
            };
        if bad {
            Err(FuelError::Numerical(
                "mixture input of the wrong shape or not finite",
            ))
        } else {
            Ok(())
        }
    }

    /// Each component's [`Prediction`] at `psi` (of length `k_psi`).
    pub fn predictions(&self, psi: &DVector<f64>) -> Vec<Prediction> {
        self.components
            .iter()
            .map(|c| c.predict(psi, self.spec.parameter_uncertainty))
            .collect()
    }

    /// One on-line step of Algorithm 3.4 (steps 2-8). On error the state is unchanged.
    pub fn step(&mut self, input: &MixtureInput) -> Result<(), FuelError> {
        self.check_input(input)?;
        let predictions = self.predictions(input.psi);
        self.step_checked(input, &predictions)
    }

    /// [`step`](Self::step) with `predictions`, [`predictions`](Self::predictions) at
    /// `input.psi` of the current statistics, made by the caller (the monitor's virtual sensor
    /// needs them before the step).
    pub(crate) fn step_predicted(
        &mut self,
        input: &MixtureInput,
        predictions: &[Prediction],
    ) -> Result<(), FuelError> {
        self.check_input(input)?;
        if predictions.len() != self.spec.components {
            return Err(FuelError::Numerical(
                "one prediction per component expected",
            ));
        }
        self.step_checked(input, predictions)
    }

    fn step_checked(
        &mut self,
        input: &MixtureInput,
        predictions: &[Prediction],
    ) -> Result<(), FuelError> {
        let m = self.spec.components;
        let k = input.switching_row;
        let d = concat(input.y, input.psi);
        // Steps 2-4: proximities of y_t, probabilities of z_t, alpha_k and w_{t-1}, in logs.
        let mut log_ungiven = std::mem::take(&mut self.log_ungiven);
        log_ungiven.resize(m, f64::NEG_INFINITY);
        let log_alpha = self.log_alpha_block(k);
        let mut log_joint = vec![0.0; m * m];
        let x = LevelData::of(&self.spec, input.y, input.standing);
        for i in 0..m {
            // The kept predictions serve the paper's proximity (same bits).
            let ungiven = match &x {
                Some(x) => match level_stats(&self.levels, self.standing_level.as_ref(), i, x) {
                    Some(level) => level_evidence(
                        &self.components[i],
                        level,
                        input.y,
                        &predictions[i],
                        x,
                        self.spec.parameter_uncertainty,
                    ),
                    None => f64::NEG_INFINITY,
                },
                None => self.components[i].log_proximity_at(input.y, &predictions[i]),
            } + self.log_category(i, input.category);
            let evidence = ungiven + log_given(input.given, i);
            for j in 0..m {
                log_joint[i * m + j] = evidence + log_alpha[j * m + i] + self.log_w[j];
            }
            let term = |j: usize| log_alpha[j * m + i] + self.log_w[j];
            let top = (0..m).map(term).fold(f64::NEG_INFINITY, f64::max);
            let prior = match top.is_finite() {
                true => top + (0..m).map(|j| (term(j) - top).exp()).sum::<f64>().ln(),
                false => top,
            };
            log_ungiven[i] = ungiven + prior;
        }
        self.log_ungiven = log_ungiven;
        // Step 5: normalise W_{i,j;t}. Step 6: w_{i;t} = sum_j W_{i,j;t} (eq. 9).
        normalize_log_weights(&mut log_joint)?;
        let mut log_w: Vec<f64> = log_joint.chunks(m).map(log_sum_exp).collect();
        normalize_log_weights(&mut log_w)?;
        // Step 7: statistics, eq. (10)-(12) and (16); step 8 (eq. 13, 15, 17) inside.
        // Into the spare statistics, so that a failure leaves the components as they were;
        // swapped in when every component succeeded (the old ones become the next spare).
        let lambda = self.spec.forgetting;
        let mut updated = std::mem::take(&mut self.spare);
        updated.truncate(m);
        for (i, comp) in self.components.iter().enumerate() {
            match updated.get_mut(i) {
                Some(spare) => spare.take_statistics_of(comp),
                None => updated.push(comp.clone()),
            }
        }
        for (i, comp) in updated.iter_mut().enumerate() {
            let w = log_w[i].exp();
            let forget = (lambda < 1.0).then(|| (lambda.powf(w), &self.v0, self.spec.prior_kappa));
            comp.update(&d, w, forget)?;
        }
        // The level statistics of the sample's kind with the same weights and forgetting (a
        // few numbers each); a standing sample leaves the moving statistics alone, and the
        // other way round.
        let (mut levels, mut standing_level) = (None, None);
        if let Some(x) = &x {
            let level_v0 = level_v0(&self.spec, x.x.len());
            let update = |level: &mut RegressionStats, i: usize| {
                let w = log_w[i].exp();
                let forget =
                    (lambda < 1.0).then(|| (lambda.powf(w), &level_v0, self.spec.prior_kappa));
                level.update(&x.d, w, forget)
            };
            match (x.standing, &self.standing_level) {
                (true, Some(level)) => {
                    let mut level = level.clone();
                    update(&mut level, STANDING_COMPONENT)?;
                    standing_level = Some(level);
                }
                _ => {
                    let mut all = self.levels.clone();
                    for (i, level) in all.iter_mut().enumerate() {
                        update(level, i)?;
                    }
                    levels = Some(all);
                }
            }
        }
        self.spare = std::mem::replace(&mut self.components, updated);
        if let Some(levels) = levels {
            self.levels = levels;
        }
        if standing_level.is_some() {
            self.standing_level = standing_level;
        }
        if let Some((q, l)) = input.category {
            for (i, table) in self.categorical.iter_mut().enumerate() {
                let w = log_w[i].exp();
                if lambda < 1.0 {
                    table.forget_row(q, lambda.powf(w));
                }
                table.add(q, l, w);
            }
        }
        let joint: Vec<f64> = log_joint.iter().map(|l| l.exp()).collect();
        for j in 0..m {
            let row = k * m + j;
            if lambda < 1.0 {
                let mass: f64 = (0..m).map(|i| joint[i * m + j]).sum();
                self.switching.forget_row(row, lambda.powf(mass));
            }
            for i in 0..m {
                self.switching.add(row, i, joint[i * m + j]);
            }
        }
        self.joint = joint;
        self.log_w = log_w;
        self.refresh_alpha(k * m..(k + 1) * m);
        Ok(())
    }

    /// Initial statistics from a batch of prior data (Algorithm 3.4, initial part; section 4.3):
    /// starting from the hard partition `labels`, `iterations` rounds of EM for a static mixture
    /// of the regression components, then the statistics are the prior plus `weight` times the
    /// responsibility-weighted data. Switching counts come from consecutive responsibilities
    /// (`W_{i,j} ~ r_{t,i} r_{t-1,j}`), the pointer from the last sample's responsibilities.
    pub fn from_batch(
        spec: MixtureSpec,
        data: &[MixtureInput],
        labels: &[usize],
        iterations: usize,
        weight: f64,
    ) -> Result<Self, FuelError> {
        let m = spec.components;
        if data.is_empty() || labels.len() != data.len() || labels.iter().any(|&l| l >= m) {
            return Err(FuelError::Numerical("initial data and labels do not match"));
        }
        let mut mix = Mixture::new(spec)?;
        for input in data {
            mix.check_input(input)?;
        }
        let ds: Vec<DVector<f64>> = data.iter().map(|x| concat(x.y, x.psi)).collect();
        let mut resp: Vec<Vec<f64>> = labels
            .iter()
            .map(|&l| (0..m).map(|i| if i == l { 1.0 } else { 0.0 }).collect())
            .collect();
        // The level data of every sample (`None` without level channels).
        let xs: Vec<Option<LevelData>> = data
            .iter()
            .map(|x| LevelData::of(&mix.spec, x.y, x.standing))
            .collect();
        let fit = |prior: &RegressionStats,
                   ds: &[(&DVector<f64>, &[f64])],
                   w: f64|
         -> Result<Vec<RegressionStats>, FuelError> {
            (0..m)
                .map(|i| {
                    let mut c = prior.clone();
                    for (d, r) in ds {
                        c.accumulate(d, w * r[i]);
                    }
                    c.recompute()?;
                    Ok(c)
                })
                .collect()
        };
        let prior = mix.components[0].clone();
        // The moving and the standing level statistics, each from its own kind of sample.
        let level_priors = (mix.levels.first().cloned(), mix.standing_level.clone());
        let fit_levels = |resp: &[Vec<f64>], w: f64| {
            let of_kind = |standing: bool| -> Vec<(&DVector<f64>, &[f64])> {
                (xs.iter().zip(resp))
                    .filter_map(|(x, r)| x.as_ref().map(|x| (x, r)))
                    .filter(|(x, _)| x.standing == standing)
                    .map(|(x, r)| (&x.d, r.as_slice()))
                    .collect()
            };
            let fit_kind = |prior: &Option<RegressionStats>, standing: bool| match prior {
                Some(prior) => fit(prior, &of_kind(standing), w),
                None => Ok(Vec::new()),
            };
            // The standing statistics are the standing component's only.
            let standing = fit_kind(&level_priors.1, true)?
                .into_iter()
                .nth(STANDING_COMPONENT);
            Ok::<_, FuelError>((fit_kind(&level_priors.0, false)?, standing))
        };
        fn weighted<'a>(
            ds: &'a [DVector<f64>],
            resp: &'a [Vec<f64>],
        ) -> Vec<(&'a DVector<f64>, &'a [f64])> {
            ds.iter()
                .zip(resp)
                .map(|(d, r)| (d, r.as_slice()))
                .collect()
        }
        for _ in 0..iterations {
            let comps = fit(&prior, &weighted(&ds, &resp), 1.0)?;
            let (levels, standing_level) = fit_levels(&resp, 1.0)?;
            let log_pi: Vec<f64> = (0..m)
                .map(|i| (resp.iter().map(|r| r[i]).sum::<f64>() + 1.0).ln())
                .collect();

            for ((input, x), r) in data.iter().zip(&xs).zip(resp.iter_mut()) {
                let mut l: Vec<f64> = (0..m)
                    .map(|i| {
                        log_pi[i]
                            + log_given(input.given, i)
                            + match x {
                                Some(x) => {
                                    match level_stats(&levels, standing_level.as_ref(), i, x) {
                                        Some(level) => level_evidence(
                                            &comps[i],
                                            level,
                                            input.y,
                                            &comps[i]
                                                .predict(input.psi, mix.spec.parameter_uncertainty),
                                            x,
                                            mix.spec.parameter_uncertainty,
                                        ),
                                        None => f64::NEG_INFINITY,
                                    }
                                }
                                None => comps[i].log_proximity(
                                    input.y,
                                    input.psi,
                                    mix.spec.parameter_uncertainty,
                                ),
                            }
                    })
                    .collect();
                normalize_log_weights(&mut l)?;
                for (ri, li) in r.iter_mut().zip(&l) {
                    *ri = li.exp();
                }
            }
        }
        mix.components = fit(&prior, &weighted(&ds, &resp), weight)?;
        (mix.levels, mix.standing_level) = fit_levels(&resp, weight)?;
        for (t, input) in data.iter().enumerate() {
            if let Some((q, l)) = input.category {
                for (i, table) in mix.categorical.iter_mut().enumerate() {
                    table.add(q, l, weight * resp[t][i]);
                }
            }

            if t > 0 {
                let k = input.switching_row;
                for j in 0..m {
                    for i in 0..m {
                        mix.switching
                            .add(k * m + j, i, weight * resp[t][i] * resp[t - 1][j]);
                    }
                }
            }
        }
        let last = resp.last().expect("data is not empty");
        mix.log_w = last.iter().map(|r| r.max(1e-300).ln()).collect();
        normalize_log_weights(&mut mix.log_w)?;
        Ok(mix.with_alpha_cache())
    }
}

/// The predicted pointer (see [`Mixture::predict_pointer_from`]) from the block of
/// `ln alpha_{i|j,k}` ([`Mixture::log_alpha_block`]) of the switching configuration `k`.
pub fn predict_pointer(log_alpha: &[f64], log_w: &[f64], out: &mut [f64]) {
    let m = log_w.len();
    with_scratch(m, |terms| {
        for (i, o) in out.iter_mut().enumerate() {
            for (j, t) in terms.iter_mut().enumerate() {
                *t = log_alpha[j * m + i] + log_w[j];
            }
            *o = log_sum_exp(terms);
        }
    })
}

/// `f` on `n` numbers of scratch, on the stack for up to 32 (one per component: the forecast
/// asks at every step of its horizon), on the heap beyond.
pub(crate) fn with_scratch<R>(n: usize, f: impl FnOnce(&mut [f64]) -> R) -> R {
    let mut stack = [0.0; 32];
    match stack.get_mut(..n) {
        Some(scratch) => f(scratch),
        None => f(&mut vec![0.0; n]),
    }
}

/// The component that holds every standing sample when standstill is a regime given
/// ([`MixtureSpec::standing_level_channels`]).
pub const STANDING_COMPONENT: usize = 0;

/// Component `i`'s level statistics for `data`'s kind of sample, from the moving `levels` and
/// the `standing` component's: `None` where the sample cannot be the component's (`ln P_i` of
/// standing or moving is minus infinity: a standing sample is only the standing component's,
/// a moving one never is, [`MixtureSpec::standing_level_channels`]).
fn level_stats<'a>(
    levels: &'a [RegressionStats],
    standing: Option<&'a RegressionStats>,
    i: usize,
    data: &LevelData,
) -> Option<&'a RegressionStats> {
    match (standing, data.standing) {
        (Some(level), true) => (i == STANDING_COMPONENT).then_some(level),
        (Some(_), false) if i == STANDING_COMPONENT => None,
        _ => levels.get(i),
    }
}

/// One sample's data for the level statistics.
struct LevelData {
    /// The level channels (the outputs of the static model): at standstill (with
    /// [`MixtureSpec::standing_level_channels`]) those measured there only.
    x: DVector<f64>,
    /// Its regressor `[1]` (a static model: a mean and a covariance).
    psi: DVector<f64>,
    /// `[x; psi]`, the data vector of the statistics.
    d: DVector<f64>,
    /// Whose statistics: the standing ones or the moving ones.
    standing: bool,
    /// The fuel's position in `x`, if it is a level.
    fuel: Option<usize>,
}

impl LevelData {
    /// The level data of `y` (`None` without level channels), `standing` or not.
    fn of(spec: &MixtureSpec, y: &DVector<f64>, standing: bool) -> Option<Self> {
        if spec.level_channels.is_empty() {
            return None;
        }
        let (channels, standing) = match (&spec.standing_level_channels, standing) {
            (Some(kept), true) => (kept.as_slice(), true),
            _ => (spec.level_channels.as_slice(), false),
        };
        let x = DVector::from_iterator(channels.len(), channels.iter().map(|&c| y[c]));
        let psi = DVector::from_element(1, 1.0);
        let d = concat(&x, &psi);
        let fuel = channels.iter().position(|&c| c == 0);
        Some(LevelData {
            x,
            psi,
            d,
            standing,
            fuel,
        })
    }
}

/// The prior information matrix of level statistics of `channels` levels, `prior_information
/// I` over `[x; psi]`.
fn level_v0(spec: &MixtureSpec, channels: usize) -> DMatrix<f64> {
    let d = channels + 1;
    DMatrix::identity(d, d) * spec.prior_information
}

/// A component's statistics of `channels` levels at the prior: a Gauss-inverse-Wishart
/// regression of the level channels on `psi = [1]` and no lags: `theta` is the mean and `r`
/// the covariance.
fn level_prior(spec: &MixtureSpec, channels: usize) -> Result<RegressionStats, FuelError> {
    RegressionStats::new(
        channels,
        level_v0(spec, channels),
        spec.prior_kappa,
        spec.level_min_variance.max(spec.min_noise_variance),
    )
}

/// The pointer's evidence for one component weighed by levels ([`MixtureSpec::level_channels`]),
/// from its regression's `prediction` at `psi` and the level data.
///
/// By the chain rule, `ln f(y_t | psi_t, c) = ln f(y_1.. | psi_t, c) + ln f(y_0 | y_1.., psi_t,
/// c)`: the fuel's conditional (the regression: fuel given every other channel now and the
/// lags) plus the density of the other channels. Of those, the derived channels are functions
/// of the speed now and `psi` (degenerate: a variance at the floor, docs/fuel.md), and with the
/// speed lagged the speed's own density given `psi` does not say how fast the vehicle goes. So
/// the second factor is replaced by `f(levels | c)`, the level channels under the component's
/// static model (no lags): the levels are what tells a standing train from a coasting one. The
/// same holds for the fuel: given its own lag any component predicts a steady fuel flow, so the
/// regression's term cannot tell an idling engine from one under load once the level has held
/// for a second. With the fuel among the levels its regression term is left out, so that each
/// datum enters once: `ln f(fuel, levels | c)` alone (with the notch's term, the caller's).
/// The approximation is `f(levels | psi, c) ~ f(levels | c)`: the lags' information about the
/// levels is given up for the pointer (the regression keeps it for the forecasts and the
/// virtual sensor).
fn level_evidence(
    comp: &RegressionStats,
    level: &RegressionStats,
    y: &DVector<f64>,
    prediction: &Prediction,
    data: &LevelData,
    parameter_uncertainty: bool,
) -> f64 {
    // Fuel's level among the levels: its density there, not again through the regression.
    let log_fuel = if data.fuel.is_some() {
        0.0
    } else {
        comp.condition_first_on_rest_at(prediction, &y.rows(1, comp.k_y() - 1).into_owned())
            .log_density_of(y[0])
    };
    log_fuel + level.log_proximity(&data.x, &data.psi, parameter_uncertainty)
}

/// `[y; psi]`.
pub(crate) fn concat(y: &DVector<f64>, psi: &DVector<f64>) -> DVector<f64> {
    DVector::from_iterator(y.len() + psi.len(), y.iter().chain(psi.iter()).copied())
}

/// Index of the largest value (first on ties).
pub(crate) fn argmax(v: &[f64]) -> usize {
    v.iter()
        .enumerate()
        .fold((0, f64::NEG_INFINITY), |(bi, bv), (i, &x)| {
            if x > bv {
                (i, x)
            } else {
                (bi, bv)
            }
        })
        .0
}
