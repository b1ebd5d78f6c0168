//! The drive stream: frames of all traction drives -> `railmon_slip::SlipMonitor` -> per-drive
//! slip probability, speed, load torque, slipping flag with hysteresis, slip events, history.

use std::sync::Arc;

use prometheus::{Gauge, IntGauge};
use railmon_bus::{DriveFrame, FrameHeader};
use railmon_slip::{DriveSample, SlipMonitor};
use serde::Serialize;
use utoipa::ToSchema;

use crate::config::DriveConfig;
use crate::metrics::Metrics;
use crate::outbox::{Outbox, Stamp, Track};
use crate::stream::{Pipeline, Rejection};

/// One drive's latest estimate.
#[derive(Clone, Debug, PartialEq, Serialize, ToSchema)]
pub struct DriveView {
    /// Drive number, 1-based.
    pub id: usize,
    /// Probability that the drive has lost adhesion, 0..1.
    pub slip_probability: f64,
    /// Estimated electrical speed, rad/s.
    pub speed_rad_s: f64,
    /// Estimated load torque, N m.
    pub load_torque_nm: f64,
    /// Slipping flag with hysteresis (on at `slip_on_ratio`, off at `slip_off_ratio`).
    pub slipping: bool,
}

/// `GET /api/v1/drives`: the latest estimate of every drive.
#[derive(Clone, Debug, Default, PartialEq, Serialize, ToSchema)]
pub struct DrivesView {
    /// Adhesion method (`vb`, `vmp`, `kmeans`, `median`, `temporal`); null before the first frame.
    pub method: Option<String>,
    /// Global load torque `M_z^(G)` over all drives, N m.
    pub global_torque_nm: Option<f64>,
    /// Stream time, s: continuous over publisher restarts and runs.
    pub time_s: Option<f64>,
    /// Run of the source (a replay with `--loop` counts up) and the time within it, s.
    pub run: u32,
    pub run_time_s: Option<f64>,
    /// Sequence number of the last frame used.
    pub sequence: Option<u64>,
    pub drives: Vec<DriveView>,
}

/// One point of the history ring (all drives).
#[derive(Clone, Debug, PartialEq)]
pub struct HistoryPoint {
    pub time_s: f64,
    pub run: u32,
    pub run_time_s: f64,
    pub drives: Vec<DriveView>,
}

/// A slip started or ended (hysteresis crossing).
#[derive(Clone, Debug, PartialEq, Serialize, ToSchema)]
pub struct SlipEventView {
    /// Increasing id (restarts with the service).
    pub id: u64,
    /// `slip_started` or `slip_ended`.
    pub kind: String,
    pub drive: usize,
    pub time_s: f64,
    pub run: u32,
    pub run_time_s: f64,
    pub slip_probability: f64,
}

/// What the ingest thread shares with the HTTP side.
pub type DriveShared = Outbox<DrivesView, HistoryPoint, SlipEventView>;

impl DriveConfig {
    /// The outbox of the drive stream, sized by this config.
    pub fn outbox(&self) -> DriveShared {
        Outbox::new(self.history_capacity, self.events_capacity)
    }
}

struct DriveGauges {
    slip_probability: Gauge,
    speed: Gauge,
    load_torque: Gauge,
    slipping: IntGauge,
}

impl DriveGauges {
    fn new(metrics: &Metrics, id: usize) -> Self {
        let label = [id.to_string()];
        let label = [label[0].as_str()];
        Self {
            slip_probability: metrics.slip_probability.with_label_values(&label),
            speed: metrics.speed.with_label_values(&label),
            load_torque: metrics.load_torque.with_label_values(&label),
            slipping: metrics.slipping.with_label_values(&label),
        }
    }
}

pub struct DrivePipeline {
    config: DriveConfig,
    shared: Arc<DriveShared>,
    metrics: Arc<Metrics>,
    monitor: Option<SlipMonitor>,
    samples: Vec<DriveSample>,
    slipping: Vec<bool>,
    gauges: Vec<DriveGauges>,
    track: Track<HistoryPoint, SlipEventView>,
}

impl DrivePipeline {
    pub fn new(config: DriveConfig, shared: Arc<DriveShared>, metrics: Arc<Metrics>) -> Self {
        let track = Track::new(config.estimator.dt_s, config.history_interval_ms);
        Self {
            config,
            shared,
            metrics,
            monitor: None,
            samples: Vec::new(),
            slipping: Vec::new(),
            gauges: Vec::new(),
            track,
        }
    }

    fn drive_views(&self) -> Vec<DriveView> {
        let Some(monitor) = &self.monitor else {
            return Vec::new();
        };
        monitor
            .last()
            .drives
            .iter()
            .zip(&self.slipping)
            .enumerate()
            .map(|(k, (d, &slipping))| DriveView {
                id: k + 1,
                slip_probability: d.slip_probability,
                speed_rad_s: d.speed_rad_s,
                load_torque_nm: d.torque_nm,
                slipping,
            })
            .collect()
    }

    fn start_monitor(&mut self, n_drives: usize) -> Result<(), Rejection> {
        let monitor =
            SlipMonitor::new(&self.config.estimator, n_drives).map_err(|e| Rejection {
                reason: "estimator",
                message: e.to_string(),
            })?;
        self.monitor = Some(monitor);
        self.slipping = vec![false; n_drives];
        self.gauges = (1..=n_drives)
            .map(|id| DriveGauges::new(&self.metrics, id))
            .collect();
        for id in 1..=n_drives {
            for kind in ["slip_started", "slip_ended"] {
                let id = id.to_string();
                self.metrics
                    .slip_events
                    .with_label_values(&[id.as_str(), kind]);
            }
        }
        Ok(())
    }

    /// Hysteresis on the slip probability; crossings become events.
    fn update_slipping(&mut self, stamp: &Stamp) {
        let Some(monitor) = &self.monitor else { return };
        for (k, drive) in monitor.last().drives.iter().enumerate() {
            let p = drive.slip_probability;
            let kind = match self.slipping[k] {
                false if p >= self.config.slip_on_ratio => "slip_started",
                true if p <= self.config.slip_off_ratio => "slip_ended",
                _ => continue,
            };
            self.slipping[k] = kind == "slip_started";
            let id = (k + 1).to_string();
            self.metrics
                .slip_events
                .with_label_values(&[id.as_str(), kind])
                .inc();
            tracing::info!(
                drive = k + 1,
                time_s = stamp.time_s,
                slip_probability = p,
                "{kind}"
            );
            self.track.push_event(|id| SlipEventView {
                id,
                kind: kind.into(),
                drive: k + 1,
                time_s: stamp.time_s,
                run: stamp.header.run,
                run_time_s: stamp.run_time_s,
                slip_probability: p,
            });
        }
    }
}

impl Pipeline for DrivePipeline {
    type Frame = DriveFrame;
    const REJECTION_REASONS: &'static [&'static str] = &[
        "too_many_drives",
        "no_drives",
        "not_finite",
        "dt_mismatch",
        "drive_count_changed",
    ];

    fn check(&self, _header: &FrameHeader, frame: &DriveFrame) -> Result<(), Rejection> {
        frame
            .checked_drives(self.config.max_drives)
            .map_err(|e| Rejection {
                reason: e.reason(),
                message: e.to_string(),
            })?;
        // The EKF's model is discretised with the configured step: other data would be misread.
        let expected_ns = self.config.estimator.dt_s * 1e9;
        if (frame.dt_ns as f64 - expected_ns).abs() > 0.01 * expected_ns {
            return Err(Rejection {
                reason: "dt_mismatch",
                message: format!(
                    "frame step {} ns, estimator configured for {expected_ns} ns (drive.estimator.dt_s)",
                    frame.dt_ns
                ),
            });
        }
        Ok(())
    }

    fn restart(&mut self) {
        self.monitor = None;
        self.track.restart();
    }

    fn step(&mut self, header: &FrameHeader, frame: &DriveFrame) -> Result<(), Rejection> {
        let drives = frame
            .checked_drives(self.config.max_drives)
            .map_err(|e| Rejection {
                reason: e.reason(),
                message: e.to_string(),
            })?;
        match &self.monitor {
            Some(m) if m.n_drives() != drives.len() => {
                return Err(Rejection {
                    reason: "drive_count_changed",
                    message: format!(
                        "{} drives, the source started with {}",
                        drives.len(),
                        m.n_drives()
                    ),
                })
            }
            Some(_) => {}
            None => self.start_monitor(drives.len())?,
        }
        self.samples.clear();
        self.samples.extend(drives.iter().map(DriveSample::from));
        let monitor = self.monitor.as_mut().expect("started above");
        monitor.step(&self.samples).map_err(|e| Rejection {
            reason: "estimator",
            message: e.to_string(),
        })?;
        let stamp = self.track.stamp(header);
        self.update_slipping(&stamp);
        if self.track.history_due(stamp.time_s) {
            let drives = self.drive_views();
            self.track.push_history(HistoryPoint {
                time_s: stamp.time_s,
                run: header.run,
                run_time_s: stamp.run_time_s,
                drives,
            });
        }
        Ok(())
    }

    fn publish(&mut self) {
        let (Some(stamp), Some(monitor)) = (self.track.flush(&self.shared), &self.monitor) else {
            return;
        };
        let estimate = monitor.last();
        let view = DrivesView {
            method: Some(estimate.method.to_string()),
            global_torque_nm: Some(estimate.global_torque_nm),
            time_s: Some(stamp.time_s),
            run: stamp.header.run,
            run_time_s: Some(stamp.run_time_s),
            sequence: Some(stamp.header.sequence),
            drives: self.drive_views(),
        };
        // Gauges and the JSON snapshot come from the same estimate: /metrics and the API agree.
        for (gauges, drive) in self.gauges.iter().zip(&view.drives) {
            gauges.slip_probability.set(drive.slip_probability);
            gauges.speed.set(drive.speed_rad_s);
            gauges.load_torque.set(drive.load_torque_nm);
            gauges.slipping.set(i64::from(drive.slipping));
        }
        self.metrics.global_torque.set(estimate.global_torque_nm);
        self.shared.snapshot.store(Arc::new(view));
    }
}
