use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use iceoryx2::port::listener::{Listener, ListenerWaitError};
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::{BackpressureAction, BackpressureInfo};
use iceoryx2::prelude::*;

use crate::node::{
    PubSubFactory, StreamServices, EVENT_FRAMES_SENT, EVENT_PUBLISHER_HELLO, EVENT_SUBSCRIBER_READY,
};
use crate::taken::{TakenFrames, TakenLedger, TakenReport};
use crate::{monotonic_ns, BusError, Frame, FrameHeader, StreamConfig, FRAME_LAYOUT_VERSION};

/// Publishes one stream's frames, numbering and stamping each, and wakes the subscribers.
pub struct FramePublisher<F: Frame> {
    stream: StreamConfig,
    frames: PubSubFactory<F>,
    // Field order is drop order: the port goes before the notifier and listener.
    publisher: Publisher<ipc::Service, F, FrameHeader>,
    /// The subscribers' acknowledgements of what they took.
    taken_subscriber: Subscriber<ipc::Service, TakenFrames, ()>,
    ledger: TakenLedger,
    notifier: Notifier<ipc::Service>,
    ready_listener: Listener<ipc::Service>,
    instance: u64,
    run: u32,
    sequence: u64,
    /// UTC (ns since the epoch) of sample time 0 of the current run.
    utc_origin_ns: i64,
}

impl<F: Frame> std::fmt::Debug for FramePublisher<F> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FramePublisher")
            .field("service", &self.stream.service_name)
            .field("sequence", &self.sequence)
            .finish()
    }
}

impl<F: Frame> FramePublisher<F> {
    pub(crate) fn new(
        stream: StreamConfig,
        services: StreamServices<F>,
        stop: Option<&'static AtomicBool>,
    ) -> Result<Self, BusError> {
        let name = stream.service_name.clone();
        let limit = Duration::from_millis(stream.backpressure_timeout_ms);
        // Lossless mode waits for a full subscriber, but never longer than `limit`: a SIGKILLed
        // subscriber never drains its buffer and would block us until its node is cleaned up.
        // A stop request ends the wait at once (the frame then reached no subscriber).
        let give_up_after_limit = move |info: &BackpressureInfo| {
            let stopping = stop.is_some_and(|s| s.load(Ordering::Relaxed));
            if info.elapsed_time < limit && !stopping {
                BackpressureAction::Retry
            } else {
                BackpressureAction::DiscardData
            }
        };
        let taken_subscriber = services
            .taken
            .subscriber_builder()
            .create()
            .map_err(|e| BusError::ipc(format!("create subscriber on `{name}/taken`"), e))?;
        // The listener exists before the port, so every readiness answer to our hello reaches it.
        let ready_listener = services
            .ready
            .listener_builder()
            .create()
            .map_err(|e| BusError::ipc(format!("create listener on `{name}/ready`"), e))?;
        let notifier = services
            .events
            .notifier_builder()
            .default_event_id(EventId::new(EVENT_FRAMES_SENT))
            .create()
            .map_err(|e| BusError::ipc(format!("create notifier on `{name}`"), e))?;
        let publisher = services
            .frames
            .publisher_builder()
            .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
            .set_backpressure_handler(give_up_after_limit)
            .create()
            .map_err(|e| BusError::ipc(format!("create publisher on `{name}`"), e))?;
        let instance = new_instance_id();
        Ok(Self {
            stream,
            frames: services.frames,
            publisher,
            taken_subscriber,
            ledger: TakenLedger::default(),
            notifier,
            ready_listener,
            instance,
            run: 0,
            sequence: 0,
            utc_origin_ns: utc_now_ns(),
        })
    }

    pub fn service_name(&self) -> &str {
        &self.stream.service_name
    }

    /// Subscribers registered on the service (connected or not yet).
    pub fn subscriber_count(&self) -> usize {
        self.frames.dynamic_config().number_of_subscribers()
    }

    /// Sequence number the next frame gets.
    pub fn next_sequence(&self) -> u64 {
        self.sequence
    }

    /// Marks the following frames as a new run of the source (estimators restart from their prior).
    pub fn start_new_run(&mut self) {
        self.run = self.run.wrapping_add(1);
    }

    /// The UTC time (ns since the Unix epoch) of sample time 0 of the current run: frames
    /// carry `acquired_utc_ns = origin + sample_time_ns`. Default: when the publisher was made.
    pub fn set_utc_origin_ns(&mut self, origin_ns: i64) {
        self.utc_origin_ns = origin_ns;
    }

    /// Waits until a subscriber has connected to this publisher: iceoryx2 queues frames for a
    /// subscriber that has not yet looked at its port only until its buffer is full and then
    /// drops them, so streaming must not start before. Says hello every 10 ms and returns when
    /// a subscriber answers that it updated its connections, when `stop()` says so (error
    /// `Stopped`) or after `timeout` (error `NoSubscriber`).
    pub fn wait_for_subscriber(
        &self,
        timeout: Option<Duration>,
        stop: &dyn Fn() -> bool,
    ) -> Result<(), BusError> {
        let start = Instant::now();
        loop {
            self.notifier
                .notify_with_custom_event_id(EventId::new(EVENT_PUBLISHER_HELLO))
                .map_err(|e| BusError::ipc(format!("hello on `{}`", self.service_name()), e))?;
            let mut ready = false;
            let waited = self.ready_listener.timed_wait(
                |event| ready |= event.id.as_value() == EVENT_SUBSCRIBER_READY,
                Duration::from_millis(10),
            );
            match waited {
                Ok(_) => {}
                // A signal (SIGTERM to stop us) interrupts the wait: not an error. Returning
                // it as one made SIGTERM exit 1 in 4 of 8 tries instead of 0.
                Err(ListenerWaitError::InterruptSignal) => {}
                Err(e) => {
                    return Err(BusError::ipc(
                        format!("wait on `{}/ready`", self.service_name()),
                        e,
                    ))
                }
            }
            if ready {
                return Ok(());
            }
            if stop() {
                return Err(BusError::Stopped {
                    service: self.stream.service_name.clone(),
                });
            }
            if timeout.is_some_and(|t| start.elapsed() > t) {
                return Err(BusError::NoSubscriber {
                    service: self.stream.service_name.clone(),
                    waited_ms: start.elapsed().as_millis() as u64,
                });
            }
        }
    }

    /// Sends one frame under the next sequence number; returns how many subscribers took it (0:
    /// nobody is subscribed, or a subscriber was full for longer than the backpressure limit).
    /// A frame nobody took still used up its number, so a subscriber sees the loss as a gap
    /// unless the caller re-sends it with [`Self::resend`]. Does not notify: call
    /// [`Self::notify`] after one frame or a batch.
    pub fn send(&mut self, frame: &F, sample_time_ns: u64) -> Result<usize, BusError> {
        let sequence = self.sequence;
        self.sequence += 1;
        self.send_numbered(frame, sample_time_ns, sequence)
    }

    /// Sends `frame` again under the number the last [`Self::send`] gave it (stamped anew), for
    /// a lossless source whose last frame reached no subscriber: a subscriber that stalled
    /// longer than the backpressure limit then misses nothing and counts no gap.
    pub fn resend(&mut self, frame: &F, sample_time_ns: u64) -> Result<usize, BusError> {
        let sequence = self.sequence.checked_sub(1).ok_or_else(|| {
            BusError::ipc(
                format!("resend on `{}`", self.stream.service_name),
                "nothing was sent yet",
            )
        })?;
        self.send_numbered(frame, sample_time_ns, sequence)
    }

    fn send_numbered(
        &mut self,
        frame: &F,
        sample_time_ns: u64,
        sequence: u64,
    ) -> Result<usize, BusError> {
        let mut sample = self
            .publisher
            .loan_uninit()
            .map_err(|e| BusError::ipc(format!("loan on `{}`", self.stream.service_name), e))?;
        *sample.user_header_mut() = FrameHeader {
            layout_version: FRAME_LAYOUT_VERSION,
            run: self.run,
            publisher_instance: self.instance,
            sequence,
            published_at_ns: monotonic_ns(),
            sample_time_ns,
            acquired_utc_ns: self.utc_origin_ns.saturating_add_unsigned(sample_time_ns),
        };
        sample
            .write_payload(*frame)
            .send()
            .map_err(|e| BusError::ipc(format!("send on `{}`", self.stream.service_name), e))
    }

    /// Reads the subscribers' acknowledgements that arrived since the last call (call it at
    /// least every [`crate::taken::TAKEN_BUFFER`] batches the subscribers drain).
    pub fn collect_taken(&mut self) -> Result<(), BusError> {
        loop {
            let ack = self.taken_subscriber.receive().map_err(|e| {
                BusError::ipc(
                    format!("receive on `{}/taken`", self.stream.service_name),
                    e,
                )
            })?;
            let Some(ack) = ack else { return Ok(()) };
            if ack.publisher_instance == self.instance {
                self.ledger.record(&ack);
            }
        }
    }

    /// What became of the frames sent so far, as acknowledged until the last
    /// [`Self::collect_taken`].
    pub fn taken_report(&self) -> TakenReport {
        self.ledger.report(self.sequence)
    }

    /// Waits until a subscriber acknowledged the last frame sent, no subscriber is left,
    /// `stop()` says so, or `timeout` passed; then reports what became of the frames.
    pub fn wait_until_taken(
        &mut self,
        timeout: Duration,
        stop: &dyn Fn() -> bool,
    ) -> Result<TakenReport, BusError> {
        let start = Instant::now();
        loop {
            self.collect_taken()?;
            let report = self.taken_report();
            let gone = self.subscriber_count() == 0;
            if report.unconfirmed == 0 || gone || stop() || start.elapsed() >= timeout {
                return Ok(report);
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// Wakes the subscribers' WaitSets.
    pub fn notify(&self) -> Result<(), BusError> {
        self.notifier
            .notify()
            .map(|_| ())
            .map_err(|e| BusError::ipc(format!("notify on `{}`", self.stream.service_name), e))
    }
}

/// The wall clock now, ns since the Unix epoch (UTC).
pub fn utc_now_ns() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_nanos()).unwrap_or(i64::MAX))
}

/// An id that tells publishers apart, also across containers where every process is PID 1
/// (the pid alone, or pid and clock bits, would then rest on the clock): std's hasher keyed
/// from the OS's randomness, over the pid and the clock.
pub(crate) fn new_instance_id() -> u64 {
    use std::hash::BuildHasher;
    std::collections::hash_map::RandomState::new().hash_one((std::process::id(), monotonic_ns()))
}
