//! The publishing loop every stream shares: wait for a subscriber, pace by the samples' own
//! time stamps, send, wake the subscriber, record, start again with `--loop`, summarise.

use std::time::{Duration, Instant};

use railmon_bus::{BusNode, Frame, FramePublisher};

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
    /// Writes the frame `next` returned last to the `--record` file (number `sent`).
    fn record(&mut self, sent: u64) -> anyhow::Result<()>;
    /// Completes the `--record` file.
    fn finish_recording(&mut self) -> anyhow::Result<()>;
    /// What one frame holds, for the summary line (`3 drives`).
    fn describe(&self) -> String;
}

fn wait_for_subscriber<F: Frame>(
    publisher: &FramePublisher<F>,
    args: &ReplayArgs,
) -> anyhow::Result<()> {
    eprintln!(
        "sensors-replay: waiting for a subscriber on `{}`",
        publisher.service_name()
    );
    publisher.wait_for_subscriber(args.wait_timeout(), &stop_requested)?;
    eprintln!("sensors-replay: subscriber connected");
    Ok(())
}

/// Publishes `source` on its stream as `args` say, until its end (or forever with `--loop`,
/// until SIGINT/SIGTERM or `--max-frames`).
pub fn publish<S: Source>(source: &mut S, args: &ReplayArgs) -> anyhow::Result<()> {
    let bus = load_bus_config(args.config.as_deref())?;
    let stream = <S::Frame as Frame>::STREAM;
    let node = BusNode::create(&bus, &format!("sensors-replay-{stream}"))?;
    let mut publisher = node.publisher::<S::Frame>()?;
    wait_for_subscriber(&publisher, args)?;
    let mut pacer = Pacer::new(args.speed);
    let notify_every = if pacer.is_paced() {
        1
    } else {
        args.notify_every.max(1)
    };
    let period_ns = (source.period_s() * 1e9).round() as u64;
    // Time of the run's start and of the last frame on the replay's own clock, for pacing.
    let (mut run_offset_ns, mut last_ns) = (0u64, 0u64);
    let (mut sent, mut undelivered, mut runs) = (0u64, 0u64, 1u64);
    let start = Instant::now();
    while !stop_requested() && args.max_frames.is_none_or(|max| sent < max) {
        let Some((frame, sample_time_ns)) = source.next()? else {
            if !args.repeat {
                break;
            }
            source.rewind()?;
            publisher.start_new_run();
            run_offset_ns = last_ns + period_ns;
            runs += 1;
            continue;
        };
        last_ns = run_offset_ns + sample_time_ns;
        pacer.wait_until(Duration::from_nanos(last_ns));
        let recipients = publisher.send(&frame, sample_time_ns)?;
        if recipients == 0 || sent.is_multiple_of(notify_every) {
            publisher.notify()?;
        }
        if recipients == 0 {
            undelivered += 1;
            eprintln!("sensors-replay: frame {sent} reached no subscriber");
            wait_for_subscriber(&publisher, args)?;
            pacer.reset(Duration::from_nanos(last_ns));
        }
        source.record(sent)?;
        sent += 1;
    }
    publisher.notify()?;
    source.finish_recording()?;
    let elapsed_s = start.elapsed().as_secs_f64();
    let speed = match args.speed {
        Speed::Max => "max".to_string(),
        Speed::Times(x) => format!("{x}x"),
    };
    eprintln!(
        "sensors-replay: sent {sent} frames ({}, {runs} run(s)) in {elapsed_s:.3} s = {:.0} frames/s at speed {speed}; undelivered {undelivered}",
        source.describe(),
        sent as f64 / elapsed_s.max(1e-9),
    );
    Ok(())
}
