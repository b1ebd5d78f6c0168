//! One ingest thread per stream: bus subscriber -> checks -> estimator step -> published
//! results. The thread owns the iceoryx2 ports (they are not `Send`) and the estimator; the
//! HTTP side reads only atomics and `arc-swap` snapshots ([`status`], `crate::outbox`), so the
//! hot path takes no lock.

mod realtime;
mod sequence;
mod status;

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use iceoryx2::prelude::CallbackProgression;
use railmon_bus::{
    monotonic_ns, BusConfig, BusError, BusNode, Frame, FrameHeader, FrameSubscriber,
};

pub use railmon_records::sample_clock::{
    resume_rule, ClockCheck, Rejection, ResumeVerdict, SampleClock, PERIOD_TOLERANCE,
};
pub use realtime::RealTimeTracker;
pub use sequence::{SequenceCheck, SequenceTracker};
pub use status::{
    ReadinessReason, RejectionRecord, StreamStatus, StreamStatusView, COMMON_REJECTION_REASONS,
};

use crate::config::IngestConfig;
use crate::snapshot::{IngestState, SnapshotFile, SnapshotPolicy};

/// A stream's estimator, as the ingest loop drives it: `check` turns a frame into the input the
/// estimator takes (or says why not) without changing anything, `step` consumes that input.
pub trait Pipeline {
    type Frame: Frame;
    /// A frame after every check: what `step` consumes.
    type Checked;
    /// The reasons this pipeline's `check` and `step` reject with (besides the common ones).
    const REJECTION_REASONS: &'static [&'static str];
    /// Several frames of one source may carry the same sample time (the bogies of one step).
    const REPEATED_TIMES: bool = false;
    /// `step` may defer a frame's estimate to a later call, which reports it through
    /// `take_completed` (the bogies of one sample time are stepped together, in parallel).
    const DEFERS_STEPS: bool = false;
    /// The period the estimator is configured for: sample times advance by whole multiples.
    fn sample_period_ns(&self) -> u64;
    /// Checks a frame without changing anything.
    fn check(&self, header: &FrameHeader, frame: &Self::Frame) -> Result<Self::Checked, Rejection>;
    /// A new source (publisher restarted, or its run restarted): start from the prior.
    fn restart(&mut self);
    /// Steps the estimator with a checked frame; on error nothing changed.
    fn step(&mut self, header: &FrameHeader, input: Self::Checked) -> Result<(), Rejection>;
    /// Carries the estimator over `skipped_periods` sample periods no frame covered (samples
    /// lost at the source, or across a restart of the service), before the next frame is
    /// stepped. The default does nothing: the next frame is stepped as if it followed the last
    /// one (the vehicle stream's mixture reads the gap from its samples' times itself).
    fn bridge(&mut self, _skipped_periods: u64) {}
    /// The source has sent nothing for the stream's staleness limit, or the service stops:
    /// publish what the estimator still holds back from the frames it has (the drive
    /// stream's fixed lag), so that nothing accepted waits for a frame that may not come.
    /// Called once per silence, then `publish`. The default holds nothing back.
    fn end_of_data(&mut self) {}
    /// Makes the latest results visible (HTTP snapshot, gauges); called once per batch.
    fn publish(&mut self);
    /// Frames whose step was deferred (`step` accepted them, a later call stepped them) and
    /// failed, with why: counted as rejections. Asked after every `step` and `publish`.
    fn take_rejections(&mut self) -> Vec<(FrameHeader, Rejection)> {
        Vec::new()
    }
    /// Frames whose deferred step has completed since the last call, each with its own step
    /// time; `None` (the default): `step` estimates its frame itself and the loop times it.
    /// Asked after every `step` and `publish`, with `take_rejections`.
    fn take_completed(&mut self) -> Option<Vec<CompletedStep>> {
        None
    }
    /// The estimator settings a saved state is only valid for (their serialised text).
    fn settings(&self) -> String {
        String::new()
    }
    /// The estimator's state to resume after a restart (`None`: nothing worth saving, or the
    /// stream does not resume).
    fn save_state(&self) -> Option<Vec<u8>> {
        None
    }
    /// Resumes from `state` (made by `save_state` with the same settings); on error nothing
    /// changed.
    fn resume_state(&mut self, _state: &[u8]) -> Result<(), String> {
        Err("this stream does not resume from snapshots".into())
    }
    /// A snapshot was there and did not fit (`reason`); the estimator starts from its prior.
    /// Called after the warning is logged, so a pipeline can also count it or store an event.
    fn snapshot_refused(&mut self, _file: &std::path::Path, _reason: &str) {}
}

/// A deferred step, done: the estimator time of its own frame (not of the call that ran it,
/// which may have stepped several bogies in parallel) and when its estimate was done.
#[derive(Clone, Copy, Debug)]
pub struct CompletedStep {
    pub published_at_ns: u64,
    pub step_ns: u64,
    pub done_at_ns: u64,
}

/// Counts what deferred steps did since the last call: their rejections, and the step time and
/// latency of each completed one.
fn record_deferred<P: Pipeline>(pipeline: &mut P, status: &StreamStatus) {
    for (header, rejection) in pipeline.take_rejections() {
        status.reject(&header, rejection);
    }
    for c in pipeline.take_completed().into_iter().flatten() {
        status.record_step(
            c.step_ns,
            c.done_at_ns,
            c.done_at_ns.saturating_sub(c.published_at_ns),
        );
    }
}

/// What the ingest loop keeps about the current source of a stream.
struct SourceTracking {
    sequence: SequenceTracker,
    clock: SampleClock,
    realtime: RealTimeTracker,
}

impl SourceTracking {
    fn restart<P: Pipeline>(&mut self, pipeline: &mut P) {
        pipeline.restart();
        self.clock.restart();
        self.realtime.restart();
    }
}

/// Handles one received frame: count, check the header, follow the source and its sequence,
/// check the sample time and the frame, step, time. The sequence is followed before the
/// frame's content is judged, so a rejected frame is counted once, as a rejection, and never
/// again as a gap.
///
/// After a resumed snapshot, the first frame used is judged by the resume rule
/// ([`resume_rule`]) against the snapshot's last sample time, not by the live clock rule; a new
/// publisher (a restarted replay) then restarts the estimator only if its sample times do not
/// continue the resumed ones within the catch-up.
fn handle_frame<P: Pipeline>(
    pipeline: &mut P,
    source: &mut SourceTracking,
    status: &StreamStatus,
    header: &FrameHeader,
    frame: &P::Frame,
    received_at_ns: u64,
) {
    status.record_received(received_at_ns);
    if let Err(e) = header.check() {
        return status.reject(header, Rejection::new(e.reason(), e.to_string()));
    }
    let mut new_source = false;
    match source.sequence.check(header, received_at_ns) {
        SequenceCheck::InOrder => {}
        SequenceCheck::NewSource if source.clock.resume_pending() => {
            // Its frames are not counted against the old publisher's sequence (no gap).
            status.record_new_source();
            new_source = true;
            tracing::info!(stream = %status.kind, instance = header.publisher_instance, run = header.run, sequence = header.sequence, "new source after a resume: its sample times decide whether the estimator goes on");
        }
        SequenceCheck::NewSource => {
            status.record_new_source();
            new_source = true;
            tracing::info!(stream = %status.kind, instance = header.publisher_instance, run = header.run, sequence = header.sequence, "new source: estimator restarts");
            source.restart(pipeline);
        }
        SequenceCheck::Gap { missing } => {
            status.record_gap(missing);
            tracing::warn!(stream = %status.kind, missing, sequence = header.sequence, "frames lost");
        }
        SequenceCheck::Stale { last } => {
            let message = format!("sequence {} is not after {last}", header.sequence);
            return status.reject(header, Rejection::new("out_of_order", message));
        }
        SequenceCheck::Competing { current } => {
            status.record_competing(received_at_ns);
            let message = format!(
                "publisher {:#x} sends while publisher {current:#x} is alive: one source at a time",
                header.publisher_instance
            );
            return status.reject(header, Rejection::new("second_source", message));
        }
    }
    source.sequence.accept(header, received_at_ns);
    let t = header.sample_time_ns;
    let clock = match source.clock.judge_resume(t) {
        Some(ResumeVerdict::Keep { skipped_periods }) => {
            tracing::info!(stream = %status.kind, sample_time_s = header.sample_time_ns as f64 * 1e-9, skipped_periods, "the resumed estimator goes on across the restart");
            ClockCheck::Ok
        }
        Some(ResumeVerdict::Restart { reason }) => {
            if !new_source {
                status.record_new_source();
            }
            tracing::info!(stream = %status.kind, sample_time_s = header.sample_time_ns as f64 * 1e-9, reason, "the source's clock does not continue the resumed snapshot: estimator restarts");
            source.restart(pipeline);
            ClockCheck::Ok
        }
        None => source.clock.check(t),
    };
    source.clock.observe(t);
    match clock {
        ClockCheck::Ok => {}
        ClockCheck::NewTimeline => {
            status.record_new_source();
            tracing::info!(stream = %status.kind, sample_time_s = header.sample_time_ns as f64 * 1e-9, "the source's clock jumped: estimator restarts");
            source.restart(pipeline);
        }
        ClockCheck::Reject(rejection) => {
            source.clock.refused(header.sample_time_ns, &rejection);
            return status.reject(header, rejection);
        }
    }
    let input = match pipeline.check(header, frame) {
        Ok(input) => input,
        Err(rejection) => return status.reject(header, rejection),
    };
    let skipped_periods = source.clock.skipped_periods(t);
    if skipped_periods > 0 {
        pipeline.bridge(skipped_periods);
        status.record_skipped_periods(skipped_periods);
        // The estimator now stands one period before this frame, whether its step succeeds
        // or not: a failed step is bridged by the next frame, never twice.
        source
            .clock
            .accept(t.saturating_sub(pipeline.sample_period_ns()));
    }
    let start = Instant::now();
    let stepped = pipeline.step(header, input);
    let step_ns = start.elapsed().as_nanos() as u64;
    match stepped {
        Ok(()) => {
            source.clock.accept(header.sample_time_ns);
            let done_at_ns = monotonic_ns();
            if !P::DEFERS_STEPS {
                status.record_step(
                    step_ns,
                    done_at_ns,
                    done_at_ns.saturating_sub(header.published_at_ns),
                );
            }
            let (lag_ns, load) =
                source
                    .realtime
                    .observe(header.sample_time_ns, done_at_ns, step_ns);
            status.record_realtime(lag_ns, load);
        }
        Err(rejection) => status.reject(header, rejection),
    }
    record_deferred(pipeline, status);
}

/// The ingest loop of one stream; returns when `shutdown` is set (or on a bus error, which is
/// also recorded in the status). Ports are dropped on return, releasing iceoryx2 resources.
pub fn run_ingest<P: Pipeline>(
    bus: &BusConfig,
    ingest: &IngestConfig,
    snapshots: Option<&SnapshotPolicy>,
    pipeline: &mut P,
    status: &StreamStatus,
    shutdown: &AtomicBool,
) -> Result<(), BusError> {
    let result = ingest_loop(bus, ingest, snapshots, pipeline, status, shutdown);
    status.record_stopped(result.as_ref().err());
    result
}

/// Saves the pipeline's state with where its source stands.
fn save_snapshot<P: Pipeline>(file: &SnapshotFile, pipeline: &P, source: &SourceTracking) {
    let (Some(state), Some((instance, run, next))) =
        (pipeline.save_state(), source.sequence.position())
    else {
        return;
    };
    let state = IngestState {
        publisher_instance: instance,
        run,
        next_sequence: next,
        last_sample_time_ns: source.clock.last(),
        pipeline: state,
    };
    if let Err(e) = file.save(&state) {
        tracing::warn!("cannot save the estimator snapshot: {e}");
    }
}

/// Resumes the pipeline from its snapshot if one fits (else it starts from its prior).
fn resume_snapshot<P: Pipeline>(
    file: &SnapshotFile,
    max_age_s: f64,
    pipeline: &mut P,
    source: &mut SourceTracking,
    kind: railmon_bus::StreamKind,
) {
    let refused = match file.load(max_age_s) {
        Ok(None) => return,
        Ok(Some(state)) => match pipeline.resume_state(&state.pipeline) {
            Ok(()) => {
                source
                    .sequence
                    .resume(state.publisher_instance, state.run, state.next_sequence);
                // The catch-up across the restart: as far in sample time as the snapshot may
                // be old in wall time (at least the live limit).
                source
                    .clock
                    .resume(state.last_sample_time_ns, (max_age_s * 1e9) as u64);
                tracing::info!(stream = %kind, file = %file.path().display(), "estimator resumed from its snapshot");
                return;
            }
            Err(e) => e,
        },
        Err(e) => e,
    };
    tracing::warn!(stream = %kind, file = %file.path().display(), "snapshot refused, the estimator starts from its prior: {refused}");
    pipeline.snapshot_refused(file.path(), &refused);
}

/// Estimates up to `max` frames the subscriber holds and publishes the estimates; returns how
/// many frames it took.
fn estimate_batch<P: Pipeline>(
    subscriber: &FrameSubscriber<P::Frame>,
    max: usize,
    pipeline: &mut P,
    source: &mut SourceTracking,
    status: &StreamStatus,
) -> Result<usize, BusError> {
    let handled = subscriber.drain(max, |rx| {
        handle_frame(
            pipeline,
            source,
            status,
            rx.header,
            rx.frame,
            rx.received_at_ns,
        )
    })?;
    if handled > 0 {
        pipeline.publish();
        record_deferred(pipeline, status);
    }
    Ok(handled)
}

/// The source is silent (or the service stops): what the estimator holds back is published.
fn end_of_data<P: Pipeline>(pipeline: &mut P, status: &StreamStatus) {
    pipeline.end_of_data();
    pipeline.publish();
    record_deferred(pipeline, status);
}

fn ingest_loop<P: Pipeline>(
    bus: &BusConfig,
    ingest: &IngestConfig,
    snapshots: Option<&SnapshotPolicy>,
    pipeline: &mut P,
    status: &StreamStatus,
    shutdown: &AtomicBool,
) -> Result<(), BusError> {
    let kind = <P::Frame as Frame>::STREAM;
    let node = BusNode::create(bus, &format!("railmon-serve-{kind}"))?;
    if node.cleaned_at_start() > 0 {
        tracing::info!(stream = %kind, dead_nodes = node.cleaned_at_start(), "cleaned up stale bus resources");
    }
    let root = node.root_path();
    for note in &root.notes {
        tracing::warn!(stream = %kind, "bus root path: {note}; falling back");
    }
    tracing::info!(stream = %kind, root_path = %root.path, "bus root path");
    let subscriber = node.subscriber::<P::Frame>()?;
    let waitset = node.waitset()?;
    let _wake_on_frames = waitset
        .attach_notification(subscriber.listener())
        .map_err(|e| BusError::Ipc {
            what: "attach listener to WaitSet".into(),
            detail: format!("{e:?}"),
        })?;
    status.record_running();
    tracing::info!(stream = %kind, service = subscriber.service_name(), "ingesting");
    let wake_interval = Duration::from_millis(ingest.wake_interval_ms);
    let cleanup_interval = Duration::from_millis(ingest.cleanup_interval_ms);
    let mut last_cleanup = Instant::now();
    // Another publisher may take over once the current one is silent for the staleness limit;
    // a sample-time advance beyond it is a jump.
    let stale_ns = status.stale_after.as_nanos() as u64;
    let mut source = SourceTracking {
        sequence: SequenceTracker::new(stale_ns),
        clock: SampleClock::new(pipeline.sample_period_ns(), P::REPEATED_TIMES, stale_ns),
        realtime: RealTimeTracker::default(),
    };
    let snapshot_file = snapshots
        .map(|policy| SnapshotFile::new(&policy.data_dir, kind.name(), &pipeline.settings()));
    if let (Some(file), Some(policy)) = (&snapshot_file, snapshots) {
        resume_snapshot(file, policy.max_age_s, pipeline, &mut source, kind);
    }
    let mut last_snapshot = Instant::now();
    // When the last frame came, while the estimator may still hold some back.
    let mut data_since: Option<Instant> = None;
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
            source.sequence.publisher_died();
        }
        // A publisher that ended cleanly sends no death notice: with one publisher left on the
        // service, a frame from a new instance is a successor, not a competitor.
        if subscriber.publisher_count() <= 1 {
            source.sequence.publisher_died();
        }
        loop {
            let handled =
                estimate_batch(&subscriber, ingest.max_batch, pipeline, &mut source, status)?;
            if handled > 0 {
                data_since = Some(Instant::now());
            }
            if handled < ingest.max_batch || shutdown.load(Ordering::Relaxed) {
                break;
            }
        }
        if data_since.is_some_and(|t| t.elapsed() >= status.stale_after) {
            end_of_data(pipeline, status);
            data_since = None;
        }
        if let (Some(file), Some(policy)) = (&snapshot_file, snapshots) {
            if last_snapshot.elapsed() >= policy.interval {
                save_snapshot(file, pipeline, &source);
                last_snapshot = Instant::now();
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
    // What the subscriber already holds is estimated before the last snapshot (a restart
    // would otherwise lose the whole buffer): at most one buffer's worth, so publishers still
    // sending cannot hold the shutdown.
    let held = bus.stream(kind).subscriber_buffer_size;
    let mut drained = 0;
    while drained < held {
        let batch = ingest.max_batch.min(held - drained);
        let handled = match estimate_batch(&subscriber, batch, pipeline, &mut source, status) {
            Ok(handled) => handled,
            Err(e) => {
                tracing::warn!(stream = %kind, "cannot drain the subscriber at shutdown: {e}");
                break;
            }
        };
        if handled == 0 {
            break;
        }
        drained += handled;
    }
    if drained > 0 {
        tracing::info!(stream = %kind, frames = drained, "estimated the frames held at shutdown");
    }
    if data_since.is_some() || drained > 0 {
        end_of_data(pipeline, status);
    }
    if let Some(file) = &snapshot_file {
        save_snapshot(file, pipeline, &source);
    }
    tracing::info!(stream = %kind, "ingest stopped");
    Ok(())
}
