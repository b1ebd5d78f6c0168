//! `railmon serve`: bus -> estimators -> HTTP API and Prometheus metrics.
//!
//! Data path, in one direction: an ingest thread per stream ([`stream::run_ingest`]) owns the
//! iceoryx2 subscriber and the stream's [`stream::Pipeline`] (for drives:
//! [`drive::DrivePipeline`] over `railmon_slip::SlipMonitor`) and publishes results through
//! atomics, `arc-swap` snapshots and non-blocking rings; the axum handlers ([`http::app`]) only
//! read those. Adding the bogie or vehicle stream means a `Pipeline` for its frame type and
//! one more ingest thread in [`start_ingest`].

pub mod config;
pub mod drive;
pub mod http;
pub mod metrics;
pub mod ring;
pub mod stream;

use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

pub use config::ServiceConfig;
pub use http::app;

use drive::{DrivePipeline, DriveShared};
use metrics::Metrics;
use railmon_bus::StreamKind;
use stream::StreamStatus;

/// Everything the HTTP handlers read; cheap to clone.
#[derive(Clone)]
pub struct AppState(Arc<AppInner>);

pub struct AppInner {
    pub config: ServiceConfig,
    pub metrics: Arc<Metrics>,
    pub drive: Arc<DriveShared>,
    /// The enabled streams (those `/readyz` requires).
    pub streams: Vec<Arc<StreamStatus>>,
    pub started: Instant,
}

impl std::ops::Deref for AppState {
    type Target = AppInner;
    fn deref(&self) -> &AppInner {
        &self.0
    }
}

impl AppState {
    pub fn new(config: ServiceConfig) -> Result<Self, prometheus::Error> {
        let metrics = Arc::new(Metrics::new()?);
        let drive = Arc::new(DriveShared::new(&config.drive));
        let mut streams = Vec::new();
        if config.drive.enabled {
            streams.push(Arc::new(StreamStatus::new(
                StreamKind::Drive,
                Duration::from_millis(config.drive.stale_after_ms),
                metrics.clone(),
            )));
        }
        Ok(Self(Arc::new(AppInner {
            config,
            metrics,
            drive,
            streams,
            started: Instant::now(),
        })))
    }

    fn stream(&self, kind: StreamKind) -> Option<Arc<StreamStatus>> {
        self.streams.iter().find(|s| s.kind == kind).cloned()
    }
}

/// Starts one ingest thread per enabled stream; they stop when `shutdown` is set.
pub fn start_ingest(
    state: &AppState,
    shutdown: Arc<AtomicBool>,
) -> std::io::Result<Vec<JoinHandle<()>>> {
    let mut threads = Vec::new();
    if let Some(status) = state.stream(StreamKind::Drive) {
        let config = state.config.clone();
        let mut pipeline = DrivePipeline::new(
            config.drive.clone(),
            state.drive.clone(),
            state.metrics.clone(),
        );
        let shutdown = shutdown.clone();
        threads.push(
            std::thread::Builder::new()
                .name("ingest-drive".into())
                .spawn(move || {
                    // A bus failure (e.g. /dev/shm full) is recorded in the status and retried:
                    // the HTTP side stays up and /readyz says the stream is not fresh.
                    while let Err(e) = stream::run_ingest(
                        &config.bus,
                        &config.ingest,
                        &mut pipeline,
                        &status,
                        &shutdown,
                    ) {
                        tracing::error!(stream = "drive", "ingest failed, retrying in 1 s: {e}");
                        for _ in 0..20 {
                            if shutdown.load(std::sync::atomic::Ordering::Relaxed) {
                                return;
                            }
                            std::thread::sleep(Duration::from_millis(50));
                        }
                    }
                })?,
        );
    }
    Ok(threads)
}
