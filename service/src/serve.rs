//! `railmon serve`: config, state, ingest threads, HTTP server, graceful shutdown.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use anyhow::Context;
use railmon_service::{app, start_ingest, AppState, ServiceConfig};

#[derive(clap::Args)]
pub struct ServeArgs {
    /// Config file (TOML); without it the embedded defaults apply. RAILMON_<SECTION>__<KEY>
    /// environment variables override both (e.g. RAILMON_HTTP__LISTEN=127.0.0.1:9000).
    #[arg(long, env = "RAILMON_CONFIG")]
    config: Option<PathBuf>,
    /// Writes the bound HTTP address (host:port) to this file once listening (for
    /// `http.listen` with port 0).
    #[arg(long)]
    addr_file: Option<PathBuf>,
}

/// Human-readable logs, or JSON lines; the filter comes from RAILMON_LOG (default `info`).
pub fn init_tracing(json: bool) {
    let filter = tracing_subscriber::EnvFilter::try_from_env("RAILMON_LOG")
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_writer(std::io::stderr);
    if json {
        builder.json().init();
    } else {
        builder.init();
    }
}

pub fn run(args: ServeArgs) -> anyhow::Result<()> {
    let config = ServiceConfig::load(args.config.as_deref(), std::env::vars())
        .context("invalid configuration")?;
    let addr = config.listen_addr()?;
    let state = AppState::new(config).context("starting the service")?;
    let state_for_close = state.clone();
    let shutdown = Arc::new(AtomicBool::new(false));
    let threads = start_ingest(&state, shutdown.clone()).context("starting ingest threads")?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("tokio runtime")?;
    let served = runtime.block_on(async {
        let listener = tokio::net::TcpListener::bind(addr)
            .await
            .with_context(|| format!("cannot listen on {addr} (http.listen)"))?;
        let bound = listener.local_addr()?;
        tracing::info!("listening on http://{bound} (API /api/v1, docs /docs, metrics /metrics)");
        if let Some(file) = &args.addr_file {
            // Whole or not at all: a reader polling for the file never sees half an address.
            let mut out = railmon_records::AtomicFile::create(file)?;
            std::io::Write::write_all(&mut out, bound.to_string().as_bytes())
                .with_context(|| format!("writing {}", file.display()))?;
            out.commit()?;
        }
        let http = state.config.http.clone();
        let counters = state.http.clone();
        railmon_service::http::server::serve(listener, app(state), &http, counters, termination())
            .await;
        anyhow::Ok(())
    });
    // Stop the ingest threads even if serving failed; they drop their iceoryx2 ports on exit.
    shutdown.store(true, Ordering::Relaxed);
    for thread in threads {
        if thread.join().is_err() {
            tracing::error!("an ingest thread panicked");
        }
    }
    // Then every event they raised is written before the process ends.
    state_for_close.close_store();
    tracing::info!("stopped");
    served
}

/// Resolves on SIGINT or SIGTERM.
async fn termination() {
    use tokio::signal::unix::{signal, SignalKind};
    let mut term = match signal(SignalKind::terminate()) {
        Ok(term) => term,
        Err(e) => {
            tracing::error!("cannot watch SIGTERM: {e}");
            let _ = tokio::signal::ctrl_c().await;
            return;
        }
    };
    tokio::select! {
        _ = tokio::signal::ctrl_c() => tracing::info!("SIGINT: shutting down"),
        _ = term.recv() => tracing::info!("SIGTERM: shutting down"),
    }
}
