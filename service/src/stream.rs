//! One ingest thread per stream: bus subscriber -> checks -> estimator step -> published
//! results. The thread owns the iceoryx2 ports (they are not `Send`) and the estimator; the
//! HTTP side reads only atomics and `arc-swap` snapshots, so the hot path takes no lock.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use arc_swap::ArcSwapOption;
use iceoryx2::prelude::CallbackProgression;
use prometheus::{Gauge, Histogram, IntCounter, IntGauge};
use railmon_bus::{monotonic_ns, BusConfig, BusError, BusNode, Frame, FrameHeader, StreamKind};
use serde::Serialize;
use utoipa::ToSchema;

use crate::config::IngestConfig;
use crate::metrics::Metrics;

/// The rejection reasons of every stream (header layout, sequence, estimator failure); each
/// [`Pipeline`] adds its own. All are exported from the start, so each series exists (at 0):
/// Prometheus queries on a counter that appears only with its first increment miss that increment.
pub const COMMON_REJECTION_REASONS: [&str; 3] = ["layout_version", "estimator", "out_of_order"];

/// Why a frame was not used.
#[derive(Clone, Debug, PartialEq)]
pub struct Rejection {
    /// Short label (`not_finite`, `too_many_drives`, ...), the metric's `reason`.
    pub reason: &'static str,
    pub message: String,
}

/// A stream's estimator, as the ingest loop drives it.
pub trait Pipeline {
    type Frame: Frame;
    /// The reasons this pipeline's `check` and `step` reject with (besides the common ones).
    const REJECTION_REASONS: &'static [&'static str];
    /// Checks a frame without changing anything.
    fn check(&self, header: &FrameHeader, frame: &Self::Frame) -> Result<(), Rejection>;
    /// A new source (publisher restarted, or its run restarted): start from the prior.
    fn restart(&mut self);
    /// Steps the estimator with a checked frame; on error nothing changed.
    fn step(&mut self, header: &FrameHeader, frame: &Self::Frame) -> Result<(), Rejection>;
    /// Makes the latest results visible (HTTP snapshot, gauges); called once per batch.
    fn publish(&mut self);
}

/// Counters and timings of one stream, shared with the HTTP side.
pub struct StreamStatus {
    pub kind: StreamKind,
    pub stale_after: Duration,
    received: IntCounter,
    gaps: IntCounter,
    rejected_total: AtomicU64,
    step: Histogram,
    latency: Histogram,
    realtime_load: Gauge,
    lag: Gauge,
    lagging_gauge: IntGauge,
    metrics: Arc<Metrics>,
    last_received_ns: AtomicU64,
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
    /// A frame came within `stale_after_s`.
    pub fresh: bool,
    pub stale_after_s: f64,
    /// Seconds since the last frame; null before the first.
    pub last_sample_age_s: Option<f64>,
    pub samples_received: u64,
    /// Frames missing from publishers' sequences.
    pub sequence_gaps: u64,
    pub samples_rejected: u64,
    pub last_rejection: Option<RejectionRecord>,
    /// Publisher lifetimes or runs seen (each restarts the estimator).
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
                .samples_rejected
                .with_label_values(&[kind.name(), reason]);
        }
        Self {
            kind,
            stale_after,
            received: metrics.samples_received.with_label_values(&label),
            gaps: metrics.sequence_gaps.with_label_values(&label),
            rejected_total: AtomicU64::new(0),
            step: metrics.estimator_step.with_label_values(&label),
            latency: metrics.publish_to_estimate.with_label_values(&label),
            realtime_load: metrics.realtime_load.with_label_values(&label),
            lag: metrics.stream_lag.with_label_values(&label),
            lagging_gauge: metrics.stream_lagging.with_label_values(&label),
            metrics,
            last_received_ns: AtomicU64::new(0),
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
    fn record_realtime(&self, lag_ns: u64, load: Option<f64>) {
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
            match lagging {
                true => {
                    tracing::warn!(stream = %self.kind, load, lag_s = lag_ns as f64 * 1e-9, "estimator cannot keep up with real time")
                }
                false => {
                    tracing::info!(stream = %self.kind, load, "estimator keeps up with real time again")
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

    /// Updates the scrape-time gauges (age, freshness).
    pub fn refresh_gauges(&self, now_ns: u64) {
        let label = [self.kind.name()];
        let age = self.last_sample_age_s(now_ns).unwrap_or(-1.0);
        self.metrics
            .last_sample_age
            .with_label_values(&label)
            .set(age);
        self.metrics
            .stream_fresh
            .with_label_values(&label)
            .set(i64::from(self.is_fresh(now_ns)));
    }

    pub fn view(&self, now_ns: u64) -> StreamStatusView {
        let mean_us = |h: &Histogram| {
            let n = h.get_sample_count();
            (n > 0).then(|| h.get_sample_sum() / n as f64 * 1e6)
        };
        let steps = self.step.get_sample_count();
        StreamStatusView {
            stream: self.kind.name().into(),
            ingesting: self.running.load(Ordering::Relaxed),
            fresh: self.is_fresh(now_ns),
            stale_after_s: self.stale_after.as_secs_f64(),
            last_sample_age_s: self.last_sample_age_s(now_ns),
            samples_received: self.received.get(),
            sequence_gaps: self.gaps.get(),
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
        }
    }

    fn reject(&self, header: &FrameHeader, rejection: Rejection) {
        self.rejected_total.fetch_add(1, Ordering::Relaxed);
        self.metrics
            .samples_rejected
            .with_label_values(&[self.kind.name(), rejection.reason])
            .inc();
        tracing::warn!(stream = %self.kind, sequence = header.sequence, reason = rejection.reason, "frame rejected: {}", rejection.message);
        self.last_rejection.store(Some(Arc::new(RejectionRecord {
            reason: rejection.reason.into(),
            message: rejection.message,
            sequence: header.sequence,
            at_ns: monotonic_ns(),
        })));
    }
}

/// What a frame's header says about the sequence of its publisher.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SequenceCheck {
    /// The next frame of the current source.
    InOrder,
    /// A new publisher or a new run: the estimator restarts.
    NewSource,
    /// `missing` frames of the current source never arrived.
    Gap { missing: u64 },
    /// Older than or equal to a frame already seen.
    Stale,
}

/// Follows one publisher's sequence numbers. A subscriber joining a running publisher starts
/// counting at the first frame it sees (earlier frames were not meant for it).
#[derive(Clone, Debug, Default)]
pub struct SequenceTracker {
    current: Option<(u64, u32)>,
    next: u64,
}

impl SequenceTracker {
    pub fn check(&self, header: &FrameHeader) -> SequenceCheck {
        if self.current != Some((header.publisher_instance, header.run)) {
            return SequenceCheck::NewSource;
        }
        match header.sequence.cmp(&self.next) {
            std::cmp::Ordering::Equal => SequenceCheck::InOrder,
            std::cmp::Ordering::Greater => SequenceCheck::Gap {
                missing: header.sequence - self.next,
            },
            std::cmp::Ordering::Less => SequenceCheck::Stale,
        }
    }

    pub fn accept(&mut self, header: &FrameHeader) {
        self.current = Some((header.publisher_instance, header.run));
        self.next = header.sequence + 1;
    }
}

/// Whether a stream's estimator keeps up with the samples' own clock. Two measures, both
/// valid whether the source is paced (real time) or as fast as backpressure lets it go:
/// - load: estimator time over the advance of the sample time, per window of one second of
///   samples (several sources of one stream, e.g. the bogies, add their times);
/// - lag: (wall time - sample time) now minus its smallest value since the source started.
///   A source keeping up has a constant offset (its transport delay); an estimator falling
///   behind makes it grow (frames wait in the buffer, then backpressure slows the publisher,
///   whose samples then fall behind the wall clock).
#[derive(Clone, Debug, Default)]
pub struct RealTimeTracker {
    baseline_ns: Option<i128>,
    window_start_sample_ns: Option<u64>,
    window_busy_ns: u64,
}

impl RealTimeTracker {
    /// One second of sample time per load value.
    const WINDOW_NS: u64 = 1_000_000_000;

    pub fn restart(&mut self) {
        *self = Self::default();
    }

    /// A frame of sample time `sample_time_ns` was estimated at `done_at_ns` (monotonic) in
    /// `step_ns`; returns the lag (ns) and the load when a window closed.
    pub fn observe(
        &mut self,
        sample_time_ns: u64,
        done_at_ns: u64,
        step_ns: u64,
    ) -> (u64, Option<f64>) {
        let offset = i128::from(done_at_ns) - i128::from(sample_time_ns);
        let baseline = *self.baseline_ns.get_or_insert(offset);
        let baseline = baseline.min(offset);
        self.baseline_ns = Some(baseline);
        let lag_ns = u64::try_from(offset - baseline).unwrap_or(u64::MAX);
        self.window_busy_ns += step_ns;
        let start = *self.window_start_sample_ns.get_or_insert(sample_time_ns);
        let advanced = sample_time_ns.saturating_sub(start);
        let load = (advanced >= Self::WINDOW_NS).then(|| {
            let load = self.window_busy_ns as f64 / advanced as f64;
            self.window_start_sample_ns = Some(sample_time_ns);
            self.window_busy_ns = 0;
            load
        });
        (lag_ns, load)
    }
}

/// Handles one received frame: count, check, track the sequence, step, time.
fn handle_frame<P: Pipeline>(
    pipeline: &mut P,
    tracker: &mut SequenceTracker,
    realtime: &mut RealTimeTracker,
    status: &StreamStatus,
    header: &FrameHeader,
    frame: &P::Frame,
    received_at_ns: u64,
) {
    status.received.inc();
    status
        .last_received_ns
        .store(received_at_ns, Ordering::Relaxed);
    let checked = header
        .check()
        .map_err(|e| Rejection {
            reason: e.reason(),
            message: e.to_string(),
        })
        .and_then(|()| pipeline.check(header, frame));
    if let Err(rejection) = checked {
        return status.reject(header, rejection);
    }
    match tracker.check(header) {
        SequenceCheck::InOrder => {}
        SequenceCheck::NewSource => {
            status.sources.fetch_add(1, Ordering::Relaxed);
            tracing::info!(stream = %status.kind, instance = header.publisher_instance, run = header.run, sequence = header.sequence, "new source: estimator restarts");
            pipeline.restart();
            realtime.restart();
        }
        SequenceCheck::Gap { missing } => {
            status.gaps.inc_by(missing);
            tracing::warn!(stream = %status.kind, missing, sequence = header.sequence, "frames lost");
        }
        SequenceCheck::Stale => {
            return status.reject(
                header,
                Rejection {
                    reason: "out_of_order",
                    message: format!(
                        "sequence {} is not after {}",
                        header.sequence,
                        tracker.next.saturating_sub(1)
                    ),
                },
            );
        }
    }
    tracker.accept(header);
    let start = Instant::now();
    let stepped = pipeline.step(header, frame);
    let step_ns = start.elapsed().as_nanos() as u64;
    match stepped {
        Ok(()) => {
            status.step.observe(step_ns as f64 * 1e-9);
            status.last_step_ns.store(step_ns, Ordering::Relaxed);
            let done_at_ns = monotonic_ns();
            let latency_ns = done_at_ns.saturating_sub(header.published_at_ns);
            status.latency.observe(latency_ns as f64 * 1e-9);
            let (lag_ns, load) = realtime.observe(header.sample_time_ns, done_at_ns, step_ns);
            status.record_realtime(lag_ns, load);
        }
        Err(rejection) => status.reject(header, rejection),
    }
}

/// The ingest loop of one stream; returns when `shutdown` is set (or on a bus error, which is
/// also recorded in the status). Ports are dropped on return, releasing iceoryx2 resources.
pub fn run_ingest<P: Pipeline>(
    bus: &BusConfig,
    ingest: &IngestConfig,
    pipeline: &mut P,
    status: &StreamStatus,
    shutdown: &AtomicBool,
) -> Result<(), BusError> {
    let result = ingest_loop(bus, ingest, pipeline, status, shutdown);
    status.running.store(false, Ordering::Relaxed);
    if let Err(e) = &result {
        status.last_error.store(Some(Arc::new(e.to_string())));
    }
    result
}

fn ingest_loop<P: Pipeline>(
    bus: &BusConfig,
    ingest: &IngestConfig,
    pipeline: &mut P,
    status: &StreamStatus,
    shutdown: &AtomicBool,
) -> Result<(), BusError> {
    let kind = <P::Frame as Frame>::STREAM;
    let node = BusNode::create(bus, &format!("railmon-serve-{kind}"))?;
    if node.cleaned_at_start() > 0 {
        tracing::info!(stream = %kind, dead_nodes = node.cleaned_at_start(), "cleaned up stale bus resources");
    }
    let subscriber = node.subscriber::<P::Frame>()?;
    let waitset = node.waitset()?;
    let _wake_on_frames = waitset
        .attach_notification(subscriber.listener())
        .map_err(|e| BusError::Ipc {
            what: "attach listener to WaitSet".into(),
            detail: format!("{e:?}"),
        })?;
    status.running.store(true, Ordering::Relaxed);
    tracing::info!(stream = %kind, service = subscriber.service_name(), "ingesting");
    let wake_interval = Duration::from_millis(ingest.wake_interval_ms);
    let cleanup_interval = Duration::from_millis(ingest.cleanup_interval_ms);
    let mut last_cleanup = Instant::now();
    let mut tracker = SequenceTracker::default();
    let mut realtime = RealTimeTracker::default();
    while !shutdown.load(Ordering::Relaxed) {
        waitset
            .wait_and_process_once_with_timeout(|_| CallbackProgression::Continue, wake_interval)
            .map_err(|e| BusError::Ipc {
                what: "wait on WaitSet".into(),
                detail: format!("{e:?}"),
            })?;
        let wakeups = subscriber.take_wakeups()?;
        if wakeups.publisher_died > 0 {
            tracing::info!(stream = %kind, "a publisher died");
        }
        loop {
            let handled = subscriber.drain(ingest.max_batch, |rx| {
                handle_frame(
                    pipeline,
                    &mut tracker,
                    &mut realtime,
                    status,
                    rx.header,
                    rx.frame,
                    rx.received_at_ns,
                )
            })?;
            if handled > 0 {
                pipeline.publish();
            }
            if handled < ingest.max_batch || shutdown.load(Ordering::Relaxed) {
                break;
            }
        }
        if last_cleanup.elapsed() >= cleanup_interval {
            let cleaned = node.cleanup_dead_nodes();
            if cleaned > 0 {
                tracing::info!(stream = %kind, dead_nodes = cleaned, "cleaned up dead bus peers");
            }
            last_cleanup = Instant::now();
        }
    }
    tracing::info!(stream = %kind, "ingest stopped");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header(instance: u64, run: u32, sequence: u64) -> FrameHeader {
        FrameHeader {
            layout_version: railmon_bus::FRAME_LAYOUT_VERSION,
            publisher_instance: instance,
            run,
            sequence,
            ..Default::default()
        }
    }

    #[test]
    fn realtime_tracker_sees_an_estimator_falling_behind() {
        let mut t = RealTimeTracker::default();
        // Keeping up: each 1 ms sample done 50 us after its time (+ a constant 7 s offset).
        let mut load = None;
        for k in 0..=1000u64 {
            let (lag, l) = t.observe(
                k * 1_000_000,
                7_000_000_000 + k * 1_000_000 + 50_000,
                50_000,
            );
            assert_eq!(lag, 0);
            load = l.or(load);
        }
        assert!((load.unwrap() - 0.05).abs() < 1e-3, "{load:?}");
        // Falling behind: 2 ms per 1 ms sample -> the lag grows by 1 ms per sample.
        t.restart();
        let mut last = (0, None);
        for k in 0..=1000u64 {
            last = t.observe(k * 1_000_000, k * 2_000_000, 2_000_000);
        }
        assert_eq!(last.0, 1_000_000_000);
        assert!((last.1.unwrap() - 2.0).abs() < 1e-2, "{last:?}");
    }

    #[test]
    fn tracker_counts_gaps_and_sees_new_sources() {
        let mut t = SequenceTracker::default();
        assert_eq!(t.check(&header(7, 0, 5)), SequenceCheck::NewSource);
        t.accept(&header(7, 0, 5));
        assert_eq!(t.check(&header(7, 0, 6)), SequenceCheck::InOrder);
        t.accept(&header(7, 0, 6));
        assert_eq!(
            t.check(&header(7, 0, 10)),
            SequenceCheck::Gap { missing: 3 }
        );
        t.accept(&header(7, 0, 10));
        assert_eq!(t.check(&header(7, 0, 10)), SequenceCheck::Stale);
        assert_eq!(t.check(&header(7, 1, 11)), SequenceCheck::NewSource);
        assert_eq!(t.check(&header(8, 0, 0)), SequenceCheck::NewSource);
    }
}
