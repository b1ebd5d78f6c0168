//! `railmon serve`: bus -> estimators -> HTTP API and Prometheus metrics.
//!
//! Data path, in one direction: an ingest thread per stream ([`ingest::run_ingest`]) owns the
//! iceoryx2 subscriber and the stream's [`ingest::Pipeline`] (drives:
//! [`drive::DrivePipeline`] over `railmon_slip::SlipMonitor`; vehicle:
//! [`vehicle::VehiclePipeline`] over `railmon_fuel::FuelMonitor`; bogies:
//! [`bogie::BogiePipeline`], one `railmon_damper::DamperMonitor` per bogie) and publishes results through
//! atomics, `arc-swap` snapshots and non-blocking rings ([`outbox`]); the axum handlers
//! ([`app::app`]) only read those. A stream is a folder (`drive/`, `bogie/`, `vehicle/`):
//! its config section, its view (JSON), its `Pipeline`, its routes and its metric families;
//! here it takes an outbox and one [`spawn_ingest`] call in [`start_ingest`].

pub mod app;
pub mod bogie;
pub mod config;
pub mod drive;
pub mod fleet;
pub mod http;
pub mod ingest;
pub mod metrics;
pub mod nats_client;
pub mod outbox;
pub mod ring;
pub mod snapshot;
pub mod store;
mod stream_keys;
pub mod uplink;
pub mod vehicle;

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

pub use app::app;
pub use config::ServiceConfig;

use bogie::{BogiePipeline, BogieShared};
use drive::{DrivePipeline, DriveShared};
use ingest::{Pipeline, StreamStatus};
use metrics::Metrics;
use railmon_bus::{Frame, StreamKind};
use vehicle::{VehiclePipeline, VehicleShared};

/// Everything the HTTP handlers read; cheap to clone.
#[derive(Clone)]
pub struct AppState(Arc<AppInner>);

pub struct AppInner {
    pub config: ServiceConfig,
    /// The vehicle, as every answer, event and metric names it.
    pub identity: config::Identity,
    pub metrics: Arc<Metrics>,
    pub drive: Arc<DriveShared>,
    pub vehicle: Arc<VehicleShared>,
    pub bogie: Arc<BogieShared>,
    /// The enabled streams (those `/readyz` requires).
    pub streams: Vec<Arc<StreamStatus>>,
    /// Connections the HTTP server refused or cut.
    pub http: Arc<http::server::HttpCounters>,
    /// Events of every stream and the active alarms (SQLite under `storage.data_dir`).
    pub store: Arc<store::EventStore>,
    store_writer: std::sync::Mutex<Option<JoinHandle<()>>>,
    /// The event uplink's counters (all 0 while `uplink.url` is empty).
    pub uplink: Arc<uplink::UplinkCounters>,
    /// The health publisher's counters (all 0 while `uplink.url` is empty).
    pub health: Arc<uplink::health::HealthCounters>,
    pub started: Instant,
}

/// Why the service could not start.
#[derive(Debug, thiserror::Error)]
pub enum StartError {
    #[error("metrics registry: {0}")]
    Metrics(#[from] prometheus::Error),
    #[error(transparent)]
    Store(#[from] store::StoreError),
}

impl std::ops::Deref for AppState {
    type Target = AppInner;
    fn deref(&self) -> &AppInner {
        &self.0
    }
}

impl AppState {
    /// Opens the event store and sets up every enabled stream's status and outbox.
    pub fn new(config: ServiceConfig) -> Result<Self, StartError> {
        let identity = config.identity.resolve();
        let metrics = Arc::new(Metrics::with_identity(&identity)?);
        let (store, store_writer) = store::EventStore::open(&config.storage, &identity)?;
        let drive = Arc::new(config.drive.outbox(store.clone()));
        let vehicle = Arc::new(config.vehicle.outbox(store.clone()));
        let bogie = Arc::new(config.bogie.outbox(store.clone()));
        let status = |kind, stale_after_ms, reasons| {
            Arc::new(StreamStatus::new(
                kind,
                Duration::from_millis(stale_after_ms),
                metrics.clone(),
                reasons,
            ))
        };
        let mut streams = Vec::new();
        if config.drive.enabled {
            streams.push(status(
                StreamKind::Drive,
                config.drive.stale_after_ms,
                DrivePipeline::REJECTION_REASONS,
            ));
        }
        if config.bogie.enabled {
            streams.push(status(
                StreamKind::Bogie,
                config.bogie.stale_after_ms,
                BogiePipeline::REJECTION_REASONS,
            ));
        }
        if config.vehicle.enabled {
            streams.push(status(
                StreamKind::Vehicle,
                config.vehicle.stale_after_ms,
                VehiclePipeline::REJECTION_REASONS,
            ));
        }
        Ok(Self(Arc::new(AppInner {
            config,
            identity,
            metrics,
            drive,
            vehicle,
            bogie,
            streams,
            http: Arc::default(),
            store,
            store_writer: std::sync::Mutex::new(Some(store_writer)),
            uplink: Arc::default(),
            health: Arc::default(),
            started: Instant::now(),
        })))
    }

    /// Writes every event still queued and stops the store's writer thread (at shutdown, after
    /// the ingest threads stopped); returns how many could not be written (counted, logged).
    pub fn close_store(&self) -> u64 {
        let dropped = self.store.close();
        let writer = self
            .store_writer
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .take();
        if let Some(writer) = writer {
            if writer.join().is_err() {
                tracing::error!("the event store's writer thread panicked");
            }
        }
        dropped
    }

    /// The status of `kind`, if that stream is enabled.
    pub fn stream(&self, kind: StreamKind) -> Option<Arc<StreamStatus>> {
        self.streams.iter().find(|s| s.kind == kind).cloned()
    }
}

/// Starts one ingest thread per enabled stream; they stop when `shutdown` is set.
pub fn start_ingest(
    state: &AppState,
    shutdown: Arc<AtomicBool>,
) -> std::io::Result<Vec<JoinHandle<()>>> {
    let mut threads = Vec::new();
    // Alarms active when the service last stopped stay active until an estimate clears them.
    let restored = state.store.active_alarms().unwrap_or_else(|e| {
        tracing::error!("cannot read the active alarms: {e}");
        Vec::new()
    });
    if !restored.is_empty() {
        tracing::info!(alarms = restored.len(), "active alarms restored");
    }
    if let Some(status) = state.stream(StreamKind::Drive) {
        let pipeline = DrivePipeline::new(
            state.config.drive.clone(),
            state.drive.clone(),
            state.metrics.clone(),
            &restored,
        );
        threads.push(spawn_ingest(state, pipeline, status, shutdown.clone())?);
    }
    if let Some(status) = state.stream(StreamKind::Vehicle) {
        let pipeline = VehiclePipeline::new(
            state.config.vehicle.clone(),
            state.vehicle.clone(),
            state.metrics.clone(),
        );
        threads.push(spawn_ingest(state, pipeline, status, shutdown.clone())?);
    }
    if let Some(status) = state.stream(StreamKind::Bogie) {
        let pipeline = BogiePipeline::with_gain_cache(
            state.config.bogie.clone(),
            state.bogie.clone(),
            state.metrics.clone(),
            &restored,
            state.config.storage.gain_cache(),
        );
        threads.push(spawn_ingest(state, pipeline, status, shutdown.clone())?);
    }
    Ok(threads)
}

/// The ingest thread of `pipeline`'s stream.
pub fn spawn_ingest<P: Pipeline + Send + 'static>(
    state: &AppState,
    mut pipeline: P,
    status: Arc<StreamStatus>,
    shutdown: Arc<AtomicBool>,
) -> std::io::Result<JoinHandle<()>> {
    let kind = <P::Frame as Frame>::STREAM;
    let config = state.config.clone();
    std::thread::Builder::new()
        .name(format!("ingest-{kind}"))
        .spawn(move || {
            // A bus failure (e.g. /dev/shm full) is recorded in the status and retried: the
            // HTTP side stays up and /readyz says the stream is not fresh.
            let snapshots = snapshot::SnapshotPolicy::of(&config.storage);
            while let Err(e) = ingest::run_ingest(
                &config.bus,
                &config.ingest,
                snapshots.as_ref(),
                &mut pipeline,
                &status,
                &shutdown,
            ) {
                tracing::error!(stream = %kind, "ingest failed, retrying in 1 s: {e}");
                for _ in 0..20 {
                    if shutdown.load(Ordering::Relaxed) {
                        return;
                    }
                    std::thread::sleep(Duration::from_millis(50));
                }
            }
        })
}
