//! A three-node `nats-server` JetStream cluster on loopback ports, as a ground would run it:
//! for tests/tests/uplink_cluster.rs and the many-vehicle simulation
//! (examples/fleet_load.rs). Needs `nats-server` (see [`crate::nats`]).

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::monitoring::free_addr;
use crate::nats::with_client;
use crate::Process;

pub const NODES: usize = 3;

/// One node of the cluster.
pub struct Node {
    pub name: String,
    pub client_addr: String,
    pub process: Process,
}

/// Starts `NODES` `nats-server`s with JetStream, routed to each other, each with its config
/// file and store under `dir`. `no_advertise`: otherwise a server tells its clients the other
/// nodes' client addresses and the service's client fails over to them past the proxy (a
/// first run saw the cursor move from 14 to 164 during the cut).
pub fn start_cluster(binary: &Path, dir: &Path) -> Vec<Node> {
    let client_addrs: Vec<String> = (0..NODES).map(|_| free_addr()).collect();
    let route_addrs: Vec<String> = (0..NODES).map(|_| free_addr()).collect();
    let routes: Vec<String> = route_addrs
        .iter()
        .map(|a| format!("\"nats-route://{a}\""))
        .collect();
    (0..NODES)
        .map(|i| {
            let name = format!("n{i}");
            let store = dir.join(&name);
            std::fs::create_dir_all(&store).unwrap();
            let config = dir.join(format!("{name}.conf"));
            std::fs::write(
                &config,
                format!(
                    "server_name: {name}\nlisten: \"{}\"\njetstream {{ store_dir: \"{}\" }}\n\
                     cluster {{\n  name: railmon-test\n  listen: \"{}\"\n  routes: [{}]\n  \
                     no_advertise: true\n}}\n",
                    client_addrs[i],
                    store.display(),
                    route_addrs[i],
                    routes.join(", ")
                ),
            )
            .unwrap();
            let child = Command::new(binary)
                .arg("-c")
                .arg(&config)
                .stdin(Stdio::null())
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .expect("starting nats-server");
            Node {
                name: name.clone(),
                client_addr: client_addrs[i].clone(),
                process: Process {
                    child,
                    name: format!("nats-server {name}"),
                },
            }
        })
        .collect()
}

/// Creates the stream with 3 replicas (as a ground would, before any vehicle connects; the
/// uplink uses an existing stream as it is), retrying until the cluster has elected its meta
/// leader and every peer is known. Returns how long that took.
pub fn create_replicated_stream(url: &str, stream: &str, timeout: Duration) -> Duration {
    let start = Instant::now();
    with_client(url, async |client| {
        let js = async_nats::jetstream::new(client);
        loop {
            let created = js
                .create_stream(async_nats::jetstream::stream::Config {
                    name: stream.into(),
                    subjects: vec!["railmon.>".into()],
                    // The uplink's own choice for a stream it creates (service/src/uplink).
                    duplicate_window: Duration::from_secs(120),
                    storage: async_nats::jetstream::stream::StorageType::File,
                    num_replicas: NODES,
                    ..Default::default()
                })
                .await;
            match created {
                Ok(_) => return start.elapsed(),
                Err(e) => assert!(
                    start.elapsed() < timeout,
                    "no replicated stream within {timeout:?}: {e}"
                ),
            }
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
    })
}
