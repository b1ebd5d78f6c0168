//! [`FuelMonitor`]: the recursive mixture run on vehicle samples, with the outputs a live
//! service or an offline report needs at every step.
//!
//! The monitor validates each sample before anything changes, standardises the continuous
//! channels with the mean and spread of the initial samples, builds the regressors
//! `psi_t = [y_{t-1}, .., y_{t-m_y}, z_{t-1}, 1]`, the categorical condition `[z_{t-1}, s_{t-1}]`
//! and the switching condition `[f_{t-1}, ..]` (`crate::data_vector`), and runs [`Mixture`].
//! Each step then computes the virtual sensor, forecasts (`crate::forecast`), blends both with
//! the single regression and calibrates their intervals (`crate::blend`), confirms the regime
//! (`crate::alarm`) and publishes a [`FuelEstimate`] (`crate::estimate`). This file is that
//! order; the parts are in theirs.

use railmon_filter::logspace::normalize_log_weights;

use crate::alarm::RegimeConfirmation;
use crate::blend::{Blend, IntervalCalibration};
use crate::config::{FuelMonitorConfig, InitialPartition};
use crate::data_vector::{Layout, Past, Prepared, Standardiser};
use crate::estimate::{fuel_range_cm3_s, in_fuel_range, FuelEstimate, MixtureEstimate};
use crate::forecast::{forecast_path, ForecastPath, ForecastStart, ForecastWork};
use crate::kinematic::{KinematicFilter, KinematicState};
use crate::mixture::{argmax, Mixture, MixtureInput, MixtureSpec};
use crate::predictive::StudentT;
use crate::regime::{ComponentName, OperatingPoint};
use crate::sample::{bin_index, Channel, DerivedChannel, VehicleSample};
use crate::FuelError;

/// With a noisy speed (`speed_noise_m_s` > 0) the acceleration check's bounds widen by this
/// many standard deviations of the reading's acceleration against the filtered speed: a
/// legitimate sample is refused by noise alone about once in 300 000 (two-sided normal tail).
const NOISE_ALLOWANCE_SD: f64 = 4.5;

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
    /// The confirmation of the reported regime (`regime_confirm_samples`); `active_streak`
    /// is the name its state has in snapshots.
    #[serde(rename = "active_streak")]
    regime_confirmation: RegimeConfirmation,
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
    /// 13: the config gained `pointer_regimes`, the kept samples their given regime (issue 25
    /// item 1).
    pub const STATE_FORMAT_VERSION: u32 = 13;

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
            regime_confirmation: RegimeConfirmation::default(),
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

    /// How the data vectors are laid out ([`Layout`]).
    fn layout(&self) -> Layout<'_> {
        Layout {
            config: &self.config,
            spec: &self.spec,
            lagged: &self.lagged,
        }
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
        let mut given = None;
        let mut reported_given = None;
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
                // The regime given (`pointer_regimes`): standstill as `standing` reads it (the
                // reading), the rest from the notch and the specific force the derived channel
                // has; validation guarantees the notch and `specific_force`.
                if let (true, Some(cat)) = (self.config.pointer_regimes, &self.config.categorical) {
                    let motion = crate::regime::Motion {
                        speed_m_s: if standing {
                            0.0
                        } else {
                            v_derived.max(self.config.naming.standstill_speed_m_s)
                        },
                        acceleration_m_s2: a,
                        specific_force_m_s2: DerivedChannel::SpecificForce
                            .value(v_derived, a, gradient),
                        notch: sample.gear.unwrap_or(0),
                        full_notch: cat.gear_groups.iter().flatten().copied().max().unwrap_or(0),
                    };
                    // Certain, as standstill is: ln P 0 for the regime's component, minus
                    // infinity for the others.
                    let regime = self.config.naming.physical_regime(&motion);
                    let m = self.config.components;
                    given = Some(
                        (0..m)
                            .map(|i| match crate::regime::given_regime(i, m) == regime {
                                true => 0.0,
                                false => f64::NEG_INFINITY,
                            })
                            .collect(),
                    );
                    // How sure the rule is, for what is published: the filter's spread of
                    // the acceleration (0 without the filter: the reading decides).
                    let sd = kinematic.as_ref().map_or(0.0, |k| k.p[3].max(0.0).sqrt());
                    let p = self
                        .config
                        .naming
                        .physical_regime_probabilities(&motion, sd);
                    reported_given = Some(
                        (0..m)
                            .map(|i| {
                                let r = crate::regime::given_regime(i, m);
                                let k = crate::regime::GIVEN_REGIMES.iter().position(|&g| g == r);
                                k.map_or(f64::NEG_INFINITY, |k| p[k].ln())
                            })
                            .collect(),
                    );
                }
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
            given,
            reported_given,
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
        let layout = self.layout();
        let mut past = Past::default();
        let mut ys = Vec::new();
        let mut psis = Vec::new();
        let mut cells = Vec::new();
        let mut rows = Vec::new();
        let mut standing = Vec::new();
        let mut given_regimes = Vec::new();
        for (t, p) in self.initial.iter().enumerate() {
            let y = st.apply(&p.y);
            if t >= start {
                standing.push(p.standing);
                given_regimes.push(p.given.clone());
                psis.push(layout.regressor(&past));
                cells.push(layout.category_cell(&past, p));
                rows.push(layout.switching_row(&past));
                ys.push(y.clone());
            }
            past.push(y, p, m_y, m_alpha);
        }
        let inputs: Vec<MixtureInput> = (0..ys.len())
            .map(|t| MixtureInput {
                y: &ys[t],
                psi: &psis[t],
                category: cells[t],
                switching_row: rows[t],
                standing: standing[t],
                given: given_regimes[t].as_deref(),
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
        // With every regime given, each sample starts in one of its regime's components: the
        // regime's samples by fuel rank (as above) over them.
        if self.config.pointer_regimes {
            for regime in crate::regime::GIVEN_REGIMES {
                let own: Vec<usize> = (0..m)
                    .filter(|&i| crate::regime::given_regime(i, m) == regime)
                    .collect();
                let members: Vec<usize> = (0..ys.len())
                    .filter(|&t| inputs[t].given.is_some_and(|g| own.contains(&argmax(g))))
                    .collect();
                let mut members = members;
                members.sort_by(|&a, &b| ys[a][0].total_cmp(&ys[b][0]));
                for (rank, &t) in members.iter().enumerate() {
                    labels[t] = own[rank * own.len() / members.len()];
                }
            }
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
            // One component holds every regime: none is given to it.
            let inputs: Vec<MixtureInput> = (inputs.iter())
                .map(|x| MixtureInput {
                    given: None,
                    ..x.clone()
                })
                .collect();
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
        let layout = self.layout();
        let psi = layout.regressor(&self.past);
        let category = layout.category_cell(&self.past, p);
        let k = layout.switching_row(&self.past);
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
                + mixture.log_category(i, category)
                + crate::mixture::log_given(p.given.as_deref(), i);
            cond.push(c);
        }
        normalize_log_weights(&mut log_v)?;
        let virtual_std: f64 = (0..m).map(|i| log_v[i].exp() * cond[i].mean).sum();
        let own_sensor = in_fuel_range(&self.config, st.fuel(virtual_std));
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
                in_fuel_range(&self.config, st.fuel(c.mean)),
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
            given: p.given.as_deref(),
        };
        // Mixture::step changes nothing when it fails; the baseline is stepped on a copy first
        // so that a failure of either leaves the monitor as it was.
        let baseline = match &self.baseline {
            Some(b) => {
                let mut b = b.clone();
                b.step(&MixtureInput {
                    given: None,
                    ..input.clone()
                })?;
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
        // With every regime given, the published probabilities weigh the rule by how sure it
        // is; the regime stays the rule's decision (`active`), which the mixture learns from.
        // Naming by the published probabilities instead named more seconds right on the
        // generated lines (held out 92.5 % median against 90.3 %) but coasting right on only
        // 55.7 % of one line's seconds (docs/notes/fuel-log.md).
        let regime_probabilities = match &p.reported_given {
            Some(g) => mixture.weights_given(g),
            None => mixture.weights(),
        };

        // Commit the rest.
        let (m_y, m_alpha) = (self.config.regression_memory, self.config.switching_memory);
        self.past.push(y, p, m_y, m_alpha);
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
        self.forecast_work
            .recycle(old, self.config.forecast_horizon_steps);
        let previous = self.estimate.mixture.as_ref();
        let regime_names = self.regime_names();
        let (regime, regime_change) = self.regime_confirmation.update(
            &self.config,
            active,
            previous.map(|e| e.regime),
            &regime_names,
            &regime_probabilities,
        );
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
            zero_step_cm3_s: in_fuel_range(&self.config, zero_step),
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
            fuel_range_cm3_s: fuel_range_cm3_s(&self.config),
        })
    }

    /// The forecast path of the mixture, blended with the baseline's (when there is one) by
    /// the current blend weights, calibrated ([`IntervalCalibration`]), with its intervals;
    /// remembers the paths for the next weights and scales.
    fn blended_forecast(&mut self) -> ForecastPath {
        let (Some(mixture), Some(st)) = (self.mixture.as_ref(), self.standardiser.as_ref()) else {
            return ForecastPath::default();
        };
        let mut work = std::mem::take(&mut self.forecast_work);
        let from = ForecastStart {
            layout: self.layout(),
            st,
            past: &self.past,
        };
        let mut own = forecast_path(from, mixture, &mut work);
        let path = match self.baseline.as_ref() {
            Some(baseline) => {
                let single = forecast_path(from, baseline, &mut work);
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
        if self.config.pointer_regimes && self.mixture.is_some() {
            // Each component holds its regime's samples only: its name is that regime (with a
            // power tier where a regime has several components).
            let m = self.config.components;
            let regimes: Vec<_> = (0..m).map(|i| crate::regime::given_regime(i, m)).collect();
            return self
                .config
                .naming
                .qualified(&regimes, &self.operating_points());
        }
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
