//! Prometheus metrics, named by the Prometheus conventions: one `railmon_` prefix, base units
//! spelled the Prometheus way (seconds, meters, newton meters, cubic meters per second, radians
//! per second), `_total` counters, `_ratio` for 0..1.
//! Counters and histograms are atomics, so the ingest threads update them without locks; label
//! lookups (which do lock) happen once per stream, drive or bogie, never per frame.
//!
//! The families every stream has are here ([`StreamMetrics`]); each stream defines its own next
//! to its pipeline (`drive::DriveMetrics`, ...). [`Families`] creates and registers a family in
//! one call, so no family is defined without being exported.
//!
//! **No value without an estimate.** Every series that reports an estimate (slip probability,
//! damping, health ratio, ESS, fuel rates and forecasts, regime probabilities, ...) is an
//! [`EstimateGauge`]: absent from `/metrics` until the estimator produced its first value, and
//! removed again while the estimate is undefined (the API's `null`, NaN here). A default of 0
//! would read as "damper at 0 % health" or "0 % slip probability" before the first frame and
//! while the sensors are silent, so an alert on `health_ratio < 0.7` would fire at every start.
//! Alert rules that must notice the absence use `absent()` or the stream metrics (`fresh`,
//! `up`), which exist from the start.
//! Process metrics are the standard `process_*` family (what every Prometheus dashboard and
//! alert expects), `railmon_build_info` says which build answers.

use std::sync::Mutex;

use prometheus::core::{
    Atomic, AtomicF64, AtomicI64, Collector, GenericGauge, GenericGaugeVec, Number,
};
use prometheus::{
    CounterVec, Encoder, Histogram, HistogramOpts, HistogramVec, IntCounter, IntCounterVec,
    IntGauge, IntGaugeVec, Opts, Registry, TextEncoder,
};

use crate::bogie::BogieMetrics;
use crate::drive::DriveMetrics;
use crate::vehicle::VehicleMetrics;

/// Buckets of one estimator step, s: 0.1 us to 50 ms, ~1.5x apart (1-1.5-2-3-5-7 per decade),
/// so that each stream's typical step spreads over several buckets. Fitted to a docker soak
/// (release build, docs/service.md, "Histogram buckets"): a drive frame (3 drives, EKF +
/// temporal) took 1.2 us at the median with 28 % of frames below the old first bucket of 1 us;
/// a vehicle update 0.26 ms, its 99th percentile 8 ms, 0.2 % above the old last bucket of 20 ms;
/// one bogie's RBPF step (N = 250-1000) 0.1-2 ms.
pub const STEP_BUCKETS_S: [f64; 33] = [
    0.1e-6, 0.15e-6, 0.2e-6, 0.3e-6, 0.5e-6, 0.7e-6, 1e-6, 1.5e-6, 2e-6, 3e-6, 5e-6, 7e-6, 10e-6,
    15e-6, 20e-6, 30e-6, 50e-6, 70e-6, 100e-6, 150e-6, 200e-6, 300e-6, 500e-6, 700e-6, 1e-3,
    1.5e-3, 2e-3, 3e-3, 5e-3, 7e-3, 10e-3, 20e-3, 50e-3,
];

/// Buckets of publish-to-estimate latency, s: 5 us to 30 s. Paced and keeping up it is 10-50 us
/// (drives) to a few ms (a bogie batch); a stream that queues (`--speed max`, a loaded machine)
/// reaches tens of ms to seconds: under load 47.7 % of bogie samples were above 50 ms, where the
/// old buckets ended, so the top buckets run to the staleness limits and beyond.
pub const LATENCY_BUCKETS_S: [f64; 20] = [
    5e-6, 10e-6, 20e-6, 50e-6, 100e-6, 200e-6, 500e-6, 1e-3, 2e-3, 5e-3, 10e-3, 20e-3, 50e-3, 0.1,
    0.2, 0.5, 1.0, 2.0, 5.0, 30.0,
];

/// A gauge of an estimate: its series exists only while there is a value (see the module
/// docs). `set(NaN)` (float gauges) removes the series; the next finite value brings it back.
/// Made by [`EstimateGaugeVec::with_label_values`], which creates no series.
pub struct EstimateGauge<P: Atomic = AtomicF64> {
    family: GenericGaugeVec<P>,
    labels: Vec<String>,
    /// The series while it exists (looked up once per appearance: label lookups lock).
    series: Mutex<Option<GenericGauge<P>>>,
}

/// An [`EstimateGauge`] of an integer (a flag): it appears with its first value.
pub type EstimateIntGauge = EstimateGauge<AtomicI64>;

impl<P: Atomic + 'static> EstimateGauge<P> {
    pub fn set(&self, value: P::T) {
        let mut series = self.series.lock().unwrap_or_else(|p| p.into_inner());
        if value.into_f64().is_nan() {
            if series.take().is_some() {
                // Err only for a wrong label count, which `with_label_values` already refused.
                let _ = self.family.remove_label_values(&self.labels);
            }
            return;
        }
        series
            .get_or_insert_with(|| self.family.with_label_values(&self.labels))
            .set(value);
    }

    /// The value, if the series exists.
    pub fn get(&self) -> Option<P::T> {
        let series = self.series.lock().unwrap_or_else(|p| p.into_inner());
        series.as_ref().map(GenericGauge::get)
    }
}

/// A family of [`EstimateGauge`]s.
#[derive(Clone)]
pub struct EstimateGaugeVec<P: Atomic = AtomicF64>(GenericGaugeVec<P>);

/// A family of [`EstimateIntGauge`]s.
pub type EstimateIntGaugeVec = EstimateGaugeVec<AtomicI64>;

impl<P: Atomic + 'static> EstimateGaugeVec<P> {
    /// The gauge of these label values, absent until its first value.
    pub fn with_label_values(&self, labels: &[&str]) -> EstimateGauge<P> {
        EstimateGauge {
            family: self.0.clone(),
            labels: labels.iter().map(|l| l.to_string()).collect(),
            series: Mutex::new(None),
        }
    }
}

/// Creates metric families in the `railmon` namespace and registers each as it is made.
pub struct Families<'r> {
    registry: &'r Registry,
    /// The names of the families made, also of those with no series yet.
    names: std::cell::RefCell<Vec<String>>,
}

impl Families<'_> {
    fn add<C: Collector + Clone + 'static>(
        &self,
        made: Result<C, prometheus::Error>,
    ) -> Result<C, prometheus::Error> {
        let collector = made?;
        self.names
            .borrow_mut()
            .extend(collector.desc().iter().map(|d| d.fq_name.clone()));
        self.registry.register(Box::new(collector.clone()))?;
        Ok(collector)
    }

    fn opts(name: &str, help: &str) -> Opts {
        Opts::new(name, help).namespace("railmon")
    }

    /// A family of estimate gauges (absent until set; see [`EstimateGauge`]).
    pub fn estimate_gauge_vec<P: Atomic + 'static>(
        &self,
        name: &str,
        help: &str,
        labels: &[&str],
    ) -> Result<EstimateGaugeVec<P>, prometheus::Error> {
        self.add(GenericGaugeVec::<P>::new(Self::opts(name, help), labels))
            .map(EstimateGaugeVec)
    }

    /// An estimate gauge without labels of its own.
    pub fn estimate_gauge(
        &self,
        name: &str,
        help: &str,
    ) -> Result<EstimateGauge, prometheus::Error> {
        Ok(self
            .estimate_gauge_vec(name, help, &[])?
            .with_label_values(&[]))
    }

    pub fn gauge_vec(
        &self,
        name: &str,
        help: &str,
        labels: &[&str],
    ) -> Result<prometheus::GaugeVec, prometheus::Error> {
        self.add(prometheus::GaugeVec::new(Self::opts(name, help), labels))
    }

    pub fn int_gauge(&self, name: &str, help: &str) -> Result<IntGauge, prometheus::Error> {
        self.add(IntGauge::with_opts(Self::opts(name, help)))
    }

    pub fn int_counter(&self, name: &str, help: &str) -> Result<IntCounter, prometheus::Error> {
        self.add(IntCounter::with_opts(Self::opts(name, help)))
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
    pub skipped_periods: IntCounterVec,
    pub samples_rejected: IntCounterVec,
    pub last_sample_age: EstimateGaugeVec,
    pub fresh: IntGaugeVec,
    pub ready: IntGaugeVec,
    pub estimator_step: HistogramVec,
    pub publish_to_estimate: HistogramVec,
    pub realtime_load: EstimateGaugeVec,
    pub lag: EstimateGaugeVec,
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
            skipped_periods: f.int_counter_vec(
                "stream_skipped_periods_total",
                "Sample periods between consecutive frames that no frame covered (samples lost at \
                 the source, or across a restart): the estimator bridged them.",
                stream,
            )?,
            samples_rejected: f.int_counter_vec(
                "stream_samples_rejected_total",
                "Frames rejected before reaching the estimator (NaN, too many drives, ...).",
                &["stream", "reason"],
            )?,
            last_sample_age: f.estimate_gauge_vec(
                "stream_last_sample_age_seconds",
                "Time since the last frame (absent before the first).",
                stream,
            )?,
            fresh: f.int_gauge_vec(
                "stream_fresh",
                "1 while the stream delivers within its staleness limit.",
                stream,
            )?,
            ready: f.int_gauge_vec(
                "stream_ready",
                "1 while estimates are made from the stream's data now (as /readyz; the reason in /api/v1/status).",
                stream,
            )?,
            estimator_step: f.histogram_vec(
                "estimator_step_duration_seconds",
                "Time of one estimator step (one frame).",
                &STEP_BUCKETS_S,
                stream,
            )?,
            publish_to_estimate: f.histogram_vec(
                "publish_to_estimate_latency_seconds",
                "From the publisher's send to the estimate being ready (CLOCK_MONOTONIC).",
                &LATENCY_BUCKETS_S,
                stream,
            )?,
            realtime_load: f.estimate_gauge_vec(
                "stream_realtime_load_ratio",
                "Estimator time over the sample time it covered, last second of samples (above 1: cannot keep up).",
                stream,
            )?,
            lag: f.estimate_gauge_vec(
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

/// `profile` of `railmon_build_info`: a debug build is ~10x slower, which matters when reading
/// the timing histograms.
const BUILD_PROFILE: &str = if cfg!(debug_assertions) {
    "debug"
} else {
    "release"
};

/// Every metric family of the service, in one registry.
pub struct Metrics {
    registry: Registry,
    /// Every `railmon_` family, also those without a series yet (estimates before the first).
    family_names: Vec<String>,
    pub stream: StreamMetrics,
    pub drive: DriveMetrics,
    pub bogie: BogieMetrics,
    pub vehicle: VehicleMetrics,
    /// Connections the HTTP server refused or evicted at `http.max_connections` (synchronised
    /// from `http::server::HttpCounters` at each scrape: [`Metrics::count_connections`]).
    http_connections_refused: IntCounter,
    http_connections_evicted: IntCounter,
    store: StoreMetrics,
    uplink: UplinkMetrics,
}

/// The event uplink's counters (synchronised from `uplink::UplinkCounters` at each scrape:
/// [`Metrics::count_uplink`]). Families without labels whose one series appears at the first
/// scrape with the uplink on: a service without an uplink exports none (no `link_up 0` to alert
/// on).
struct UplinkMetrics {
    sent: IntCounterVec,
    acknowledged: IntCounterVec,
    duplicates: IntCounterVec,
    backlog: IntGaugeVec,
    acknowledged_id: IntGaugeVec,
    last_ack: prometheus::GaugeVec,
    link_up: IntGaugeVec,
    failures: IntCounterVec,
    health_sent: IntCounterVec,
    health_failures: IntCounterVec,
}

impl UplinkMetrics {
    fn new(f: &Families) -> Result<Self, prometheus::Error> {
        Ok(Self {
            sent: f.int_counter_vec(
                "uplink_events_sent_total",
                "Events published to the ground's JetStream stream (re-sends included).",
                &[],
            )?,
            acknowledged: f.int_counter_vec(
                "uplink_events_acknowledged_total",
                "Events the ground's stream acknowledged (duplicates included).",
                &[],
            )?,
            duplicates: f.int_counter_vec(
                "uplink_events_duplicate_total",
                "Acknowledged as already stored: a re-send the stream's duplicate window dropped.",
                &[],
            )?,
            backlog: f.int_gauge_vec(
                "uplink_backlog_events",
                "Stored events the ground has not acknowledged yet.",
                &[],
            )?,
            acknowledged_id: f.int_gauge_vec(
                "uplink_acknowledged_event_id",
                "The cursor: every event up to this id is on the ground.",
                &[],
            )?,
            last_ack: f.gauge_vec(
                "uplink_last_ack_timestamp_seconds",
                "Unix time of the last acknowledgement from the ground (0: none yet).",
                &[],
            )?,
            link_up: f.int_gauge_vec(
                "uplink_link_up",
                "1 while connected to a NATS server.",
                &[],
            )?,
            failures: f.int_counter_vec(
                "uplink_failures_total",
                "Uplink failures by kind: link lost (disconnected), stream lookup or creation, publish, acknowledgement (timed out or refused), event store, connection setup.",
                &["kind"],
            )?,
            health_sent: f.int_counter_vec(
                "uplink_health_sent_total",
                "Health summaries (with their alarm snapshots) the ground's stream acknowledged.",
                &[],
            )?,
            health_failures: f.int_counter_vec(
                "uplink_health_failures_total",
                "Health summaries not sent, by kind: link down at the tick (disconnected), connection setup, event store, publish, acknowledgement.",
                &["kind"],
            )?,
        })
    }
}

/// The event store's counters (synchronised from `store::StoreCounters` at each scrape:
/// [`Metrics::count_store`]).
struct StoreMetrics {
    stored: IntCounter,
    pending: IntGauge,
    dropped: IntCounterVec,
    write_errors: IntCounter,
    unreadable: IntCounter,
}

/// Why events were dropped (`railmon_events_dropped_total{reason}`).
pub const DROP_REASONS: [&str; 2] = ["buffer_full", "shutdown"];

impl StoreMetrics {
    fn new(f: &Families) -> Result<Self, prometheus::Error> {
        let dropped = f.int_counter_vec(
            "events_dropped_total",
            "Events raised but never stored: the backlog of unwritten events was full (buffer_full), or the service stopped before the database took them (shutdown).",
            &["reason"],
        )?;
        for reason in DROP_REASONS {
            dropped.with_label_values(&[reason]);
        }
        Ok(Self {
            stored: f.int_counter("events_stored_total", "Events committed to the event database.")?,
            pending: f.int_gauge(
                "events_pending",
                "Events waiting to be written (they wait here while the database does not take writes).",
            )?,
            dropped,
            write_errors: f.int_counter(
                "event_store_write_errors_total",
                "Failed commits of the event database (each retried with backoff).",
            )?,
            unreadable: f.int_counter(
                "events_unreadable_total",
                "Stored rows that could not be read as events (skipped in pages, each counted once).",
            )?,
        })
    }
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
            names: Default::default(),
        };
        let stream = StreamMetrics::new(&f)?;
        let drive = DriveMetrics::new(&f)?;
        let bogie = BogieMetrics::new(&f)?;
        let vehicle = VehicleMetrics::new(&f)?;
        // The standard names (`process_cpu_seconds_total`, `process_resident_memory_bytes`,
        // ...), no namespace.
        #[cfg(target_os = "linux")]
        registry.register(Box::new(
            prometheus::process_collector::ProcessCollector::for_self(),
        ))?;
        f.int_gauge_vec(
            "build_info",
            "Always 1: the build that answers (version, profile).",
            &["version", "profile"],
        )?
        .with_label_values(&[env!("CARGO_PKG_VERSION"), BUILD_PROFILE])
        .set(1);
        let http_connections_refused = f.int_counter(
            "http_connections_refused_total",
            "Connections the HTTP server closed at once because http.max_connections were open, \
             each serving a request.",
        )?;
        let http_connections_evicted = f.int_counter(
            "http_connections_evicted_total",
            "Idle connections the HTTP server closed to admit a new one when http.max_connections \
             were open.",
        )?;
        let store = StoreMetrics::new(&f)?;
        let uplink = UplinkMetrics::new(&f)?;
        let family_names = f.names.into_inner();
        Ok(Metrics {
            http_connections_refused,
            http_connections_evicted,
            store,
            uplink,
            registry,
            family_names,
            stream,
            drive,
            bogie,
            vehicle,
        })
    }

    /// The names of every `railmon_` metric family, including those with no series yet.
    pub fn family_names(&self) -> &[String] {
        &self.family_names
    }

    /// Whether `name` is a series name of an exported family (histograms: also its `_bucket`,
    /// `_sum`, `_count`), whether or not it has a series now.
    pub fn exports(&self, name: &str) -> bool {
        self.family_names.iter().any(|f| {
            name.strip_prefix(f.as_str())
                .is_some_and(|rest| ["", "_bucket", "_sum", "_count"].contains(&rest))
        })
    }

    /// Brings the refused and evicted connection counters to the server's own counts (a
    /// counter only rises).
    pub fn count_connections(&self, refused: u64, evicted: u64) {
        for (counter, total) in [
            (&self.http_connections_refused, refused),
            (&self.http_connections_evicted, evicted),
        ] {
            counter.inc_by(total.saturating_sub(counter.get()));
        }
    }

    /// Brings the event store's series to its counters (counters only rise).
    pub fn count_store(&self, status: &crate::store::StoreStatus) {
        let rise = |counter: &IntCounter, total: u64| {
            counter.inc_by(total.saturating_sub(counter.get()));
        };
        let s = &self.store;
        rise(&s.stored, status.events_stored);
        rise(&s.write_errors, status.write_errors);
        rise(&s.unreadable, status.events_unreadable);
        rise(
            &s.dropped.with_label_values(&["buffer_full"]),
            status.events_dropped_buffer_full,
        );
        rise(
            &s.dropped.with_label_values(&["shutdown"]),
            status.events_dropped_shutdown,
        );
        s.pending
            .set(i64::try_from(status.events_pending).unwrap_or(i64::MAX));
    }

    /// Brings the uplink's series to its counters (counters only rise).
    pub fn count_uplink(&self, counters: &crate::uplink::UplinkCounters) {
        use std::sync::atomic::Ordering::Relaxed;
        let rise = |counter: &IntCounter, total: u64| {
            counter.inc_by(total.saturating_sub(counter.get()));
        };
        let u = &self.uplink;
        rise(
            &u.sent.with_label_values(&[] as &[&str]),
            counters.sent.load(Relaxed),
        );
        rise(
            &u.acknowledged.with_label_values(&[] as &[&str]),
            counters.acknowledged.load(Relaxed),
        );
        rise(
            &u.duplicates.with_label_values(&[] as &[&str]),
            counters.duplicates.load(Relaxed),
        );
        for (kind, n) in crate::uplink::FAILURE_KINDS.iter().zip(&counters.failures) {
            rise(&u.failures.with_label_values(&[kind]), n.load(Relaxed));
        }
        let as_i64 = |n: u64| i64::try_from(n).unwrap_or(i64::MAX);
        u.backlog
            .with_label_values(&[] as &[&str])
            .set(as_i64(counters.backlog.load(Relaxed)));
        u.acknowledged_id
            .with_label_values(&[] as &[&str])
            .set(as_i64(counters.cursor.load(Relaxed)));
        u.link_up
            .with_label_values(&[] as &[&str])
            .set(counters.link_up.load(Relaxed));
        u.last_ack
            .with_label_values(&[] as &[&str])
            .set(counters.last_ack_unix_ms.load(Relaxed) as f64 / 1000.0);
    }

    /// Brings the health publisher's series to its counters (counters only rise).
    pub fn count_uplink_health(&self, counters: &crate::uplink::health::HealthCounters) {
        use std::sync::atomic::Ordering::Relaxed;
        let rise = |counter: &IntCounter, total: u64| {
            counter.inc_by(total.saturating_sub(counter.get()));
        };
        let u = &self.uplink;
        rise(
            &u.health_sent.with_label_values(&[] as &[&str]),
            counters.sent.load(Relaxed),
        );
        let kinds = crate::uplink::health::HEALTH_FAILURE_KINDS;
        for (kind, n) in kinds.iter().zip(&counters.failures) {
            rise(
                &u.health_failures.with_label_values(&[kind]),
                n.load(Relaxed),
            );
        }
    }

    /// The text exposition format.
    pub fn render(&self) -> Result<String, prometheus::Error> {
        let mut out = Vec::new();
        TextEncoder::new().encode(&self.registry.gather(), &mut out)?;
        Ok(String::from_utf8_lossy(&out).into_owned())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lines_of(metrics: &Metrics, name: &str) -> Vec<String> {
        let text = metrics.render().unwrap();
        text.lines()
            .filter(|l| l.starts_with(name))
            .map(str::to_string)
            .collect()
    }

    #[test]
    fn an_estimate_gauge_exists_only_while_it_has_a_value() {
        let metrics = Metrics::new().unwrap();
        let name = "railmon_bogie_damper_health_ratio";
        let gauge = metrics.bogie.health.with_label_values(&["1", "csay"]);
        assert!(lines_of(&metrics, name).is_empty());
        assert_eq!(gauge.get(), None);
        gauge.set(0.42);
        assert_eq!(
            lines_of(&metrics, name),
            ["railmon_bogie_damper_health_ratio{bogie=\"1\",damper=\"csay\"} 0.42"]
        );
        gauge.set(f64::NAN);
        assert!(
            lines_of(&metrics, name).is_empty(),
            "NaN removes the series"
        );
        assert_eq!(gauge.get(), None);
        gauge.set(0.9);
        assert_eq!(gauge.get(), Some(0.9));
        assert_eq!(lines_of(&metrics, name).len(), 1);
        // A flag appears with its first value, 0 included.
        let flag = metrics.bogie.degraded.with_label_values(&["1", "csay"]);
        assert!(lines_of(&metrics, "railmon_bogie_damper_degraded").is_empty());
        flag.set(0);
        assert_eq!(lines_of(&metrics, "railmon_bogie_damper_degraded").len(), 1);
    }

    #[test]
    fn process_metrics_are_standard_and_the_build_is_named() {
        let metrics = Metrics::new().unwrap();
        let text = metrics.render().unwrap();
        assert!(!text.contains("railmon_process_"), "{text}");
        #[cfg(target_os = "linux")]
        assert!(
            text.lines()
                .any(|l| l.starts_with("process_resident_memory_bytes ")),
            "{text}"
        );
        let build = format!(
            "railmon_build_info{{profile=\"{BUILD_PROFILE}\",version=\"{}\"}} 1",
            env!("CARGO_PKG_VERSION")
        );
        assert!(text.lines().any(|l| l == build), "{build} in {text}");
        // Refused connections are counted from the server's own count, never backwards.
        metrics.count_connections(3, 5);
        metrics.count_connections(2, 4);
        let refused = metrics.render().unwrap();
        for line in [
            "railmon_http_connections_refused_total 3",
            "railmon_http_connections_evicted_total 5",
        ] {
            assert!(refused.lines().any(|l| l == line), "{line} in {refused}");
        }
        // Declared families are known before they have a series.
        assert!(metrics
            .family_names()
            .iter()
            .any(|n| n == "railmon_bogie_damper_health_ratio"));
    }

    #[test]
    fn buckets_increase_and_reach_past_the_measured_ranges() {
        for buckets in [&STEP_BUCKETS_S[..], &LATENCY_BUCKETS_S[..]] {
            assert!(buckets.windows(2).all(|w| w[0] < w[1]), "{buckets:?}");
        }
        // One bogie step under load reached ~5 ms, a vehicle update 8 ms (99th percentile); a
        // drive frame takes ~1 us (release); latency under load tens of seconds.
        assert!(STEP_BUCKETS_S[STEP_BUCKETS_S.len() - 1] >= 20e-3);
        const { assert!(STEP_BUCKETS_S[0] <= 0.2e-6) };
        assert!(LATENCY_BUCKETS_S[LATENCY_BUCKETS_S.len() - 1] >= 10.0);
    }
}
