//! The multi-step fuel forecast (the paper's future work 2): the mixture's pointer and each
//! component's regressor propagated over the horizon, the steps joined as in the interacting
//! multiple model filter ([`forecast_path`]). Run by the monitor on the mixture and on the
//! single regression it is blended with (`crate::blend`).

use std::collections::VecDeque;

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use crate::data_vector::{Layout, Past, Standardiser};
use crate::estimate::in_fuel_range;
use crate::mixture::Mixture;
use crate::predictive::StudentT;
use crate::sample::bin_index;

/// What a forecast starts from, borrowed from the monitor: how its data vectors are laid out,
/// its standardiser and its past (the regressor now and the last fuel and acceleration levels).
#[derive(Clone, Copy)]
pub(crate) struct ForecastStart<'a> {
    pub(crate) layout: Layout<'a>,
    pub(crate) st: &'a Standardiser,
    pub(crate) past: &'a Past,
}

/// Multi-step forecast of fuel from the current state of `mixture` (the paper's future
/// work 2). Each component keeps its own forecast regressor, the mean and covariance of
/// `psi_{t+h}` given `c_{t+h} = i`, and the steps are joined as in the interacting multiple
/// model filter (Blom and Bar-Shalom, IEEE TAC 33(8), 1988, the mixing step): after step
/// `h` each component's regressor is shifted with its own forecast, then mixed for the
/// next step with the probabilities `P(c_{t+h} = j | c_{t+h+1} = i) = alpha_{i|j,k_j} p_j /
/// p_i'`, `k_j` the switching row at component `j`'s forecast fuel level, and the spread
/// of the mixed regressors added to the covariance. The step's predictive is the mixture
/// over components of Student-t densities with squared scale `r_i (1 + zeta_i) + theta_i'
/// Sigma_i theta_i`, its mean `sum_i p_i theta_i' psi_i`.
///
/// Before, one regressor (the mixture's mean) fed every component and the switching row
/// was that of the mean's level: on the railcar routes a traction component was fed the
/// average of idling and traction, the forecast drifted towards idling (bias -6.4 cm^3/s
/// at 10 s on `fuel-railcar.toml`, single regression +0.16) and, without the blend, lost to
/// the single regression from 2 s on.
///
/// Every vector and matrix of the recursion lives in `work` (allocated once, reused at
/// every step: the forecast is most of a step's arithmetic, and its temporaries were a
/// sixth of the step's time in `malloc` and `free`); each number is computed by the same
/// operations in the same order as with the temporaries, so the bits are the same.
pub(crate) fn forecast_path(
    from: ForecastStart,
    mixture: &Mixture,
    work: &mut ForecastWork,
) -> ForecastPath {
    let layout = from.layout;
    // Gear and constant (the regressor's tail) are known: the covariance lives on the
    // lagged channels alone.
    let uncertain = layout.lagged.len() * layout.config.regression_memory;
    if work.dims != (layout.spec.k_y, layout.spec.k_psi, uncertain) {
        *work = ForecastWork::new(layout, uncertain);
    }
    work.fit(mixture.spec().components);
    crate::kernel::with_size!(uncertain, |n| forecast_path_sized(n, from, mixture, work))
}

/// [`forecast_path`] with the size of the regressor's uncertain part, `n`, a
/// [`crate::kernel::Size`]: the recursion's loops over it are the step's innermost, and
/// with a compile-time bound the compiler unrolls them and drops their bounds checks.
fn forecast_path_sized<N: crate::kernel::Size>(
    n: N,
    from: ForecastStart,
    mixture: &Mixture,
    work: &mut ForecastWork,
) -> ForecastPath {
    use crate::kernel::{lower_times_norm_squared, nalgebra_dot, propagate_covariance};
    let ForecastStart { layout, st, past } = from;
    let horizon = layout.config.forecast_horizon_steps;
    let m = mixture.spec().components;
    let (k_psi, n2) = (layout.spec.k_psi, n.get() * n.get());
    let parameter_uncertainty = layout.config.parameter_uncertainty;
    let ForecastWork {
        psi,
        sigma,
        shifted_psi,
        shifted_sigma,
        rows,
        mean,
        psi_now,
        solve,
        sigma_theta,
        propagated,
        deviation,
        p,
        log_p,
        levels,
        sources,
        y_read,
        factor_inverse,
        covariance_from,
        first_zeta,
        spare_terms,
        joint,
        ..
    } = work;
    if parameter_uncertainty && horizon > 1 {
        for (comp, l_inv) in mixture.components().iter().zip(factor_inverse.iter_mut()) {
            comp.v_psi_factor_inverse_into(l_inv);
        }
    }
    // Given c_{t+h+1} = i: the regressor's mean and covariance, and log p(c_{t+h+1}).
    psi_now.copy_from(&layout.regressor(past));
    for psi_i in psi.chunks_exact_mut(k_psi).take(m) {
        psi_i.copy_from_slice(psi_now.as_slice());
    }
    sigma[..m * n2].fill(0.0);
    // The first step's `zeta` of every component, `psi' V_psi^-1 psi` as `zeta_with`
    // computes it (the next update's step reads it), the components' solves interleaved.
    if parameter_uncertainty {
        let solved = &mut first_zeta[..m * k_psi];
        for x in solved.chunks_exact_mut(k_psi) {
            x.copy_from_slice(psi_now.as_slice());
        }
        let factor = |c: usize| mixture.components()[c].v_psi_factor();
        crate::kernel::with_size!(k_psi, |s| crate::kernel::cholesky_solve_each(
            s, factor, solved
        ));
    }
    levels.clear();
    levels.extend(past.fuel_levels.iter().copied());
    let acceleration_level = past.acceleration_level;
    let row = layout.switching_row_of(levels.iter().copied(), acceleration_level);
    mixture.predict_pointer_from(mixture.log_weights(), row, &mut log_p[..m]);
    for (p_i, l) in p.iter_mut().zip(log_p.iter()).take(m) {
        *p_i = l.exp();
    }
    let mut path = ForecastPath::with_capacity(horizon);
    for h in 0..horizon {
        let last = h + 1 == horizon;
        // Only the fuel of the mixture's mean is used (its value and its level).
        let mut y0 = 0.0;
        let mut terms = spare_terms.pop().unwrap_or_default();
        terms.clear();
        for (i, comp) in mixture.components().iter().enumerate() {
            let (theta, r) = (comp.theta().as_slice(), comp.r().as_slice());
            let psi_i = &psi[i * k_psi..(i + 1) * k_psi];
            let sigma_i = &sigma[i * n2..(i + 1) * n2];
            let inflate = if h == 0 {
                // The next update's virtual sensor and step predict at this regressor
                // from these statistics: their own operations (psi_i is psi_now).
                comp.mean_into(psi_now, mean);
                let inflate = match parameter_uncertainty {
                    true => {
                        let x = &first_zeta[i * k_psi..(i + 1) * k_psi];
                        1.0 + nalgebra_dot(psi_now.as_slice(), x).max(0.0)
                    }
                    false => 1.0,
                };
                path.first_predictions.push(crate::regression::Prediction {
                    mean: mean.clone(),
                    inflate,
                });
                inflate
            } else {
                // Beyond the first step only fuel and the lagged channels of the mean
                // are read.
                let mean = mean.as_mut_slice();
                for &u in y_read.iter() {
                    mean[u] = nalgebra_dot(&theta[u * k_psi..(u + 1) * k_psi], psi_i);
                }
                // Sigma theta and theta' Sigma theta: at the last step only the fuel
                // element is read.
                let read = if last { &[0][..] } else { &y_read[..] };
                propagate_covariance(n, theta, k_psi, sigma_i, read, sigma_theta, propagated);
                match parameter_uncertainty {
                    true => {
                        let (l_inv, work) = (factor_inverse[i].as_slice(), solve.as_mut_slice());
                        1.0 + crate::kernel::with_size!(k_psi, |s| {
                            lower_times_norm_squared(s, l_inv, psi_i, work)
                        })
                    }
                    false => 1.0,
                }
            };
            let mean = mean.as_slice();
            let fuel_var = r[0] * inflate + if h > 0 { propagated[0] } else { 0.0 };
            terms.push(st.fuel_term(p[i], mean[0], fuel_var, comp.predictive_dof()));
            y0 += mean[0] * p[i];
            if !last {
                // The elements of Cov(y) the shift reads, computed where it reads them.
                let propagated = &propagated[..];
                let c_yy = |at: usize| r[at] * inflate + if h > 0 { propagated[at] } else { 0.0 };
                if h == 0 {
                    // Sigma = 0: so is Cov(psi, y) = Sigma theta.
                    sigma_theta.fill(0.0);
                }
                let level = bin_index(&layout.config.fuel_bins_cm3_s, st.fuel(mean[0]));
                let shifted = &mut shifted_psi[i * k_psi..(i + 1) * k_psi];
                for ((out, source), psi_a) in shifted.iter_mut().zip(sources.iter()).zip(psi_i) {
                    *out = match *source {
                        Source::Y(u) => mean[u],
                        Source::Psi(u) => psi_i[u],
                        Source::Known => *psi_a,
                    };
                }
                shift_regressor_covariance(
                    n,
                    covariance_from,
                    sigma_i,
                    sigma_theta,
                    c_yy,
                    &mut shifted_sigma[i * n2..(i + 1) * n2],
                );
                rows[i] = layout.switching_row_of(
                    std::iter::once(level)
                        .chain(levels.iter().copied())
                        .take(layout.config.switching_memory),
                    acceleration_level,
                );
            }
        }
        path.push(in_fuel_range(layout.config, st.fuel(y0)), terms);
        if !last {
            mix_regressors(
                n,
                mixture,
                &p[..m],
                k_psi,
                &shifted_psi[..m * k_psi],
                &shifted_sigma[..m * n2],
                &rows[..m],
                &mut psi[..m * k_psi],
                &mut sigma[..m * n2],
                &mut log_p[..m],
                &mut joint[..m],
                deviation,
            );
            p[..m].copy_from_slice(&log_p[..m]);
        }
        let level = bin_index(&layout.config.fuel_bins_cm3_s, st.fuel(y0));
        levels.push_front(level);
        levels.truncate(layout.config.switching_memory);
    }
    path
}

/// Where each element of the next forecast regressor comes from (the new `y` in its newest
/// lag, the older lags shifted, gear and constant known), written into `out`.
fn regressor_sources(layout: Layout, out: &mut Vec<Source>) {
    let n_lag = layout.lagged.len();
    let lagged_len = n_lag * layout.config.regression_memory;
    out.clear();
    out.extend(
        (0..layout.spec.k_psi).map(|a| match (a < lagged_len, a / n_lag.max(1)) {
            (false, _) => Source::Known,
            (true, 0) => Source::Y(layout.lagged[a % n_lag]),
            (true, k) => Source::Psi((k - 1) * n_lag + a % n_lag),
        }),
    );
}

/// A fuel forecast path: mean and predictive per step (`t+1 .. t+H`), raw units.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub(crate) struct ForecastPath {
    pub(crate) mean_cm3_s: Vec<f64>,
    pub(crate) terms: Vec<Vec<StudentT>>,
    /// The mixture's components' predictions at the first step's regressor (what the next
    /// update's virtual sensor and step need: the same statistics, the same `psi`). Not in
    /// snapshots: a restored monitor computes them again.
    #[serde(skip)]
    pub(crate) first_predictions: Vec<crate::regression::Prediction>,
}

impl ForecastPath {
    pub(crate) fn with_capacity(n: usize) -> Self {
        ForecastPath {
            mean_cm3_s: Vec::with_capacity(n),
            terms: Vec::with_capacity(n),
            first_predictions: Vec::new(),
        }
    }

    pub(crate) fn push(&mut self, mean_cm3_s: f64, terms: Vec<StudentT>) {
        self.mean_cm3_s.push(mean_cm3_s);
        self.terms.push(terms);
    }
}

/// Where an element of the next forecast regressor comes from.
#[derive(Clone, Copy, Debug)]
enum Source {
    /// Channel `u` of the forecast `y`.
    Y(usize),
    /// Element `u` of the regressor now.
    Psi(usize),
    /// Gear and constant: held, no uncertainty.
    Known,
}

/// The work space of [`forecast_path`], flat buffers sized once for the
/// monitor's dimensions (`m_c` grows them): per component (the first `m_c` used, component
/// `i` at `i * k_psi` and `i * n^2`) the regressor's mean and covariance given the component,
/// the same shifted by one step, the switching row at its forecast level, `L^-1` of its
/// `V_psi`; one component's mean, the regressor now, a `k_psi` vector (the solve of `zeta`),
/// `Sigma theta` (which is also `Cov(psi, y)`, `n x k_y`), `theta' Sigma theta` (`k_y x
/// k_y`), the mixing's deviation (`n`), the first step's solves; the pointer; the forecast
/// fuel levels; the term lists of the replaced path; the
/// sources of the shifted regressor and of its covariance. The covariances cover the
/// regressor's uncertain part only, its lagged channels (the leading `n` elements): gear and
/// constant are known, their rows and columns zero. Matrices column-major, the covariances
/// whole (both triangles). Not in snapshots (rebuilt on first use).
#[derive(Clone, Debug, Default)]
pub(crate) struct ForecastWork {
    /// `(k_y, k_psi, n)` the buffers are made for.
    dims: (usize, usize, usize),
    psi: Vec<f64>,
    sigma: Vec<f64>,
    shifted_psi: Vec<f64>,
    shifted_sigma: Vec<f64>,
    rows: Vec<usize>,
    mean: DVector<f64>,
    psi_now: DVector<f64>,
    solve: DVector<f64>,
    sigma_theta: Vec<f64>,
    propagated: Vec<f64>,
    deviation: Vec<f64>,
    p: Vec<f64>,
    log_p: Vec<f64>,
    levels: VecDeque<usize>,
    sources: Vec<Source>,
    /// The channels of `y` the recursion reads beyond the first step: fuel and the lagged
    /// ones (sorted); the lagged ones alone.
    y_read: Vec<usize>,
    y_lagged: Vec<usize>,
    /// Per component `L^-1`, `V_psi = L L'`: `zeta` beyond the first step.
    factor_inverse: Vec<DMatrix<f64>>,
    /// The shift's gather of the covariance ([`covariance_sources`]).
    covariance_from: Vec<CovarianceSource>,
    /// Per component the first step's solve `V_psi^-1 psi` (`k_psi` each).
    first_zeta: Vec<f64>,
    /// The term lists of the forecast path the last one replaced (buffers for the next).
    spare_terms: Vec<Vec<StudentT>>,
    /// The mixing's joint probabilities of one target component (`m_c`).
    joint: Vec<f64>,
}

impl ForecastWork {
    /// The work space for the sizes of `layout`, `n` of its regressor's elements uncertain, for
    /// no component yet ([`Self::fit`]).
    fn new(layout: Layout, n: usize) -> Self {
        let (k_y, k_psi) = (layout.spec.k_y, layout.spec.k_psi);
        let mut work = ForecastWork {
            dims: (k_y, k_psi, n),
            mean: DVector::zeros(k_y),
            psi_now: DVector::zeros(k_psi),
            solve: DVector::zeros(k_psi),
            sigma_theta: vec![0.0; n * k_y],
            propagated: vec![0.0; k_y * k_y],
            deviation: vec![0.0; n],
            ..ForecastWork::default()
        };
        regressor_sources(layout, &mut work.sources);
        for source in &work.sources {
            if let Source::Y(u) = *source {
                work.y_lagged.push(u);
            }
        }
        work.y_lagged.sort_unstable();
        work.y_lagged.dedup();
        work.y_read.push(0);
        work.y_read.extend(work.y_lagged.iter().copied());
        work.y_read.sort_unstable();
        work.y_read.dedup();
        covariance_sources(&work.sources, n, k_y, &mut work.covariance_from);
        work
    }

    /// Keeps the term lists of `old`, the path the newest one replaced, as buffers for the
    /// next path's steps (at most `horizon`).
    pub(crate) fn recycle(&mut self, old: ForecastPath, horizon: usize) {
        self.spare_terms.extend(old.terms.into_iter().take(horizon));
        self.spare_terms.truncate(horizon);
    }

    /// Room for `m` components (allocates only when `m` grows).
    fn fit(&mut self, m: usize) {
        let (_, k_psi, n) = self.dims;
        if self.rows.len() < m {
            self.psi.resize(m * k_psi, 0.0);
            self.first_zeta.resize(m * k_psi, 0.0);
            self.sigma.resize(m * n * n, 0.0);
            self.shifted_psi.resize(m * k_psi, 0.0);
            self.shifted_sigma.resize(m * n * n, 0.0);
            self.factor_inverse.resize(m, DMatrix::zeros(k_psi, k_psi));
            self.rows.resize(m, 0);
            self.p.resize(m, 0.0);
            self.log_p.resize(m, 0.0);
            self.joint.resize(m, 0.0);
        }
    }
}

/// The interacting-multiple-model mixing step of [`forecast_path`]: from `p_j =
/// p(c_{t+h} = j)` and each component's shifted regressor (mean, `k_psi` each, covariance,
/// `n x n` each, switching row at its level), the pointer `p_i' = sum_j alpha_{i|j,k_j} p_j`
/// (normalised, written into `p_next`) and each component's regressor given `c_{t+h+1} = i`
/// (written into `psi`, `sigma`). `joint` (`m_c`) and `d` (`n`): scratch. The pointer is normalised
/// as probabilities, `p_i' / sum p'`, not through logarithms (`ln`, log-sum-exp, `exp`: four
/// transcendental calls per component and step, a tenth of the monitor's step once the
/// rest was lean); it differs from that by rounding and is not read by the mixture's step.
#[allow(clippy::too_many_arguments)]
fn mix_regressors<N: crate::kernel::Size>(
    n: N,
    mixture: &Mixture,
    p: &[f64],
    k_psi: usize,
    shifted_psi: &[f64],
    shifted_sigma: &[f64],
    rows: &[usize],
    psi: &mut [f64],
    sigma: &mut [f64],
    p_next: &mut [f64],
    joint: &mut [f64],
    d: &mut [f64],
) {
    let joint = &mut joint[..p.len()];
    let n2 = n.get() * n.get();
    let d = &mut d[..n.get()];
    for (i, (mean, cov)) in psi
        .chunks_exact_mut(k_psi)
        .zip(sigma.chunks_exact_mut(n2))
        .enumerate()
    {
        // Unnormalised P(c_{t+h} = j, c_{t+h+1} = i).
        for (j, x) in joint.iter_mut().enumerate() {
            *x = mixture.alpha(rows[j], j, i) * p[j];
        }
        let total: f64 = joint.iter().sum();
        // A component no path reaches keeps the pointer's mix (its weight is ~0 anyway).
        let reached = total > 0.0 && total.is_finite();
        let mu = |j: usize| if reached { joint[j] / total } else { p[j] };
        mean.fill(0.0);
        for (j, s) in shifted_psi.chunks_exact(k_psi).enumerate() {
            let mu_j = mu(j);
            for (a, b) in mean.iter_mut().zip(s) {
                *a += b * mu_j;
            }
        }
        // cov += (c + d d') mu_j, d = s - mean, on the uncertain block, the lower
        // triangle (c is symmetric), mirrored after.
        cov.fill(0.0);
        for (j, (s, c)) in shifted_psi
            .chunks_exact(k_psi)
            .zip(shifted_sigma.chunks_exact(n2))
            .enumerate()
        {
            let mu_j = mu(j);
            for ((d, s), mean) in d.iter_mut().zip(s).zip(mean.iter()) {
                *d = s - mean;
            }
            crate::kernel::add_spread_lower(n, cov, c, d, mu_j);
        }
        crate::kernel::mirror_lower(n, cov);
        p_next[i] = total;
    }
    let total: f64 = p_next.iter().sum();
    match total > 0.0 && total.is_finite() {
        true => p_next.iter_mut().for_each(|x| *x /= total),
        // No path reaches any component (cannot happen with a proper switching table).
        false => p_next.copy_from_slice(p),
    }
}

/// Where each element of the lower triangle of the next forecast regressor's covariance (its
/// uncertain part) comes from, column by column: an index into `Cov(y)`, `Cov(psi, y)` (`Sigma
/// theta`, `n x k_y`) or `Sigma` (`n x n`), all column-major. Made once per forecast from the
/// [`Source`]s, so that the shift at every step and component is a gather.
#[derive(Clone, Copy, Debug)]
enum CovarianceSource {
    Y(usize),
    PsiY(usize),
    Psi(usize),
    Zero,
}

/// The [`CovarianceSource`]s of the `n x n` uncertain block from `sources`, `k_y` channels,
/// written into `out`.
fn covariance_sources(sources: &[Source], n: usize, k_y: usize, out: &mut Vec<CovarianceSource>) {
    out.clear();
    for b in 0..n {
        for a in b..n {
            out.push(match (sources[a], sources[b]) {
                (Source::Known, _) | (_, Source::Known) => CovarianceSource::Zero,
                (Source::Y(u), Source::Y(v)) => CovarianceSource::Y(v * k_y + u),
                (Source::Psi(u), Source::Y(v)) | (Source::Y(v), Source::Psi(u)) => {
                    CovarianceSource::PsiY(v * n + u)
                }
                (Source::Psi(u), Source::Psi(v)) => CovarianceSource::Psi(v * n + u),
            });
        }
    }
}

/// Covariance of the next forecast regressor `psi'` into `out` (its uncertain part, `n x n`),
/// from that of `psi`, `Cov(psi, y)` and `Cov(y)` (`c_yy(v k_y + u)`, column-major) by the
/// gather `from` ([`covariance_sources`]), the lower triangle mirrored.
#[inline(always)]
fn shift_regressor_covariance<N: crate::kernel::Size>(
    n: N,
    from: &[CovarianceSource],
    sigma_psi: &[f64],
    c_psi_y: &[f64],
    c_yy: impl Fn(usize) -> f64,
    out: &mut [f64],
) {
    let nn = n.get();
    let out = &mut out[..nn * nn];
    let mut from = from.iter();
    for b in 0..nn {
        for a in b..nn {
            out[b * nn + a] = match from.next() {
                Some(CovarianceSource::Y(x)) => c_yy(*x),
                Some(CovarianceSource::PsiY(x)) => c_psi_y[*x],
                Some(CovarianceSource::Psi(x)) => sigma_psi[*x],
                Some(CovarianceSource::Zero) | None => 0.0,
            };
        }
    }
    crate::kernel::mirror_lower(n, out);
}
