//! Prometheus metrics, named by the Prometheus conventions: one `railmon_` prefix, base units
//! (seconds, radians per second, newton metres, cubic metres per second for fuel), `_total`
//! counters, `_ratio` for 0..1.
//! Counters and histograms are atomics, so the ingest threads update them without locks; label
//! lookups (which do lock) happen once per stream or drive, never per frame.

use prometheus::{
    Encoder, Gauge, GaugeVec, Histogram, HistogramOpts, HistogramVec, IntCounter, IntCounterVec,
    IntGauge, IntGaugeVec, Opts, Registry, TextEncoder,
};

/// Histogram buckets from 1 us to 50 ms (values in seconds).
pub const MICROSECOND_BUCKETS_S: [f64; 14] = [
    1e-6, 2e-6, 5e-6, 10e-6, 20e-6, 50e-6, 100e-6, 200e-6, 500e-6, 1e-3, 2e-3, 5e-3, 10e-3, 50e-3,
];

/// Buckets of the absolute fuel forecast error, m^3/s: 0.01 to 10 cm^3/s (a 2.5 l engine at
/// full load burns ~10 cm^3/s).
pub const FUEL_ERROR_BUCKETS_M3_S: [f64; 10] =
    [1e-8, 2e-8, 5e-8, 1e-7, 2e-7, 5e-7, 1e-6, 2e-6, 5e-6, 1e-5];

pub struct Metrics {
    registry: Registry,
    pub samples_received: IntCounterVec,
    pub sequence_gaps: IntCounterVec,
    pub samples_rejected: IntCounterVec,
    pub last_sample_age: GaugeVec,
    pub stream_fresh: IntGaugeVec,
    pub estimator_step: HistogramVec,
    pub publish_to_estimate: HistogramVec,
    pub realtime_load: GaugeVec,
    pub stream_lag: GaugeVec,
    pub stream_lagging: IntGaugeVec,
    pub bogie_damping: GaugeVec,
    pub bogie_health: GaugeVec,
    pub bogie_degraded: IntGaugeVec,
    pub bogie_ess: GaugeVec,
    pub bogie_events: IntCounterVec,
    pub slip_probability: GaugeVec,
    pub speed: GaugeVec,
    pub load_torque: GaugeVec,
    pub slipping: IntGaugeVec,
    pub global_torque: Gauge,
    pub slip_events: IntCounterVec,
    pub vehicle_fuel_rate: GaugeVec,
    pub vehicle_fuel_forecast: GaugeVec,
    pub vehicle_fuel_consumed: GaugeVec,
    pub vehicle_forecast_error: Gauge,
    pub vehicle_forecast_abs_error: Histogram,
    pub vehicle_regime_probability: GaugeVec,
    pub vehicle_regime_active: IntGauge,
    pub vehicle_regime_changes: IntCounter,
    pub vehicle_speed: Gauge,
    pub vehicle_initialising: IntGauge,
}

fn opts(name: &str, help: &str) -> Opts {
    Opts::new(name, help).namespace("railmon")
}

fn histogram(name: &str, help: &str) -> HistogramOpts {
    HistogramOpts::new(name, help)
        .namespace("railmon")
        .buckets(MICROSECOND_BUCKETS_S.to_vec())
}

impl Metrics {
    pub fn new() -> Result<Self, prometheus::Error> {
        let registry = Registry::new();
        let stream = &["stream"];
        let drive = &["drive"];
        let m = Metrics {
            samples_received: IntCounterVec::new(
                opts(
                    "stream_samples_received_total",
                    "Frames taken from the bus.",
                ),
                stream,
            )?,
            sequence_gaps: IntCounterVec::new(
                opts(
                    "stream_sequence_gaps_total",
                    "Frames missing from a publisher's sequence (lost on the bus).",
                ),
                stream,
            )?,
            samples_rejected: IntCounterVec::new(
                opts(
                    "stream_samples_rejected_total",
                    "Frames rejected before reaching the estimator (NaN, too many drives, ...).",
                ),
                &["stream", "reason"],
            )?,
            last_sample_age: GaugeVec::new(
                opts(
                    "stream_last_sample_age_seconds",
                    "Time since the last frame (-1: none yet).",
                ),
                stream,
            )?,
            stream_fresh: IntGaugeVec::new(
                opts(
                    "stream_fresh",
                    "1 while the stream delivers within its staleness limit.",
                ),
                stream,
            )?,
            estimator_step: HistogramVec::new(
                histogram(
                    "estimator_step_duration_seconds",
                    "Time of one estimator step (one frame).",
                ),
                stream,
            )?,
            publish_to_estimate: HistogramVec::new(
                histogram(
                    "publish_to_estimate_latency_seconds",
                    "From the publisher's send to the estimate being ready (CLOCK_MONOTONIC).",
                ),
                stream,
            )?,
            realtime_load: GaugeVec::new(
                opts(
                    "stream_realtime_load_ratio",
                    "Estimator time over the sample time it covered, last second of samples (above 1: cannot keep up).",
                ),
                stream,
            )?,
            stream_lag: GaugeVec::new(
                opts(
                    "stream_lag_seconds",
                    "How far the estimates fall behind the samples' own clock (growth of wall minus sample time since the source's best).",
                ),
                stream,
            )?,
            stream_lagging: IntGaugeVec::new(
                opts(
                    "stream_lagging",
                    "1 while the estimator does not keep up with real time (load above 1 or lag above the staleness limit).",
                ),
                stream,
            )?,
            bogie_damping: GaugeVec::new(
                opts(
                    "bogie_damping_newton_seconds_per_meter",
                    "Estimated damping coefficient (RBPF posterior mean and 5%/95% quantiles).",
                ),
                &["bogie", "damper", "quantity"],
            )?,
            bogie_health: GaugeVec::new(
                opts(
                    "bogie_damper_health_ratio",
                    "Damper health: posterior mean over nominal damping.",
                ),
                &["bogie", "damper"],
            )?,
            bogie_degraded: IntGaugeVec::new(
                opts(
                    "bogie_damper_degraded",
                    "1 while the damper is flagged degraded (hysteresis on the health ratio).",
                ),
                &["bogie", "damper"],
            )?,
            bogie_ess: GaugeVec::new(
                opts(
                    "bogie_effective_sample_size",
                    "Effective sample size of the bogie's particle filter (particles).",
                ),
                &["bogie"],
            )?,
            bogie_events: IntCounterVec::new(
                opts(
                    "bogie_damper_events_total",
                    "Damper degraded / recovered events.",
                ),
                &["bogie", "damper", "kind"],
            )?,
            slip_probability: GaugeVec::new(
                opts(
                    "drive_slip_probability_ratio",
                    "Probability that the drive has lost adhesion.",
                ),
                drive,
            )?,
            speed: GaugeVec::new(
                opts(
                    "drive_speed_radians_per_second",
                    "Estimated electrical speed of the drive.",
                ),
                drive,
            )?,
            load_torque: GaugeVec::new(
                opts(
                    "drive_load_torque_newton_metres",
                    "Estimated load torque of the drive.",
                ),
                drive,
            )?,
            slipping: IntGaugeVec::new(
                opts(
                    "drive_slipping",
                    "1 while the drive is flagged as slipping (hysteresis).",
                ),
                drive,
            )?,
            global_torque: Gauge::with_opts(opts(
                "drive_global_torque_newton_metres",
                "Global (adhesion-consistent) load torque over all drives.",
            ))?,
            slip_events: IntCounterVec::new(
                opts("drive_slip_events_total", "Slip started / ended events."),
                &["drive", "kind"],
            )?,
            vehicle_fuel_rate: GaugeVec::new(
                opts(
                    "vehicle_fuel_rate_cubic_meters_per_second",
                    "Fuel flow now: measured, virtual sensor, 0-step estimate, 1-step forecast made a step ago.",
                ),
                &["kind"],
            )?,
            vehicle_fuel_forecast: GaugeVec::new(
                opts(
                    "vehicle_fuel_forecast_cubic_meters_per_second",
                    "Forecast fuel flow horizon_s seconds ahead.",
                ),
                &["horizon_s"],
            )?,
            vehicle_fuel_consumed: GaugeVec::new(
                opts(
                    "vehicle_fuel_consumed_cubic_meters",
                    "Fuel used since the source started: measured, and from the virtual sensor since initialisation.",
                ),
                &["kind"],
            )?,
            vehicle_forecast_error: Gauge::with_opts(opts(
                "vehicle_fuel_forecast_error_cubic_meters_per_second",
                "Measured fuel minus its honest 1-step forecast, last sample.",
            ))?,
            vehicle_forecast_abs_error: Histogram::with_opts(
                HistogramOpts::new(
                    "vehicle_fuel_forecast_absolute_error_cubic_meters_per_second",
                    "Absolute error of the honest 1-step fuel forecast.",
                )
                .namespace("railmon")
                .buckets(FUEL_ERROR_BUCKETS_M3_S.to_vec()),
            )?,
            vehicle_regime_probability: GaugeVec::new(
                opts(
                    "vehicle_regime_probability_ratio",
                    "Probability of each driving regime (mixture component, 0-based).",
                ),
                &["regime"],
            )?,
            vehicle_regime_active: IntGauge::with_opts(opts(
                "vehicle_regime_active",
                "The most probable regime (0-based; -1 while initialising).",
            ))?,
            vehicle_regime_changes: IntCounter::with_opts(opts(
                "vehicle_regime_changes_total",
                "Changes of the most probable regime.",
            ))?,
            vehicle_speed: Gauge::with_opts(opts(
                "vehicle_speed_meters_per_second",
                "Measured vehicle speed.",
            ))?,
            vehicle_initialising: IntGauge::with_opts(opts(
                "vehicle_estimator_initialising",
                "1 while the fuel estimator collects its initial samples.",
            ))?,
            registry,
        };
        m.register_all()?;
        Ok(m)
    }

    fn register_all(&self) -> Result<(), prometheus::Error> {
        let r = &self.registry;
        r.register(Box::new(self.samples_received.clone()))?;
        r.register(Box::new(self.sequence_gaps.clone()))?;
        r.register(Box::new(self.samples_rejected.clone()))?;
        r.register(Box::new(self.last_sample_age.clone()))?;
        r.register(Box::new(self.stream_fresh.clone()))?;
        r.register(Box::new(self.estimator_step.clone()))?;
        r.register(Box::new(self.publish_to_estimate.clone()))?;
        r.register(Box::new(self.realtime_load.clone()))?;
        r.register(Box::new(self.stream_lag.clone()))?;
        r.register(Box::new(self.stream_lagging.clone()))?;
        r.register(Box::new(self.bogie_damping.clone()))?;
        r.register(Box::new(self.bogie_health.clone()))?;
        r.register(Box::new(self.bogie_degraded.clone()))?;
        r.register(Box::new(self.bogie_ess.clone()))?;
        r.register(Box::new(self.bogie_events.clone()))?;
        r.register(Box::new(self.slip_probability.clone()))?;
        r.register(Box::new(self.speed.clone()))?;
        r.register(Box::new(self.load_torque.clone()))?;
        r.register(Box::new(self.slipping.clone()))?;
        r.register(Box::new(self.global_torque.clone()))?;
        r.register(Box::new(self.slip_events.clone()))?;
        r.register(Box::new(self.vehicle_fuel_rate.clone()))?;
        r.register(Box::new(self.vehicle_fuel_forecast.clone()))?;
        r.register(Box::new(self.vehicle_fuel_consumed.clone()))?;
        r.register(Box::new(self.vehicle_forecast_error.clone()))?;
        r.register(Box::new(self.vehicle_forecast_abs_error.clone()))?;
        r.register(Box::new(self.vehicle_regime_probability.clone()))?;
        r.register(Box::new(self.vehicle_regime_active.clone()))?;
        r.register(Box::new(self.vehicle_regime_changes.clone()))?;
        r.register(Box::new(self.vehicle_speed.clone()))?;
        r.register(Box::new(self.vehicle_initialising.clone()))?;
        #[cfg(target_os = "linux")]
        r.register(Box::new(
            prometheus::process_collector::ProcessCollector::new(
                std::process::id() as i32,
                "railmon",
            ),
        ))?;
        Ok(())
    }

    /// The text exposition format.
    pub fn render(&self) -> Result<String, prometheus::Error> {
        let mut out = Vec::new();
        TextEncoder::new().encode(&self.registry.gather(), &mut out)?;
        Ok(String::from_utf8_lossy(&out).into_owned())
    }
}
