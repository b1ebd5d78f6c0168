use iceoryx2::port::listener::Listener;
use std::cell::RefCell;

use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;

use crate::node::{
    PubSubFactory, StreamServices, EVENT_PUBLISHER_DEAD, EVENT_PUBLISHER_HELLO,
    EVENT_SUBSCRIBER_READY,
};
use crate::taken::TakenFrames;
use crate::{monotonic_ns, BusError, Frame, FrameHeader, StreamConfig};

/// Publishers whose taken ranges a subscriber remembers (the most recent ones).
const TAKEN_PUBLISHERS: usize = 8;

/// A frame as handed to the consumer: borrowed from shared memory, valid during the callback.
pub struct ReceivedFrame<'a, F> {
    pub header: &'a FrameHeader,
    pub frame: &'a F,
    /// CLOCK_MONOTONIC when it was taken from the buffer, ns.
    pub received_at_ns: u64,
}

/// Receives one stream's frames; its listener wakes a WaitSet when frames were sent.
pub struct FrameSubscriber<F: Frame> {
    stream: StreamConfig,
    frames: PubSubFactory<F>,
    subscriber: Subscriber<ipc::Service, F, FrameHeader>,
    /// Tells the publishers what this subscriber took ([`crate::taken`]).
    taken_publisher: Publisher<ipc::Service, TakenFrames, ()>,
    /// Per publisher instance, the range taken so far (most recent last).
    taken: RefCell<Vec<TakenFrames>>,
    instance: u64,
    listener: Listener<ipc::Service>,
    ready_notifier: Notifier<ipc::Service>,
}

impl<F: Frame> std::fmt::Debug for FrameSubscriber<F> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FrameSubscriber")
            .field("service", &self.stream.service_name)
            .finish()
    }
}

/// What the listener reported since the last look.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Wakeups {
    pub frames_sent: usize,
    pub publisher_died: usize,
    /// Publishers that said hello (and were answered after connecting to them).
    pub publisher_hello: usize,
}

impl<F: Frame> FrameSubscriber<F> {
    pub(crate) fn new(stream: StreamConfig, services: StreamServices<F>) -> Result<Self, BusError> {
        let subscriber = services
            .frames
            .subscriber_builder()
            .buffer_size(stream.subscriber_buffer_size)
            .create()
            .map_err(|e| {
                BusError::ipc(format!("create subscriber on `{}`", stream.service_name), e)
            })?;
        let taken_publisher = services.taken.publisher_builder().create().map_err(|e| {
            BusError::ipc(
                format!("create publisher on `{}/taken`", stream.service_name),
                e,
            )
        })?;
        let listener = services.events.listener_builder().create().map_err(|e| {
            BusError::ipc(format!("create listener on `{}`", stream.service_name), e)
        })?;
        let ready_notifier = services
            .ready
            .notifier_builder()
            .default_event_id(EventId::new(EVENT_SUBSCRIBER_READY))
            .create()
            .map_err(|e| {
                BusError::ipc(
                    format!("create notifier on `{}/ready`", stream.service_name),
                    e,
                )
            })?;
        let this = Self {
            stream,
            frames: services.frames,
            subscriber,
            taken_publisher,
            taken: RefCell::new(Vec::new()),
            instance: crate::publisher::new_instance_id(),
            listener,
            ready_notifier,
        };
        this.attach()?;
        Ok(this)
    }

    pub fn service_name(&self) -> &str {
        &self.stream.service_name
    }

    /// Connects to every publisher registered now. iceoryx2 drops what a publisher sends
    /// before this side is connected, so call it right after creation (done by `new`) and
    /// whenever woken up (done by [`Self::drain`]).
    pub fn attach(&self) -> Result<(), BusError> {
        self.subscriber.update_connections().map_err(|e| {
            BusError::ipc(
                format!("connect subscriber on `{}`", self.stream.service_name),
                e,
            )
        })?;
        self.taken_publisher.update_connections().map_err(|e| {
            BusError::ipc(
                format!("connect publisher on `{}/taken`", self.stream.service_name),
                e,
            )
        })
    }

    pub fn publisher_count(&self) -> usize {
        self.frames.dynamic_config().number_of_publishers()
    }

    /// The listener to attach to a WaitSet.
    pub fn listener(&self) -> &Listener<ipc::Service> {
        &self.listener
    }

    /// Consumes the pending notifications (so the WaitSet does not wake again for them) and
    /// answers a publisher's hello: connect to it, then tell it that it may start streaming.
    pub fn take_wakeups(&self) -> Result<Wakeups, BusError> {
        let mut wakeups = Wakeups::default();
        self.listener
            .try_wait(|event| match event.id.as_value() {
                EVENT_PUBLISHER_DEAD => wakeups.publisher_died += 1,
                EVENT_PUBLISHER_HELLO => wakeups.publisher_hello += 1,
                _ => wakeups.frames_sent += 1,
            })
            .map_err(|e| BusError::ipc(format!("listen on `{}`", self.stream.service_name), e))?;
        if wakeups.publisher_hello > 0 {
            self.attach()?;
            self.ready_notifier.notify().map_err(|e| {
                BusError::ipc(format!("answer on `{}/ready`", self.stream.service_name), e)
            })?;
        }
        Ok(wakeups)
    }

    /// Hands up to `max` waiting frames to `consume`, in order; returns how many. Then tells
    /// their publishers what this subscriber has taken from them.
    pub fn drain(
        &self,
        max: usize,
        mut consume: impl FnMut(ReceivedFrame<'_, F>),
    ) -> Result<usize, BusError> {
        let mut count = 0;
        // Publisher instances whose frames this batch took (usually one).
        let mut touched: Vec<u64> = Vec::new();
        while count < max {
            let sample = self.subscriber.receive().map_err(|e| {
                BusError::ipc(format!("receive on `{}`", self.stream.service_name), e)
            })?;
            let Some(sample) = sample else { break };
            let header = *sample.user_header();
            consume(ReceivedFrame {
                header: &header,
                frame: sample.payload(),
                received_at_ns: monotonic_ns(),
            });
            self.record_taken(&header);
            if !touched.contains(&header.publisher_instance) {
                touched.push(header.publisher_instance);
            }
            count += 1;
        }
        for instance in touched {
            self.acknowledge(instance)?;
        }
        Ok(count)
    }

    fn record_taken(&self, header: &FrameHeader) {
        let mut taken = self.taken.borrow_mut();
        match taken
            .iter_mut()
            .find(|t| t.publisher_instance == header.publisher_instance)
        {
            Some(t) => {
                t.first_sequence = t.first_sequence.min(header.sequence);
                t.last_sequence = t.last_sequence.max(header.sequence);
            }
            None => {
                if taken.len() == TAKEN_PUBLISHERS {
                    taken.remove(0);
                }
                taken.push(TakenFrames {
                    publisher_instance: header.publisher_instance,
                    subscriber_instance: self.instance,
                    first_sequence: header.sequence,
                    last_sequence: header.sequence,
                });
            }
        }
    }

    /// Sends the range taken from publisher `instance` (never blocks: safe overflow).
    fn acknowledge(&self, instance: u64) -> Result<(), BusError> {
        let Some(ack) = self
            .taken
            .borrow()
            .iter()
            .find(|t| t.publisher_instance == instance)
            .copied()
        else {
            return Ok(());
        };
        self.taken_publisher
            .send_copy(ack)
            .map(|_| ())
            .map_err(|e| BusError::ipc(format!("send on `{}/taken`", self.stream.service_name), e))
    }
}
