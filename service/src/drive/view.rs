//! What the drive stream shows: the JSON of `/api/v1/drives...` and its history and events.

use serde::Serialize;
use utoipa::ToSchema;

use crate::outbox::Outbox;

/// One drive's latest estimate.
#[derive(Clone, Debug, PartialEq, Serialize, ToSchema)]
pub struct DriveView {
    /// Drive number, 1-based.
    pub id: usize,
    /// Probability that the drive has lost adhesion, 0..1.
    pub slip_probability: f64,
    /// Estimated electrical speed of the rotor field (pole pairs x mechanical), rad/s.
    pub electrical_speed_rad_s: f64,
    /// Estimated mechanical speed of the motor shaft, rad/s.
    pub mechanical_speed_rad_s: f64,
    /// Estimated load torque, N m.
    pub load_torque_nm: f64,
    /// Slipping flag with hysteresis (`drive.estimator.alarm`: on at `on_probability`, off at
    /// `off_probability`).
    pub slipping: bool,
}

/// `GET /api/v1/drives`: the latest estimate of every drive.
#[derive(Clone, Debug, Default, PartialEq, Serialize, ToSchema)]
pub struct DrivesView {
    /// Adhesion method (`vb`, `vmp`, `kmeans`, `median`, `temporal`); null before the first frame.
    pub method: Option<String>,
    /// What the slip probabilities were judged against: `train_speed` (the train's measured
    /// speed came with the frames and every drive is calibrated against it) or `group` (the
    /// other drives only: blind to every drive losing adhesion at once, docs/adhesion.md);
    /// null before the first frame.
    pub reference: Option<String>,
    /// Global load torque `M_z^(G)` over all drives, N m.
    pub global_torque_nm: Option<f64>,
    /// Stream time, s: continuous over publisher restarts and runs.
    pub time_s: Option<f64>,
    /// When the newest sample used was acquired, RFC 3339 UTC.
    pub time_utc: Option<String>,
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

/// The drive stream's fields of a `slip_started` / `slip_ended` event (hysteresis crossing;
/// subject: the drive number).
#[derive(Clone, Debug, PartialEq, Serialize, ToSchema)]
pub struct SlipEventDetail {
    pub drive: usize,
    pub slip_probability: f64,
}

/// What the ingest thread shares with the HTTP side.
pub type DriveShared = Outbox<DrivesView, HistoryPoint>;
