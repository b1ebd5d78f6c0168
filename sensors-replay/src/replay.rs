//! The publishing loop every stream shares: wait for a subscriber, pace by the samples' own
//! time stamps, send, wake the subscriber, record, start again with `--loop`, summarise.

use std::time::{Duration, Instant};

use railmon_bus::{BusError, BusNode, Frame, FramePublisher, TakenReport};

use crate::pacing::{Pacer, Speed};
use crate::{load_bus_config, stop_requested, ReplayArgs};

/// Where one stream's frames come from (a simulator or a recording).
pub trait Source {
    type Frame: Frame;
    /// Nominal step between samples, s: with `--loop`, the next run starts one step after the
    /// last sample of the previous one.
    fn period_s(&self) -> f64;
    /// The next frame and its time within the run, ns; `None` at the end of the run.
    fn next(&mut self) -> anyhow::Result<Option<(Self::Frame, u64)>>;
    /// Back to the first sample (for `--loop`).
    fn rewind(&mut self) -> anyhow::Result<()>;
    /// Writes the frame `next` returned last to the `--record` file: frame number `sent`
    /// (all runs), of the run that started `run_offset_s` after the first one. Every stream
    /// records every run, its times shifted by that offset, so a `--loop` recording keeps
    /// the replay's continuous clock.
    fn record(&mut self, sent: u64, run_offset_s: f64) -> anyhow::Result<()>;
    /// Completes the `--record` file and puts it in place (called only when frames were
    /// sent; otherwise the recorder is dropped, which leaves an existing file untouched).
    fn finish_recording(&mut self) -> anyhow::Result<()>;
    /// What one frame holds, for the summary line (`3 drives`).
    fn describe(&self) -> String;
}

/// Why a replay ended without error, and what became of its frames.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Outcome {
    pub report: TakenReport,
    /// SIGINT / SIGTERM ended it.
    pub stopped: bool,
}

/// The source holds no samples (a header-only file): nothing was sent (exit code 4).
#[derive(Debug, thiserror::Error)]
#[error("{0}: no samples, nothing sent")]
pub struct NoSamples(pub String);

/// Waits until a subscriber answers; false when SIGINT/SIGTERM came first (a normal end).
fn wait_for_subscriber<F: Frame>(
    publisher: &FramePublisher<F>,
    args: &ReplayArgs,
) -> anyhow::Result<bool> {
    eprintln!(
        "sensors-replay: waiting for a subscriber on `{}`",
        publisher.service_name()
    );
    match publisher.wait_for_subscriber(args.wait_timeout(), &stop_requested) {
        Ok(()) => {
            eprintln!("sensors-replay: subscriber connected");
            Ok(true)
        }
        Err(BusError::Stopped { .. }) => Ok(false),
        Err(e) => Err(e.into()),
    }
}

/// How long the end of a replay waits for a subscriber to take the last frames before it
/// reports them as unconfirmed.
const FINAL_TAKE_TIMEOUT: Duration = Duration::from_secs(10);

/// Publishes `source` on its stream as `args` say, until its end (or forever with `--loop`,
/// until SIGINT/SIGTERM or `--max-frames`).
pub fn publish<S: Source>(
    source: &mut S,
    args: &ReplayArgs,
    what: &str,
) -> anyhow::Result<Outcome> {
    let bus = load_bus_config(args.config.as_deref())?;
    let stream = <S::Frame as Frame>::STREAM;
    let node = BusNode::create(&bus, &format!("sensors-replay-{stream}"))?;
    for note in &node.root_path().notes {
        eprintln!("sensors-replay: bus root path: {note}; falling back");
    }
    if !node.root_path().notes.is_empty() {
        eprintln!("sensors-replay: bus root path {}", node.root_path().path);
    }
    let mut publisher = node.publisher_stopped_by::<S::Frame>(Some(&crate::STOP))?;
    // The first frame is read before waiting for a subscriber: an empty or bad input is
    // reported at once, not after a service connected.
    let mut first = source.next()?;
    if first.is_none() {
        return Err(NoSamples(what.to_string()).into());
    }
    let connected = wait_for_subscriber(&publisher, args)?;
    // Acquisition times: the given start (or now) plus the time on the replay's own clock.
    let utc_start_ns = args.start_utc.unwrap_or_else(railmon_bus::utc_now_ns);
    publisher.set_utc_origin_ns(utc_start_ns);
    let mut pacer = Pacer::new(args.speed, Duration::from_secs_f64(args.max_gap_s));
    let notify_every = if pacer.is_paced() {
        1
    } else {
        args.notify_every.max(1)
    };
    let period_ns = (source.period_s() * 1e9).round() as u64;
    // Time of the run's start and of the last frame on the replay's own clock, for pacing.
    let (mut run_offset_ns, mut last_ns) = (0u64, 0u64);
    let (mut sent, mut resent, mut runs, mut sent_in_run) = (0u64, 0u64, 1u64, 0u64);
    let start = Instant::now();
    // The loop in a closure: whatever ends it (an error included), what was sent is
    // recorded and counted below.
    let streamed = (|| -> anyhow::Result<()> {
        'frames: while connected
            && !stop_requested()
            && args.max_frames.is_none_or(|max| sent < max)
        {
            let next = match first.take() {
                Some(frame) => Some(frame),
                None => source.next()?,
            };
            let Some((frame, sample_time_ns)) = next else {
                if sent_in_run == 0 {
                    return Err(NoSamples(what.to_string()).into());
                }
                if !args.repeat {
                    break;
                }
                source.rewind()?;
                publisher.start_new_run();
                run_offset_ns = last_ns.saturating_add(period_ns);
                publisher.set_utc_origin_ns(utc_start_ns.saturating_add_unsigned(run_offset_ns));
                runs += 1;
                sent_in_run = 0;
                continue;
            };
            last_ns = run_offset_ns.saturating_add(sample_time_ns);
            if !pacer.wait_until(Duration::from_nanos(last_ns), &stop_requested) {
                break; // stopped during the wait: the service may be stopping too
            }
            let mut recipients = publisher.send(&frame, sample_time_ns)?;
            // No subscriber took the frame: none is connected, or it stayed full for longer than
            // the backpressure limit (stalled, or killed). Once a live subscriber answers the
            // hand-shake, the same frame goes again under the same number: nothing is lost.
            while recipients == 0 {
                publisher.notify()?;
                publisher.collect_taken()?;
                if stop_requested() {
                    break 'frames; // the frame was refused because we are stopping
                }
                eprintln!("sensors-replay: frame {sent} reached no subscriber; re-sending it");
                if !wait_for_subscriber(&publisher, args)? {
                    break 'frames;
                }
                pacer.reset(Duration::from_nanos(last_ns));
                recipients = publisher.resend(&frame, sample_time_ns)?;
                resent += 1;
            }
            if sent.is_multiple_of(notify_every) {
                publisher.notify()?;
                publisher.collect_taken()?;
            }
            source.record(sent, run_offset_ns as f64 / 1e9)?;
            sent += 1;
            sent_in_run += 1;
        }
        Ok(())
    })();
    publisher.notify()?;
    let stopped = stop_requested();
    node.cleanup_dead_nodes(); // a dead subscriber is not waited for
    let report = match &streamed {
        Ok(()) => publisher.wait_until_taken(FINAL_TAKE_TIMEOUT, &stop_requested)?,
        Err(_) => {
            publisher.collect_taken()?;
            publisher.taken_report()
        }
    };
    if sent > 0 {
        // Also after an error (a bad row, a service that did not come back): the frames sent.
        source.finish_recording()?;
    } else if let Some(path) = &args.record {
        // Nothing was sent: an existing recording stays as it was.
        eprintln!(
            "sensors-replay: nothing sent, {} left untouched",
            path.display()
        );
    }
    let elapsed_s = start.elapsed().as_secs_f64();
    let speed = match args.speed {
        Speed::Max => "max".to_string(),
        Speed::Times(x) => format!("{x}x"),
    };
    eprintln!(
        "sensors-replay: sent {sent} frames ({}, {runs} run(s)) in {elapsed_s:.3} s = {:.0} frames/s at speed {speed}; re-sent {resent}",
        source.describe(),
        sent as f64 / elapsed_s.max(1e-9),
    );
    eprintln!(
        "sensors-replay: taken {} lost {} unconfirmed {} (lost: sent, never taken by any subscriber, e.g. held by a service that died)",
        report.taken, report.lost, report.unconfirmed
    );
    streamed?;
    Ok(Outcome { report, stopped })
}

/// What [`publish`] sends and records, without a bus: `runs` runs of `source` (the clock of
/// each run starting one period after the previous run's last frame), each frame with its time
/// on the replay's clock, ns. For the sources' tests.
#[cfg(test)]
pub fn replay_offline<S: Source>(
    source: &mut S,
    runs: u64,
) -> anyhow::Result<Vec<(S::Frame, u64)>> {
    let period_ns = (source.period_s() * 1e9).round() as u64;
    let (mut run_offset_ns, mut last_ns, mut sent) = (0u64, 0u64, 0u64);
    let mut frames = Vec::new();
    for run in 0..runs {
        if run > 0 {
            source.rewind()?;
            run_offset_ns = last_ns + period_ns;
        }
        while let Some((frame, sample_time_ns)) = source.next()? {
            last_ns = run_offset_ns + sample_time_ns;
            source.record(sent, run_offset_ns as f64 / 1e9)?;
            frames.push((frame, last_ns));
            sent += 1;
        }
    }
    source.finish_recording()?;
    Ok(frames)
}
