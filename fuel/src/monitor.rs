//! [`FuelMonitor`]: the recursive mixture run on vehicle samples, with the outputs a live
//! service or an offline report needs at every step.
//!
//! The monitor validates each sample before anything changes, standardises the continuous
//! channels with the mean and spread of the initial samples (so that one prior and one variance
//! floor fit fuel in cm^3/s and engine speed in rpm alike; the proximities only shift by a
//! constant common to all components, so the pointer is unaffected), builds the regressors
//! `psi_t = [y_{t-1}, .., y_{t-m_y}, z_{t-1}, 1]`, the categorical condition `[z_{t-1}, s_{t-1}]`
//! and the switching condition `[f_{t-1}, ..]`, and runs [`Mixture`].

use std::collections::VecDeque;

use nalgebra::{DMatrix, DVector};
use railmon_filter::logspace::normalize_log_weights;
use serde::Serialize;

use crate::config::{FuelMonitorConfig, InitialPartition};
use crate::kinematic::{KinematicFilter, KinematicState};
use crate::mixture::{argmax, Mixture, MixtureInput, MixtureSpec};
use crate::predictive::{central_interval, Interval, StudentT};
use crate::regime::{ComponentName, OperatingPoint};
use crate::sample::{bin_index, Channel, DerivedChannel, VehicleSample};
use crate::FuelError;

/// With a noisy speed (`speed_noise_m_s` > 0) the acceleration check's bounds widen by this
/// many standard deviations of the reading's acceleration against the filtered speed: a
/// legitimate sample is refused by noise alone about once in 300 000 (two-sided normal tail).
const NOISE_ALLOWANCE_SD: f64 = 4.5;

/// Probability mass of the predictive intervals the monitor reports.
pub const INTERVAL_MASS: f64 = 0.9;

/// The estimator's outputs once it is initialised.
#[derive(Clone, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct MixtureEstimate {
    /// The paper's 0-step estimate (section 4.4): `theta' psi_t` of the active component, the
    /// pointer picked and the statistics updated with `y_t` itself. Not a forecast.
    pub zero_step_cm3_s: f64,
    /// Honest 1-step forecast of this sample's fuel, made at `t-1` from data up to `t-1`, the
    /// pointer predicted with the switching model (blended with the single regression when
    /// `forecast_blend` is on): the first element of the previous sample's `forecast_cm3_s`.
    pub one_step_forecast_cm3_s: f64,
    /// Predictive of the 1-step forecast (made at `t-1`): the first of the previous sample's
    /// `forecast_predictive` (empty while no forecast was made). Its 90 % interval:
    /// [`MixtureEstimate::one_step_interval_cm3_s`].
    pub one_step_predictive: Vec<StudentT>,
    /// Virtual fuel sensor: fuel now from the other channels now (and data up to `t-1`), each
    /// component's Gaussian conditioned on the observed channels, weighted by the predicted
    /// pointer times the likelihood of those channels. Equals the 1-step forecast when fuel is
    /// the only continuous channel (and there is no gear). Blended with the single
    /// regression's virtual sensor when `forecast_blend` is on (horizon 0 of the blend).
    pub virtual_sensor_cm3_s: f64,
    /// Predictive of the virtual sensor: the mixture over components of each one's Student-t
    /// of fuel given the other channels, weighted as the virtual sensor is. Its 90 % interval:
    /// [`MixtureEstimate::virtual_sensor_interval_cm3_s`].
    pub virtual_sensor_predictive: Vec<StudentT>,
    /// Fuel forecasts for `t+1 .. t+H` (H = `forecast_horizon_steps`): pointer propagated with
    /// the switching model, regressors filled with the forecast means, gear, speed level and
    /// acceleration level held at their last values.
    pub forecast_cm3_s: Vec<f64>,
    /// Predictive of each forecast: the mixture of the components' Student-t densities under
    /// the propagated pointer, with the regressor's uncertainty propagated (moment matching)
    /// from step 2 on; pooled with the single regression's by the blend weights. Their 90 %
    /// intervals: [`MixtureEstimate::forecast_interval_cm3_s`].
    pub forecast_predictive: Vec<Vec<StudentT>>,
    /// `w_{i;t}`: probability of each component (driving regime).
    pub regime_probabilities: Vec<f64>,
    /// `argmax_i w_{i;t}`: the point estimate of the pointer.
    pub active_regime: usize,
    /// The reported driving regime: the active regime once it has been active for
    /// `regime_confirm_samples` samples in a row (the first estimate's active regime at start).
    pub regime: usize,
    /// What each component means, from its statistics after this sample (`crate::regime`):
    /// unique within the mixture.
    pub regime_names: Vec<ComponentName>,
    /// The name of `regime`.
    pub regime_name: ComponentName,
    /// `regime` differs from the previous sample's (`None` on the first estimate): the
    /// `regime_changed` event, raised by the service and written by `railmon analyze fuel`.
    pub regime_change: Option<RegimeChange>,
    /// Fuel integrated from the virtual sensor since initialisation, cm^3.
    pub cumulative_virtual_fuel_cm3: f64,
    /// The fuel channel's plausible range (`ranges`), cm^3/s, its lower end at least 0. Every
    /// fuel value above and every interval end is projected into it: a fuel flow is never
    /// negative, but a regression's mean is not bounded. Near fuel cut-off the means dip a
    /// little below 0 (the Camry files: 21-85 virtual-sensor values per file, down to -1.13
    /// cm^3/s), and a component that has just become active (unsettled, its regression near the
    /// prior) extrapolated a railcar's virtual sensor to -95.75 cm^3/s once (docs/fuel.md).
    /// Projected, every error against a measured value in the range is at most the unprojected
    /// one, and every interval covers the same measured values.
    pub fuel_range_cm3_s: [f64; 2],
}

/// The intervals are computed from the predictive terms only when asked: each end is a quantile
/// of a Student-t mixture found by Newton steps on its CDF (a continued fraction per term), and
/// computing the 22 ends in every `update` made the step 3.4 times slower (docs/fuel.md,
/// "Benchmark"); the service needs them once per published view, `railmon analyze fuel` at every
/// step. Same terms, same function: the same bits on every path.
impl MixtureEstimate {
    /// 90 % predictive interval of the 1-step forecast (NaN while no forecast was made).
    pub fn one_step_interval_cm3_s(&self) -> Interval {
        self.interval(&self.one_step_predictive)
    }

    /// 90 % predictive interval of the virtual sensor.
    pub fn virtual_sensor_interval_cm3_s(&self) -> Interval {
        self.interval(&self.virtual_sensor_predictive)
    }

    /// 90 % predictive interval of each forecast step (`t+1 .. t+H`).
    pub fn forecast_interval_cm3_s(&self) -> Vec<Interval> {
        (self.forecast_predictive.iter())
            .map(|terms| self.interval(terms))
            .collect()
    }

    /// The central 90 % interval of `terms`, its ends in the fuel's range.
    fn interval(&self, terms: &[StudentT]) -> Interval {
        let i = central_interval(terms, INTERVAL_MASS);
        let [min, max] = self.fuel_range_cm3_s;
        Interval {
            lower: i.lower.clamp(min, max),
            upper: i.upper.clamp(min, max),
        }
    }
}

/// The alarm rule of the fuel stream: the reported regime changed. The event `regime_changed`
/// of the service and of `railmon analyze fuel` (`events.csv`) carries these fields.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct RegimeChange {
    pub from_regime: usize,
    pub to_regime: usize,
    /// What the regimes mean, named on this sample (the component left may have been renamed
    /// since it was entered: the name is of its statistics now). Names are unique per
    /// component, so they differ.
    pub from_name: ComponentName,
    pub to_name: ComponentName,
    /// Probability of the new regime on this sample.
    pub probability: f64,
}

/// The `kind` of a [`RegimeChange`] event.
pub const REGIME_CHANGED: &str = "regime_changed";

/// Everything the monitor reports after a sample.
#[derive(Clone, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct FuelEstimate {
    pub time_s: f64,
    /// Measured fuel now.
    pub fuel_cm3_s: f64,
    /// Measured fuel integrated over time, cm^3.
    pub cumulative_fuel_cm3: f64,
    /// Samples accepted so far.
    pub samples: u64,
    /// `None` while the first `init_samples` are being collected (and on the sample that
    /// completes them: its forecast did not exist).
    pub mixture: Option<MixtureEstimate>,
}

/// A sample reduced to what the mixture uses, checked.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
struct Prepared {
    time_s: f64,
    /// Continuous channels in the monitor's order (fuel first), raw units.
    y: Vec<f64>,
    category: Option<usize>,
    /// Speed below the standstill threshold (only with `pointer_standing`; false otherwise).
    #[serde(default)]
    standing: bool,
    speed_level: usize,
    fuel_level: usize,
    /// Discretised `v_t - v_{t-1}` (0 when acceleration bins are off or on the first sample).
    acceleration_level: usize,
    speed_m_s: Option<f64>,
    /// The kinematic filter's state after this sample (`speed_noise_m_s` > 0 only).
    kinematic: Option<KinematicState>,
}

/// Mean and spread of each channel from the initial samples.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
struct Standardiser {
    mean: Vec<f64>,
    scale: Vec<f64>,
}

impl Standardiser {
    /// `min_scales[c]`: the floor of channel `c`'s spread.
    fn from_samples(min_scales: &[f64], samples: &[Prepared]) -> Self {
        let n = samples.len() as f64;
        let mut mean = vec![0.0; min_scales.len()];
        let mut scale = vec![0.0; min_scales.len()];
        for (c, floor) in min_scales.iter().enumerate() {
            let m = samples.iter().map(|s| s.y[c]).sum::<f64>() / n;
            let var = samples.iter().map(|s| (s.y[c] - m).powi(2)).sum::<f64>() / n;
            mean[c] = m;
            scale[c] = var.sqrt().max(*floor);
        }
        Standardiser { mean, scale }
    }

    fn apply(&self, y: &[f64]) -> DVector<f64> {
        DVector::from_iterator(
            y.len(),
            y.iter()
                .enumerate()
                .map(|(c, v)| (v - self.mean[c]) / self.scale[c]),
        )
    }

    fn fuel(&self, standardised: f64) -> f64 {
        self.mean[0] + self.scale[0] * standardised
    }

    /// A Student-t term of fuel from its standardised location and variance.
    fn fuel_term(&self, weight: f64, location: f64, variance: f64, dof: f64) -> StudentT {
        StudentT {
            weight,
            location: self.fuel(location),
            scale: self.scale[0] * variance.max(0.0).sqrt(),
            dof,
        }
    }
}

/// What the regressors need from the past: newest first.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
struct Past {
    y: VecDeque<DVector<f64>>,
    category: Option<usize>,
    speed_level: usize,
    fuel_levels: VecDeque<usize>,
    acceleration_level: usize,
}

/// The recursive fuel estimator on vehicle samples. See the crate documentation.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct FuelMonitor {
    config: FuelMonitorConfig,
    channels: Vec<Channel>,
    /// Channels computed from the speed, after `channels` in `y`.
    derived: Vec<DerivedChannel>,
    /// Indices (into `channels`) of the channels whose past enters `psi`.
    lagged: Vec<usize>,
    spec: MixtureSpec,
    previous_time_s: Option<f64>,
    previous_speed_m_s: Option<f64>,
    /// Speed and acceleration filtered up to the last accepted sample (`speed_noise_m_s` > 0).
    kinematic: Option<KinematicState>,
    initial: Vec<Prepared>,
    standardiser: Option<Standardiser>,
    past: Past,
    mixture: Option<Mixture>,
    /// The single regression the forecasts and the virtual sensor are blended with
    /// (`forecast_blend`, `m_c > 1`).
    baseline: Option<Mixture>,
    blend: Blend,
    /// Forecast path made at the previous step (blended, calibrated).
    pending_forecast: ForecastPath,
    /// The forecast's work space (not in snapshots).
    #[serde(skip)]
    forecast_work: ForecastWork,
    /// Scales of the predictives that keep the 90 % intervals' coverage at 90 %.
    calibration: IntervalCalibration,
    /// The active regime and for how many samples in a row it has been active.
    active_streak: (usize, usize),
    estimate: FuelEstimate,
}

impl FuelMonitor {
    /// The version of this type's serialised layout (everything in it: the mixture, its
    /// forecasts and calibration, the regime names, the kept samples), which the service writes
    /// into each vehicle snapshot. Raise it with every change of the layout;
    /// `tests/state_layout.rs` pins the layout under it
    /// (`tests/data/golden/state-layout-fuel.txt`), so a change cannot ship without it.
    /// 3: the mixture's spec gained `measured_channels` (issue 14's measured-data density).
    /// 4: the mixture gained `level_channels` and the level statistics (issue 14 item 3).
    /// 5: the config gained `pointer_standing` and `pointer_level_resolutions`, the mixture's
    /// spec `level_scales`, the kept samples `standing` (bincode has no field defaults).
    /// 6: the channel ranges in its settings gained `acceleration_m_s2`.
    /// 7: the forecast blend gained horizon 0 (the virtual sensor's weight sums).
    /// 8: the mixture's spec gained `standing_level_channels` and the mixture the standing
    /// level statistics; `pointer_standing` changed meaning.
    /// 9: the mixture's estimate gained `fuel_range_cm3_s`.
    /// 10: the standing level statistics are the standing component's only.
    /// 11: the rejected experiments left (issue 27): the config lost `measured_proximity`,
    /// `pointer_level_regressors` and `pointer_level_resolutions`, the mixture's spec
    /// `measured_channels`, `level_regressors` and `level_scales`.
    /// 12: the config gained `speed_noise_m_s`, the monitor and its kept samples the kinematic
    /// filter's state (issue 25 item 4).
    pub const STATE_FORMAT_VERSION: u32 = 12;

    /// A monitor with validated `config`; it collects `init_samples` before estimating.
    pub fn new(config: &FuelMonitorConfig) -> Result<Self, FuelError> {
        config.validate()?;
        let mut channels = vec![Channel::Fuel];
        channels.extend(
            config
                .channels
                .iter()
                .copied()
                .filter(|c| *c != Channel::Fuel),
        );
        let derived = config.derived_channels.clone();
        let k_y = channels.len() + derived.len();
        let lagged: Vec<usize> = match &config.lagged_channels {
            Some(list) => (0..channels.len())
                .filter(|&i| list.contains(&channels[i]))
                .collect(),
            None => (0..channels.len()).collect(),
        };
        let categories = config.notch_categories();
        let spec = MixtureSpec {
            components: config.components,
            k_y,
            k_psi: lagged.len() * config.regression_memory + usize::from(categories > 0) + 1,
            categories,
            categorical_rows: config.notch_categories().max(1) * config.speed_levels(),
            switching_rows: config.switching_rows(),
            forgetting: config.forgetting,
            parameter_uncertainty: config.parameter_uncertainty,
            prior_information: config.prior_information,
            prior_kappa: config.prior_kappa,
            min_noise_variance: config.min_noise_variance,
            dirichlet_prior: config.dirichlet_prior,
            switching_prior_stay: config.switching_prior_stay,
            switching_prior_move: config.switching_prior_move,
            level_channels: config.pointer_level_indices()?,
            level_min_variance: config.pointer_level_min_variance,
            // With the levels, standstill is a state of its own: only the measured channels
            // other than the speed stay levels there (speed and everything derived from it
            // are 0).
            standing_level_channels: (config.pointer_standing
                && !config.pointer_levels.is_empty())
            .then(|| {
                let levels = config.pointer_level_indices()?;
                let kept: Vec<usize> = (levels.iter().copied())
                    .filter(|&c| c < channels.len() && channels[c] != Channel::Speed)
                    .collect();
                match kept.is_empty() {
                    true => Err(FuelError::invalid(
                        "pointer_levels",
                        format!("{:?}", config.pointer_levels),
                        "with `pointer_standing`, must hold a channel measured at standstill (fuel)",
                    )),
                    false => Ok(kept),
                }
            })
            .transpose()?,
        };
        Ok(FuelMonitor {
            config: config.clone(),
            channels,
            derived,
            lagged,
            spec,
            previous_time_s: None,
            previous_speed_m_s: None,
            kinematic: None,
            initial: Vec::new(),
            standardiser: None,
            past: Past::default(),
            mixture: None,
            baseline: None,
            blend: Blend::new(config.forecast_horizon_steps),
            pending_forecast: ForecastPath::default(),
            forecast_work: ForecastWork::default(),
            calibration: IntervalCalibration::new(config.forecast_horizon_steps),
            active_streak: (0, 0),
            estimate: FuelEstimate::default(),
        })
    }

    pub fn config(&self) -> &FuelMonitorConfig {
        &self.config
    }

    /// The continuous channels in the order the mixture uses (fuel first).
    pub fn channels(&self) -> &[Channel] {
        &self.channels
    }

    /// The mixture, once initialised (statistics in standardised units).
    pub fn mixture(&self) -> Option<&Mixture> {
        self.mixture.as_ref()
    }

    /// The last estimate.
    pub fn estimate(&self) -> &FuelEstimate {
        &self.estimate
    }

    /// Checks a sample against the configuration without changing anything.
    fn prepare(&self, sample: &VehicleSample) -> Result<Prepared, FuelError> {
        if !sample.time_s.is_finite() || self.previous_time_s.is_some_and(|p| sample.time_s <= p) {
            return Err(FuelError::TimeNotIncreasing {
                time_s: sample.time_s,
                previous_s: self.previous_time_s.unwrap_or(f64::NEG_INFINITY),
            });
        }
        if let Some(previous_s) = self.previous_time_s {
            self.config.check_sample_step(previous_s, sample.time_s)?;
        }
        let ranges = &self.config.ranges;
        let mut y = self
            .channels
            .iter()
            .map(|&c| sample.checked(c, ranges))
            .collect::<Result<Vec<f64>, FuelError>>()?;
        let (category, speed_level) = match &self.config.categorical {
            Some(cat) => {
                let gear = sample.gear.ok_or(FuelError::MissingGear {
                    time_s: sample.time_s,
                })?;
                let l = cat.category(gear).ok_or(FuelError::UnknownCategory {
                    gear,
                    time_s: sample.time_s,
                })?;
                let level = if self.config.speed_bins_m_s.is_empty() {
                    0
                } else {
                    bin_index(
                        &self.config.speed_bins_m_s,
                        sample.checked(Channel::Speed, ranges)?,
                    )
                };
                (Some(l), level)
            }
            None => (None, 0),
        };
        let standing = self.config.pointer_standing
            && sample.checked(Channel::Speed, ranges)? < self.config.naming.standstill_speed_m_s;
        let needs_speed =
            !(self.config.acceleration_bins_m_s2.is_empty() && self.derived.is_empty());
        // Whenever the estimator uses the speed, its change since the last accepted sample
        // must be one the vehicle can make (km/h read as m/s is 3.6 times too fast).
        let speed_m_s = match needs_speed || self.channels.contains(&Channel::Speed) {
            true => Some(sample.checked(Channel::Speed, ranges)?),
            false => None,
        };
        // Speed and acceleration for the derived channels: the reading and its difference, or
        // with a noisy sensor the kinematic filter's.
        let (kinematic, acceleration_m_s2, derived_speed_m_s) =
            match (speed_m_s, self.config.speed_noise_m_s > 0.0) {
                (Some(v), true) => {
                    let filter = KinematicFilter {
                        speed_noise_m_s: self.config.speed_noise_m_s,
                    };
                    let next = match &self.kinematic {
                        None => filter.start(sample.time_s, v),
                        Some(state) => {
                            let (a, sd) = filter.implied_acceleration(state, sample.time_s, v);
                            ranges.check_implied_acceleration(
                                (state.time_s, state.speed_m_s()),
                                sample.time_s,
                                v,
                                a,
                                NOISE_ALLOWANCE_SD * sd,
                            )?;
                            filter.step(state, sample.time_s, v)?
                        }
                    };
                    let (a, v) = (next.acceleration_m_s2(), next.speed_m_s());
                    (Some(next), a, v)
                }
                (Some(v), false) => {
                    let a = ranges.check_acceleration(
                        self.previous_time_s.zip(self.previous_speed_m_s),
                        sample.time_s,
                        v,
                    )?;
                    (None, a, v)
                }
                (None, _) => (None, 0.0, 0.0),
            };
        let acceleration_level = match (needs_speed, speed_m_s) {
            (true, Some(v)) => {
                let a = acceleration_m_s2;
                let v_derived = derived_speed_m_s;
                let gradient = if self.derived.contains(&DerivedChannel::SpecificForce) {
                    crate::sample::effective_gradient_permille(
                        v,
                        sample.checked(Channel::Gradient, ranges)?,
                        self.config.naming.standstill_speed_m_s,
                    )
                } else {
                    0.0
                };
                y.extend(self.derived.iter().map(|d| d.value(v_derived, a, gradient)));
                bin_index(&self.config.acceleration_bins_m_s2, a)
            }
            _ => 0,
        };
        Ok(Prepared {
            acceleration_level,
            speed_m_s,
            kinematic,
            time_s: sample.time_s,
            fuel_level: bin_index(&self.config.fuel_bins_cm3_s, y[0]),
            y,
            category,
            standing,
            speed_level,
        })
    }

    /// Checks `sample` as [`FuelMonitor::update`] would, without changing anything: `Err`
    /// (with [`FuelError::reason`]) when `update` would refuse it.
    pub fn check(&self, sample: &VehicleSample) -> Result<(), FuelError> {
        self.prepare(sample).map(|_| ())
    }

    /// Processes one sample: validates it (on error nothing changes), then Algorithm 3.4's
    /// on-line step and the outputs. The first `init_samples` only fill the initial batch.
    pub fn update(&mut self, sample: &VehicleSample) -> Result<&FuelEstimate, FuelError> {
        let p = self.prepare(sample)?;
        let dt = self
            .previous_time_s
            .map_or(self.config.sample_period_s, |prev| p.time_s - prev);
        let mixture_estimate = match self.mixture.is_some() {
            true => Some(self.online_step(&p, dt)?),
            false => {
                self.initial.push(p.clone());
                if self.initial.len() == self.config.init_samples {
                    self.initialise()?;
                }
                None
            }
        };
        self.previous_time_s = Some(p.time_s);
        self.previous_speed_m_s = p.speed_m_s;
        self.kinematic = p.kinematic.clone();
        let e = &mut self.estimate;
        e.time_s = p.time_s;
        e.fuel_cm3_s = p.y[0];
        e.cumulative_fuel_cm3 += p.y[0] * dt;
        e.samples += 1;
        e.mixture = mixture_estimate;
        Ok(&self.estimate)
    }

    fn regressor(&self, past: &Past) -> DVector<f64> {
        let mut psi = Vec::with_capacity(self.spec.k_psi);
        for y in past.y.iter().take(self.config.regression_memory) {
            psi.extend(self.lagged.iter().map(|&i| y[i]));
        }
        let notches = self.config.notch_categories();
        if notches > 0 {
            // The paper puts the gear itself in psi (section 4.2); centred, so that it does
            // not compete with the constant.
            let l = past.category.unwrap_or(0) as f64;
            psi.push(l - 0.5 * (notches - 1) as f64);
        }
        psi.push(1.0);
        DVector::from_vec(psi)
    }

    /// The categorical cell `(q, l)` of the sample `now`: `q` the previous notch and speed
    /// level, `l` the notch now.
    fn category_cell(&self, past: &Past, now: &Prepared) -> Option<(usize, usize)> {
        now.category.map(|l| {
            (
                past.category.unwrap_or(0) * self.config.speed_levels() + past.speed_level,
                l,
            )
        })
    }

    fn switching_row(&self, past: &Past) -> usize {
        self.switching_row_of(past.fuel_levels.iter().copied(), past.acceleration_level)
    }

    /// Row of the switching table for fuel levels (newest first) and an acceleration level:
    /// the newest level is the least significant digit (base: the number of levels).
    fn switching_row_of(
        &self,
        levels_newest_first: impl Iterator<Item = usize>,
        acceleration_level: usize,
    ) -> usize {
        let n_f = self.config.fuel_levels();
        let (k_f, _) =
            levels_newest_first.fold((0, 1), |(k, digit), f| (k + f * digit, digit * n_f));
        k_f * self.config.acceleration_levels() + acceleration_level
    }

    fn push_past(past: &mut Past, y: DVector<f64>, p: &Prepared, m_y: usize, m_alpha: usize) {
        past.y.push_front(y);
        past.y.truncate(m_y);
        past.category = p.category;
        past.speed_level = p.speed_level;
        past.fuel_levels.push_front(p.fuel_level);
        past.fuel_levels.truncate(m_alpha);
        past.acceleration_level = p.acceleration_level;
    }

    /// Initial part of Algorithm 3.4 from the collected samples: the components start from a
    /// partition of the samples by fuel level (quantiles), refined by EM.
    fn initialise(&mut self) -> Result<(), FuelError> {
        let min_scales: Vec<f64> = self
            .channels
            .iter()
            .map(|c| c.min_scale())
            .chain(self.derived.iter().map(|d| d.min_scale()))
            .collect();
        let st = Standardiser::from_samples(&min_scales, &self.initial);
        let (m_y, m_alpha) = (self.config.regression_memory, self.config.switching_memory);
        let start = m_y.max(m_alpha);
        let mut past = Past::default();
        let mut ys = Vec::new();
        let mut psis = Vec::new();
        let mut cells = Vec::new();
        let mut rows = Vec::new();
        let mut standing = Vec::new();
        for (t, p) in self.initial.iter().enumerate() {
            let y = st.apply(&p.y);
            if t >= start {
                standing.push(p.standing);
                psis.push(self.regressor(&past));
                cells.push(self.category_cell(&past, p));
                rows.push(self.switching_row(&past));
                ys.push(y.clone());
            }
            Self::push_past(&mut past, y, p, m_y, m_alpha);
        }
        let inputs: Vec<MixtureInput> = (0..ys.len())
            .map(|t| MixtureInput {
                y: &ys[t],
                psi: &psis[t],
                category: cells[t],
                switching_row: rows[t],
                standing: standing[t],
            })
            .collect();
        let m = self.config.components;
        let mut order: Vec<usize> = (0..ys.len()).collect();
        if self.config.init_partition == InitialPartition::FuelRank {
            // Component 0 the lowest fuel, m_c - 1 the highest.
            order.sort_by(|&a, &b| ys[a][0].total_cmp(&ys[b][0]));
        }
        // With standstill a regime given, its samples are the standing component's and the
        // moving ones share the others.
        let given = usize::from(self.spec.standing_level_channels.is_some());
        order.retain(|&t| given == 0 || !standing[t]);
        let mut labels = vec![crate::mixture::STANDING_COMPONENT; ys.len()];
        for (rank, &t) in order.iter().enumerate() {
            labels[t] = given + rank * (m - given) / order.len();
        }
        let mixture = Mixture::from_batch(
            self.spec.clone(),
            &inputs,
            &labels,
            self.config.init_iterations,
            self.config.init_weight,
        )?;
        let baseline = if self.config.forecast_blend && m > 1 {
            // One component: its pointer is 1 whatever the evidence, so no level statistics.
            let spec = MixtureSpec {
                components: 1,
                level_channels: Vec::new(),
                standing_level_channels: None,
                ..self.spec.clone()
            };
            let zeros = vec![0; labels.len()];
            Some(Mixture::from_batch(
                spec,
                &inputs,
                &zeros,
                0,
                self.config.init_weight,
            )?)
        } else {
            None
        };
        self.past = past;
        self.standardiser = Some(st);
        self.mixture = Some(mixture);
        self.baseline = baseline;
        self.pending_forecast = self.blended_forecast();
        self.initial = Vec::new();
        Ok(())
    }

    fn online_step(&mut self, p: &Prepared, dt: f64) -> Result<MixtureEstimate, FuelError> {
        let (Some(st), Some(mixture)) = (self.standardiser.as_ref(), self.mixture.as_ref()) else {
            return Err(FuelError::Numerical("monitor not initialised"));
        };
        let y = st.apply(&p.y);
        let psi = self.regressor(&self.past);
        let category = self.category_cell(&self.past, p);
        let k = self.switching_row(&self.past);
        let m = self.config.components;

        // Virtual sensor (before the update: it must not see fuel now).
        let mut log_pred = vec![0.0; m];
        mixture.predict_pointer_from(mixture.log_weights(), k, &mut log_pred);
        let y_other = y.rows(1, y.len() - 1).into_owned();
        let mut cond = Vec::with_capacity(m);
        let mut log_v = vec![0.0; m];
        // The step's proximities need the same predictions; the forecast made at the end of the
        // last update made them already, at this `psi` from these statistics (its first step),
        // unless the monitor was restored from a snapshot since.
        let fresh;
        let predictions = match &self.pending_forecast.first_predictions {
            made if made.len() == m => made.as_slice(),
            _ => {
                fresh = mixture.predictions(&psi);
                fresh.as_slice()
            }
        };
        for (i, comp) in mixture.components().iter().enumerate() {
            let c = comp.condition_first_on_rest_at(&predictions[i], &y_other);
            log_v[i] = log_pred[i]
                + mixture.log_evidence_without_fuel(i, &y, p.standing, &c)
                + mixture.log_category(i, category);
            cond.push(c);
        }
        normalize_log_weights(&mut log_v)?;
        let virtual_std: f64 = (0..m).map(|i| log_v[i].exp() * cond[i].mean).sum();
        let own_sensor = self.in_fuel_range(st.fuel(virtual_std));
        let own_terms: Vec<StudentT> = (0..m)
            .map(|i| {
                let dof = mixture.components()[i].predictive_dof();
                st.fuel_term(log_v[i].exp(), cond[i].mean, cond[i].variance, dof)
            })
            .collect();
        // Blended with the single regression's virtual sensor as the forecasts are (horizon 0
        // of [`Blend`]: weights from the errors up to `t-1`), then calibrated as they are.
        let single_sensor = self.baseline.as_ref().map(|b| {
            let c = b.components()[0].condition_first_on_rest_at(&b.predictions(&psi)[0], &y_other);
            let dof = b.components()[0].predictive_dof();
            (
                self.in_fuel_range(st.fuel(c.mean)),
                vec![st.fuel_term(1.0, c.mean, c.variance, dof)],
            )
        });
        let (virtual_sensor, mut virtual_terms) = match &single_sensor {
            Some((single, terms)) => self
                .blend
                .pool(0, (own_sensor, &own_terms), (*single, terms)),
            None => (own_sensor, own_terms),
        };
        self.calibration
            .scale(0, virtual_sensor, &mut virtual_terms);

        let input = MixtureInput {
            y: &y,
            psi: &psi,
            category,
            switching_row: k,
            standing: p.standing,
        };
        // Mixture::step changes nothing when it fails; the baseline is stepped on a copy first
        // so that a failure of either leaves the monitor as it was.
        let baseline = match &self.baseline {
            Some(b) => {
                let mut b = b.clone();
                b.step(&input)?;
                Some(b)
            }
            None => None,
        };
        let mixture = self.mixture.as_mut().expect("checked above");
        mixture.step_predicted(&input, predictions)?;
        if baseline.is_some() {
            self.baseline = baseline;
        }
        let active = mixture.active();
        let zero_step = st.fuel(mixture.components()[active].mean(&psi)[0]);
        let regime_probabilities = mixture.weights();

        // Commit the rest.
        let (m_y, m_alpha) = (self.config.regression_memory, self.config.switching_memory);
        Self::push_past(&mut self.past, y, p, m_y, m_alpha);
        let one_step = self.pending_forecast.mean_cm3_s.first().copied();
        let one_step_terms = self.pending_forecast.terms.first().cloned();
        self.blend.observe(p.y[0], self.config.blend_forgetting);
        if let Some((single, _)) = single_sensor {
            self.blend
                .observe_sensor(own_sensor, single, p.y[0], self.config.blend_forgetting);
        }
        self.calibration.observe(0, &virtual_terms, p.y[0]);
        self.calibration.observe_forecasts(p.y[0]);
        let next = self.blended_forecast();
        let old = std::mem::replace(&mut self.pending_forecast, next);
        let spare = &mut self.forecast_work.spare_terms;
        spare.extend(
            old.terms
                .into_iter()
                .take(self.config.forecast_horizon_steps),
        );
        spare.truncate(self.config.forecast_horizon_steps);
        let previous = self.estimate.mixture.as_ref();
        self.active_streak = match self.active_streak {
            (regime, n) if regime == active => (regime, n + 1),
            _ => (active, 1),
        };
        let regime = match previous {
            Some(e) if self.active_streak.1 < self.config.regime_confirm_samples => e.regime,
            _ => active,
        };
        let regime_names = self.regime_names();
        let regime_change = previous
            .filter(|e| e.regime != regime)
            .map(|e| RegimeChange {
                from_regime: e.regime,
                to_regime: regime,
                from_name: regime_names[e.regime],
                to_name: regime_names[regime],
                probability: regime_probabilities[regime],
            });
        let cumulative_virtual =
            previous.map_or(0.0, |e| e.cumulative_virtual_fuel_cm3) + virtual_sensor * dt;
        // The forecast's copies in the buffers of the estimate this one replaces.
        let (mut forecast_cm3_s, mut forecast_predictive) = match self.estimate.mixture.as_mut() {
            Some(e) => (
                std::mem::take(&mut e.forecast_cm3_s),
                std::mem::take(&mut e.forecast_predictive),
            ),
            None => Default::default(),
        };
        forecast_cm3_s.clone_from(&self.pending_forecast.mean_cm3_s);
        forecast_predictive.clone_from(&self.pending_forecast.terms);
        Ok(MixtureEstimate {
            zero_step_cm3_s: self.in_fuel_range(zero_step),
            one_step_forecast_cm3_s: one_step.unwrap_or(f64::NAN),
            one_step_predictive: one_step_terms.unwrap_or_default(),
            virtual_sensor_cm3_s: virtual_sensor,
            virtual_sensor_predictive: virtual_terms,
            forecast_cm3_s,
            forecast_predictive,
            regime_probabilities,
            active_regime: active,
            regime,
            regime_name: regime_names[regime],
            regime_names,
            regime_change,
            cumulative_virtual_fuel_cm3: cumulative_virtual,
            fuel_range_cm3_s: self.fuel_range_cm3_s(),
        })
    }

    /// `fuel_cm3_s` projected into the fuel's plausible range: every fuel mean a forecaster
    /// makes (the mixture's and the single regression's virtual sensor and forecasts, the 0-step
    /// estimate) is projected before it is blended, scored by the blend or published, so the
    /// blend's weights are fitted to what is published (`MixtureEstimate::fuel_range_cm3_s`).
    fn in_fuel_range(&self, fuel_cm3_s: f64) -> f64 {
        let [min, max] = self.fuel_range_cm3_s();
        fuel_cm3_s.clamp(min, max)
    }

    /// The range fuel estimates are projected into: the fuel channel's plausible range, its
    /// lower end at least 0 (the range admits a meter's small negative readings, -1 cm^3/s on
    /// the road car; a flow is never negative).
    fn fuel_range_cm3_s(&self) -> [f64; 2] {
        let [min, max] = self.config.ranges.of(Channel::Fuel);
        [min.max(0.0), max]
    }

    /// The forecast path of the mixture, blended with the baseline's (when there is one) by
    /// the current blend weights, calibrated ([`IntervalCalibration`]), with its intervals;
    /// remembers the paths for the next weights and scales.
    fn blended_forecast(&mut self) -> ForecastPath {
        let Some(mixture) = self.mixture.as_ref() else {
            return ForecastPath::default();
        };
        let mut work = std::mem::take(&mut self.forecast_work);
        let mut own = self.forecast_path(mixture, &mut work);
        let path = match self.baseline.as_ref() {
            Some(baseline) => {
                let single = self.forecast_path(baseline, &mut work);
                let mut blended = self.blend.combine(&own, &single);
                blended.first_predictions = std::mem::take(&mut own.first_predictions);
                self.blend.remember(own.mean_cm3_s, single.mean_cm3_s);
                blended
            }
            None => own,
        };
        self.forecast_work = work;
        self.calibration.calibrate(path)
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
    fn forecast_path(&self, mixture: &Mixture, work: &mut ForecastWork) -> ForecastPath {
        let Some(st) = self.standardiser.as_ref() else {
            return ForecastPath::default();
        };
        // Gear and constant (the regressor's tail) are known: the covariance lives on the
        // lagged channels alone.
        let uncertain = self.lagged.len() * self.config.regression_memory;
        if work.dims != (self.spec.k_y, self.spec.k_psi, uncertain) {
            *work = ForecastWork::new(self, uncertain);
        }
        work.fit(mixture.spec().components);
        crate::kernel::with_size!(uncertain, |n| self
            .forecast_path_sized(n, st, mixture, work))
    }

    /// [`Self::forecast_path`] with the size of the regressor's uncertain part, `n`, a
    /// [`crate::kernel::Size`]: the recursion's loops over it are the step's innermost, and
    /// with a compile-time bound the compiler unrolls them and drops their bounds checks.
    fn forecast_path_sized<N: crate::kernel::Size>(
        &self,
        n: N,
        st: &Standardiser,
        mixture: &Mixture,
        work: &mut ForecastWork,
    ) -> ForecastPath {
        use crate::kernel::{lower_times_norm_squared, nalgebra_dot, propagate_covariance};
        let horizon = self.config.forecast_horizon_steps;
        let m = mixture.spec().components;
        let (k_psi, n2) = (self.spec.k_psi, n.get() * n.get());
        let parameter_uncertainty = self.config.parameter_uncertainty;
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
        psi_now.copy_from(&self.regressor(&self.past));
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
        levels.extend(self.past.fuel_levels.iter().copied());
        let acceleration_level = self.past.acceleration_level;
        let row = self.switching_row_of(levels.iter().copied(), acceleration_level);
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
                            let (l_inv, work) =
                                (factor_inverse[i].as_slice(), solve.as_mut_slice());
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
                    let c_yy =
                        |at: usize| r[at] * inflate + if h > 0 { propagated[at] } else { 0.0 };
                    if h == 0 {
                        // Sigma = 0: so is Cov(psi, y) = Sigma theta.
                        sigma_theta.fill(0.0);
                    }
                    let level = bin_index(&self.config.fuel_bins_cm3_s, st.fuel(mean[0]));
                    let shifted = &mut shifted_psi[i * k_psi..(i + 1) * k_psi];
                    for ((out, source), psi_a) in shifted.iter_mut().zip(sources.iter()).zip(psi_i)
                    {
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
                    rows[i] = self.switching_row_of(
                        std::iter::once(level)
                            .chain(levels.iter().copied())
                            .take(self.config.switching_memory),
                        acceleration_level,
                    );
                }
            }
            path.push(self.in_fuel_range(st.fuel(y0)), terms);
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
            let level = bin_index(&self.config.fuel_bins_cm3_s, st.fuel(y0));
            levels.push_front(level);
            levels.truncate(self.config.switching_memory);
        }
        path
    }

    /// Where each element of the next forecast regressor comes from (the new `y` in its newest
    /// lag, the older lags shifted, gear and constant known), written into `out`.
    fn regressor_sources(&self, out: &mut Vec<Source>) {
        let n_lag = self.lagged.len();
        let lagged_len = n_lag * self.config.regression_memory;
        out.clear();
        out.extend(
            (0..self.spec.k_psi).map(|a| match (a < lagged_len, a / n_lag.max(1)) {
                (false, _) => Source::Known,
                (true, 0) => Source::Y(self.lagged[a % n_lag]),
                (true, k) => Source::Psi((k - 1) * n_lag + a % n_lag),
            }),
        );
    }

    /// Each component's operating point (`crate::regime`): the mean of the data vector it has
    /// absorbed, `V[., 1] / (V[1, 1] - V_0[1, 1])` with `1` the constant of `psi`, in physical
    /// units. Empty
    /// before initialisation.
    pub fn operating_points(&self) -> Vec<OperatingPoint> {
        let (Some(st), Some(mixture)) = (self.standardiser.as_ref(), self.mixture.as_ref()) else {
            return Vec::new();
        };
        let k_y = self.spec.k_y;
        let one = k_y + self.spec.k_psi - 1;
        let speed = self.channels.iter().position(|&c| c == Channel::Speed);
        let acceleration = self
            .derived
            .iter()
            .position(|&d| d == DerivedChannel::Acceleration)
            .map(|i| self.channels.len() + i);
        // Speed a sample ago: its place in the newest lag block of psi, when speed is lagged.
        let lagged_speed = speed
            .and_then(|s| self.lagged.iter().position(|&i| i == s))
            .filter(|_| self.config.regression_memory > 0)
            .map(|p| k_y + p);
        let prior = self.config.prior_information;
        mixture
            .components()
            .iter()
            .map(|comp| {
                let v = comp.v();
                // V_0 = epsilon I adds to the diagonal only (also under stabilised forgetting,
                // which keeps the prior's share at V_0): the weighted count is the rest.
                let samples = v[(one, one)] - prior;
                let raw = |j: usize| v[(j, one)] / samples.max(f64::MIN_POSITIVE);
                let physical = |c: usize, j: usize| st.mean[c] + st.scale[c] * raw(j);
                let speed_m_s = speed.map(|s| physical(s, s));
                let acceleration_m_s2 = match (acceleration, speed, lagged_speed) {
                    (Some(a), _, _) => Some(physical(a, a)),
                    (None, Some(s), Some(lag)) => {
                        Some(st.scale[s] * (raw(s) - raw(lag)) / self.config.sample_period_s)
                    }
                    _ => None,
                };
                OperatingPoint {
                    samples,
                    fuel_cm3_s: physical(0, 0),
                    speed_m_s,
                    acceleration_m_s2,
                    standing_share: None,
                }
            })
            .zip(0..)
            .map(|(point, i)| OperatingPoint {
                standing_share: mixture.standing_share(i),
                ..point
            })
            .collect()
    }

    /// What each component means (`crate::regime`), from the operating points: a name unique
    /// per component. Empty before initialisation.
    pub fn regime_names(&self) -> Vec<ComponentName> {
        self.config.naming.names(&self.operating_points())
    }

    /// Index of the most probable component now (`None` before initialisation).
    pub fn active_regime(&self) -> Option<usize> {
        self.mixture.as_ref().map(|m| argmax(m.log_weights()))
    }

    /// The reported (confirmed) regime of the last estimate (`None` before the first).
    pub fn regime(&self) -> Option<usize> {
        self.estimate.mixture.as_ref().map(|m| m.regime)
    }
}

/// A fuel forecast path: mean and predictive per step (`t+1 .. t+H`), raw units.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
struct ForecastPath {
    mean_cm3_s: Vec<f64>,
    terms: Vec<Vec<StudentT>>,
    /// The mixture's components' predictions at the first step's regressor (what the next
    /// update's virtual sensor and step need: the same statistics, the same `psi`). Not in
    /// snapshots: a restored monitor computes them again.
    #[serde(skip)]
    first_predictions: Vec<crate::regression::Prediction>,
}

impl ForecastPath {
    fn with_capacity(n: usize) -> Self {
        ForecastPath {
            mean_cm3_s: Vec::with_capacity(n),
            terms: Vec::with_capacity(n),
            first_predictions: Vec::new(),
        }
    }

    fn push(&mut self, mean_cm3_s: f64, terms: Vec<StudentT>) {
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

/// The work space of [`FuelMonitor::forecast_path`], flat buffers sized once for the
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
struct ForecastWork {
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
    /// The work space for `monitor`'s sizes, `n` of its regressor's elements uncertain, for
    /// no component yet ([`Self::fit`]).
    fn new(monitor: &FuelMonitor, n: usize) -> Self {
        let (k_y, k_psi) = (monitor.spec.k_y, monitor.spec.k_psi);
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
        monitor.regressor_sources(&mut work.sources);
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

/// The interacting-multiple-model mixing step of [`FuelMonitor::forecast_path`]: from `p_j =
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

/// One-sided 95 % point of the standard normal: the blend gives the mixture the lower end of
/// the one-sided 95 % confidence interval of its least-squares weight ([`HorizonSums::weight`]).
const BLEND_WEIGHT_Z: f64 = 1.644_853_626_951_472;

/// Blend of the mixture with the single regression, per horizon: index 0 the virtual sensor,
/// `h` the forecast `h` steps ahead. Per horizon the forgotten sums that give the combination
/// weight and its standard error, and the forecast paths still waiting for their targets
/// (newest first). The virtual sensor's target is measured at the step it is made for, so its
/// errors do not overlap and its sums have no lag beyond 0 (as the 1-step forecast's).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
struct Blend {
    sums: Vec<HorizonSums>,
    waiting: VecDeque<(Vec<f64>, Vec<f64>)>,
}

/// The errors of one horizon's forecasts, `e_m` (mixture) and `e_s` (single regression),
/// forgotten with `blend_forgetting`.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
struct HorizonSums {
    /// `sum e_m^2`, `sum e_s^2`, `sum e_m e_s`.
    squares: [f64; 3],
    /// The score's parts `a_t = d_t e_s`, `b_t = d_t^2` (`d = e_s - e_m`) of the newest errors,
    /// newest first, as many as the horizon.
    recent: VecDeque<(f64, f64)>,
    /// Per lag `k` below the horizon: `sum a_t a_{t-k}`, `sum (a_t b_{t-k} + b_t a_{t-k})`,
    /// `sum b_t b_{t-k}`.
    lag_sums: Vec<[f64; 3]>,
}

impl HorizonSums {
    fn new(h: usize) -> Self {
        HorizonSums {
            squares: [0.0; 3],
            recent: VecDeque::with_capacity(h),
            lag_sums: vec![[0.0; 3]; h],
        }
    }

    fn observe(&mut self, em: f64, es: f64, forgetting: f64) {
        for (sum, e) in self.squares.iter_mut().zip([em * em, es * es, em * es]) {
            *sum = forgetting * *sum + e;
        }
        let d = es - em;
        let (a, b) = (d * es, d * d);
        self.recent.push_front((a, b));
        self.recent.truncate(self.lag_sums.len());
        for (k, sums) in self.lag_sums.iter_mut().enumerate() {
            let (ak, bk) = self.recent.get(k).copied().unwrap_or((0.0, 0.0));
            for (sum, x) in sums.iter_mut().zip([a * ak, a * bk + b * ak, b * bk]) {
                *sum = forgetting * *sum + x;
            }
        }
    }

    /// Weight of the mixture: the least-squares weight `w = argmin sum (w e_m + (1 - w)
    /// e_s)^2 = sum e_s d / sum d^2` (the regression of `e_s` on `d = e_s - e_m`), lowered by
    /// `z` times its standard error, in `[0, 1]`; 0 (the single regression alone) until there
    /// are as many errors as the horizon. The standard error is Newey and West's
    /// (Econometrica 55(3), 1987: Bartlett weights `1 - k/h` over `h - 1` lags, since
    /// forecasts `h` steps ahead overlap and their errors are correlated up to lag `h - 1`) of
    /// the score `g_t = d_t (e_s - w d_t) = a_t - w b_t`: `se = sqrt(sum_k c_k sum_t g_t
    /// g_{t-k}) / sum d^2`, `c_0 = 1`, `c_k = 2 (1 - k/h)`.
    ///
    /// Why a lower confidence bound and not the weight itself: where the mixture adds nothing
    /// (true weight 0) the estimated weight is noise around 0, positive half of the time, and
    /// after a change of which method is better it lags; both cost squared error against the
    /// single regression (the weight itself left the blend 0.2-0.8 % worse than the single
    /// regression from 7 s on the highway and aggressive Camry files). With the bound the
    /// weight is 0 with probability about 95 % when the mixture does not help, and the
    /// mixture keeps a weight where its help is significant (the railcar routes, the city).
    fn weight(&self) -> f64 {
        let [mm, ss, ms] = self.squares;
        let dd = mm + ss - 2.0 * ms;
        let h = self.lag_sums.len();
        if !(dd > 1e-12 * (mm + ss) && dd > 0.0) || self.recent.len() < h {
            return 0.0;
        }
        let w = (ss - ms) / dd;
        let long_run_variance: f64 = self
            .lag_sums
            .iter()
            .enumerate()
            .map(|(k, [aa, ab, bb])| {
                let bartlett = if k == 0 {
                    1.0
                } else {
                    2.0 * (1.0 - k as f64 / h as f64)
                };
                bartlett * (aa - w * ab + w * w * bb)
            })
            .sum();
        let standard_error = long_run_variance.max(0.0).sqrt() / dd;
        (w - BLEND_WEIGHT_Z * standard_error).clamp(0.0, 1.0)
    }
}

impl Blend {
    fn new(horizon: usize) -> Self {
        Blend {
            sums: (0..=horizon).map(|h| HorizonSums::new(h.max(1))).collect(),
            waiting: VecDeque::with_capacity(horizon + 1),
        }
    }

    /// Weight of the mixture at horizon `h` (0 the virtual sensor), [`HorizonSums::weight`].
    fn weight(&self, h: usize) -> f64 {
        self.sums[h].weight()
    }

    /// Scores the waiting forecasts of this sample's measured fuel (forgetting older errors).
    fn observe(&mut self, fuel_cm3_s: f64, forgetting: f64) {
        for (age, (own, single)) in self.waiting.iter().enumerate() {
            let (Some(m), Some(s)) = (own.get(age), single.get(age)) else {
                continue;
            };
            self.sums[age + 1].observe(m - fuel_cm3_s, s - fuel_cm3_s, forgetting);
        }
    }

    /// Scores this sample's virtual sensors (mixture `own`, single regression `single`) of its
    /// measured fuel; they were made before it was seen, so the next weight is causal.
    fn observe_sensor(&mut self, own: f64, single: f64, fuel_cm3_s: f64, forgetting: f64) {
        self.sums[0].observe(own - fuel_cm3_s, single - fuel_cm3_s, forgetting);
    }

    fn remember(&mut self, own: Vec<f64>, single: Vec<f64>) {
        self.waiting.push_front((own, single));
        self.waiting.truncate(self.sums.len() - 1);
    }

    /// Horizon `h`'s blend (0 the virtual sensor): mean `w m + (1 - w) s`, predictive the pool
    /// of both mixtures' terms with weights `w` and `1 - w`.
    fn pool(
        &self,
        h: usize,
        (own_mean, own_terms): (f64, &[StudentT]),
        (single_mean, single_terms): (f64, &[StudentT]),
    ) -> (f64, Vec<StudentT>) {
        let w = self.weight(h);
        let scaled = |terms: &[StudentT], by: f64| {
            terms
                .iter()
                .map(move |t| StudentT {
                    weight: t.weight * by,
                    ..*t
                })
                .collect::<Vec<_>>()
        };
        let mut terms = scaled(own_terms, w);
        terms.extend(scaled(single_terms, 1.0 - w));
        (w * own_mean + (1.0 - w) * single_mean, terms)
    }

    /// The blended forecast path (without intervals), [`Blend::pool`] per horizon.
    fn combine(&self, own: &ForecastPath, single: &ForecastPath) -> ForecastPath {
        let mut out = ForecastPath::with_capacity(own.mean_cm3_s.len());
        for h in 1..=own.mean_cm3_s.len() {
            let (mean, terms) = self.pool(
                h,
                (own.mean_cm3_s[h - 1], &own.terms[h - 1]),
                (single.mean_cm3_s[h - 1], &single.terms[h - 1]),
            );
            out.push(mean, terms);
        }
        out
    }
}

/// Step of the calibration's log scale per sample (see [`IntervalCalibration`]).
const CALIBRATION_STEP: f64 = 0.05;

/// Adaptive calibration of the 90 % intervals (adaptive conformal inference: Gibbs and Candes,
/// "Adaptive conformal inference under distribution shift", NeurIPS 2021, eq. 2, here on the
/// log of a scale instead of on the miscoverage level). Every predictive (index 0 the virtual
/// sensor, `h` the forecast `h` steps ahead) is widened or narrowed about its mean by a factor
/// `s = exp(l)` (locations and scales of its terms); once its target is measured, `l <- l +
/// gamma (miss - 0.1)`, `miss` = 1 when the target fell outside the 90 % interval (its CDF
/// value outside [0.05, 0.95]).
///
/// Why: the mixture's predictive is right in the bulk and wrong in the tails. Fuel errors are
/// small noise plus rare large jumps (the driver's decisions within the horizon: a notch or
/// pedal change), kurtosis 5-145 of the standardised errors against 3 for the Gaussian
/// components. A Gaussian fitted to both covers the 1-step bulk too widely (coverage 0.957 and
/// 0.960 on the railcar routes) and, accumulated over 10 s, misses the jumps (0.827 on the
/// hilly route; mean squared standardised error 10 at 10 s against 1 by the model). A
/// heavy-tailed component noise would be the model's fix; it is not the paper's estimator.
///
/// Guarantee (the telescoping sum of the updates): over `T` targets, the share of misses is
/// exactly `0.1 + (l_T - l_0) / (gamma T)`, so the long-run coverage is 90 % whenever the
/// scale stays bounded, which it does: a wide enough interval misses nothing (so `l` falls)
/// and a narrow enough one misses everything (so `l` rises); on any data, not one file's.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
struct IntervalCalibration {
    /// `l` of the virtual sensor (0) and of each forecast step (`h`).
    log_scale: Vec<f64>,
    /// Calibrated predictives of the forecast paths still waiting for their targets, newest
    /// first.
    waiting: VecDeque<Vec<Vec<StudentT>>>,
}

impl IntervalCalibration {
    fn new(horizon: usize) -> Self {
        IntervalCalibration {
            log_scale: vec![0.0; horizon + 1],
            waiting: VecDeque::with_capacity(horizon + 1),
        }
    }

    /// `terms` widened about `mean` by the current scale of predictive `index`.
    fn scale(&self, index: usize, mean: f64, terms: &mut [StudentT]) {
        let s = self.log_scale[index].exp();
        for t in terms {
            t.location = mean + s * (t.location - mean);
            t.scale *= s;
        }
    }

    /// Updates the scale of predictive `index` with its (calibrated) `terms` and the target.
    fn observe(&mut self, index: usize, terms: &[StudentT], target: f64) {
        let total: f64 = terms.iter().map(|t| t.weight).sum();
        if !(total > 0.0 && total.is_finite() && target.is_finite()) {
            return;
        }
        // The target's CDF value in [0.05, 0.95], decided by a bound where it can be.
        let tail = 0.5 * (1.0 - INTERVAL_MASS);
        let miss = f64::from(u8::from(!crate::predictive::cdf_within(
            terms,
            total,
            target,
            tail,
            1.0 - tail,
        )));
        self.log_scale[index] += CALIBRATION_STEP * (miss - (1.0 - INTERVAL_MASS));
    }

    /// Scores the waiting forecasts of this sample (the newest path's first step, the one
    /// before's second, ...).
    fn observe_forecasts(&mut self, target: f64) {
        let waiting = std::mem::take(&mut self.waiting);
        for (age, terms) in waiting.iter().enumerate() {
            if let Some(step) = terms.get(age) {
                self.observe(age + 1, step, target);
            }
        }
        self.waiting = waiting;
    }

    /// `path` with every step's predictive scaled; remembers it for the updates.
    fn calibrate(&mut self, mut path: ForecastPath) -> ForecastPath {
        for (h, (terms, mean)) in path.terms.iter_mut().zip(&path.mean_cm3_s).enumerate() {
            self.scale(h + 1, *mean, terms);
        }
        // The copy goes into the buffers of the path it pushes out (no allocation once the
        // queue is full).
        let horizon = self.log_scale.len() - 1;
        let mut kept = match self.waiting.len() >= horizon {
            true => self.waiting.pop_back().unwrap_or_default(),
            false => Vec::new(),
        };
        kept.clone_from(&path.terms);
        self.waiting.push_front(kept);
        self.waiting.truncate(horizon);
        path
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The virtual sensor's blend (horizon 0), on seeded errors with known truth. Where the
    /// mixture's sensor is the single regression's plus independent noise (true weight 0) the
    /// weight is 0 nearly always and the blend's squared error is the single regression's
    /// (the least-squares weight itself would be positive half of the time). Where the
    /// mixture's error is `(e_s + n) / 2`, `n` independent of `e_s` with its variance (true
    /// weight 1, its standard error about `1 / sqrt(632)` with forgetting 0.999) the weight
    /// stays near 1.
    #[test]
    fn virtual_sensor_blend_is_the_single_regression_unless_the_mixture_helps_significantly() {
        use rand::SeedableRng;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(14);
        let mut normal = || -> f64 { rand::Rng::sample(&mut rng, rand_distr::StandardNormal) };
        let unit = |location: f64| {
            vec![StudentT {
                weight: 1.0,
                location,
                scale: 1.0,
                dof: 1e9,
            }]
        };
        let (mut useless, mut better) = (Blend::new(10), Blend::new(10));
        let (mut zero_weights, mut weight_sum) = (0, 0.0);
        let mut squares = [0.0; 4]; // blended useless, single, blended better, mixture better
        for t in 0..1000 {
            let fuel = 10.0 + normal();
            let single = fuel + normal();
            let noisy = single + normal();
            let good = fuel + 0.5 * (single - fuel) + 0.5 * normal();
            if t >= 200 {
                let w = useless.weight(0);
                zero_weights += usize::from(w == 0.0);
                let (blended, terms) =
                    useless.pool(0, (noisy, &unit(noisy)), (single, &unit(single)));
                assert_eq!(blended, w * noisy + (1.0 - w) * single);
                assert_eq!(terms.len(), 2);
                assert_eq!(terms[0].weight, w);
                weight_sum += better.weight(0);
                let (blended_good, _) =
                    better.pool(0, (good, &unit(good)), (single, &unit(single)));
                for (sum, e) in squares
                    .iter_mut()
                    .zip([blended, single, blended_good, good])
                {
                    *sum += (e - fuel).powi(2);
                }
            }
            useless.observe_sensor(noisy, single, fuel, 0.999);
            better.observe_sensor(good, single, fuel, 0.999);
        }
        assert!(
            zero_weights >= 720,
            "{zero_weights} of 800 steps at weight 0"
        );
        assert!(squares[0] <= 1.01 * squares[1], "{squares:?}");
        assert!(weight_sum / 800.0 > 0.85, "{weight_sum}");
        assert!(better.weight(0) > 0.85, "{}", better.weight(0));
        assert!(squares[2] <= 1.02 * squares[3], "{squares:?}");
        assert!(squares[2] < 0.6 * squares[1], "{squares:?}");
        // The forecast horizons are untouched by the sensor's errors.
        assert!((1..=10).all(|h| better.weight(h) == 0.0));
    }

    /// The calibration's guarantee on targets its predictive gets wrong (a unit normal against
    /// Student-t targets with 2 degrees of freedom and twice the scale, seeded): the share of
    /// misses equals `0.1 + l_T / (gamma T)` (the telescoping sum of the updates, to rounding)
    /// and ends near 10 %, where the uncalibrated interval misses about 29 %.
    #[test]
    fn calibrated_intervals_miss_ten_percent_of_targets_they_were_not_made_for() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let mut calibration = IntervalCalibration::new(1);
        let unit = [StudentT {
            weight: 1.0,
            location: 0.0,
            scale: 1.0,
            dof: 1e9,
        }];
        let (n, mut misses, mut raw_misses) = (20_000, 0usize, 0usize);
        for _ in 0..n {
            // Student-t with 2 dof: a normal over the root of a chi-square(2) / 2.
            let z: f64 = rng.sample(rand_distr::StandardNormal);
            let chi2 = -2.0 * (1.0 - rng.random::<f64>()).ln();
            let target = 2.0 * z / (chi2 / 2.0).sqrt();
            let mut terms = unit;
            calibration.scale(0, 0.0, &mut terms);
            let interval = central_interval(&terms, INTERVAL_MASS);
            misses += usize::from(!interval.contains(target));
            raw_misses += usize::from(!central_interval(&unit, INTERVAL_MASS).contains(target));
            calibration.observe(0, &terms, target);
        }
        let share = misses as f64 / n as f64;
        let identity = 0.1 + calibration.log_scale[0] / (CALIBRATION_STEP * n as f64);
        assert!((share - identity).abs() < 1e-9, "{share} vs {identity}");
        assert!((share - 0.1).abs() < 0.005, "{share}");
        assert!(raw_misses as f64 / n as f64 > 0.25, "{raw_misses}");
    }
}
