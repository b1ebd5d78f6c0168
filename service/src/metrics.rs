//! Prometheus metrics, named by the Prometheus conventions: one `railmon_` prefix, base units
//! spelled the Prometheus way (seconds, meters, newton meters, cubic meters per second, radians
//! per second), `_total` counters, `_ratio` for 0..1.
//! Counters and histograms are atomics, so the ingest threads update them without locks; label
//! lookups (which do lock) happen once per stream, drive or bogie, never per frame.
//!
//! The families every stream has are here ([`StreamMetrics`]); each stream defines its own next
//! to its pipeline (`drive::DriveMetrics`, ...). [`Families`] creates and registers a family in
//! one call, so no family is defined without being exported.

use prometheus::core::Collector;
use prometheus::{
    CounterVec, Encoder, Gauge, GaugeVec, Histogram, HistogramOpts, HistogramVec, IntCounter,
    IntCounterVec, IntGauge, IntGaugeVec, Opts, Registry, TextEncoder,
};

use crate::bogie::BogieMetrics;
use crate::drive::DriveMetrics;
use crate::vehicle::VehicleMetrics;

/// Histogram buckets from 1 us to 50 ms (values in seconds).
pub const MICROSECOND_BUCKETS_S: [f64; 14] = [
    1e-6, 2e-6, 5e-6, 10e-6, 20e-6, 50e-6, 100e-6, 200e-6, 500e-6, 1e-3, 2e-3, 5e-3, 10e-3, 50e-3,
];

/// Creates metric families in the `railmon` namespace and registers each as it is made.
pub struct Families<'r> {
    registry: &'r Registry,
}

impl Families<'_> {
    fn add<C: Collector + Clone + 'static>(
        &self,
        made: Result<C, prometheus::Error>,
    ) -> Result<C, prometheus::Error> {
        let collector = made?;
        self.registry.register(Box::new(collector.clone()))?;
        Ok(collector)
    }

    fn opts(name: &str, help: &str) -> Opts {
        Opts::new(name, help).namespace("railmon")
    }

    pub fn gauge(&self, name: &str, help: &str) -> Result<Gauge, prometheus::Error> {
        self.add(Gauge::with_opts(Self::opts(name, help)))
    }

    pub fn int_gauge(&self, name: &str, help: &str) -> Result<IntGauge, prometheus::Error> {
        self.add(IntGauge::with_opts(Self::opts(name, help)))
    }

    pub fn int_counter(&self, name: &str, help: &str) -> Result<IntCounter, prometheus::Error> {
        self.add(IntCounter::with_opts(Self::opts(name, help)))
    }

    pub fn gauge_vec(
        &self,
        name: &str,
        help: &str,
        labels: &[&str],
    ) -> Result<GaugeVec, prometheus::Error> {
        self.add(GaugeVec::new(Self::opts(name, help), labels))
    }

    pub fn int_gauge_vec(
        &self,
        name: &str,
        help: &str,
        labels: &[&str],
    ) -> Result<IntGaugeVec, prometheus::Error> {
        self.add(IntGaugeVec::new(Self::opts(name, help), labels))
    }

    pub fn counter_vec(
        &self,
        name: &str,
        help: &str,
        labels: &[&str],
    ) -> Result<CounterVec, prometheus::Error> {
        self.add(CounterVec::new(Self::opts(name, help), labels))
    }

    pub fn int_counter_vec(
        &self,
        name: &str,
        help: &str,
        labels: &[&str],
    ) -> Result<IntCounterVec, prometheus::Error> {
        self.add(IntCounterVec::new(Self::opts(name, help), labels))
    }

    fn histogram_opts(name: &str, help: &str, buckets: &[f64]) -> HistogramOpts {
        HistogramOpts::new(name, help)
            .namespace("railmon")
            .buckets(buckets.to_vec())
    }

    pub fn histogram(
        &self,
        name: &str,
        help: &str,
        buckets: &[f64],
    ) -> Result<Histogram, prometheus::Error> {
        self.add(Histogram::with_opts(Self::histogram_opts(
            name, help, buckets,
        )))
    }

    pub fn histogram_vec(
        &self,
        name: &str,
        help: &str,
        buckets: &[f64],
        labels: &[&str],
    ) -> Result<HistogramVec, prometheus::Error> {
        self.add(HistogramVec::new(
            Self::histogram_opts(name, help, buckets),
            labels,
        ))
    }
}

/// The families of every stream (label `stream`).
pub struct StreamMetrics {
    pub samples_received: IntCounterVec,
    pub sequence_gaps: IntCounterVec,
    pub samples_rejected: IntCounterVec,
    pub last_sample_age: GaugeVec,
    pub fresh: IntGaugeVec,
    pub estimator_step: HistogramVec,
    pub publish_to_estimate: HistogramVec,
    pub realtime_load: GaugeVec,
    pub lag: GaugeVec,
    pub lagging: IntGaugeVec,
}

impl StreamMetrics {
    fn new(f: &Families) -> Result<Self, prometheus::Error> {
        let stream = &["stream"];
        Ok(Self {
            samples_received: f.int_counter_vec(
                "stream_samples_received_total",
                "Frames taken from the bus.",
                stream,
            )?,
            sequence_gaps: f.int_counter_vec(
                "stream_sequence_gaps_total",
                "Frames missing from a publisher's sequence (lost on the bus).",
                stream,
            )?,
            samples_rejected: f.int_counter_vec(
                "stream_samples_rejected_total",
                "Frames rejected before reaching the estimator (NaN, too many drives, ...).",
                &["stream", "reason"],
            )?,
            last_sample_age: f.gauge_vec(
                "stream_last_sample_age_seconds",
                "Time since the last frame (-1: none yet).",
                stream,
            )?,
            fresh: f.int_gauge_vec(
                "stream_fresh",
                "1 while the stream delivers within its staleness limit.",
                stream,
            )?,
            estimator_step: f.histogram_vec(
                "estimator_step_duration_seconds",
                "Time of one estimator step (one frame).",
                &MICROSECOND_BUCKETS_S,
                stream,
            )?,
            publish_to_estimate: f.histogram_vec(
                "publish_to_estimate_latency_seconds",
                "From the publisher's send to the estimate being ready (CLOCK_MONOTONIC).",
                &MICROSECOND_BUCKETS_S,
                stream,
            )?,
            realtime_load: f.gauge_vec(
                "stream_realtime_load_ratio",
                "Estimator time over the sample time it covered, last second of samples (above 1: cannot keep up).",
                stream,
            )?,
            lag: f.gauge_vec(
                "stream_lag_seconds",
                "How far the estimates fall behind the samples' own clock (growth of wall minus sample time since the source's best).",
                stream,
            )?,
            lagging: f.int_gauge_vec(
                "stream_lagging",
                "1 while the estimator does not keep up with real time (load above 1 or lag above the staleness limit).",
                stream,
            )?,
        })
    }
}

/// Every metric family of the service, in one registry.
pub struct Metrics {
    registry: Registry,
    pub stream: StreamMetrics,
    pub drive: DriveMetrics,
    pub bogie: BogieMetrics,
    pub vehicle: VehicleMetrics,
}

impl Metrics {
    /// The families without identity labels (tests).
    pub fn new() -> Result<Self, prometheus::Error> {
        Self::with_labels(std::collections::HashMap::new())
    }

    /// Every series labelled with the vehicle's identity (`vehicle_id`, and `fleet` when set):
    /// a fleet Prometheus scraping many services selects a vehicle without per-vehicle scrape
    /// configuration (docs/service.md argues the choice).
    pub fn with_identity(identity: &crate::config::Identity) -> Result<Self, prometheus::Error> {
        let mut labels = std::collections::HashMap::new();
        labels.insert("vehicle_id".to_string(), identity.vehicle_id.clone());
        if !identity.fleet.is_empty() {
            labels.insert("fleet".to_string(), identity.fleet.clone());
        }
        Self::with_labels(labels)
    }

    fn with_labels(
        labels: std::collections::HashMap<String, String>,
    ) -> Result<Self, prometheus::Error> {
        let registry = Registry::new_custom(None, Some(labels))?;
        let f = Families {
            registry: &registry,
        };
        let stream = StreamMetrics::new(&f)?;
        let drive = DriveMetrics::new(&f)?;
        let bogie = BogieMetrics::new(&f)?;
        let vehicle = VehicleMetrics::new(&f)?;
        #[cfg(target_os = "linux")]
        registry.register(Box::new(
            prometheus::process_collector::ProcessCollector::new(
                std::process::id() as i32,
                "railmon",
            ),
        ))?;
        Ok(Metrics {
            registry,
            stream,
            drive,
            bogie,
            vehicle,
        })
    }

    /// The text exposition format.
    pub fn render(&self) -> Result<String, prometheus::Error> {
        let mut out = Vec::new();
        TextEncoder::new().encode(&self.registry.gather(), &mut out)?;
        Ok(String::from_utf8_lossy(&out).into_owned())
    }
}
