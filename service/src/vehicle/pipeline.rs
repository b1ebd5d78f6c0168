//! The ingest side of the vehicle stream: checked frames -> `FuelMonitor` update -> forecast
//! error, regime-change events -> history, snapshot and gauges once per batch.

use std::sync::Arc;

use railmon_bus::{FrameHeader, VehicleFrame};
use railmon_fuel::{FuelError, FuelMonitor, VehicleSample, REGIME_CHANGED};

use railmon_bus::StreamKind;

use super::view::{
    IntervalView, RegimeEventDetail, VehicleHistoryPoint, VehicleShared, VehicleView,
};
use super::VehicleConfig;
use crate::ingest::{Pipeline, Rejection};
use crate::metrics::{EstimateGauge, Metrics};
use crate::outbox::{run_time_s, Stamp, Track};
use crate::snapshot::StateFormat;

/// Cubic metres per cubic centimetre: the metrics are in base units.
const M3_PER_CM3: f64 = 1e-6;

/// Label values of `railmon_vehicle_fuel_rate_cubic_meters_per_second{kind}`.
const FUEL_RATE_KINDS: [&str; 4] = [
    "measured",
    "virtual_sensor",
    "zero_step",
    "one_step_forecast",
];

/// Gauges looked up once (label lookups lock), set once per batch.
struct VehicleGauges {
    /// In the order of [`FUEL_RATE_KINDS`].
    fuel_rate: [EstimateGauge; 4],
    forecast: Vec<EstimateGauge>,
    consumed_measured: EstimateGauge,
    consumed_virtual: EstimateGauge,
    regime_probability: Vec<EstimateGauge>,
}

impl VehicleGauges {
    fn new(metrics: &Metrics, config: &VehicleConfig) -> Self {
        let estimator = &config.estimator;
        let step_s = estimator.sample_period_s;
        Self {
            fuel_rate: FUEL_RATE_KINDS.map(|k| metrics.vehicle.fuel_rate.with_label_values(&[k])),
            forecast: (1..=estimator.forecast_horizon_steps)
                .map(|h| {
                    let horizon = format!("{}", h as f64 * step_s);
                    metrics
                        .vehicle
                        .fuel_forecast
                        .with_label_values(&[horizon.as_str()])
                })
                .collect(),
            consumed_measured: metrics
                .vehicle
                .fuel_consumed
                .with_label_values(&["measured"]),
            consumed_virtual: metrics
                .vehicle
                .fuel_consumed
                .with_label_values(&["virtual_sensor"]),
            regime_probability: (0..estimator.components)
                .map(|i| {
                    let regime = i.to_string();
                    metrics
                        .vehicle
                        .regime_probability
                        .with_label_values(&[regime.as_str()])
                })
                .collect(),
        }
    }
}

/// Why the estimator refused a sample, as a metric label: the estimator crate's own
/// ([`FuelError::reason`], which `railmon analyze fuel` counts by too); `estimator` for a
/// failure that is not the sample's.
fn rejection_of(e: FuelError) -> Rejection {
    Rejection {
        reason: e.reason().unwrap_or("estimator"),
        message: e.to_string(),
    }
}

/// 1-step forecast error statistics of the current source.
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
struct ForecastErrors {
    last_cm3_s: Option<f64>,
    sum_squares: f64,
    n: u64,
}

pub struct VehiclePipeline {
    config: VehicleConfig,
    shared: Arc<VehicleShared>,
    metrics: Arc<Metrics>,
    gauges: VehicleGauges,
    monitor: Option<FuelMonitor>,
    errors: ForecastErrors,
    regime_changes: u64,
    speed_m_s: Option<f64>,
    track: Track<VehicleHistoryPoint>,
}

impl VehiclePipeline {
    pub fn new(config: VehicleConfig, shared: Arc<VehicleShared>, metrics: Arc<Metrics>) -> Self {
        let gauges = VehicleGauges::new(&metrics, &config);
        metrics.vehicle.regime_active.set(-1);
        metrics.vehicle.initialising.set(1);
        let track = Track::new(
            StreamKind::Vehicle,
            config.estimator.sample_period_s,
            config.history_interval_ms,
        );
        Self {
            config,
            shared,
            metrics,
            gauges,
            monitor: None,
            errors: ForecastErrors::default(),
            regime_changes: 0,
            speed_m_s: None,
            track,
        }
    }

    /// The monitor of the current source (created on its first frame).
    fn monitor(&mut self) -> Result<&mut FuelMonitor, Rejection> {
        if self.monitor.is_none() {
            self.monitor = Some(FuelMonitor::new(&self.config.estimator).map_err(rejection_of)?);
        }
        Ok(self.monitor.as_mut().expect("created above"))
    }

    /// Forecast error, regime-change event and history point of the estimate just made.
    fn follow(&mut self, stamp: &Stamp) {
        let Some(monitor) = &self.monitor else { return };
        let estimate = monitor.estimate();
        if let Some(m) = &estimate.mixture {
            let error = estimate.fuel_cm3_s - m.one_step_forecast_cm3_s;
            if error.is_finite() {
                self.errors.last_cm3_s = Some(error);
                self.errors.sum_squares += error * error;
                self.errors.n += 1;
                self.metrics
                    .vehicle
                    .forecast_abs_error
                    .observe(error.abs() * M3_PER_CM3);
            }
            if let Some(change) = m.regime_change {
                self.regime_changes += 1;
                self.metrics.vehicle.regime_changes.inc();
                tracing::info!(
                    time_s = stamp.time_s,
                    from = change.from_regime,
                    to = change.to_regime,
                    from_name = %change.from_name,
                    to_name = %change.to_name,
                    probability = change.probability,
                    "{REGIME_CHANGED}"
                );
                let detail = RegimeEventDetail::from(change);
                self.track
                    .push_event(stamp, REGIME_CHANGED, String::new(), &detail, None);
            }
        }
        if self.track.history_due(stamp.time_s) {
            let m = estimate.mixture.as_ref();
            self.track.push_history(VehicleHistoryPoint {
                time_s: stamp.time_s,
                run: stamp.header.run,
                run_time_s: stamp.run_time_s,
                fuel_rate_cm3_s: estimate.fuel_cm3_s,
                virtual_sensor_cm3_s: m.map(|m| m.virtual_sensor_cm3_s),
                one_step_forecast_cm3_s: m.map(|m| m.one_step_forecast_cm3_s),
                virtual_sensor_interval_cm3_s: m
                    .and_then(|m| IntervalView::of(m.virtual_sensor_interval_cm3_s())),
                one_step_interval_cm3_s: m
                    .and_then(|m| IntervalView::of(m.one_step_interval_cm3_s())),
                regime: m.map(|m| m.regime),
                regime_name: m.map(|m| m.regime_name.to_string()),
                regime_probabilities: m.map_or_else(Vec::new, |m| m.regime_probabilities.clone()),
                cumulative_fuel_cm3: estimate.cumulative_fuel_cm3,
            });
        }
    }

    fn view(&self, stamp: &Stamp, monitor: &FuelMonitor) -> VehicleView {
        let estimate = monitor.estimate();
        let m = estimate.mixture.as_ref();
        VehicleView {
            time_s: Some(stamp.time_s),
            time_utc: Some(stamp.time_utc()),
            run: stamp.header.run,
            run_time_s: Some(stamp.run_time_s),
            sequence: Some(stamp.header.sequence),
            samples: estimate.samples,
            initialising: monitor.mixture().is_none(),
            fuel_rate_cm3_s: Some(estimate.fuel_cm3_s),
            speed_m_s: self.speed_m_s,
            virtual_sensor_cm3_s: m.map(|m| m.virtual_sensor_cm3_s),
            virtual_sensor_interval_cm3_s: m
                .and_then(|m| IntervalView::of(m.virtual_sensor_interval_cm3_s())),
            zero_step_cm3_s: m.map(|m| m.zero_step_cm3_s),
            one_step_forecast_cm3_s: m.map(|m| m.one_step_forecast_cm3_s),
            one_step_interval_cm3_s: m.and_then(|m| IntervalView::of(m.one_step_interval_cm3_s())),
            forecast_step_s: self.config.estimator.sample_period_s,
            forecast_cm3_s: m.map_or_else(Vec::new, |m| m.forecast_cm3_s.clone()),
            forecast_interval_cm3_s: m.map_or_else(Vec::new, |m| {
                m.forecast_interval_cm3_s()
                    .into_iter()
                    .filter_map(IntervalView::of)
                    .collect()
            }),
            regime: m.map(|m| m.regime),
            most_probable_regime: m.map(|m| m.active_regime),
            regime_name: m.map(|m| m.regime_name.to_string()),
            most_probable_regime_name: m.map(|m| m.regime_names[m.active_regime].to_string()),
            regime_probabilities: m.map_or_else(Vec::new, |m| m.regime_probabilities.clone()),
            regime_names: m.map_or_else(Vec::new, |m| {
                m.regime_names.iter().map(|n| n.to_string()).collect()
            }),
            cumulative_fuel_cm3: estimate.cumulative_fuel_cm3,
            cumulative_virtual_fuel_cm3: m.map(|m| m.cumulative_virtual_fuel_cm3),
            forecast_error_cm3_s: self.errors.last_cm3_s,
            forecast_rmse_cm3_s: (self.errors.n > 0)
                .then(|| (self.errors.sum_squares / self.errors.n as f64).sqrt()),
            regime_changes: self.regime_changes,
        }
    }

    /// Gauges from the view, so `/metrics` and the API agree (m^3/s = 1e-6 cm^3/s).
    fn set_gauges(&self, view: &VehicleView) {
        let g = &self.gauges;
        let rates = [
            view.fuel_rate_cm3_s,
            view.virtual_sensor_cm3_s,
            view.zero_step_cm3_s,
            view.one_step_forecast_cm3_s,
        ];
        for (gauge, rate) in g.fuel_rate.iter().zip(rates) {
            gauge.set(rate.map_or(f64::NAN, |r| r * M3_PER_CM3));
        }
        for (k, gauge) in g.forecast.iter().enumerate() {
            let value = view.forecast_cm3_s.get(k).copied();
            gauge.set(value.map_or(f64::NAN, |v| v * M3_PER_CM3));
        }
        g.consumed_measured
            .set(view.cumulative_fuel_cm3 * M3_PER_CM3);
        g.consumed_virtual.set(
            view.cumulative_virtual_fuel_cm3
                .map_or(f64::NAN, |v| v * M3_PER_CM3),
        );
        for (k, gauge) in g.regime_probability.iter().enumerate() {
            gauge.set(
                view.regime_probabilities
                    .get(k)
                    .copied()
                    .unwrap_or(f64::NAN),
            );
        }
        let metrics = &self.metrics;
        metrics
            .vehicle
            .regime_active
            .set(view.regime.map_or(-1, |r| r as i64));
        metrics.vehicle.forecast_error.set(
            view.forecast_error_cm3_s
                .map_or(f64::NAN, |e| e * M3_PER_CM3),
        );
        metrics
            .vehicle
            .speed
            .set(view.speed_m_s.unwrap_or(f64::NAN));
        metrics
            .vehicle
            .initialising
            .set(i64::from(view.initialising));
    }
}

/// What a vehicle snapshot holds.
#[derive(serde::Serialize, serde::Deserialize)]
struct SavedVehicle {
    monitor: FuelMonitor,
    errors: ForecastErrors,
    regime_changes: u64,
    speed_m_s: Option<f64>,
    clock: crate::outbox::TrackClock,
}

/// The layout of [`SavedVehicle`] around the monitor, and the monitor's own (its crate's
/// `FuelMonitor::STATE_FORMAT_VERSION`). Raise `version` with every change of what
/// `SavedVehicle` holds beside the monitor: a snapshot of another layout is refused by its
/// version instead of failing to decode, or decoding into other numbers.
const SAVED_VEHICLE: StateFormat = StateFormat {
    magic: b"railmon-vehicle\0",
    // 3-12: changes of the monitor's layout, now its crate's version (`FuelMonitor`).
    // 13: the monitor's layout has its own version (`estimator_version`), its crate's.
    version: 13,
    estimator_version: FuelMonitor::STATE_FORMAT_VERSION,
    what: "vehicle state",
};

impl Pipeline for VehiclePipeline {
    type Frame = VehicleFrame;
    /// Known channel bits, every present value finite.
    type Checked = VehicleSample;
    const REJECTION_REASONS: &'static [&'static str] = &[
        "unknown_channels",
        "not_finite",
        "missing_channel",
        "out_of_range",
        "acceleration_out_of_range",
        "unknown_category",
        "time_not_increasing",
    ];

    fn sample_period_ns(&self) -> u64 {
        (self.config.estimator.sample_period_s * 1e9).round() as u64
    }

    fn check(
        &self,
        header: &FrameHeader,
        frame: &VehicleFrame,
    ) -> Result<VehicleSample, Rejection> {
        frame
            .checked_sample(run_time_s(header))
            .map_err(|e| Rejection::new(e.reason(), e.to_string()))
    }

    fn restart(&mut self) {
        self.monitor = None;
        self.errors = ForecastErrors::default();
        self.regime_changes = 0;
        self.track.restart();
    }

    fn step(&mut self, header: &FrameHeader, sample: VehicleSample) -> Result<(), Rejection> {
        let monitor = self.monitor()?;
        // `update` validates the whole sample first: on error the estimator is unchanged.
        monitor.update(&sample).map_err(rejection_of)?;
        self.speed_m_s = sample.speed_m_s;
        let stamp = self.track.stamp(header);
        self.follow(&stamp);
        Ok(())
    }

    fn settings(&self) -> String {
        serde_json::to_string(&self.config.estimator).unwrap_or_default()
    }

    /// The mixture's statistics, the forecast error tally and stream time.
    fn save_state(&self) -> Option<Vec<u8>> {
        let saved = SavedVehicle {
            monitor: self.monitor.clone()?,
            errors: self.errors,
            regime_changes: self.regime_changes,
            speed_m_s: self.speed_m_s,
            clock: self.track.clock(),
        };
        SAVED_VEHICLE.encode(&saved)
    }

    fn resume_state(&mut self, state: &[u8]) -> Result<(), String> {
        let saved: SavedVehicle = SAVED_VEHICLE.decode(state)?;
        self.monitor = Some(saved.monitor);
        self.errors = saved.errors;
        self.regime_changes = saved.regime_changes;
        self.speed_m_s = saved.speed_m_s;
        self.track.resume_clock(saved.clock);
        Ok(())
    }

    /// A snapshot that does not fit: the estimator starts from its prior, and the store gets a
    /// `snapshot_refused` event saying which file and why (the log has a warning too).
    fn snapshot_refused(&mut self, file: &std::path::Path, reason: &str) {
        self.metrics.vehicle.snapshot_refused.inc();
        let event = crate::snapshot::refused_event(StreamKind::Vehicle, file, reason);
        self.shared.store.append(vec![event]);
    }

    fn publish(&mut self) {
        let (Some(stamp), Some(monitor)) = (self.track.flush(&self.shared), &self.monitor) else {
            return;
        };
        let view = self.view(&stamp, monitor);
        self.set_gauges(&view);
        self.shared.snapshot.store(Arc::new(view));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What the snapshot holds around the monitor is pinned under `SAVED_VEHICLE`'s version
    /// (the monitor itself under its crate's, `fuel/tests/state_layout.rs`).
    #[test]
    fn state_layout_golden_is_pinned_under_the_format_version() {
        let saved = SavedVehicle {
            monitor: FuelMonitor::new(&Default::default()).unwrap(),
            errors: ForecastErrors {
                last_cm3_s: Some(1.0),
                sum_squares: 2.0,
                n: 3,
            },
            regime_changes: 4,
            speed_m_s: Some(5.0),
            clock: crate::outbox::TrackClock {
                run_offset_s: 3.0,
                last_time_s: Some(2.5),
                next_history_s: 2.6,
            },
        };
        railmon_golden::check_state_layout(
            "state-layout-service-vehicle.txt",
            SAVED_VEHICLE.version,
            &[saved],
            &["state-layout-fuel.txt"],
        );
    }
}
