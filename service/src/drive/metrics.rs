//! Metric families of the drive stream (label `drive`, 1-based).

use prometheus::{CounterVec, IntCounter, IntCounterVec};

use crate::metrics::{EstimateGauge, EstimateGaugeVec, EstimateIntGaugeVec, Families};

pub struct DriveMetrics {
    pub slip_probability: EstimateGaugeVec,
    pub electrical_speed: EstimateGaugeVec,
    pub mechanical_speed: EstimateGaugeVec,
    pub load_torque: EstimateGaugeVec,
    pub slipping: EstimateIntGaugeVec,
    pub global_torque: EstimateGauge,
    pub slip_events: IntCounterVec,
    pub slip_seconds: CounterVec,
    pub snapshot_refused: IntCounter,
}

impl DriveMetrics {
    pub fn new(f: &Families) -> Result<Self, prometheus::Error> {
        let drive = &["drive"];
        Ok(Self {
            slip_probability: f.estimate_gauge_vec(
                "drive_slip_probability_ratio",
                "Probability that the drive has lost adhesion.",
                drive,
            )?,
            electrical_speed: f.estimate_gauge_vec(
                "drive_electrical_speed_radians_per_second",
                "Estimated electrical speed of the drive (pole pairs x mechanical).",
                drive,
            )?,
            mechanical_speed: f.estimate_gauge_vec(
                "drive_mechanical_speed_radians_per_second",
                "Estimated mechanical speed of the motor shaft.",
                drive,
            )?,
            load_torque: f.estimate_gauge_vec(
                "drive_load_torque_newton_meters",
                "Estimated load torque of the drive.",
                drive,
            )?,
            slipping: f.estimate_gauge_vec(
                "drive_slipping",
                "1 while the drive is flagged as slipping (hysteresis).",
                drive,
            )?,
            global_torque: f.estimate_gauge(
                "drive_global_torque_newton_meters",
                "Global (adhesion-consistent) load torque over all drives.",
            )?,
            slip_events: f.int_counter_vec(
                "drive_slip_events_total",
                "Slip started / ended events.",
                &["drive", "kind"],
            )?,
            slip_seconds: f.counter_vec(
                "drive_slip_seconds_total",
                "Sample time the drive spent flagged slipping: its rate over any window shows slips shorter than a scrape interval.",
                drive,
            )?,
            snapshot_refused: f.int_counter(
                "drive_snapshot_refused_total",
                "Drive snapshots found at start and refused (another format version, other \
                 settings, too old, corrupt): the drives started from their prior.",
            )?,
        })
    }
}
