//! The ingest side of the drive stream: checked frames -> `SlipMonitor` step -> slipping flags
//! and events -> history, snapshot and gauges once per batch.

use std::sync::Arc;

use railmon_bus::{DriveFrame, FrameHeader};
use railmon_slip::{
    DriveRanges, DriveSample, SlipAlarm, SlipAlarmEvent, SlipAlarmKind, SlipEstimate, SlipMonitor,
};

use railmon_bus::StreamKind;

use super::view::{DriveShared, DriveView, DrivesView, HistoryPoint, SlipEventDetail};
use super::DriveConfig;
use crate::ingest::{Pipeline, Rejection};
use crate::metrics::{EstimateGauge, EstimateIntGauge, Metrics};
use crate::outbox::{Stamp, Track};
use crate::snapshot::StateFormat;
use crate::store::ActiveAlarm;

struct DriveGauges {
    slip_seconds: prometheus::Counter,
    slip_probability: EstimateGauge,
    electrical_speed: EstimateGauge,
    mechanical_speed: EstimateGauge,
    load_torque: EstimateGauge,
    slipping: EstimateIntGauge,
}

impl DriveGauges {
    fn new(metrics: &Metrics, id: usize) -> Self {
        let id = id.to_string();
        let label = [id.as_str()];
        let m = &metrics.drive;
        Self {
            slip_seconds: m.slip_seconds.with_label_values(&label),
            slip_probability: m.slip_probability.with_label_values(&label),
            electrical_speed: m.electrical_speed.with_label_values(&label),
            mechanical_speed: m.mechanical_speed.with_label_values(&label),
            load_torque: m.load_torque.with_label_values(&label),
            slipping: m.slipping.with_label_values(&label),
        }
    }
}

pub struct DrivePipeline {
    config: DriveConfig,
    shared: Arc<DriveShared>,
    metrics: Arc<Metrics>,
    monitor: Option<SlipMonitor>,
    /// The slipping flags (`railmon_slip::SlipAlarm`, the rule `analyze adhesion` applies too).
    alarm: SlipAlarm,
    /// Scratch: the alarm's events of one step.
    alarm_events: Vec<SlipAlarmEvent>,
    gauges: Vec<DriveGauges>,
    track: Track<HistoryPoint>,
}

impl DrivePipeline {
    /// `restored`: the alarms active when the service stopped (drives flagged slipping stay
    /// flagged until an estimate clears them, with an event).
    pub fn new(
        config: DriveConfig,
        shared: Arc<DriveShared>,
        metrics: Arc<Metrics>,
        restored: &[ActiveAlarm],
    ) -> Self {
        let track = Track::new(
            StreamKind::Drive,
            config.estimator.dt_s,
            config.history_interval_ms,
        );
        // Validated with the config: the thresholds are in range.
        let mut alarm = SlipAlarm::new(config.estimator.alarm, 0)
            .expect("drive.estimator.alarm was validated with the config");
        for alarm_state in restored
            .iter()
            .filter(|a| a.stream == "drive" && a.alarm == "slipping")
        {
            if let Ok(drive @ 1..=railmon_bus::MAX_DRIVES) = alarm_state.subject.parse::<usize>() {
                alarm.restore(drive, true);
            }
        }
        Self {
            config,
            shared,
            metrics,
            monitor: None,
            alarm,
            alarm_events: Vec::new(),
            gauges: Vec::new(),
            track,
        }
    }

    fn drive_views(&self, estimate: &SlipEstimate) -> Vec<DriveView> {
        let pole_pairs = self.config.estimator.motor.pole_pairs;
        estimate
            .drives
            .iter()
            .zip(self.alarm.slipping())
            .enumerate()
            .map(|(k, (d, &slipping))| DriveView {
                id: k + 1,
                slip_probability: d.slip_probability,
                electrical_speed_rad_s: d.speed_rad_s,
                mechanical_speed_rad_s: d.speed_rad_s / pole_pairs,
                load_torque_nm: d.torque_nm,
                slipping,
            })
            .collect()
    }

    fn start_monitor(&mut self, n_drives: usize) -> Result<(), Rejection> {
        let estimator_error = |e: railmon_slip::SlipError| Rejection {
            reason: "estimator",
            message: e.to_string(),
        };
        let mut monitor =
            SlipMonitor::new(&self.config.estimator, n_drives).map_err(estimator_error)?;
        monitor
            .set_speed_reference(self.config.speed_reference)
            .map_err(estimator_error)?;
        self.monitor = Some(monitor);
        // Flags carry over a restart of the source (and of the service): never a silent clear.
        self.alarm.resize(n_drives);
        self.gauges = (1..=n_drives)
            .map(|id| DriveGauges::new(&self.metrics, id))
            .collect();
        for id in 1..=n_drives {
            for kind in ["slip_started", "slip_ended"] {
                let id = id.to_string();
                self.metrics
                    .drive
                    .slip_events
                    .with_label_values(&[id.as_str(), kind]);
            }
        }
        Ok(())
    }

    /// The stamp of the step `estimate` names: `lag_steps` sample periods before `newest`,
    /// the frame that published it (the fixed lag, `railmon_slip::fixed_lag`).
    fn dated(&self, newest: &Stamp, estimate: &SlipEstimate) -> Stamp {
        // In whole nanoseconds, as the bus stamps samples: the step's own sample time.
        let back_ns = estimate.lag_steps * self.sample_period_ns();
        let run_time_ns = newest.header.sample_time_ns.saturating_sub(back_ns);
        let run_time_s = run_time_ns as f64 / 1e9;
        Stamp {
            time_s: (newest.time_s - newest.run_time_s) + run_time_s,
            run_time_s,
            utc_ns: newest.utc_ns - back_ns as i64,
            ..*newest
        }
    }

    /// A published estimate: the slip alarm over its probabilities (its crossings become
    /// events) and the history, dated at the step it names.
    fn on_estimate(&mut self, estimate: &SlipEstimate, newest: &Stamp) {
        let stamp = self.dated(newest, estimate);
        let dt_s = self.config.estimator.dt_s;
        for (gauges, &slipping) in self.gauges.iter().zip(self.alarm.slipping()) {
            if slipping {
                gauges.slip_seconds.inc_by(dt_s);
            }
        }
        let probabilities: Vec<f64> = estimate.drives.iter().map(|d| d.slip_probability).collect();
        self.alarm_events.clear();
        self.alarm.update(&probabilities, &mut self.alarm_events);
        for event in &self.alarm_events {
            let kind = event.kind.name();
            let id = event.drive.to_string();
            self.metrics
                .drive
                .slip_events
                .with_label_values(&[id.as_str(), kind])
                .inc();
            tracing::info!(
                drive = event.drive,
                time_s = stamp.time_s,
                slip_probability = event.slip_probability,
                "{kind}"
            );
            let started = event.kind == SlipAlarmKind::SlipStarted;
            let detail = SlipEventDetail {
                drive: event.drive,
                slip_probability: event.slip_probability,
            };
            self.track
                .push_event(&stamp, kind, id, &detail, Some(("slipping", started)));
        }
        if self.track.history_due(stamp.time_s) {
            let drives = self.drive_views(estimate);
            self.track.push_history(HistoryPoint {
                time_s: stamp.time_s,
                run: stamp.header.run,
                run_time_s: stamp.run_time_s,
                drives,
            });
        }
    }

    /// Publishes the steps still behind the fixed lag (before a gap the EKFs relock after,
    /// and before a new source), dated from the last frame: nothing accepted is dropped.
    fn drain_monitor(&mut self, monitor: &mut SlipMonitor) {
        let Some(newest) = self.track.last_stamp() else {
            if monitor.pending() > 0 {
                tracing::warn!(
                    pending = monitor.pending(),
                    "drive steps behind the fixed lag with no frame to date them by: not published"
                );
            }
            return;
        };
        loop {
            match monitor.drain() {
                Ok(Some(e)) => {
                    let e = e.clone();
                    self.on_estimate(&e, &newest);
                }
                Ok(None) => break,
                Err(e) => {
                    tracing::error!("drive estimator failed draining the fixed lag: {e}");
                    break;
                }
            }
        }
    }
}

/// What a drive snapshot holds.
#[derive(serde::Serialize, serde::Deserialize)]
struct SavedDrive {
    monitor: SlipMonitor,
    clock: crate::outbox::TrackClock,
    /// The last frame, which dates the steps the monitor still holds behind its fixed lag.
    last_frame: Option<crate::outbox::SavedStamp>,
}

/// The layout of [`SavedDrive`] around the monitor, and the monitor's own (its crate's
/// `SlipMonitor::STATE_FORMAT_VERSION`). Raise `version` with every change of what
/// `SavedDrive` holds beside the monitor: a snapshot of another layout is refused by its
/// version instead of failing to decode, or decoding into other numbers.
const SAVED_DRIVES: StateFormat = StateFormat {
    magic: b"railmon-drives\0",
    // 3: the EKF bank lost the load-jump test's state (the rejected `[ekf.jump]`, issue 27).
    // 4: the monitor's layout has its own version (`estimator_version`), its crate's.
    // 5: the last frame's stamp (the fixed lag's held steps are dated from it).
    version: 5,
    estimator_version: SlipMonitor::STATE_FORMAT_VERSION,
    what: "drive state",
};

impl Pipeline for DrivePipeline {
    type Frame = DriveFrame;
    /// One sample per drive, every value finite, the configured step; the train speed when
    /// the frame carries one (finite, in range).
    type Checked = (Vec<DriveSample>, Option<f64>);
    const REJECTION_REASONS: &'static [&'static str] = &[
        "too_many_drives",
        "no_drives",
        "not_finite",
        "dt_mismatch",
        "drive_count_changed",
        "out_of_range",
        "train_speed_out_of_range",
        "unknown_channels",
    ];

    fn sample_period_ns(&self) -> u64 {
        (self.config.estimator.dt_s * 1e9).round() as u64
    }

    fn check(
        &self,
        _header: &FrameHeader,
        frame: &DriveFrame,
    ) -> Result<(Vec<DriveSample>, Option<f64>), Rejection> {
        let drives = frame
            .checked_drives(self.config.max_drives)
            .map_err(|e| Rejection::new(e.reason(), e.to_string()))?;
        // An implausible train speed is a sensor fault: the frame is refused and counted, not
        // judged against the group as if no speed had come.
        let train_speed_m_s = frame
            .checked_train_speed()
            .map_err(|e| Rejection::new(e.reason(), e.to_string()))?;
        // The EKF's model is discretised with the configured step: other data would be misread.
        let expected_ns = self.config.estimator.dt_s * 1e9;
        if (frame.dt_ns as f64 - expected_ns).abs() > 0.01 * expected_ns {
            return Err(Rejection::new(
                "dt_mismatch",
                format!(
                    "frame step {} ns, estimator configured for {expected_ns} ns (drive.estimator.dt_s)",
                    frame.dt_ns
                ),
            ));
        }
        let ranges = DriveRanges {
            max_abs_current_a: self.config.max_abs_current_a,
            max_abs_voltage_v: self.config.max_abs_voltage_v,
        };
        let samples: Vec<DriveSample> = drives.iter().map(DriveSample::from).collect();
        if let Some(r) = ranges.first_beyond(&samples) {
            return Err(Rejection::new(
                "out_of_range",
                format!(
                    "drive {}: {} = {:.4e} is beyond +-{} (drive.{}; wrong units?)",
                    r.drive + 1,
                    r.field,
                    r.value,
                    r.max,
                    r.key
                ),
            ));
        }
        if let Some(m) = &self.monitor {
            if m.n_drives() != drives.len() {
                return Err(Rejection::new(
                    "drive_count_changed",
                    format!(
                        "{} drives, the source started with {}",
                        drives.len(),
                        m.n_drives()
                    ),
                ));
            }
        }
        Ok((samples, train_speed_m_s))
    }

    fn restart(&mut self) {
        if let Some(mut m) = self.monitor.take() {
            self.drain_monitor(&mut m);
        }
        self.track.restart();
    }

    fn step(
        &mut self,
        header: &FrameHeader,
        (samples, train_speed_m_s): (Vec<DriveSample>, Option<f64>),
    ) -> Result<(), Rejection> {
        if self.monitor.is_none() {
            self.start_monitor(samples.len())?;
        }
        let mut monitor = self.monitor.take().expect("started above");
        let published = monitor
            .step_with_train_speed(&samples, train_speed_m_s)
            .map(|e| e.is_some());
        let published = match published {
            Ok(p) => p,
            Err(e) => {
                self.monitor = Some(monitor);
                return Err(Rejection::new("estimator", e.to_string()));
            }
        };
        let stamp = self.track.stamp(header);
        if published {
            // The estimate of the step FIXED_LAG_STEPS frames back, dated at that step.
            self.on_estimate(monitor.last(), &stamp);
        }
        self.monitor = Some(monitor);
        Ok(())
    }

    /// The estimator's and the train-speed reference's settings: a snapshot taken under
    /// others is refused.
    /// Short gaps are predicted through; after a longer one (a restart of the service) the
    /// EKFs relock from the back-EMF as at start (`SlipMonitor::bridge`).
    fn bridge(&mut self, skipped_periods: u64) {
        let Some(mut m) = self.monitor.take() else {
            return;
        };
        // After a gap the EKFs relock after, the steps behind the fixed lag are published
        // first (`SlipMonitor::bridge` hands them over), dated from the last frame.
        let mut drained = Vec::new();
        if let Err(e) = m.bridge(skipped_periods, &mut |e| drained.push(e.clone())) {
            tracing::error!("drive estimator failed draining the fixed lag: {e}");
        }
        if let Some(newest) = self.track.last_stamp() {
            for e in &drained {
                self.on_estimate(e, &newest);
            }
        } else if !drained.is_empty() {
            tracing::warn!(
                steps = drained.len(),
                "drive steps behind the fixed lag with no frame to date them by: not published"
            );
        }
        self.monitor = Some(m);
    }

    fn settings(&self) -> String {
        serde_json::json!({
            "estimator": self.config.estimator,
            "speed_reference": self.config.speed_reference,
        })
        .to_string()
    }

    /// The monitor (EKF states and covariances, the adhesion estimator's carried posterior)
    /// and stream time. The slipping flags are not saved: the event store's active alarms,
    /// committed with the events, are newer and restored at start.
    fn save_state(&self) -> Option<Vec<u8>> {
        let saved = SavedDrive {
            monitor: self.monitor.clone()?,
            clock: self.track.clock(),
            last_frame: self.track.last_stamp().map(Into::into),
        };
        SAVED_DRIVES.encode(&saved)
    }

    fn resume_state(&mut self, state: &[u8]) -> Result<(), String> {
        let saved: SavedDrive = SAVED_DRIVES.decode(state)?;
        self.start_monitor(saved.monitor.n_drives())
            .map_err(|r| r.message)?;
        self.monitor = Some(saved.monitor);
        self.track.resume_clock(saved.clock);
        self.track.resume_last(saved.last_frame.map(Into::into));
        Ok(())
    }

    /// A snapshot that does not fit: the estimator starts from its prior, and the store gets a
    /// `snapshot_refused` event saying which file and why (the log has a warning too).
    fn snapshot_refused(&mut self, file: &std::path::Path, reason: &str) {
        self.metrics.drive.snapshot_refused.inc();
        let event = crate::snapshot::refused_event(StreamKind::Drive, file, reason);
        self.shared.store.append(vec![event]);
    }

    /// The source is silent (or the service stops): the steps behind the fixed lag are
    /// published from the frames there are, dated from the last frame.
    fn end_of_data(&mut self) {
        if let Some(mut m) = self.monitor.take() {
            if m.pending() > 0 {
                self.drain_monitor(&mut m);
                self.track.touch();
            }
            self.monitor = Some(m);
        }
    }

    fn publish(&mut self) {
        let (Some(stamp), Some(monitor)) = (self.track.flush(&self.shared), &self.monitor) else {
            return;
        };
        if !monitor.has_published() {
            // The first FIXED_LAG_STEPS frames: no estimate yet, and the view says so.
            return;
        }
        let estimate = monitor.last();
        // The view is of the step the estimate names (FIXED_LAG_STEPS periods back).
        let stamp = self.dated(&stamp, estimate);
        let view = DrivesView {
            method: Some(estimate.method.to_string()),
            reference: Some(estimate.reference.name().to_owned()),
            global_torque_nm: Some(estimate.global_torque_nm),
            time_s: Some(stamp.time_s),
            time_utc: Some(stamp.time_utc()),
            run: stamp.header.run,
            run_time_s: Some(stamp.run_time_s),
            sequence: Some(stamp.header.sequence),
            drives: self.drive_views(estimate),
        };
        // Gauges and the JSON snapshot come from the same estimate: /metrics and the API agree.
        for (gauges, drive) in self.gauges.iter().zip(&view.drives) {
            gauges.slip_probability.set(drive.slip_probability);
            gauges.electrical_speed.set(drive.electrical_speed_rad_s);
            gauges.mechanical_speed.set(drive.mechanical_speed_rad_s);
            gauges.load_torque.set(drive.load_torque_nm);
            gauges.slipping.set(i64::from(drive.slipping));
        }
        self.metrics
            .drive
            .global_torque
            .set(estimate.global_torque_nm);
        self.shared.snapshot.store(Arc::new(view));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What the snapshot holds around the monitor is pinned under `SAVED_DRIVES`'s version
    /// (the monitor itself under its crate's, `slip/tests/state_layout.rs`).
    #[test]
    fn state_layout_golden_is_pinned_under_the_format_version() {
        let saved = SavedDrive {
            monitor: SlipMonitor::new(&Default::default(), 2).unwrap(),
            clock: crate::outbox::TrackClock {
                run_offset_s: 3.0,
                last_time_s: Some(2.5),
                next_history_s: 2.6,
            },
            last_frame: Some(crate::outbox::SavedStamp {
                run: 1,
                publisher_instance: 7,
                sequence: 19_999,
                sample_time_ns: 2_499_875_000,
                acquired_utc_ns: 1_700_000_002_499_875_000,
                time_s: 2.5,
                run_time_s: 2.499875,
                utc_ns: 1_700_000_002_499_875_000,
            }),
        };
        railmon_golden::check_state_layout(
            "state-layout-service-drive.txt",
            SAVED_DRIVES.version,
            &[saved],
            &["state-layout-slip.txt"],
        );
    }
}
