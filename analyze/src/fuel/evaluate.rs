//! Runs the mixture and its baselines over one sample sequence and scores them, no I/O.
//!
//! Three estimators see the same samples in the same run: the mixture ([`FuelMonitor`] with the
//! given config), the single recursive regression (the same config with one component) and
//! persistence (`y_{t-1}`, or `y_t` for every horizon); a fourth, the recursive least squares
//! on speed, acceleration and power demand ([`RlsPeer`]), is the virtual sensor's peer. Every score is computed over the same
//! target times for all methods: those after both estimators finished initialisation.

use std::collections::VecDeque;

use railmon_fuel::{
    ComponentName, FuelError, FuelMonitor, FuelMonitorConfig, Interval, OperatingPoint,
    RegimeChange, RegimeName, VehicleSample,
};

use super::rls::RlsPeer;
use crate::report::{Refusals, Timeline};
use railmon_records::sample_clock::{Rejection, TimeJudge, VEHICLE_STALE_AFTER_MS};

/// The reasons a vehicle sample is refused for, the labels of the service's vehicle stream:
/// its sample clock's (`railmon_records::sample_clock`) and the estimator's
/// (`railmon_fuel::FuelError::reason`; `unknown_channels` is the bus frame's own).
pub const REFUSAL_REASONS: [&str; 11] = [
    "time_backwards",
    "time_repeated",
    "time_jump",
    "rate_mismatch",
    "not_finite",
    "missing_channel",
    "out_of_range",
    "acceleration_out_of_range",
    "unknown_category",
    "time_not_increasing",
    "period_mismatch",
];

/// Forgetting and prior of the recursive-least-squares peer: none, and a weak prior.
const RLS_FORGETTING: f64 = 1.0;
const RLS_PRIOR_COVARIANCE: f64 = 1e4;

/// One evaluated time step.
#[derive(Clone, Debug, PartialEq)]
pub struct PredictionRow {
    pub time_s: f64,
    pub fuel_cm3_s: f64,
    pub zero_step_cm3_s: f64,
    pub one_step_cm3_s: f64,
    pub virtual_sensor_cm3_s: f64,
    pub single_one_step_cm3_s: f64,
    pub single_virtual_sensor_cm3_s: f64,
    pub persistence_cm3_s: f64,
    pub rls_virtual_sensor_cm3_s: f64,
    pub one_step_interval_cm3_s: Interval,
    pub virtual_sensor_interval_cm3_s: Interval,
    pub regime_probabilities: Vec<f64>,
    pub active_regime: usize,
    /// The reported regime (active for `regime_confirm_samples` in a row).
    pub regime: usize,
    /// The names of the active and of the reported regime (`railmon_fuel::regime`), unique
    /// per component.
    pub active_regime_name: ComponentName,
    pub regime_name: ComponentName,
    pub label: Option<usize>,
    pub speed_m_s: Option<f64>,
    pub engine_speed_rpm: Option<f64>,
}

/// One line of `summary.csv`.
#[derive(Clone, Debug, PartialEq)]
pub struct ScoreRow {
    pub method: &'static str,
    /// 0 for estimates of the current sample (0-step, virtual sensor).
    pub horizon_s: usize,
    pub rmse: f64,
    pub mae: f64,
    pub n: usize,
    /// Share of the measured values inside the method's 90 % predictive interval (`None`:
    /// the method gives no interval).
    pub coverage_90: Option<f64>,
    /// Diebold-Mariano statistic of the squared-error difference against the single regression
    /// (`mixture` at horizon `h` against `single_regression` at `h`, `virtual_sensor` against
    /// `single_regression_virtual_sensor`; `None` for the other rows): the mean of `e^2 -
    /// e_single^2` over its Newey-West standard error with Bartlett weights over `h - 1` lags
    /// (h-step errors overlap). Negative: the mixture is better; beyond -1.645 / +1.645
    /// significantly better / worse at 5 % one-sided (Diebold and Mariano, JBES 13(3), 1995).
    pub diebold_mariano_vs_single: Option<f64>,
}

/// The Diebold-Mariano statistic of the loss differences `d` of forecasts `h` steps ahead (see
/// [`ScoreRow::diebold_mariano_vs_single`]); 0 when every difference is 0 (the same
/// forecasts: the blend gave the mixture no weight), NaN with fewer than two differences.
pub fn diebold_mariano(d: &[f64], h: usize) -> f64 {
    let n = d.len() as f64;
    if d.len() < 2 {
        return f64::NAN;
    }
    if d.iter().all(|x| *x == 0.0) {
        return 0.0;
    }
    let mean = d.iter().sum::<f64>() / n;
    let autocovariance = |k: usize| {
        d.iter()
            .skip(k)
            .zip(d)
            .map(|(a, b)| (a - mean) * (b - mean))
            .sum::<f64>()
            / n
    };
    let long_run: f64 = autocovariance(0)
        + (1..h.max(1))
            .map(|k| 2.0 * (1.0 - k as f64 / h as f64) * autocovariance(k))
            .sum::<f64>();
    mean / (long_run / n).sqrt()
}

/// Regime recognition against known labels.
#[derive(Clone, Debug, PartialEq)]
pub struct RegimeScore {
    /// `confusion[component][label]`: samples where that component was active under that label.
    pub confusion: Vec<Vec<usize>>,
    /// Label matched to each component.
    pub matched_label: Vec<usize>,
    /// `true`: one component per label (best permutation); `false`: each component to its
    /// majority label (when the numbers of components and labels differ).
    pub one_to_one: bool,
    pub correct: usize,
    /// Samples whose reported (confirmed) regime's matched label is right.
    pub confirmed_correct: usize,
    pub n: usize,
}

impl RegimeScore {
    pub fn accuracy(&self) -> f64 {
        self.correct as f64 / self.n.max(1) as f64
    }

    /// Accuracy of the reported regime, under the active regime's matching.
    pub fn confirmed_accuracy(&self) -> f64 {
        self.confirmed_correct as f64 / self.n.max(1) as f64
    }
}

/// Named regimes against labels that are regime names (the railcar's idle / accelerating /
/// cruising / coasting / braking): no matching, a sample is right when its regime's name is
/// its label.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedRegimeScore {
    /// `confusion[name][label]`, names in the order of [`RegimeName::ALL`]: samples whose
    /// active regime had that name under that label.
    pub confusion: Vec<Vec<usize>>,
    /// The same for the reported (confirmed) regime.
    pub confirmed_confusion: Vec<Vec<usize>>,
    /// Each label as a name.
    pub label_names: Vec<RegimeName>,
}

impl NamedRegimeScore {
    /// Scores `rows` when every label is a regime name (`None` otherwise).
    pub fn of(rows: &[PredictionRow], labels: &[String]) -> Option<Self> {
        let label_names = labels
            .iter()
            .map(|l| RegimeName::parse(l))
            .collect::<Option<Vec<_>>>()?;
        let index = |n: RegimeName| RegimeName::ALL.iter().position(|&m| m == n).unwrap_or(0);
        let mut confusion = vec![vec![0usize; labels.len()]; RegimeName::ALL.len()];
        let mut confirmed_confusion = confusion.clone();
        for r in rows {
            if let Some(l) = r.label {
                confusion[index(r.active_regime_name.regime)][l] += 1;
                confirmed_confusion[index(r.regime_name.regime)][l] += 1;
            }
        }
        Some(NamedRegimeScore {
            confusion,
            confirmed_confusion,
            label_names,
        })
    }

    fn share_right(&self, confusion: &[Vec<usize>]) -> f64 {
        let mut right = 0;
        let mut n = 0;
        for (name, row) in RegimeName::ALL.iter().zip(confusion) {
            for (label, count) in self.label_names.iter().zip(row) {
                n += count;
                right += if name == label { *count } else { 0 };
            }
        }
        right as f64 / n.max(1) as f64
    }

    /// Share of samples whose active regime's name is the label.
    pub fn accuracy(&self) -> f64 {
        self.share_right(&self.confusion)
    }

    /// The same for the reported regime.
    pub fn confirmed_accuracy(&self) -> f64 {
        self.share_right(&self.confirmed_confusion)
    }
}

/// A `regime_changed` event of the mixture, by the rule the service raises it with
/// ([`railmon_fuel::MixtureEstimate::regime_change`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RegimeEvent {
    /// Time of the sample that raised it, s.
    pub time_s: f64,
    pub change: RegimeChange,
}

/// Why a sample was refused: the estimator's checks, or the service's sample clock (the
/// sample's time `time_s`).
#[derive(Clone, Debug)]
pub enum Refused {
    Sample(FuelError),
    Time { time_s: f64, rejection: Rejection },
}

impl std::fmt::Display for Refused {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Refused::Sample(e) => e.fmt(f),
            Refused::Time { time_s, rejection } => write!(
                f,
                "sample at t = {time_s} s: {} ({})",
                rejection.message, rejection.reason
            ),
        }
    }
}

/// Everything a run produces.
#[derive(Clone, Debug)]
pub struct Evaluation {
    pub rows: Vec<PredictionRow>,
    /// The mixture's regime-change events, in time order.
    pub events: Vec<RegimeEvent>,
    pub scores: Vec<ScoreRow>,
    pub regimes: Option<RegimeScore>,
    /// Named regimes against the labels, when the labels are regime names.
    pub named_regimes: Option<NamedRegimeScore>,
    /// Each component's operating point and name at the end of the run.
    pub operating_points: Vec<(OperatingPoint, ComponentName)>,
    pub components: usize,
    pub samples: usize,
    /// The samples the mixture refused (each counted under [`FuelError::reason`], as the
    /// service counts them) and skipped: no estimator saw them.
    pub refused: Refusals,
    /// The first refused sample: its index in the samples, and why.
    pub first_refusal: Option<(usize, Refused)>,
    /// Periods no sample covered and new timelines, as the service's sample clock judges
    /// the times.
    pub timeline: Timeline,
}

impl Evaluation {
    /// The score of `method` at `horizon_s`.
    pub fn score(&self, method: &str, horizon_s: usize) -> Option<&ScoreRow> {
        self.scores
            .iter()
            .find(|s| s.method == method && s.horizon_s == horizon_s)
    }
}

#[derive(Default)]
struct ErrorSum {
    sq: f64,
    abs: f64,
    n: usize,
    /// Values inside the interval, and values scored against one.
    covered: usize,
    with_interval: usize,
}

impl ErrorSum {
    fn add(&mut self, estimate: f64, truth: f64) {
        let e = estimate - truth;
        self.sq += e * e;
        self.abs += e.abs();
        self.n += 1;
    }

    fn add_with_interval(&mut self, estimate: f64, interval: &Interval, truth: f64) {
        self.add(estimate, truth);
        self.with_interval += 1;
        self.covered += usize::from(interval.contains(truth));
    }

    fn row(&self, method: &'static str, horizon_s: usize) -> ScoreRow {
        let n = self.n.max(1) as f64;
        ScoreRow {
            method,
            horizon_s,
            rmse: (self.sq / n).sqrt(),
            mae: self.abs / n,
            n: self.n,
            coverage_90: (self.with_interval > 0)
                .then(|| self.covered as f64 / self.with_interval as f64),
            diebold_mariano_vs_single: None,
        }
    }
}

/// A forecast path and its intervals, made at one step.
struct Path {
    mean: Vec<f64>,
    interval: Vec<Interval>,
}

impl Path {
    fn of(m: &railmon_fuel::MixtureEstimate) -> Self {
        Path {
            mean: m.forecast_cm3_s.clone(),
            interval: m.forecast_interval_cm3_s(),
        }
    }
}

/// Runs the three estimators over `samples`. `labels[t]` (indices into a label list of length
/// `n_labels`) enables the regime score. `on_step` is called after every sample (progress).
/// A sample the mixture refuses (`FuelMonitor::check`: the service's checks, with its
/// reasons) is counted in [`Evaluation::refused`] and skipped by every estimator, as the
/// service skips it; an error that is not about one sample ends the run. Sample times are
/// judged first, as the service's vehicle stream judges them (its sample clock at the
/// mixture's `sample_period_s`, at most the stream's default `stale_after_ms` between
/// samples): a longer gap is refused (`time_jump`) and, once the next sample confirms it, a
/// new timeline on which every estimator starts afresh.
pub fn evaluate(
    config: &FuelMonitorConfig,
    samples: &[VehicleSample],
    labels: Option<(&[usize], &[String])>,
    mut on_step: impl FnMut(),
) -> Result<Evaluation, FuelError> {
    let mut mixture = FuelMonitor::new(config)?;
    let mut single = FuelMonitor::new(&config.single_regression())?;
    let mut clock = TimeJudge::new(
        (config.sample_period_s * 1e9).round() as u64,
        false,
        VEHICLE_STALE_AFTER_MS,
    );
    let mut timeline = Timeline::default();
    let horizon = config.forecast_horizon_steps;
    let mut rls = RlsPeer::new(RLS_FORGETTING, RLS_PRIOR_COVARIANCE);
    let mut rls_sum = ErrorSum::default();
    // Forecast paths made at earlier steps, newest first: (mixture, single, persistence value).
    let mut paths: VecDeque<(Path, Path, f64)> = VecDeque::with_capacity(horizon + 1);
    let mut mix_h: Vec<ErrorSum> = (0..=horizon).map(|_| ErrorSum::default()).collect();
    let mut single_h: Vec<ErrorSum> = (0..=horizon).map(|_| ErrorSum::default()).collect();
    let mut persist_h: Vec<ErrorSum> = (0..=horizon).map(|_| ErrorSum::default()).collect();
    let (mut virtual_mix, mut virtual_single) = (ErrorSum::default(), ErrorSum::default());
    // Squared error of the mixture minus the single regression's, per horizon (0: the virtual
    // sensors), for the Diebold-Mariano statistics.
    let mut loss_differences: Vec<Vec<f64>> = vec![Vec::new(); horizon + 1];
    let loss_difference = |a: f64, b: f64, truth: f64| (a - truth).powi(2) - (b - truth).powi(2);
    let mut rows = Vec::new();
    let mut events = Vec::new();
    let mut previous_fuel: Option<f64> = None;
    let mut refused = Refusals::new(&REFUSAL_REASONS);
    let mut first_refusal = None;
    for (t, sample) in samples.iter().enumerate() {
        // A time no frame can carry (NaN, negative) is left to the mixture's own check.
        let time_ns = TimeJudge::ns_of(sample.time_s);
        match time_ns.map(|ns| clock.time(ns)) {
            Some(Err(rejection)) => {
                refused.add(rejection.reason);
                first_refusal.get_or_insert((
                    t,
                    Refused::Time {
                        time_s: sample.time_s,
                        rejection,
                    },
                ));
                on_step();
                continue;
            }
            Some(Ok(true)) => {
                // A new timeline: as the service restarts its vehicle pipeline, every
                // estimator starts afresh; forecasts made before the jump are not scored.
                mixture = FuelMonitor::new(config)?;
                single = FuelMonitor::new(&config.single_regression())?;
                rls = RlsPeer::new(RLS_FORGETTING, RLS_PRIOR_COVARIANCE);
                paths.clear();
                previous_fuel = None;
                timeline.new_timelines_s.push(sample.time_s);
            }
            _ => {}
        }
        // The single regression checks the same channels and ranges (its config differs in
        // the number of components only): a sample is refused by both or by neither.
        if let Err(e) = mixture.check(sample).and_then(|()| single.check(sample)) {
            let reason = e.reason().ok_or_else(|| e.clone())?;
            refused.add(reason);
            first_refusal.get_or_insert((t, Refused::Sample(e)));
            on_step();
            continue;
        }
        // The mixture bridges a gap from the samples' times itself (no `bridge`).
        if let Some(ns) = time_ns {
            timeline.skipped_periods += clock.skipped_periods(ns);
        }
        let a = mixture.update(sample)?.mixture.clone();
        let b = single.update(sample)?.mixture.clone();
        if let Some(ns) = time_ns {
            clock.used(ns);
        }
        let fuel = sample.fuel_cm3_s.unwrap_or(f64::NAN);
        // The peer needs speed; without it (a fuel-only source) it is not scored.
        let rls_estimate = sample.speed_m_s.map(|v| {
            let estimate = rls.estimate(sample.time_s, v);
            rls.update(sample.time_s, v, fuel);
            estimate
        });
        if let Some(change) = a.as_ref().and_then(|a| a.regime_change) {
            events.push(RegimeEvent {
                time_s: sample.time_s,
                change,
            });
        }
        if let (Some(a), Some(b)) = (a, b) {
            // Forecasts of this sample made h steps ago (h = 1 is element 0 of the newest path).
            for (age, (pm, ps, pp)) in paths.iter().enumerate() {
                let h = age + 1;
                mix_h[h].add_with_interval(pm.mean[h - 1], &pm.interval[h - 1], fuel);
                single_h[h].add_with_interval(ps.mean[h - 1], &ps.interval[h - 1], fuel);
                persist_h[h].add(*pp, fuel);
                loss_differences[h].push(loss_difference(pm.mean[h - 1], ps.mean[h - 1], fuel));
            }
            loss_differences[0].push(loss_difference(
                a.virtual_sensor_cm3_s,
                b.virtual_sensor_cm3_s,
                fuel,
            ));
            mix_h[0].add(a.zero_step_cm3_s, fuel);
            single_h[0].add(b.zero_step_cm3_s, fuel);
            virtual_mix.add_with_interval(
                a.virtual_sensor_cm3_s,
                &a.virtual_sensor_interval_cm3_s(),
                fuel,
            );
            virtual_single.add_with_interval(
                b.virtual_sensor_cm3_s,
                &b.virtual_sensor_interval_cm3_s(),
                fuel,
            );
            if let Some(e) = rls_estimate {
                rls_sum.add(e, fuel);
            }
            paths.push_front((Path::of(&a), Path::of(&b), fuel));
            paths.truncate(horizon);
            rows.push(PredictionRow {
                time_s: sample.time_s,
                fuel_cm3_s: fuel,
                zero_step_cm3_s: a.zero_step_cm3_s,
                one_step_cm3_s: a.one_step_forecast_cm3_s,
                virtual_sensor_cm3_s: a.virtual_sensor_cm3_s,
                single_one_step_cm3_s: b.one_step_forecast_cm3_s,
                single_virtual_sensor_cm3_s: b.virtual_sensor_cm3_s,
                persistence_cm3_s: previous_fuel.unwrap_or(fuel),
                rls_virtual_sensor_cm3_s: rls_estimate.unwrap_or(f64::NAN),
                one_step_interval_cm3_s: a.one_step_interval_cm3_s(),
                virtual_sensor_interval_cm3_s: a.virtual_sensor_interval_cm3_s(),
                regime_probabilities: a.regime_probabilities.clone(),
                active_regime: a.active_regime,
                regime: a.regime,
                active_regime_name: a.regime_names[a.active_regime],
                regime_name: a.regime_name,
                label: labels.map(|(l, _)| l[t]),
                speed_m_s: sample.speed_m_s,
                engine_speed_rpm: sample.engine_speed_rpm,
            });
        }
        previous_fuel = Some(fuel);
        on_step();
    }
    let against_single = |mut row: ScoreRow, h: usize| {
        row.diebold_mariano_vs_single = Some(diebold_mariano(&loss_differences[h], h));
        row
    };
    let mut scores = vec![
        mix_h[0].row("mixture", 0),
        against_single(virtual_mix.row("virtual_sensor", 0), 0),
        single_h[0].row("single_regression", 0),
        virtual_single.row("single_regression_virtual_sensor", 0),
    ];
    if rls_sum.n > 0 {
        scores.push(rls_sum.row("rls_virtual_sensor", 0));
    }
    for h in 1..=horizon {
        scores.push(against_single(mix_h[h].row("mixture", h), h));
        scores.push(single_h[h].row("single_regression", h));
        scores.push(persist_h[h].row("persistence", h));
    }
    let regimes = labels.map(|(_, names)| score_regimes(&rows, config.components, names.len()));
    let named_regimes = labels.and_then(|(_, names)| NamedRegimeScore::of(&rows, names));
    let names = mixture.regime_names();
    let operating_points = mixture.operating_points().into_iter().zip(names).collect();
    Ok(Evaluation {
        rows,
        events,
        scores,
        regimes,
        named_regimes,
        operating_points,
        components: config.components,
        samples: samples.len(),
        refused,
        first_refusal,
        timeline,
    })
}

/// Confusion of active component vs label, and the matching of components to labels.
pub fn score_regimes(rows: &[PredictionRow], components: usize, n_labels: usize) -> RegimeScore {
    let mut confusion = vec![vec![0usize; n_labels]; components];
    for r in rows {
        if let Some(l) = r.label {
            confusion[r.active_regime][l] += 1;
        }
    }
    let n = confusion.iter().flatten().sum();
    let (matched_label, one_to_one) = if components == n_labels && components <= 8 {
        (best_permutation(&confusion), true)
    } else {
        let majority = confusion
            .iter()
            .map(|row| (0..n_labels).max_by_key(|&l| row[l]).unwrap_or(0))
            .collect();
        (majority, false)
    };
    let correct = matched_label
        .iter()
        .enumerate()
        .map(|(c, &l)| confusion[c][l])
        .sum();
    let confirmed_correct = rows
        .iter()
        .filter(|r| r.label == Some(matched_label[r.regime]))
        .count();
    RegimeScore {
        confusion,
        matched_label,
        one_to_one,
        correct,
        confirmed_correct,
        n,
    }
}

/// The assignment component -> label (a permutation) with the most agreeing samples, by
/// exhaustive search (at most 8! = 40320 permutations).
fn best_permutation(confusion: &[Vec<usize>]) -> Vec<usize> {
    fn search(
        confusion: &[Vec<usize>],
        c: usize,
        used: &mut Vec<bool>,
        current: &mut Vec<usize>,
        best: &mut (usize, Vec<usize>),
    ) {
        if c == confusion.len() {
            let total = current
                .iter()
                .enumerate()
                .map(|(i, &l)| confusion[i][l])
                .sum();
            if total > best.0 || best.1.is_empty() {
                *best = (total, current.clone());
            }
            return;
        }
        for l in 0..used.len() {
            if !used[l] {
                used[l] = true;
                current.push(l);
                search(confusion, c + 1, used, current, best);
                current.pop();
                used[l] = false;
            }
        }
    }
    let mut best = (0, Vec::new());
    let n_labels = confusion.first().map_or(0, |r| r.len());
    search(
        confusion,
        0,
        &mut vec![false; n_labels],
        &mut Vec::new(),
        &mut best,
    );
    best.1
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(active: usize, label: usize) -> PredictionRow {
        PredictionRow {
            time_s: 0.0,
            fuel_cm3_s: 0.0,
            zero_step_cm3_s: 0.0,
            one_step_cm3_s: 0.0,
            virtual_sensor_cm3_s: 0.0,
            single_one_step_cm3_s: 0.0,
            single_virtual_sensor_cm3_s: 0.0,
            persistence_cm3_s: 0.0,
            rls_virtual_sensor_cm3_s: 0.0,
            one_step_interval_cm3_s: Interval::default(),
            virtual_sensor_interval_cm3_s: Interval::default(),
            regime_probabilities: vec![],
            active_regime: active,
            regime: active,
            active_regime_name: ComponentName::default(),
            regime_name: ComponentName::default(),
            label: Some(label),
            speed_m_s: None,
            engine_speed_rpm: None,
        }
    }

    /// By hand: d = 1, 2, 3, 4 has mean 2.5, variance 1.25 (over n) and lag-1 autocovariance
    /// 0.3125; one step ahead 2.5 / sqrt(1.25 / 4), two steps ahead the Bartlett weight 1/2 on
    /// lag 1 gives 2.5 / sqrt((1.25 + 0.3125) / 4) = 4.
    #[test]
    fn diebold_mariano_matches_a_hand_computation() {
        let d = [1.0, 2.0, 3.0, 4.0];
        assert!((diebold_mariano(&d, 1) - 2.5 / (1.25f64 / 4.0).sqrt()).abs() < 1e-12);
        assert!((diebold_mariano(&d, 2) - 4.0).abs() < 1e-12);
        assert!(diebold_mariano(&[1.0], 1).is_nan());
        assert_eq!(diebold_mariano(&[0.0; 5], 3), 0.0);
    }

    #[test]
    fn matching_finds_the_best_permutation_not_the_greedy_one() {
        // Component 0 is mostly label 0 (5) but also label 1 (4); component 1 is only label 0 (4).
        // Greedy would give 0->0 (5) + 1->1 (0) = 5; the best is 0->1 (4) + 1->0 (4) = 8.
        let mut rows = Vec::new();
        rows.extend((0..5).map(|_| row(0, 0)));
        rows.extend((0..4).map(|_| row(0, 1)));
        rows.extend((0..4).map(|_| row(1, 0)));
        let s = score_regimes(&rows, 2, 2);
        assert_eq!(s.matched_label, vec![1, 0]);
        assert_eq!((s.correct, s.n), (8, 13));
        assert!(s.one_to_one);
    }

    #[test]
    fn more_components_than_labels_map_to_majorities() {
        let rows = vec![row(0, 0), row(1, 0), row(2, 1), row(2, 1), row(2, 0)];
        let s = score_regimes(&rows, 3, 2);
        assert_eq!(s.matched_label, vec![0, 0, 1]);
        assert_eq!(s.correct, 4);
        assert!(!s.one_to_one);
    }
}
