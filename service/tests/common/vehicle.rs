//! Feeds the vehicle pipeline with the `fuel-cycles` scenario's simulated samples, without the bus.

use std::path::Path;
use std::sync::{Arc, OnceLock};

use railmon_bus::{FrameHeader, VehicleFrame, FRAME_LAYOUT_VERSION};
use railmon_fuel::VehicleSample;
use railmon_service::config::VehicleConfig;
use railmon_service::ingest::{Pipeline, Rejection};
use railmon_service::metrics::Metrics;
use railmon_service::vehicle::{VehiclePipeline, VehicleShared, VehicleView};

/// The simulated samples of `config/scenarios/fuel-cycles.toml` (all channels and the gear).
pub fn fuel_cycles() -> &'static [VehicleSample] {
    static SAMPLES: OnceLock<Vec<VehicleSample>> = OnceLock::new();
    SAMPLES.get_or_init(|| {
        let path =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenarios/fuel-cycles.toml");
        railmon_analyze::fuel::simulate_scenario(&path)
            .unwrap()
            .0
            .samples
    })
}

pub fn vehicle_header(sequence: u64, time_s: f64) -> FrameHeader {
    FrameHeader {
        layout_version: FRAME_LAYOUT_VERSION,
        sequence,
        sample_time_ns: (time_s * 1e9).round() as u64,
        ..Default::default()
    }
}

/// The enabled vehicle stream with the default estimator.
pub fn vehicle_config() -> VehicleConfig {
    VehicleConfig {
        enabled: true,
        ..VehicleConfig::default()
    }
}

pub struct VehicleHarness {
    pub pipeline: VehiclePipeline,
    pub shared: Arc<VehicleShared>,
    pub step: usize,
}

impl VehicleHarness {
    pub fn new(config: VehicleConfig) -> Self {
        let shared = Arc::new(config.outbox(super::memory_store()));
        Self::with(config, shared, Arc::new(Metrics::new().unwrap()))
    }

    /// Publishes into `shared` and `metrics` (those of an `AppState`).
    pub fn with(config: VehicleConfig, shared: Arc<VehicleShared>, metrics: Arc<Metrics>) -> Self {
        let mut pipeline = VehiclePipeline::new(config, shared.clone(), metrics);
        pipeline.restart();
        Self {
            pipeline,
            shared,
            step: 0,
        }
    }

    /// Checks and steps one frame of `sample` (as the ingest loop does).
    pub fn offer(&mut self, sample: &VehicleSample) -> Result<(), Rejection> {
        let frame = VehicleFrame::from_sample(sample);
        let header = vehicle_header(self.step as u64, sample.time_s);
        let input = self.pipeline.check(&header, &frame)?;
        self.pipeline.step(&header, input)?;
        self.step += 1;
        Ok(())
    }

    /// Steps the next simulated sample; returns it.
    pub fn advance(&mut self) -> Option<VehicleSample> {
        let sample = *fuel_cycles().get(self.step)?;
        self.offer(&sample).unwrap();
        Some(sample)
    }

    pub fn view(&mut self) -> VehicleView {
        self.pipeline.publish();
        // Events are written by the store's thread: wait for them, as a reader would.
        self.shared.store.flush();
        VehicleView::clone(&self.shared.snapshot.load())
    }
}
