//! What the monitor publishes after each sample: [`FuelEstimate`], with the mixture's outputs
//! in [`MixtureEstimate`] once it is initialised; their 90 % intervals, computed from the kept
//! predictive terms when asked; the fuel range every published fuel value is projected into.

use serde::{Deserialize, Serialize};

use crate::alarm::RegimeChange;
use crate::config::FuelMonitorConfig;
use crate::predictive::{central_interval, Interval, StudentT};
use crate::regime::ComponentName;
use crate::sample::Channel;

/// Probability mass of the predictive intervals the monitor reports.
pub const INTERVAL_MASS: f64 = 0.9;

/// The estimator's outputs once it is initialised.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
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

/// Everything the monitor reports after a sample.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
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

/// `fuel_cm3_s` projected into the fuel's plausible range: every fuel mean a forecaster
/// makes (the mixture's and the single regression's virtual sensor and forecasts, the 0-step
/// estimate) is projected before it is blended, scored by the blend or published, so the
/// blend's weights are fitted to what is published ([`MixtureEstimate::fuel_range_cm3_s`]).
pub(crate) fn in_fuel_range(config: &FuelMonitorConfig, fuel_cm3_s: f64) -> f64 {
    let [min, max] = fuel_range_cm3_s(config);
    fuel_cm3_s.clamp(min, max)
}

/// The range fuel estimates are projected into: the fuel channel's plausible range, its
/// lower end at least 0 (the range admits a meter's small negative readings, -1 cm^3/s on
/// the road car; a flow is never negative).
pub(crate) fn fuel_range_cm3_s(config: &FuelMonitorConfig) -> [f64; 2] {
    let [min, max] = config.ranges.of(Channel::Fuel);
    [min.max(0.0), max]
}
