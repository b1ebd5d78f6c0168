//! Feeds the drive pipeline with the seed scenario's simulated frames, without the bus.
#![allow(dead_code)] // each test binary uses a different part

pub mod vehicle;

use std::path::Path;
use std::sync::Arc;

use railmon_bus::{DriveChannels, DriveFrame, FrameHeader, FRAME_LAYOUT_VERSION};
use railmon_service::config::Identity;
use railmon_service::drive::{DrivePipeline, DriveShared, DrivesView};
use railmon_service::ingest::Pipeline;
use railmon_service::metrics::Metrics;
use railmon_service::store::{EventQuery, EventStore, EventView};
use railmon_service::ServiceConfig;
use railmon_slip::{AdhesionScenario, DriveSample, DriveSimulator};

pub fn seed() -> AdhesionScenario {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenarios/adhesion-seed.toml");
    AdhesionScenario::from_toml_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

pub fn frame_of(samples: &[DriveSample], dt_ns: u64) -> DriveFrame {
    let drives: Vec<DriveChannels> = samples.iter().map(DriveChannels::from).collect();
    DriveFrame::new(dt_ns, &drives).unwrap()
}

pub fn header(step: u64, dt_ns: u64) -> FrameHeader {
    FrameHeader {
        layout_version: FRAME_LAYOUT_VERSION,
        sequence: step,
        sample_time_ns: step * dt_ns,
        ..Default::default()
    }
}

pub struct Harness {
    pub pipeline: DrivePipeline,
    pub shared: Arc<DriveShared>,
    pub simulator: DriveSimulator,
    pub dt_ns: u64,
    pub step: u64,
}

/// The default settings with the event store in memory (tests must not share a database).
pub fn test_config() -> ServiceConfig {
    let mut config = ServiceConfig::default();
    config.storage.data_dir = ":memory:".into();
    config
}

/// An event store of its own, in memory.
pub fn memory_store() -> Arc<EventStore> {
    EventStore::open(&test_config().storage, &Identity::default())
        .unwrap()
        .0
}

/// Every event in `store`, oldest first (after writing what is queued).
pub fn stored_events(store: &EventStore) -> Vec<EventView> {
    store.flush();
    store
        .page(&EventQuery {
            limit: 100_000,
            ..EventQuery::default()
        })
        .unwrap()
}

impl Harness {
    pub fn new() -> Self {
        let shared = Arc::new(ServiceConfig::default().drive.outbox(memory_store()));
        Self::with(shared, Arc::new(Metrics::new().unwrap()))
    }

    /// Publishes into `shared` and `metrics` (those of an `AppState`).
    pub fn with(shared: Arc<DriveShared>, metrics: Arc<Metrics>) -> Self {
        let scenario = seed();
        let config = ServiceConfig::default().drive;
        let mut pipeline = DrivePipeline::new(config, shared.clone(), metrics, &[]);
        pipeline.restart();
        Self {
            pipeline,
            shared,
            simulator: DriveSimulator::new(&scenario).unwrap(),
            dt_ns: (scenario.dt_s() * 1e9).round() as u64,
            step: 0,
        }
    }

    /// Steps the pipeline with the next simulated frame; returns the samples used.
    pub fn advance(&mut self) -> Option<Vec<DriveSample>> {
        let (samples, _) = self.simulator.step()?;
        let samples = samples.to_vec();
        let frame = frame_of(&samples, self.dt_ns);
        let header = header(self.step, self.dt_ns);
        let input = self.pipeline.check(&header, &frame).unwrap();
        self.pipeline.step(&header, input).unwrap();
        self.step += 1;
        Some(samples)
    }

    pub fn view(&mut self) -> DrivesView {
        self.pipeline.publish();
        // Events are written by the store's thread: wait for them, as a reader would.
        self.shared.store.flush();
        DrivesView::clone(&self.shared.snapshot.load())
    }
}
