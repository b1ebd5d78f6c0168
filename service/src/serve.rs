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

/// Human-readable logs, or JSON lines, on stderr. The filter (`info`, `warn`,
/// `railmon_service=debug,info`, ...) comes from `RAILMON_LOG`, else from the conventional
/// `RUST_LOG`, else `info`; a filter that does not parse is said once and `info` applies.
pub fn init_tracing(json: bool) {
    let (filter, refused) = log_filter(|name| std::env::var(name).ok());
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_writer(std::io::stderr);
    if json {
        builder.json().init();
    } else {
        builder.init();
    }
    if let Some((name, value, e)) = refused {
        tracing::warn!("{name}={value:?} is not a log filter ({e}); logging at info");
    }
}

/// The variables that set the log filter, the first set one wins.
const LOG_FILTER_VARIABLES: [&str; 2] = ["RAILMON_LOG", "RUST_LOG"];

/// The log filter from the environment (`var` reads a variable), and the variable that did not
/// parse, if any.
fn log_filter(
    var: impl Fn(&str) -> Option<String>,
) -> (
    tracing_subscriber::EnvFilter,
    Option<(&'static str, String, String)>,
) {
    use tracing_subscriber::EnvFilter;
    let set = LOG_FILTER_VARIABLES.iter().find_map(|&name| {
        var(name)
            .filter(|v| !v.trim().is_empty())
            .map(|v| (name, v))
    });
    match set {
        None => (EnvFilter::new("info"), None),
        Some((name, value)) => match EnvFilter::try_new(&value) {
            Ok(filter) => (filter, None),
            Err(e) => (EnvFilter::new("info"), Some((name, value, e.to_string()))),
        },
    }
}

pub fn run(args: ServeArgs) -> anyhow::Result<()> {
    let config = ServiceConfig::load(args.config.as_deref(), std::env::vars())
        .context("invalid configuration")?;
    // A file size limit (RLIMIT_FSIZE) reached gives write errors (EFBIG), which the event
    // store and the snapshots handle, instead of killing the process.
    // SAFETY: sets a signal's disposition to ignore; no handler runs.
    unsafe { libc::signal(libc::SIGXFSZ, libc::SIG_IGN) };
    let addr = config.listen_addr()?;
    // The bus root path is checked once here: an unusable one (another user's, open to others,
    // a symlink) is a setting to fix, not a bus failure the ingest threads would retry for ever.
    let xdg_runtime_dir = std::env::var("XDG_RUNTIME_DIR").ok();
    railmon_bus::root_path::resolve_root_path(&config.bus.root_path, xdg_runtime_dir.as_deref())
        .context("invalid configuration")?;
    let state = AppState::new(config).context("starting the service")?;
    if state.config.uplink.enabled() {
        railmon_service::uplink::check_identity(&state.identity)
            .map_err(anyhow::Error::msg)
            .context("invalid configuration")?;
    }
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
        if state.config.uplink.enabled() {
            // Its own task: a slow or lost link never holds up the estimators or the store's
            // writer; it stops with the runtime (its cursor is committed after every page).
            tokio::spawn(railmon_service::uplink::run(
                state.store.clone(),
                state.config.uplink.clone(),
                state.uplink.clone(),
            ));
            // Latest wins, on its own connection: a summary never waits behind the events.
            tokio::spawn(railmon_service::uplink::health::run(
                state.clone(),
                state.health.clone(),
            ));
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
    // Then every event they raised is written before the process ends, or counted and logged.
    let dropped = state_for_close.close_store();
    served?;
    if dropped > 0 {
        anyhow::bail!(
            "stopped with {dropped} events not stored: the event database did not take writes"
        );
    }
    tracing::info!("stopped");
    Ok(())
}

/// Resolves on SIGINT or SIGTERM.
pub async fn termination() {
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

#[cfg(test)]
mod tests {
    use super::log_filter;

    fn filter_of(vars: &[(&str, &str)]) -> (String, bool) {
        let (filter, refused) = log_filter(|name| {
            vars.iter()
                .find(|(k, _)| *k == name)
                .map(|(_, v)| v.to_string())
        });
        (filter.to_string(), refused.is_some())
    }

    #[test]
    fn railmon_log_overrides_rust_log_which_overrides_info() {
        assert_eq!(filter_of(&[]), ("info".into(), false));
        assert_eq!(filter_of(&[("RUST_LOG", "debug")]), ("debug".into(), false));
        assert_eq!(
            filter_of(&[("RUST_LOG", "debug"), ("RAILMON_LOG", "warn")]),
            ("warn".into(), false)
        );
        // An empty RAILMON_LOG is not set.
        assert_eq!(
            filter_of(&[("RUST_LOG", "debug"), ("RAILMON_LOG", "")]),
            ("debug".into(), false)
        );
        assert_eq!(filter_of(&[("RUST_LOG", "info,[")]), ("info".into(), true));
    }
}
