//! What the HTTP side sees of one stream: counters, timings, freshness, the last rejection.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use arc_swap::ArcSwapOption;
use prometheus::{Histogram, IntCounter, IntGauge};
use railmon_bus::{monotonic_ns, FrameHeader, StreamKind};
use serde::Serialize;
use utoipa::ToSchema;

use super::Rejection;
use crate::metrics::{EstimateGauge, Metrics};

/// The rejection reasons of every stream (header layout, sequence, estimator failure); each
/// [`super::Pipeline`] adds its own. All are exported from the start, so each series exists (at 0):
/// Prometheus queries on a counter that appears only with its first increment miss that increment.
pub const COMMON_REJECTION_REASONS: [&str; 9] = [
    "layout_version",
    "estimator",
    "out_of_order",
    "second_source",
    "time_backwards",
    "time_repeated",
    "time_jump",
    "period_mismatch",
    "rate_mismatch",
];

/// At most one log line of rejected frames per stream (whatever the reason) per this long;
/// the rest are counted and the count is logged with the next line (a stream of bad frames at
/// 8 kHz logged 1.5 MB/s).
const REJECTION_LOG_INTERVAL_NS: u64 = 1_000_000_000;

/// Whether a stream's estimates are being produced from its data now, and if not, why.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum ReadinessReason {
    Ready,
    /// The ingest thread is not running (a bus error: see `last_error`).
    NotIngesting,
    /// No frame yet.
    NoData,
    /// No frame within the staleness limit.
    Stale,
    /// Frames arrive but none was estimated within the staleness limit (all rejected).
    Rejecting,
    /// The estimator does not keep up with real time.
    Lagging,
    /// A second publisher sent within the staleness limit while the current one is alive.
    CompetingSources,
}

/// Counters and timings of one stream, shared with the HTTP side.
pub struct StreamStatus {
    pub kind: StreamKind,
    pub stale_after: Duration,
    received: IntCounter,
    gaps: IntCounter,
    skipped_periods: IntCounter,
    rejected_total: AtomicU64,
    step: Histogram,
    latency: Histogram,
    realtime_load: EstimateGauge,
    lag: EstimateGauge,
    last_sample_age: EstimateGauge,
    lagging_gauge: IntGauge,
    metrics: Arc<Metrics>,
    last_received_ns: AtomicU64,
    /// Monotonic time of the last frame the estimator used.
    last_estimated_ns: AtomicU64,
    /// Monotonic time a competing publisher was last refused.
    last_competing_ns: AtomicU64,
    /// Rate limiting of rejection log lines: when the last line was written, and how many
    /// rejections were not logged since.
    last_rejection_log_ns: AtomicU64,
    rejections_not_logged: AtomicU64,
    last_step_ns: AtomicU64,
    sources: AtomicU64,
    last_rejection: ArcSwapOption<RejectionRecord>,
    last_error: ArcSwapOption<String>,
    running: AtomicBool,
    /// `f64` bits of the last real-time load (NaN: none yet).
    realtime_load_bits: AtomicU64,
    lag_ns: AtomicU64,
    lagging: AtomicBool,
}

#[derive(Clone, Debug, Serialize, ToSchema)]
pub struct RejectionRecord {
    /// Short label, as in the metric `railmon_stream_samples_rejected_total{reason}`.
    pub reason: String,
    pub message: String,
    /// Sequence number of the rejected frame in its publisher.
    pub sequence: u64,
    #[serde(skip)]
    pub at_ns: u64,
}

/// `GET /api/v1/status`, one entry per stream.
#[derive(Clone, Debug, Serialize, ToSchema)]
pub struct StreamStatusView {
    pub stream: String,
    /// The ingest thread is running (false after a bus error; see `last_error`).
    pub ingesting: bool,
    /// Estimates are being produced from this stream's data now (what `/readyz` requires).
    pub ready: bool,
    /// Why not, or `ready`.
    pub readiness: ReadinessReason,
    /// A frame came within `stale_after_s`.
    pub fresh: bool,
    pub stale_after_s: f64,
    /// Seconds since the last frame; null before the first.
    pub last_sample_age_s: Option<f64>,
    pub samples_received: u64,
    /// Frames missing from publishers' sequences.
    pub sequence_gaps: u64,
    /// Sample periods between consecutive frames that no frame covered (samples the source
    /// lost before sending, or the time across a restart), bridged by the estimator.
    pub skipped_periods: u64,
    pub samples_rejected: u64,
    pub last_rejection: Option<RejectionRecord>,
    /// Publisher lifetimes or runs seen (each restarts the estimator, unless it continues a
    /// resumed snapshot's sample clock), and restarts of a resumed estimator by the resume rule.
    pub sources: u64,
    pub estimator_steps: u64,
    pub estimator_step_mean_us: Option<f64>,
    pub estimator_step_last_us: Option<f64>,
    pub publish_to_estimate_mean_us: Option<f64>,
    /// Estimator time over the sample time it covered, over the last second of samples
    /// (all sources of the stream together); above 1 the estimator cannot keep up.
    pub realtime_load: Option<f64>,
    /// How far the estimates fall behind the samples' own clock, s: the growth of (wall
    /// time - sample time) since its smallest value in the current source.
    pub lag_s: f64,
    /// The estimator does not keep up: `realtime_load` above 1 or `lag_s` above `stale_after_s`.
    pub lagging: bool,
    pub last_error: Option<String>,
    /// The drive stream only: what its last estimate's slip probabilities were judged
    /// against, `group` (the other drives) or `train_speed` (the train's measured speed), as
    /// in `/api/v1/drives`; absent for the other streams and before the first estimate.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reference: Option<String>,
    /// The bogie stream only: whether its filters run their configured particles (`full`) or
    /// fewer to keep up with real time (`degraded`), as `compute` in `/api/v1/bogies`; absent
    /// for the other streams.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub compute: Option<crate::bogie::ComputeView>,
}

impl StreamStatus {
    /// The status of `kind`, whose pipeline rejects with `reasons` (and the common ones).
    pub fn new(
        kind: StreamKind,
        stale_after: Duration,
        metrics: Arc<Metrics>,
        reasons: &[&str],
    ) -> Self {
        let label = [kind.name()];
        for &reason in COMMON_REJECTION_REASONS.iter().chain(reasons) {
            metrics
                .stream
                .samples_rejected
                .with_label_values(&[kind.name(), reason]);
        }
        Self {
            kind,
            stale_after,
            received: metrics.stream.samples_received.with_label_values(&label),
            gaps: metrics.stream.sequence_gaps.with_label_values(&label),
            skipped_periods: metrics.stream.skipped_periods.with_label_values(&label),
            rejected_total: AtomicU64::new(0),
            step: metrics.stream.estimator_step.with_label_values(&label),
            latency: metrics.stream.publish_to_estimate.with_label_values(&label),
            realtime_load: metrics.stream.realtime_load.with_label_values(&label),
            lag: metrics.stream.lag.with_label_values(&label),
            last_sample_age: metrics.stream.last_sample_age.with_label_values(&label),
            lagging_gauge: metrics.stream.lagging.with_label_values(&label),
            metrics,
            last_received_ns: AtomicU64::new(0),
            last_estimated_ns: AtomicU64::new(0),
            last_competing_ns: AtomicU64::new(0),
            last_rejection_log_ns: AtomicU64::new(0),
            rejections_not_logged: AtomicU64::new(0),
            last_step_ns: AtomicU64::new(0),
            sources: AtomicU64::new(0),
            last_rejection: ArcSwapOption::empty(),
            last_error: ArcSwapOption::empty(),
            running: AtomicBool::new(false),
            realtime_load_bits: AtomicU64::new(f64::NAN.to_bits()),
            lag_ns: AtomicU64::new(0),
            lagging: AtomicBool::new(false),
        }
    }

    /// Records how well the estimator keeps up (see [`RealTimeTracker`]); says so in the log
    /// when that changes.
    pub(super) fn record_realtime(&self, lag_ns: u64, load: Option<f64>) {
        self.lag_ns.store(lag_ns, Ordering::Relaxed);
        self.lag.set(lag_ns as f64 * 1e-9);
        if let Some(load) = load {
            self.realtime_load_bits
                .store(load.to_bits(), Ordering::Relaxed);
            self.realtime_load.set(load);
        }
        let load = f64::from_bits(self.realtime_load_bits.load(Ordering::Relaxed));
        let lagging = load > 1.0 || lag_ns as u128 > self.stale_after.as_nanos();
        if self.lagging.swap(lagging, Ordering::Relaxed) != lagging {
            self.lagging_gauge.set(i64::from(lagging));
            // Before a second of samples has been timed there is no load: the log says
            // `unmeasured`, not `NaN`.
            let load = match load.is_finite() {
                true => format!("{load:.3}"),
                false => "unmeasured".to_owned(),
            };
            match lagging {
                true => {
                    tracing::warn!(stream = %self.kind, %load, lag_s = lag_ns as f64 * 1e-9, "estimator cannot keep up with real time")
                }
                false => {
                    tracing::info!(stream = %self.kind, %load, "estimator keeps up with real time again")
                }
            }
        }
    }

    /// Seconds since the last frame (None before the first).
    pub fn last_sample_age_s(&self, now_ns: u64) -> Option<f64> {
        match self.last_received_ns.load(Ordering::Relaxed) {
            0 => None,
            t => Some(now_ns.saturating_sub(t) as f64 * 1e-9),
        }
    }

    pub fn is_fresh(&self, now_ns: u64) -> bool {
        self.last_sample_age_s(now_ns)
            .is_some_and(|age| age <= self.stale_after.as_secs_f64())
    }

    /// Whether estimates are being produced from this stream's data now, and if not, why.
    pub fn readiness(&self, now_ns: u64) -> ReadinessReason {
        let within =
            |t: u64| t > 0 && now_ns.saturating_sub(t) <= self.stale_after.as_nanos() as u64;
        if !self.running.load(Ordering::Relaxed) {
            ReadinessReason::NotIngesting
        } else if self.last_received_ns.load(Ordering::Relaxed) == 0 {
            ReadinessReason::NoData
        } else if !self.is_fresh(now_ns) {
            ReadinessReason::Stale
        } else if !within(self.last_estimated_ns.load(Ordering::Relaxed)) {
            ReadinessReason::Rejecting
        } else if self.lagging.load(Ordering::Relaxed) {
            ReadinessReason::Lagging
        } else if within(self.last_competing_ns.load(Ordering::Relaxed)) {
            ReadinessReason::CompetingSources
        } else {
            ReadinessReason::Ready
        }
    }

    /// Updates the scrape-time gauges (age, freshness).
    pub fn refresh_gauges(&self, now_ns: u64) {
        let label = [self.kind.name()];
        // Absent before the first frame.
        self.last_sample_age
            .set(self.last_sample_age_s(now_ns).unwrap_or(f64::NAN));
        self.metrics
            .stream
            .fresh
            .with_label_values(&label)
            .set(i64::from(self.is_fresh(now_ns)));
        self.metrics
            .stream
            .ready
            .with_label_values(&label)
            .set(i64::from(self.readiness(now_ns) == ReadinessReason::Ready));
    }

    pub fn view(&self, now_ns: u64) -> StreamStatusView {
        let mean_us = |h: &Histogram| {
            let n = h.get_sample_count();
            (n > 0).then(|| h.get_sample_sum() / n as f64 * 1e6)
        };
        let steps = self.step.get_sample_count();
        let readiness = self.readiness(now_ns);
        StreamStatusView {
            stream: self.kind.name().into(),
            ready: readiness == ReadinessReason::Ready,
            readiness,
            ingesting: self.running.load(Ordering::Relaxed),
            fresh: self.is_fresh(now_ns),
            stale_after_s: self.stale_after.as_secs_f64(),
            last_sample_age_s: self.last_sample_age_s(now_ns),
            samples_received: self.received.get(),
            sequence_gaps: self.gaps.get(),
            skipped_periods: self.skipped_periods.get(),
            samples_rejected: self.rejected_total.load(Ordering::Relaxed),
            last_rejection: self.last_rejection.load_full().map(|r| (*r).clone()),
            sources: self.sources.load(Ordering::Relaxed),
            estimator_steps: steps,
            estimator_step_mean_us: mean_us(&self.step),
            estimator_step_last_us: (steps > 0)
                .then(|| self.last_step_ns.load(Ordering::Relaxed) as f64 * 1e-3),
            publish_to_estimate_mean_us: mean_us(&self.latency),
            realtime_load: Some(f64::from_bits(
                self.realtime_load_bits.load(Ordering::Relaxed),
            ))
            .filter(|l| !l.is_nan()),
            lag_s: self.lag_ns.load(Ordering::Relaxed) as f64 * 1e-9,
            lagging: self.lagging.load(Ordering::Relaxed),
            last_error: self.last_error.load_full().map(|e| (*e).clone()),
            reference: None,
            compute: None,
        }
    }

    pub(super) fn record_received(&self, received_at_ns: u64) {
        self.received.inc();
        self.last_received_ns
            .store(received_at_ns, Ordering::Relaxed);
    }

    pub(super) fn record_new_source(&self) {
        self.sources.fetch_add(1, Ordering::Relaxed);
    }

    pub(super) fn record_gap(&self, missing: u64) {
        self.gaps.inc_by(missing);
    }

    pub(super) fn record_skipped_periods(&self, periods: u64) {
        self.skipped_periods.inc_by(periods);
    }

    pub(super) fn record_competing(&self, now_ns: u64) {
        self.last_competing_ns.store(now_ns, Ordering::Relaxed);
    }

    pub(super) fn record_step(&self, step_ns: u64, done_at_ns: u64, latency_ns: u64) {
        self.last_estimated_ns.store(done_at_ns, Ordering::Relaxed);
        self.step.observe(step_ns as f64 * 1e-9);
        self.last_step_ns.store(step_ns, Ordering::Relaxed);
        self.latency.observe(latency_ns as f64 * 1e-9);
    }

    pub(super) fn record_running(&self) {
        self.running.store(true, Ordering::Relaxed);
    }

    pub(super) fn record_stopped(&self, error: Option<&railmon_bus::BusError>) {
        self.running.store(false, Ordering::Relaxed);
        if let Some(e) = error {
            self.last_error.store(Some(Arc::new(e.to_string())));
        }
    }

    pub(super) fn reject(&self, header: &FrameHeader, rejection: Rejection) {
        self.rejected_total.fetch_add(1, Ordering::Relaxed);
        self.metrics
            .stream
            .samples_rejected
            .with_label_values(&[self.kind.name(), rejection.reason])
            .inc();
        let now = monotonic_ns();
        let last_log = self.last_rejection_log_ns.load(Ordering::Relaxed);
        if last_log == 0 || now.saturating_sub(last_log) >= REJECTION_LOG_INTERVAL_NS {
            self.last_rejection_log_ns.store(now, Ordering::Relaxed);
            let not_logged = self.rejections_not_logged.swap(0, Ordering::Relaxed);
            tracing::warn!(stream = %self.kind, sequence = header.sequence, reason = rejection.reason, not_logged, "frame rejected: {} ({not_logged} more rejections since the last line)", rejection.message);
        } else {
            self.rejections_not_logged.fetch_add(1, Ordering::Relaxed);
        }
        self.last_rejection.store(Some(Arc::new(RejectionRecord {
            reason: rejection.reason.into(),
            message: rejection.message,
            sequence: header.sequence,
            at_ns: monotonic_ns(),
        })));
    }
}
