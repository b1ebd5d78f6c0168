//! Configuration of the fuel monitor: which channels, how they are discretised, the mixture's
//! sizes, memories, priors and forgetting. Every field is validated by
//! [`FuelMonitorConfig::validate`], which names the field and the value it rejects.

use railmon_settings::Presets;
use serde::{Deserialize, Serialize};

use crate::regime::RegimeNaming;
use crate::sample::{Channel, ChannelRanges, DerivedChannel};
use crate::FuelError;

/// The categorical channel `z` (the gear of a car, section 4.1, or the throttle notch of a
/// diesel railcar) and how its raw values are grouped into categories. The paper groups gears
/// `{-1, 0} -> 1, {1, 2, 3} -> 2, 4 -> 3, 5 -> 4, 6 -> 5` so that the categories are about equally
/// frequent.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CategoricalConfig {
    /// What the channel is (`gear`, `notch`), as errors and reports name it. The values travel
    /// in the sample's `gear` field and the recording's `gear` column whatever the name.
    #[serde(default = "CategoricalConfig::default_name")]
    pub name: String,
    /// `gear_groups[l]` lists the raw values of category `l`. A value in no group is an error
    /// ([`FuelError::UnknownCategory`]); a category never observed keeps its Dirichlet prior.
    pub gear_groups: Vec<Vec<i32>>,
}

impl Default for CategoricalConfig {
    fn default() -> Self {
        CategoricalConfig {
            name: Self::default_name(),
            gear_groups: vec![vec![-1, 0], vec![1, 2, 3], vec![4], vec![5], vec![6]],
        }
    }
}

impl CategoricalConfig {
    fn default_name() -> String {
        "gear".to_owned()
    }

    /// The throttle notch of a diesel railcar or locomotive, 0 (idle) to 8 (full power),
    /// grouped into idle, low, middle and high power (a notch of its own would leave most
    /// categories rare: a driver notches through 1-3 in seconds).
    pub fn throttle_notch() -> Self {
        CategoricalConfig {
            name: "notch".to_owned(),
            gear_groups: vec![vec![0], vec![1, 2, 3], vec![4, 5, 6], vec![7, 8]],
        }
    }

    /// Category index of a raw gear.
    pub fn category(&self, gear: i32) -> Option<usize> {
        self.gear_groups.iter().position(|g| g.contains(&gear))
    }
}

/// How far a time step may be from a whole number of sample periods, as a share of a period
/// (the service's sample clock uses the same share).
pub const SAMPLE_PERIOD_TOLERANCE: f64 = 0.01;

/// Bounds of `regime_confirm_samples` (declared to the settings reference and checked):
/// at most an hour of 1 Hz samples.
const REGIME_CONFIRM_SAMPLES: std::ops::RangeInclusive<usize> = 1..=3600;
/// Bounds of the integer settings below (declared to the settings reference and checked).
/// Components: each holds a regression's statistics and a row of the switching tables.
const COMPONENTS: std::ops::RangeInclusive<usize> = 1..=64;
const REGRESSION_MEMORY: std::ops::RangeInclusive<usize> = 0..=10;
/// The outer bounds; within them the switching condition may have at most
/// `SWITCHING_ROWS_MAX` configurations (fuel levels^m_alpha x acceleration levels).
const SWITCHING_MEMORY: std::ops::RangeInclusive<usize> = 1..=12;
const SWITCHING_ROWS_MAX: f64 = 4096.0;
/// The outer bounds; within them at least the longer memory plus three samples.
const INIT_SAMPLES: std::ops::RangeInclusive<usize> = 4..=1_000_000;
const INIT_ITERATIONS: std::ops::RangeInclusive<usize> = 0..=1000;
/// Up to an hour of 1 Hz samples ahead.
const FORECAST_HORIZON_STEPS: std::ops::RangeInclusive<usize> = 1..=3600;
/// Bounds of float settings below with ends other than 0 (declared to the settings reference
/// and checked).
const SPEED_NOISE_M_S: std::ops::RangeInclusive<f64> = 0.0..=5.0;
const INIT_WEIGHT_MAX: f64 = 1000.0;

/// How the initial samples are split among the components before EM.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum InitialPartition {
    /// By rank of the fuel flow: component 0 the lowest `1/m_c` of the samples, and so on.
    FuelRank,
    /// Consecutive time blocks of equal length: for initial data recorded as one stretch per
    /// known regime (the paper's prior data `Delta_0`), component `i` starts from stretch `i`.
    TimeBlocks,
}

/// Settings of [`crate::FuelMonitor`]. `Default` is the setting used on the Camry files (fuel
/// and speed only, no gear; chosen on those files, see `docs/fuel.md`): regression memory 2 (so
/// that `psi` carries the last acceleration), the switching conditioned on the fuel level and
/// the sign of the last acceleration, slow forgetting (0.998, memory ~500 s) so the components
/// follow a warming engine, weak priors. It is the one default: the service, `railmon analyze
/// fuel --input` and scenarios without `[monitor]` take it from here. Named
/// presets, asked for with `preset = "<name>"` in a settings table (`railmon_settings::deserialize_with_preset`):
/// `paper` ([`FuelMonitorConfig::paper`]: five channels + gear, memory 1, switching on the fuel
/// level only, no forgetting) and `driving_style` ([`FuelMonitorConfig::driving_style`], the
/// setting of `config/scenarios/fuel-cycles.toml` and the demo).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct FuelMonitorConfig {
    /// Continuous channels `y_t`; must contain `fuel`. Internally fuel comes first.
    pub channels: Vec<Channel>,
    /// Channels whose past values enter the regressor `psi_t` (absent: all of `channels`, the
    /// paper's `psi_t = [y_{t-1}, z_{t-1}, 1]`). With a subset, the other channels are static
    /// within a component (a mean per component): their level then tells the components apart,
    /// which is what recognising a regime needs, while fuel keeps its dynamics.
    pub lagged_channels: Option<Vec<Channel>>,
    /// Channels computed from the speed now and a sample ago, appended to `y_t` after the
    /// measured ones (never lagged into `psi`): what the engine must deliver now. The virtual
    /// sensor conditions fuel on them, so within a component it is a regression of fuel on
    /// speed, acceleration, power demand and speed powers, which a fuel map is close to
    /// (tractive power ~ m a v + c_r m g v + c_d v^3); and the pointer sees them (measured on
    /// the railcar routes: mostly their degenerate density, not what the driver does, which
    /// is why the railcar preset weighs the pointer by levels). Need the `speed` channel.
    pub derived_channels: Vec<DerivedChannel>,
    /// Names of channels of `y_t` (measured, `fuel` included, or derived: `speed`,
    /// `specific_force`, ...) whose levels weigh the pointer: the evidence for a component is
    /// the density of these channels' values under a static Gauss-inverse-Wishart of the
    /// component (no lags), updated with the pointer's weights, plus, when `fuel` is not among
    /// them, fuel given every other channel now and the lags (its regression); and the notch's
    /// term (`Mixture`, docs/notes/fuel-log.md "The pointer weighed by levels"). Changes the
    /// pointer and so the update weights; the regressions, the virtual sensor (weighted by the same
    /// evidence without fuel) and the forecasts are computed from them as before. Empty: off
    /// (the paper's evidence). The railcar preset's: `["fuel",
    /// "speed", "specific_force"]` with `pointer_level_min_variance = 3e-2` and
    /// `pointer_standing` (docs/fuel.md "Standstill, a regime given").
    pub pointer_levels: Vec<String>,
    /// Floor on the eigenvalues of the level statistics' covariance (standardised units). A
    /// standing train's speed is exactly 0 and a station's grade exactly constant, so a level
    /// component's covariance collapses to its floor; at `min_noise_variance`'s 1e-6 a stop
    /// at another grade then costs hundreds of nats and another component takes it
    /// (docs/fuel.md: 3e-2 there). 1e-6 by default, which only matters with `pointer_levels`.
    #[schemars(range(min = 0.0))]
    pub pointer_level_min_variance: f64,
    /// Standstill (speed below `naming.standstill_speed_m_s`) is a regime given, not learned:
    /// component 0 holds every standing sample and no moving one, and its level statistics
    /// are over the levels measured at standstill (the fuel; the speed and what is derived
    /// from it are 0 there, the same for every component). The other components share the
    /// moving samples. A standing train's speed is a point mass, which a Gaussian level either
    /// fits at a tuning floor or merges with the slow creep into a platform (standing named
    /// idle on 51-79 % of the railcar route's standing seconds with the levels alone);
    /// `MixtureSpec::standing_level_channels`, docs/fuel.md "Standstill, a regime given".
    /// Component 0 is named `idle` (`crate::regime`). Needs `pointer_levels` with a channel
    /// measured at standstill, `speed` and at least 2 components. On in the railcar preset.
    pub pointer_standing: bool,
    /// Every regime is given, not learned: each sample's regime is read from physics (the
    /// notch, the acceleration, the grade-corrected acceleration and standstill;
    /// `RegimeNaming::physical_regime`) and only that regime's components may hold it, so
    /// components are named by their regime, the same on any line.
    /// Component 0 is `idle`, then `(components - 1) / 4` components for each of accelerating,
    /// cruising, coasting and braking, in that order (`regime::given_regime`); within a regime
    /// the mixture learns which holds what (fuel regression, levels, switching), and names
    /// them by power tier. Learned components named by their means held several regimes on
    /// lines they were not tuned on (issue 25 item 1, docs/fuel.md "Generated lines"). Needs
    /// `pointer_standing`, `components` = 1 + 4 k, the notch as `categorical` and
    /// `specific_force` in `derived_channels`. On in the railcar preset (9 components).
    #[serde(default)]
    pub pointer_regimes: bool,
    /// Standard deviation of the speed sensor's noise while moving, m/s (a tachometer reads 0
    /// standing). Above 0 the speed feeds a kinematic Kalman filter of speed and acceleration
    /// (`crate::kinematic`, white jerk): the derived channels take its speed and acceleration
    /// instead of the difference of two readings, whose noise is `sqrt(2)` times the sensor's
    /// per second, and the acceleration check widens its bounds by 4.5 standard deviations of
    /// the reading against the filtered speed, so that noise alone is not refused. 0 (the
    /// default): no filter, the difference as before (a measured speed with no noise worth
    /// filtering, as on the Camry files).
    #[schemars(range(min = *SPEED_NOISE_M_S.start(), max = *SPEED_NOISE_M_S.end()))]
    pub speed_noise_m_s: f64,
    /// Blend each h-step fuel forecast of the mixture with that of a single regression run
    /// alongside (same settings, one component), weighted per horizon by the convex
    /// combination with the smallest squared error so far (errors of forecasts whose target has
    /// been measured, data up to `t` only, forgotten with `blend_forgetting`). The mixture's
    /// mean forecast loses the regime after a few steps (the pointer is propagated, not known);
    /// the blend then moves towards the single regression. The virtual sensor is blended by
    /// the same rule (its own weight, from its own errors): on some routes the mixture's is
    /// significantly worse than the single regression's (docs/fuel.md). Off: the mixture alone
    /// (the paper).
    pub forecast_blend: bool,
    /// Forgetting of the squared-error sums that set the blend weights, in (0, 1].
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = 1.0))]
    pub blend_forgetting: f64,
    /// The categorical channel `z_t` (gear), if the source has one.
    pub categorical: Option<CategoricalConfig>,
    /// Number of components `m_c` (driving regimes).
    #[schemars(range(min = *COMPONENTS.start(), max = *COMPONENTS.end()))]
    pub components: usize,
    /// Memory `m_y` of the regression: `psi_t = [y_{t-1}, .., y_{t-m_y}, z_{t-1}, 1]`.
    #[schemars(range(min = *REGRESSION_MEMORY.start(), max = *REGRESSION_MEMORY.end()))]
    pub regression_memory: usize,
    /// Bin edges (m/s) discretising the speed into `s_t` (section 4.2: 4 values). Used in the
    /// categorical component's condition `[z_{t-1}, s_{t-1}]`.
    pub speed_bins_m_s: Vec<f64>,
    /// Bin edges (cm^3/s) discretising the fuel into `f_t` (section 4.2: 3 values), the data
    /// the switching model `c_t | c_{t-1}, f_{t-1}` depends on.
    pub fuel_bins_cm3_s: Vec<f64>,
    /// Bin edges (m/s^2) discretising the acceleration `a_{t-1} = v_{t-1} - v_{t-2}` (per
    /// sample period) for the switching model: `phi_{t-1} = [f_{t-1}, .., a_{t-1}]`. Empty: the
    /// paper's `phi_{t-1} = f_{t-1}` only. Whether the driver is speeding up, cruising or
    /// slowing down is what decides the regime next second (fuel cut-off follows braking), so
    /// this is the most informative discrete datum the switching can condition on.
    pub acceleration_bins_m_s2: Vec<f64>,
    /// Memory `m_alpha` of the switching model: `phi_{t-1} = [f_{t-1}, .., f_{t-m_alpha}]`
    /// (the paper's future work 3: longer switching memory); the condition may take at most
    /// 4096 values (fuel levels^`m_alpha` x acceleration levels).
    #[schemars(range(min = *SWITCHING_MEMORY.start(), max = *SWITCHING_MEMORY.end()))]
    pub switching_memory: usize,
    /// Samples used to initialise the statistics before the on-line part (150 in the paper); at
    /// least the longer of the two memories plus 3.
    #[schemars(range(min = *INIT_SAMPLES.start(), max = *INIT_SAMPLES.end()))]
    pub init_samples: usize,
    /// How the initial samples are first split among the components.
    pub init_partition: InitialPartition,
    /// EM iterations on the initial samples (0: the initial partition by fuel level as is).
    #[schemars(range(min = *INIT_ITERATIONS.start(), max = *INIT_ITERATIONS.end()))]
    pub init_iterations: usize,
    /// Weight of each initial sample in the statistics, in (0, 1000] (below 1 the on-line data
    /// take over sooner; above 1 the initial data count as more than one sample each).
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = INIT_WEIGHT_MAX))]
    pub init_weight: f64,
    /// Exponential forgetting factor lambda in (0, 1]; 1 = none. Applied as `lambda^w` to a
    /// component updated with weight `w`, towards the prior (stabilised forgetting).
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = 1.0))]
    pub forgetting: f64,
    /// Prior information matrix `V_0 = prior_information * I` (standardised units).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub prior_information: f64,
    /// Prior count `kappa_0`.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub prior_kappa: f64,
    /// Prior Dirichlet count of every cell of the categorical tables.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub dirichlet_prior: f64,
    /// Prior switching count for staying in the same component (`c_t = c_{t-1}`).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub switching_prior_stay: f64,
    /// Prior switching count for every change of component.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub switching_prior_move: f64,
    /// Floor on the eigenvalues of each component's noise covariance (standardised units).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub min_noise_variance: f64,
    /// Use the GiW predictive covariance `r (1 + psi' V_psi^-1 psi)` for the proximities instead
    /// of the paper's plug-in `r`.
    pub parameter_uncertainty: bool,
    /// Horizon of the multi-step fuel forecast, in samples.
    #[schemars(range(min = *FORECAST_HORIZON_STEPS.start(), max = *FORECAST_HORIZON_STEPS.end()))]
    pub forecast_horizon_steps: usize,
    /// The reported regime follows the most probable component once that has been the most
    /// probable for this many samples in a row (1: at once, the paper's pointer estimate). The
    /// pointer estimate flickers: on `fuel-cycles.toml` it changes 233 times in 8475 s while the
    /// driving style changes 4 times; confirming over 10 samples leaves 63 changes and the same
    /// accuracy (docs/fuel.md), so a regime-change event means a change of regime.
    #[schemars(range(min = *REGIME_CONFIRM_SAMPLES.start(), max = *REGIME_CONFIRM_SAMPLES.end()))]
    pub regime_confirm_samples: usize,
    /// Nominal sampling period (s): consecutive time stamps must lie a whole number of periods
    /// apart (within 1 %), at most `max_gap_s`; used to integrate the first sample's fuel.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub sample_period_s: f64,
    /// Longest gap between consecutive samples (s) the estimator bridges: beyond it a sample is
    /// refused ([`FuelError::SamplePeriod`]). Time stamps in ms read as s give 1000 s steps.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub max_gap_s: f64,
    /// Plausible range of every channel (the vehicle's, not the estimator's).
    pub ranges: ChannelRanges,
    /// Thresholds of the rule naming each component from its operating point (idle,
    /// accelerating, cruising, coasting, braking; `crate::regime`), the vehicle's.
    pub naming: RegimeNaming,
}

impl Default for FuelMonitorConfig {
    fn default() -> Self {
        FuelMonitorConfig {
            channels: vec![Channel::Fuel, Channel::Speed],
            lagged_channels: None,
            derived_channels: vec![
                DerivedChannel::Acceleration,
                DerivedChannel::PowerDemand,
                DerivedChannel::SpeedSquared,
                DerivedChannel::SpeedCubed,
            ],
            pointer_levels: Vec::new(),
            pointer_level_min_variance: 1e-6,
            speed_noise_m_s: 0.0,
            pointer_standing: false,
            pointer_regimes: false,
            forecast_blend: true,
            blend_forgetting: 0.999,
            categorical: None,
            components: 3,
            regression_memory: 2,
            speed_bins_m_s: vec![0.5, 8.0, 20.0],
            fuel_bins_cm3_s: vec![0.05, 0.8],
            acceleration_bins_m_s2: vec![-0.3, 0.3],
            switching_memory: 1,
            init_samples: 150,
            init_partition: InitialPartition::FuelRank,
            init_iterations: 10,
            init_weight: 1.0,
            forgetting: 0.998,
            prior_information: 1e-4,
            prior_kappa: 1.0,
            dirichlet_prior: 1.0,
            switching_prior_stay: 1.0,
            switching_prior_move: 1.0,
            min_noise_variance: 1e-6,
            parameter_uncertainty: true,
            forecast_horizon_steps: 10,
            regime_confirm_samples: 10,
            sample_period_s: 1.0,
            max_gap_s: 60.0,
            ranges: ChannelRanges::default(),
            naming: RegimeNaming::default(),
        }
    }
}

impl FuelMonitorConfig {
    /// The paper's setting (section 4): five continuous channels, the gear as the categorical
    /// channel, 3 components, 150 initial samples.
    pub fn paper() -> Self {
        FuelMonitorConfig {
            channels: Channel::PAPER.to_vec(),
            derived_channels: Vec::new(),
            forecast_blend: false,
            categorical: Some(CategoricalConfig::default()),
            regression_memory: 1,
            acceleration_bins_m_s2: Vec::new(),
            forgetting: 1.0,
            ..Default::default()
        }
    }

    /// The setting validated on `config/scenarios/fuel-cycles.toml` (preset `driving_style`):
    /// the paper's five channels and the gear, one component per driving style (2), regression
    /// memory 2, initialised from 1200 prior samples recorded as one time block per style, no
    /// forgetting, and a switching prior worth 10^4 samples with a 1/1000 chance of a change per
    /// second, so that the pointer weighs minutes of evidence (a driving style lasts minutes).
    /// Needs a source with all five channels and the gear, and prior data laid out that way.
    pub fn driving_style() -> Self {
        FuelMonitorConfig {
            channels: Channel::PAPER.to_vec(),
            derived_channels: Vec::new(),
            categorical: Some(CategoricalConfig::default()),
            components: 2,
            regression_memory: 2,
            init_samples: 1200,
            init_partition: InitialPartition::TimeBlocks,
            init_iterations: 0,
            forgetting: 1.0,
            acceleration_bins_m_s2: Vec::new(),
            switching_prior_stay: 10_000.0,
            switching_prior_move: 10.0,
            ..Default::default()
        }
    }

    /// A diesel railcar (DMU) or locomotive (preset `railcar`): fuel and speed, the throttle
    /// notch as the categorical channel, acceleration, power demand and `v^2` derived (no
    /// `v^3`: at railway speeds the aerodynamic share is small against rolling and grade
    /// resistance), fuel levels of a railcar engine (idle below 3 cm^3/s, part load below 20),
    /// forgetting 0.99, the railcar's channel ranges and regime names. Otherwise the default's
    /// estimator settings.
    ///
    /// Not the gradient (issue 14 item 3, docs/fuel.md): a route's gradient is piecewise
    /// constant, so as a channel with its own lag in `psi` its residual is zero except at the
    /// ends of sections, its variance sits at the floor and the components' likelihoods turn on
    /// which of them fits `gradient_t = gradient_{t-1}` best (one took 86 % of the route);
    /// without a lag the components split by gradient instead of by what the driver does.
    /// Either way the regimes were not recognised (named accuracy 17-40 % against 55-66 %
    /// without it, on two routes and four seeds). Forgetting 0.99 (memory ~100 s, a railcar's
    /// regime lasts tens of seconds to minutes; 0.998 kept 500 s): the components follow the
    /// current operating points and the names follow the components (45 % with 0.998).
    ///
    /// The regime is recognised by levels, not by the regression's density (issue 14 item 3):
    /// the pointer weighs fuel, speed and the grade-corrected acceleration (`specific_force`,
    /// so the source must send the `gradient`) under static per-component statistics, and
    /// standstill is a regime given (`pointer_standing`). On 16 cells (two routes, seven seeds,
    /// loaded and noisier) named accuracy 69.9-83.8 % against 46.6-67.3 % with the
    /// regression's density, standing named idle 100 %, coasting 43-86 % against 1-45 %
    /// (docs/fuel.md "Standstill, a regime given").
    pub fn railcar() -> Self {
        FuelMonitorConfig {
            channels: vec![Channel::Fuel, Channel::Speed],
            derived_channels: vec![
                DerivedChannel::Acceleration,
                DerivedChannel::PowerDemand,
                DerivedChannel::SpeedSquared,
                DerivedChannel::SpecificForce,
            ],
            categorical: Some(CategoricalConfig::throttle_notch()),
            speed_bins_m_s: vec![0.5, 10.0, 25.0],
            fuel_bins_cm3_s: vec![3.0, 20.0],
            acceleration_bins_m_s2: vec![-0.1, 0.1],
            forgetting: 0.99,
            // Idle, then two per moving regime (`pointer_regimes`): one per regime named every
            // second right but fitted one fuel regression over all of a regime's notches, and
            // the virtual sensor lost its lead on the shipped route (docs/notes/fuel-log.md).
            components: 9,
            pointer_levels: ["fuel", "speed", "specific_force"]
                .map(String::from)
                .to_vec(),
            pointer_level_min_variance: 3e-2,
            pointer_standing: true,
            pointer_regimes: true,
            ranges: ChannelRanges::railcar(),
            naming: RegimeNaming::railcar(),
            ..Default::default()
        }
    }

    /// Indices into `y_t` (fuel first, the other measured channels in `channels` order, then
    /// the derived ones, as [`crate::FuelMonitor`] lays it out) of `pointer_levels`.
    pub fn pointer_level_indices(&self) -> Result<Vec<usize>, FuelError> {
        self.y_indices("pointer_levels", &self.pointer_levels)
    }

    /// Indices into `y_t` of the channels `names` of the setting `field`.
    fn y_indices(&self, field: &'static str, names: &[String]) -> Result<Vec<usize>, FuelError> {
        let y: Vec<&str> = std::iter::once(Channel::Fuel.name())
            .chain(
                self.channels
                    .iter()
                    .filter(|c| **c != Channel::Fuel)
                    .map(|c| c.name()),
            )
            .chain(self.derived_channels.iter().map(|d| d.name()))
            .collect();
        names
            .iter()
            .enumerate()
            .map(|(i, name)| match y.iter().position(|c| c == name) {
                Some(_) if names[..i].contains(name) => {
                    Err(FuelError::invalid(field, name, "listed twice"))
                }
                Some(index) => Ok(index),
                None => Err(FuelError::invalid(
                    field,
                    name,
                    "not a channel of `channels` or `derived_channels`",
                )),
            })
            .collect()
    }

    /// The same setting with one component: the single recursive regression baseline (with
    /// no standing component: one component is every regime).
    pub fn single_regression(&self) -> Self {
        FuelMonitorConfig {
            components: 1,
            pointer_standing: false,
            pointer_regimes: false,
            ..self.clone()
        }
    }

    /// Number of values of the discretised fuel `f`.
    pub fn fuel_levels(&self) -> usize {
        self.fuel_bins_cm3_s.len() + 1
    }

    /// Number of values of the discretised acceleration in the switching condition.
    pub fn acceleration_levels(&self) -> usize {
        self.acceleration_bins_m_s2.len() + 1
    }

    /// Number of configurations of the switching condition `phi_{t-1}`.
    pub fn switching_rows(&self) -> usize {
        self.fuel_levels().pow(self.switching_memory as u32) * self.acceleration_levels()
    }

    /// Categories of the categorical channel itself (the notch or gear groups; 0 without).
    pub fn notch_categories(&self) -> usize {
        self.categorical.as_ref().map_or(0, |c| c.gear_groups.len())
    }

    /// Number of values of the discretised speed `s`.
    pub fn speed_levels(&self) -> usize {
        self.speed_bins_m_s.len() + 1
    }

    /// Whether a sample at `time_s` may follow one at `previous_s`: later by a whole number of
    /// `sample_period_s` (within 1 %), at most `max_gap_s`. Data at another rate or with time
    /// stamps in another unit (ms for s) would otherwise be estimated as if it were right (the
    /// derived acceleration divides by the step). The service's sample clock applies the same
    /// rule to frames (`records/src/sample_clock.rs`), with its own, shorter gap limit.
    pub fn check_sample_step(&self, previous_s: f64, time_s: f64) -> Result<(), FuelError> {
        if !time_s.is_finite() || time_s <= previous_s {
            return Err(FuelError::TimeNotIncreasing { time_s, previous_s });
        }
        let step_s = time_s - previous_s;
        let periods = step_s / self.sample_period_s;
        if step_s > self.max_gap_s
            || periods.round() < 1.0
            || (periods - periods.round()).abs() > SAMPLE_PERIOD_TOLERANCE
        {
            return Err(FuelError::SamplePeriod {
                time_s,
                step_s,
                period_s: self.sample_period_s,
                max_gap_s: self.max_gap_s,
            });
        }
        Ok(())
    }

    /// Checks every field; the error names the first bad one.
    pub fn validate(&self) -> Result<(), FuelError> {
        if !SPEED_NOISE_M_S.contains(&self.speed_noise_m_s) {
            return Err(FuelError::invalid(
                "speed_noise_m_s",
                self.speed_noise_m_s,
                "must be in [0, 5] m/s",
            ));
        }
        if !self.channels.contains(&Channel::Fuel) {
            return Err(FuelError::invalid(
                "channels",
                format!("{:?}", self.channels),
                "must contain `fuel`",
            ));
        }
        for (i, c) in self.channels.iter().enumerate() {
            if self.channels[..i].contains(c) {
                return Err(FuelError::invalid("channels", c, "listed twice"));
            }
        }
        if let Some(lagged) = &self.lagged_channels {
            if let Some(c) = lagged
                .iter()
                .enumerate()
                .find(|(i, c)| !self.channels.contains(c) || lagged[..*i].contains(c))
            {
                return Err(FuelError::invalid(
                    "lagged_channels",
                    c.1,
                    "not in `channels`, or listed twice",
                ));
            }
        }
        if let Some(cat) = &self.categorical {
            if cat.gear_groups.len() < 2 || cat.gear_groups.iter().any(|g| g.is_empty()) {
                return Err(FuelError::invalid(
                    "categorical.gear_groups",
                    format!("{:?}", cat.gear_groups),
                    "needs at least two non-empty groups",
                ));
            }
            for (i, g) in cat.gear_groups.iter().enumerate() {
                for gear in g {
                    if cat.gear_groups[..i].iter().any(|h| h.contains(gear))
                        || g.iter().filter(|x| *x == gear).count() > 1
                    {
                        return Err(FuelError::invalid(
                            "categorical.gear_groups",
                            gear,
                            "gear listed twice",
                        ));
                    }
                }
            }
        }
        if !COMPONENTS.contains(&self.components) {
            return Err(FuelError::invalid(
                "components",
                self.components,
                "must be in 1..=64",
            ));
        }
        if !REGRESSION_MEMORY.contains(&self.regression_memory) {
            return Err(FuelError::invalid(
                "regression_memory",
                self.regression_memory,
                "must be in 0..=10 (0: static components)",
            ));
        }
        check_edges("speed_bins_m_s", &self.speed_bins_m_s)?;
        check_edges("fuel_bins_cm3_s", &self.fuel_bins_cm3_s)?;
        check_edges("acceleration_bins_m_s2", &self.acceleration_bins_m_s2)?;
        if !SWITCHING_MEMORY.contains(&self.switching_memory)
            || (self.fuel_levels() as f64).powi(self.switching_memory as i32)
                * self.acceleration_levels() as f64
                > SWITCHING_ROWS_MAX
        {
            return Err(FuelError::invalid(
                "switching_memory",
                self.switching_memory,
                "must be in 1..=12 with at most 4096 configurations of [f_{t-1}, .., a_{t-1}]",
            ));
        }
        let min_init = self.regression_memory.max(self.switching_memory) + 3;
        if self.init_samples < min_init || !INIT_SAMPLES.contains(&self.init_samples) {
            return Err(FuelError::invalid(
                "init_samples",
                self.init_samples,
                "must cover the memories plus two samples, and be at most 10^6",
            ));
        }
        if !INIT_ITERATIONS.contains(&self.init_iterations) {
            return Err(FuelError::invalid(
                "init_iterations",
                self.init_iterations,
                "must be at most 1000",
            ));
        }
        if !(self.init_weight > 0.0 && self.init_weight <= INIT_WEIGHT_MAX) {
            return Err(FuelError::invalid(
                "init_weight",
                self.init_weight,
                "must be in (0, 1000]",
            ));
        }
        check_open_unit("forgetting", self.forgetting)?;
        check_open_unit("blend_forgetting", self.blend_forgetting)?;
        for (i, d) in self.derived_channels.iter().enumerate() {
            if self.derived_channels[..i].contains(d) {
                return Err(FuelError::invalid("derived_channels", d, "listed twice"));
            }
        }
        if !self.derived_channels.is_empty() && !self.channels.contains(&Channel::Speed) {
            return Err(FuelError::invalid(
                "derived_channels",
                format!("{:?}", self.derived_channels),
                "need `speed` in `channels`",
            ));
        }
        self.pointer_level_indices()?;
        if self.pointer_standing
            && (self.pointer_levels.is_empty()
                || self.components < 2
                || !self.channels.contains(&Channel::Speed))
        {
            return Err(FuelError::invalid(
                "pointer_standing",
                true,
                "needs `pointer_levels`, `speed` in `channels` and at least 2 `components`",
            ));
        }
        if self.pointer_regimes
            && !(self.pointer_standing
                && self.components >= crate::regime::GIVEN_REGIMES.len()
                && (self.components - 1).is_multiple_of(crate::regime::GIVEN_REGIMES.len() - 1)
                && self.categorical.is_some()
                && self
                    .derived_channels
                    .contains(&DerivedChannel::SpecificForce))
        {
            return Err(FuelError::invalid(
                "pointer_regimes",
                true,
                "needs `pointer_standing`, `components` 1 + 4 k (idle, k per moving regime), the notch as \
                 `categorical` and `specific_force` in `derived_channels`",
            ));
        }
        check_positive("prior_information", self.prior_information)?;
        check_positive("prior_kappa", self.prior_kappa)?;
        check_positive("dirichlet_prior", self.dirichlet_prior)?;
        check_positive("switching_prior_stay", self.switching_prior_stay)?;
        check_positive("switching_prior_move", self.switching_prior_move)?;
        check_positive("min_noise_variance", self.min_noise_variance)?;
        // Unchecked before: an infinite floor made every level covariance infinite.
        if !(self.pointer_level_min_variance.is_finite() && self.pointer_level_min_variance >= 0.0)
        {
            return Err(FuelError::invalid(
                "pointer_level_min_variance",
                self.pointer_level_min_variance,
                "must be finite and >= 0",
            ));
        }
        if !REGIME_CONFIRM_SAMPLES.contains(&self.regime_confirm_samples) {
            return Err(FuelError::invalid(
                "regime_confirm_samples",
                self.regime_confirm_samples,
                "must be in 1..=3600",
            ));
        }
        if !FORECAST_HORIZON_STEPS.contains(&self.forecast_horizon_steps) {
            return Err(FuelError::invalid(
                "forecast_horizon_steps",
                self.forecast_horizon_steps,
                "must be in 1..=3600",
            ));
        }
        check_positive("sample_period_s", self.sample_period_s)?;
        if !(self.max_gap_s.is_finite() && self.max_gap_s >= self.sample_period_s) {
            return Err(FuelError::invalid(
                "max_gap_s",
                self.max_gap_s,
                "must be finite and at least `sample_period_s`",
            ));
        }
        self.ranges.validate()?;
        self.naming.validate()?;
        Ok(())
    }
}

fn check_positive(field: &'static str, v: f64) -> Result<(), FuelError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(FuelError::invalid(field, v, "must be finite and > 0"))
    }
}

fn check_open_unit(field: &'static str, v: f64) -> Result<(), FuelError> {
    if v > 0.0 && v <= 1.0 {
        Ok(())
    } else {
        Err(FuelError::invalid(field, v, "must be in (0, 1]"))
    }
}

impl Presets for FuelMonitorConfig {
    const PRESETS: &'static [&'static str] = &["paper", "driving_style", "railcar"];

    fn preset(name: &str) -> Option<Self> {
        match name {
            "paper" => Some(Self::paper()),
            "driving_style" => Some(Self::driving_style()),
            "railcar" => Some(Self::railcar()),
            _ => None,
        }
    }
}

fn check_edges(field: &'static str, edges: &[f64]) -> Result<(), FuelError> {
    if edges.iter().any(|e| !e.is_finite()) || edges.windows(2).any(|w| w[0] >= w[1]) {
        return Err(FuelError::invalid(
            field,
            format!("{edges:?}"),
            "must be finite and strictly increasing",
        ));
    }
    if edges.len() > 63 {
        return Err(FuelError::invalid(field, edges.len(), "at most 63 edges"));
    }
    Ok(())
}
