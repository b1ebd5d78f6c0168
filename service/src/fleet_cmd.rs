//! `railmon fleet`: the fleet view over the vehicles' JetStream stream (docs/fleet.md), with
//! the same settings file style as `railmon serve` (its `[fleet]` and `[http]` sections).

use std::path::PathBuf;

use anyhow::Context;
use railmon_service::ServiceConfig;

#[derive(clap::Args)]
pub struct FleetArgs {
    /// Config file (TOML); `[fleet]` (NATS url, credentials, stream, listen address) and
    /// `[http]` (limits) apply. RAILMON_FLEET__<KEY> environment variables override it (e.g.
    /// RAILMON_FLEET__URL=nats://ground:4222).
    #[arg(long, env = "RAILMON_CONFIG")]
    config: Option<PathBuf>,
    /// Writes the bound HTTP address (host:port) to this file once listening (for
    /// `fleet.listen` with port 0).
    #[arg(long)]
    addr_file: Option<PathBuf>,
    /// Creates the stream (`fleet.stream`, subjects `<fleet.subject_prefix>.>`, file storage,
    /// the uplink's duplicate window) with this many replicas (1..=5) when the servers have none,
    /// retrying for up to a minute while a cluster elects its leader; an existing stream is used
    /// as it is. For a ground whose vehicles may not create streams (compose.yaml's fleet).
    #[arg(long, value_name = "REPLICAS", value_parser = clap::value_parser!(u8).range(1..=5))]
    create_stream: Option<u8>,
}

pub fn run(args: FleetArgs) -> anyhow::Result<()> {
    let config = ServiceConfig::load(args.config.as_deref(), std::env::vars())
        .context("invalid configuration")?;
    let fleet = config.fleet.clone();
    if fleet.url.trim().is_empty() {
        anyhow::bail!("invalid configuration: fleet.url is empty: set the NATS server(s) holding the vehicles' stream");
    }
    let addr = fleet.listen_addr().context("invalid configuration")?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("tokio runtime")?;
    runtime.block_on(async {
        let reader =
            railmon_service::fleet::Fleet::connect(&fleet, args.create_stream.map(usize::from))
                .await
                .with_context(|| format!("reading the stream {} at {}", fleet.stream, fleet.url))?;
        let listener = tokio::net::TcpListener::bind(addr)
            .await
            .with_context(|| format!("cannot listen on {addr} (fleet.listen)"))?;
        let bound = listener.local_addr()?;
        tracing::info!(
            stream = %fleet.stream,
            "fleet view on http://{bound} (API /api/v1, docs /docs)"
        );
        if let Some(file) = &args.addr_file {
            let mut out = railmon_records::AtomicFile::create(file)?;
            std::io::Write::write_all(&mut out, bound.to_string().as_bytes())
                .with_context(|| format!("writing {}", file.display()))?;
            out.commit()?;
        }
        let app = railmon_service::fleet::routes::app(reader, &config.http);
        let counters = std::sync::Arc::default();
        railmon_service::http::server::serve(
            listener,
            app,
            &config.http,
            counters,
            crate::serve::termination(),
        )
        .await;
        anyhow::Ok(())
    })
}
