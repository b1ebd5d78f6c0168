//! The railmon iceoryx2 bus: zero-copy payloads, service names, publisher and subscriber helpers.
//!
//! One publish-subscribe service per stream (`drive`, `bogie`, `vehicle`) carries `#[repr(C)]`
//! frames with a [`FrameHeader`] user header (per-publisher sequence number and CLOCK_MONOTONIC
//! timestamp); an event service of the same name wakes the subscriber's WaitSet. The iceoryx2 0.10
//! traps this crate defends against (see `shared/docs/bus-notes.md`):
//! - samples sent before the subscriber attaches are lost: [`FramePublisher::wait_for_subscriber`]
//!   waits for a subscriber's hand-shake, and [`FrameSubscriber::attach`] connects early;
//! - a SIGKILLed subscriber blocks a lossless publisher: the backpressure handler gives up on a
//!   full subscriber after `backpressure_timeout_ms`, and [`FramePublisher::resend`] sends the
//!   frame again under its number once a live subscriber answers;
//! - stale shared memory after a crash: [`BusNode::create`] cleans up dead nodes;
//! - a killed subscriber takes the frames in its buffer with it: subscribers acknowledge what
//!   they took ([`taken`]), so the publisher counts what nobody took;
//! - signals: nodes and WaitSets never install signal handlers (the binaries own SIGINT/SIGTERM);
//! - ports are not `Send`: each thread creates its own [`BusNode`] and ports.

mod clock;
pub mod config;
mod error;
pub mod frames;
mod node;
pub mod utc;
pub use node::iceoryx2_config;
mod publisher;
pub mod root_path;
mod subscriber;
pub mod taken;

pub use clock::monotonic_ns;
pub use config::{BusConfig, StreamConfig, StreamKind};
pub use error::BusError;
pub use frames::{
    BogieFrame, DriveChannels, DriveFrame, Frame, FrameError, FrameHeader, VehicleFrame,
    FRAME_LAYOUT_VERSION, MAX_DRIVES,
};
pub use node::BusNode;
pub use publisher::{utc_now_ns, FramePublisher};
pub use root_path::RootPath;
pub use subscriber::{FrameSubscriber, ReceivedFrame, Wakeups};
pub use taken::{TakenFrames, TakenLedger, TakenReport};

/// The WaitSet type the subscriber side attaches listeners to.
pub type WaitSet = iceoryx2::prelude::WaitSet<iceoryx2::prelude::ipc::Service>;
