use std::sync::atomic::AtomicBool;

use iceoryx2::config::Config;
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::{event, publish_subscribe};

use crate::root_path::{resolve_root_path, RootPath};
use crate::taken::{TakenFrames, TAKEN_BUFFER};
use crate::{
    BusConfig, BusError, Frame, FrameHeader, FramePublisher, FrameSubscriber, StreamConfig, WaitSet,
};

/// Shipped iceoryx2 settings (`config/iceoryx2.toml`), embedded so that no process depends on
/// its working directory and iceoryx2 never falls back to its "no config file" warning.
const ICEORYX2_CONFIG_TOML: &str = include_str!("../../config/iceoryx2.toml");

/// Event ids on a stream's event service (publishers notify, subscribers listen).
pub(crate) const EVENT_FRAMES_SENT: usize = 1;
pub(crate) const EVENT_PUBLISHER_DEAD: usize = 2;
/// "I exist, connect to me": sent by a publisher until a subscriber answers.
pub(crate) const EVENT_PUBLISHER_HELLO: usize = 3;
/// Event id on the stream's `<service>/ready` event service (subscribers notify, publishers
/// listen): "I updated my connections after your hello".
pub(crate) const EVENT_SUBSCRIBER_READY: usize = 4;

/// The services of one stream: frames, data events, readiness answers, and what the
/// subscribers took ([`crate::taken`]).
pub(crate) struct StreamServices<F: Frame> {
    pub(crate) frames: PubSubFactory<F>,
    pub(crate) events: EventFactory,
    pub(crate) ready: EventFactory,
    pub(crate) taken: TakenFactory,
}

pub(crate) type PubSubFactory<F> = publish_subscribe::PortFactory<ipc::Service, F, FrameHeader>;
pub(crate) type TakenFactory = publish_subscribe::PortFactory<ipc::Service, TakenFrames, ()>;
pub(crate) type EventFactory = event::PortFactory<ipc::Service>;

/// One iceoryx2 node of this process (one per thread that owns ports: ports are not `Send`).
pub struct BusNode {
    node: Node<ipc::Service>,
    config: BusConfig,
    root_path: RootPath,
    cleaned_at_start: u64,
}

impl std::fmt::Debug for BusNode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BusNode")
            .field("name", &self.node.name().as_str())
            .field("prefix", &self.config.prefix)
            .finish()
    }
}

/// The iceoryx2 config for `bus`: the shipped file with railmon's prefix and `root_path`
/// (resolved by [`crate::root_path::resolve_root_path`]).
pub fn iceoryx2_config(bus: &BusConfig, root_path: &str) -> Result<Config, BusError> {
    let mut config: Config = toml::from_str(ICEORYX2_CONFIG_TOML)
        .map_err(|e| BusError::ipc("embedded config/iceoryx2.toml", e.to_string()))?;
    config.global.prefix = FileName::new(bus.prefix.as_bytes()).map_err(|e| BusError::Config {
        key: "bus.prefix".into(),
        reason: format!("`{}`: {e:?}", bus.prefix),
    })?;
    let root = Path::new(root_path.as_bytes()).map_err(|e| BusError::Config {
        key: "bus.root_path".into(),
        reason: format!("`{root_path}`: {e:?}"),
    })?;
    config.global.set_root_path(&root);
    Ok(config)
}

/// Where POSIX shared memory (`shm_open`) lives on Linux: iceoryx2's segments.
const SHM_DIR: &str = "/dev/shm";

/// Whether `file_name` is the global management segment of the bus with `prefix`:
/// `<prefix><40 hex digits>_node.<major>_<minor>_<patch>.global_mgmt` (iceoryx2 0.10,
/// `node/global_management_segment.rs`). Exact, so that prefix `railmon_` does not match the
/// segment of prefix `railmon_demo_`.
fn is_global_management_segment(file_name: &str, prefix: &str) -> bool {
    let Some(rest) = file_name.strip_prefix(prefix) else {
        return false;
    };
    let Some((hash, rest)) = rest.split_once("_node.") else {
        return false;
    };
    hash.len() == 40
        && hash.bytes().all(|b| b.is_ascii_hexdigit())
        && rest
            .strip_suffix(".global_mgmt")
            .is_some_and(|version| version.split('_').all(|n| n.parse::<u32>().is_ok()))
}

/// iceoryx2 creates its global management segment (16 bytes in /dev/shm: the node counter)
/// with `enable_global_access(true)`, i.e. `fchmod` to 0666 after creation (so a umask does
/// not help), and keeps it when the last node ends (`has_ownership(false)`). Every other file
/// of the bus is 0600 or under the private root path (crate::root_path): railmon's bus
/// belongs to one user, so this one is made 0600 too, right after the node opened it. Only
/// our own file is changed (one of another user is left alone: `chmod` would fail anyway).
fn make_global_management_segment_private(prefix: &str) -> Result<(), BusError> {
    use std::os::unix::fs::{MetadataExt, PermissionsExt};
    let entries = match std::fs::read_dir(SHM_DIR) {
        Ok(entries) => entries,
        // Not Linux's /dev/shm: nothing we know how to fix.
        Err(_) => return Ok(()),
    };
    // SAFETY: geteuid(2) has no preconditions and cannot fail.
    let euid = unsafe { libc::geteuid() };
    for entry in entries.flatten() {
        let name = entry.file_name();
        if !is_global_management_segment(&name.to_string_lossy(), prefix) {
            continue;
        }
        let Ok(meta) = entry.metadata() else { continue };
        if meta.uid() != euid || meta.mode() & 0o077 == 0 {
            continue;
        }
        std::fs::set_permissions(entry.path(), std::fs::Permissions::from_mode(0o600)).map_err(
            |e| BusError::ipc(format!("make {} private (0600)", entry.path().display()), e),
        )?;
    }
    Ok(())
}

impl BusNode {
    /// Creates a node that installs no signal handler and first removes what dead nodes (a
    /// SIGKILLed service or replay) left in shared memory and under the root path.
    pub fn create(config: &BusConfig, name: &str) -> Result<Self, BusError> {
        config.validate()?;
        let xdg_runtime_dir = std::env::var("XDG_RUNTIME_DIR").ok();
        let root_path = resolve_root_path(&config.root_path, xdg_runtime_dir.as_deref())?;
        let ipc_config = iceoryx2_config(config, &root_path.path)?;
        let node_name =
            NodeName::new(name).map_err(|e| BusError::ipc(format!("node name `{name}`"), e))?;
        let node = NodeBuilder::new()
            .name(&node_name)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .config(&ipc_config)
            .create::<ipc::Service>()
            .map_err(|e| BusError::ipc(format!("create node `{name}`"), e))?;
        make_global_management_segment_private(&config.prefix)?;
        // Node creation already cleans dead nodes (config/iceoryx2.toml); the explicit call
        // catches nodes that died in between and gives the caller a number to log.
        let cleaned_at_start = node.try_cleanup_dead_nodes().cleanups;
        Ok(Self {
            node,
            config: config.clone(),
            root_path,
            cleaned_at_start,
        })
    }

    /// The root path in use, and why earlier candidates of the default were not used.
    pub fn root_path(&self) -> &RootPath {
        &self.root_path
    }

    pub fn config(&self) -> &BusConfig {
        &self.config
    }

    /// Dead nodes removed when this node was created.
    pub fn cleaned_at_start(&self) -> u64 {
        self.cleaned_at_start
    }

    /// Removes resources of nodes that died since (their processes are gone); returns how many.
    /// Also wakes listeners of the dead publishers' event services.
    pub fn cleanup_dead_nodes(&self) -> u64 {
        self.node.try_cleanup_dead_nodes().cleanups
    }

    /// A WaitSet that leaves signals to the application.
    pub fn waitset(&self) -> Result<WaitSet, BusError> {
        WaitSetBuilder::new()
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()
            .map_err(|e| BusError::ipc("create WaitSet", e))
    }

    pub fn publisher<F: Frame>(&self) -> Result<FramePublisher<F>, BusError> {
        self.publisher_stopped_by(None)
    }

    /// A publisher whose sends stop waiting on a full subscriber as soon as `stop` is set
    /// (a replay must react to SIGTERM within 100 ms, also while a stalled service holds it).
    pub fn publisher_stopped_by<F: Frame>(
        &self,
        stop: Option<&'static AtomicBool>,
    ) -> Result<FramePublisher<F>, BusError> {
        let stream = self.config.stream(F::STREAM);
        let services = self.open_services::<F>(&stream)?;
        FramePublisher::new(stream, services, stop)
    }

    pub fn subscriber<F: Frame>(&self) -> Result<FrameSubscriber<F>, BusError> {
        let stream = self.config.stream(F::STREAM);
        let services = self.open_services::<F>(&stream)?;
        FrameSubscriber::new(stream, services)
    }

    fn open_services<F: Frame>(
        &self,
        stream: &StreamConfig,
    ) -> Result<StreamServices<F>, BusError> {
        let service_name = |name: &str| {
            ServiceName::new(name).map_err(|e| BusError::Config {
                key: format!("bus.{}.service_name", F::STREAM),
                reason: format!("`{name}`: {e:?}"),
            })
        };
        let name = service_name(&stream.service_name)?;
        let ready_name = format!("{}/ready", stream.service_name);
        let frames = self
            .node
            .service_builder(&name)
            .publish_subscribe::<F>()
            .user_header::<FrameHeader>()
            .enable_safe_overflow(stream.safe_overflow)
            .subscriber_max_buffer_size(stream.subscriber_buffer_size)
            .history_size(0)
            .open_or_create()
            .map_err(|e| {
                BusError::ipc(
                    format!("open publish-subscribe service `{}`", stream.service_name),
                    e,
                )
            })?;
        let events = self
            .node
            .service_builder(&name)
            .event()
            .notifier_dead_event(EventId::new(EVENT_PUBLISHER_DEAD))
            .open_or_create()
            .map_err(|e| {
                BusError::ipc(format!("open event service `{}`", stream.service_name), e)
            })?;
        let ready = self
            .node
            .service_builder(&service_name(&ready_name)?)
            .event()
            .open_or_create()
            .map_err(|e| BusError::ipc(format!("open event service `{ready_name}`"), e))?;
        let taken_name = format!("{}/taken", stream.service_name);
        let taken = self
            .node
            .service_builder(&service_name(&taken_name)?)
            .publish_subscribe::<TakenFrames>()
            .enable_safe_overflow(true)
            .subscriber_max_buffer_size(TAKEN_BUFFER)
            .history_size(0)
            .open_or_create()
            .map_err(|e| {
                BusError::ipc(format!("open publish-subscribe service `{taken_name}`"), e)
            })?;
        Ok(StreamServices {
            frames,
            events,
            ready,
            taken,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_global_management_segment_is_recognised_for_its_prefix_only() {
        let name = "railmon_9204dd183d1c4d8e1ff592a30766ffa6765aa8b5_node.0_10_0.global_mgmt";
        assert!(is_global_management_segment(name, "railmon_"));
        let demo = "railmon_demo_9204dd183d1c4d8e1ff592a30766ffa6765aa8b5_node.0_10_0.global_mgmt";
        assert!(!is_global_management_segment(demo, "railmon_"));
        assert!(is_global_management_segment(demo, "railmon_demo_"));
        let dynamic = "railmon_112437a14a36c452eeea7e2aefc2af954fc5a3f2_1584568348.dynamic";
        assert!(!is_global_management_segment(dynamic, "railmon_"));
        let other = "railmon_9204dd183d1c4d8e1ff592a30766ffa6765aa8b5_node.0_10_0.event_mgmt";
        assert!(!is_global_management_segment(other, "railmon_"));
    }
}
