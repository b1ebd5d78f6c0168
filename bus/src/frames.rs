//! Zero-copy payloads. Every type is `#[repr(C)]`, fixed-size and carries an explicit iceoryx2
//! type name with its layout version, so a publisher and subscriber built from different layouts
//! fail to connect with a type mismatch instead of misreading memory.

use iceoryx2::prelude::ZeroCopySend;

use crate::StreamKind;

/// Bumped whenever a payload layout changes (also part of every type name).
pub const FRAME_LAYOUT_VERSION: u32 = 5;

/// Capacity of a [`DriveFrame`]: the most drives one vehicle publishes in one frame.
pub const MAX_DRIVES: usize = 32;

/// User header of every frame. iceoryx2's own sample header has no sequence number, so the
/// publisher numbers its frames here; the subscriber counts gaps per `publisher_instance`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, ZeroCopySend)]
#[type_name("railmon::FrameHeader.v5")]
#[repr(C)]
pub struct FrameHeader {
    /// [`FRAME_LAYOUT_VERSION`] of the publisher.
    pub layout_version: u32,
    /// Source run: a replay that starts its scenario again (`--loop`) increments it, which tells
    /// the estimators to start from their prior instead of carrying state across the jump.
    pub run: u32,
    /// Identifies one publisher lifetime (process id and start time); a restarted publisher
    /// starts again at sequence 0 under a new instance.
    pub publisher_instance: u64,
    /// 0, 1, 2, ... per publisher instance.
    pub sequence: u64,
    /// CLOCK_MONOTONIC at send, ns ([`crate::monotonic_ns`]).
    pub published_at_ns: u64,
    /// Time of the measurement since the start of its run, ns.
    pub sample_time_ns: u64,
    /// When the measurement was taken, UTC, ns since the Unix epoch (0: unknown). A replay of a
    /// recording maps the file's time onto a start time it is given (default: when it starts).
    pub acquired_utc_ns: i64,
}

/// A payload type bound to its stream.
pub trait Frame: ZeroCopySend + Copy + std::fmt::Debug + 'static {
    const STREAM: StreamKind;
}

/// What one PMSM drive measures in one control step: stator voltages (the controller's
/// outputs, known inputs to the model) and stator currents in the alpha-beta frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, ZeroCopySend)]
#[type_name("railmon::DriveChannels.v1")]
#[repr(C)]
pub struct DriveChannels {
    pub u_alpha_v: f64,
    pub u_beta_v: f64,
    pub i_alpha_a: f64,
    pub i_beta_a: f64,
}

// The estimator's own sample type (not `#[repr(C)]`, no type name): one conversion each way.
impl From<&railmon_slip::DriveSample> for DriveChannels {
    fn from(s: &railmon_slip::DriveSample) -> Self {
        DriveChannels {
            u_alpha_v: s.u_alpha_v,
            u_beta_v: s.u_beta_v,
            i_alpha_a: s.i_alpha_a,
            i_beta_a: s.i_beta_a,
        }
    }
}

impl From<&DriveChannels> for railmon_slip::DriveSample {
    fn from(d: &DriveChannels) -> Self {
        railmon_slip::DriveSample {
            u_alpha_v: d.u_alpha_v,
            u_beta_v: d.u_beta_v,
            i_alpha_a: d.i_alpha_a,
            i_beta_a: d.i_beta_a,
        }
    }
}

/// All drives of one vehicle at one control step, and the train's own measured speed when the
/// vehicle has one (layout 4, issue 23 item 2).
///
/// The train speed's presence is a bit in `present` ([`DriveFrame::TRAIN_SPEED`]), not a NaN
/// value: a NaN or infinite speed from a faulty sensor must be refused (`not_finite`) like any
/// other channel, which it could not be if NaN meant "no sensor".
#[derive(Clone, Copy, Debug, PartialEq, ZeroCopySend)]
#[type_name("railmon::DriveFrame.v2")]
#[repr(C)]
pub struct DriveFrame {
    /// Drives in use, `drives[..n_drives]`; a frame claiming more than [`MAX_DRIVES`] is invalid.
    pub n_drives: u32,
    /// Bit set of the optional channels present: [`DriveFrame::TRAIN_SPEED`] (v1: `reserved`, 0,
    /// so a v1 frame read as v2 would say "no train speed"; the type name keeps them apart).
    pub present: u32,
    /// Control step of the publisher, ns.
    pub dt_ns: u64,
    /// The train's measured speed (radar, GNSS, an unpowered axle), m/s, a magnitude in
    /// `railmon_slip::TRAIN_SPEED_RANGE_M_S` (0..=100); valid with [`DriveFrame::TRAIN_SPEED`],
    /// else 0 and ignored.
    pub train_speed_m_s: f64,
    pub drives: [DriveChannels; MAX_DRIVES],
}

impl Frame for DriveFrame {
    const STREAM: StreamKind = StreamKind::Drive;
}

/// Why a received frame is not used.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum FrameError {
    #[error("frame layout version {found}, expected {FRAME_LAYOUT_VERSION}")]
    LayoutVersion { found: u32 },
    #[error("drive count {count} exceeds the maximum {max}")]
    TooManyDrives { count: usize, max: usize },
    #[error("drive count 0")]
    NoDrives,
    /// `place` says where in the frame: `drive 2`, `vehicle`.
    #[error("{place} {channel} is {value} (not finite)")]
    NotFinite {
        place: String,
        channel: &'static str,
        value: f64,
    },
    #[error("channel bits {bits:#x} name channels this layout does not have")]
    UnknownChannels { bits: u32 },
    #[error(
        "bogie {bogie_id} speed_m_s is {speed_m_s} (must be in 0..={})",
        railmon_damper::sample::MAX_SPEED_M_S
    )]
    SpeedOutOfRange { bogie_id: u32, speed_m_s: f64 },
    #[error(
        "train_speed_m_s is {train_speed_m_s} (must be in {}..={} m/s)",
        railmon_slip::TRAIN_SPEED_RANGE_M_S.0,
        railmon_slip::TRAIN_SPEED_RANGE_M_S.1
    )]
    TrainSpeedOutOfRange { train_speed_m_s: f64 },
}

/// The first NaN or infinity among `values`, as a [`FrameError::NotFinite`] at `place`.
fn check_finite<const N: usize>(
    place: impl FnOnce() -> String,
    values: [(&'static str, f64); N],
) -> Result<(), FrameError> {
    match values.into_iter().find(|(_, v)| !v.is_finite()) {
        Some((channel, value)) => Err(FrameError::NotFinite {
            place: place(),
            channel,
            value,
        }),
        None => Ok(()),
    }
}

impl FrameError {
    /// Short label for metrics (`reason="not_finite"`).
    pub fn reason(&self) -> &'static str {
        match self {
            FrameError::LayoutVersion { .. } => "layout_version",
            FrameError::TooManyDrives { .. } => "too_many_drives",
            FrameError::NoDrives => "no_drives",
            FrameError::NotFinite { .. } => "not_finite",
            FrameError::UnknownChannels { .. } => "unknown_channels",
            FrameError::SpeedOutOfRange { .. } => "speed_out_of_range",
            FrameError::TrainSpeedOutOfRange { .. } => "train_speed_out_of_range",
        }
    }
}

impl FrameHeader {
    pub fn check(&self) -> Result<(), FrameError> {
        if self.layout_version == FRAME_LAYOUT_VERSION {
            Ok(())
        } else {
            Err(FrameError::LayoutVersion {
                found: self.layout_version,
            })
        }
    }
}

impl DriveFrame {
    /// `present` bit: the frame carries the train speed.
    pub const TRAIN_SPEED: u32 = 1 << 0;
    const ALL: u32 = Self::TRAIN_SPEED;

    /// A frame of `drives.len()` drives, without a train speed; the unused slots are zero.
    pub fn new(dt_ns: u64, drives: &[DriveChannels]) -> Result<Self, FrameError> {
        if drives.len() > MAX_DRIVES {
            return Err(FrameError::TooManyDrives {
                count: drives.len(),
                max: MAX_DRIVES,
            });
        }
        let mut frame = DriveFrame {
            n_drives: drives.len() as u32,
            present: 0,
            dt_ns,
            train_speed_m_s: 0.0,
            drives: [DriveChannels::default(); MAX_DRIVES],
        };
        frame.drives[..drives.len()].copy_from_slice(drives);
        Ok(frame)
    }

    /// The frame with the train speed `train_speed_m_s` (m/s) when there is one.
    pub fn with_train_speed(mut self, train_speed_m_s: Option<f64>) -> Self {
        match train_speed_m_s {
            Some(v) => {
                self.present |= Self::TRAIN_SPEED;
                self.train_speed_m_s = v;
            }
            None => {
                self.present &= !Self::TRAIN_SPEED;
                self.train_speed_m_s = 0.0;
            }
        }
        self
    }

    /// The train speed, after checking that `present` names only known channels and that a
    /// present speed is finite and in `railmon_slip::TRAIN_SPEED_RANGE_M_S`.
    pub fn checked_train_speed(&self) -> Result<Option<f64>, FrameError> {
        if self.present & !Self::ALL != 0 {
            return Err(FrameError::UnknownChannels { bits: self.present });
        }
        if self.present & Self::TRAIN_SPEED == 0 {
            return Ok(None);
        }
        let v = self.train_speed_m_s;
        check_finite(|| "vehicle".to_string(), [("train_speed_m_s", v)])?;
        let (lo, hi) = railmon_slip::TRAIN_SPEED_RANGE_M_S;
        if !(lo..=hi).contains(&v) {
            return Err(FrameError::TrainSpeedOutOfRange { train_speed_m_s: v });
        }
        Ok(Some(v))
    }

    /// The drives in use, after checking the count against `max_drives` (at most
    /// [`MAX_DRIVES`]) and every value for NaN/inf.
    pub fn checked_drives(&self, max_drives: usize) -> Result<&[DriveChannels], FrameError> {
        let count = self.n_drives as usize;
        let max = max_drives.min(MAX_DRIVES);
        if count > max {
            return Err(FrameError::TooManyDrives { count, max });
        }
        if count == 0 {
            return Err(FrameError::NoDrives);
        }
        let drives = &self.drives[..count];
        for (drive, d) in drives.iter().enumerate() {
            check_finite(
                || format!("drive {}", drive + 1),
                [
                    ("u_alpha_v", d.u_alpha_v),
                    ("u_beta_v", d.u_beta_v),
                    ("i_alpha_a", d.i_alpha_a),
                    ("i_beta_a", d.i_beta_a),
                ],
            )?;
        }
        Ok(drives)
    }
}

/// One 1 Hz sample of a road vehicle's channels (fuel monitoring). A source that lacks a channel
/// (the Camry dynamometer files have only fuel and speed) leaves its bit in `present` clear;
/// the value of an absent channel is ignored.
#[derive(Clone, Copy, Debug, Default, PartialEq, ZeroCopySend)]
#[type_name("railmon::VehicleFrame.v2")]
#[repr(C)]
pub struct VehicleFrame {
    /// Bit set per channel present: [`VehicleFrame::FUEL`], [`VehicleFrame::SPEED`], ...
    pub present: u32,
    /// Selected gear (-1 reverse, 0 neutral, 1..), valid with [`VehicleFrame::GEAR`].
    pub gear: i32,
    pub fuel_cm3_s: f64,
    pub speed_m_s: f64,
    pub pedal_pct: f64,
    pub engine_torque_nm: f64,
    pub engine_speed_rpm: f64,
    /// Track or road gradient, per mille (v2: a railcar's route).
    pub gradient_permille: f64,
}

impl Frame for VehicleFrame {
    const STREAM: StreamKind = StreamKind::Vehicle;
}

impl VehicleFrame {
    pub const FUEL: u32 = 1 << 0;
    pub const SPEED: u32 = 1 << 1;
    pub const PEDAL: u32 = 1 << 2;
    pub const ENGINE_TORQUE: u32 = 1 << 3;
    pub const ENGINE_SPEED: u32 = 1 << 4;
    pub const GEAR: u32 = 1 << 5;
    pub const GRADIENT: u32 = 1 << 6;
    const ALL: u32 = (1 << 7) - 1;

    /// The frame of a sample (its `time_s` travels in the header's `sample_time_ns`).
    pub fn from_sample(s: &railmon_fuel::VehicleSample) -> Self {
        let bit = |bit: u32, present: bool| if present { bit } else { 0 };
        VehicleFrame {
            present: bit(Self::FUEL, s.fuel_cm3_s.is_some())
                | bit(Self::SPEED, s.speed_m_s.is_some())
                | bit(Self::PEDAL, s.pedal_pct.is_some())
                | bit(Self::ENGINE_TORQUE, s.engine_torque_nm.is_some())
                | bit(Self::ENGINE_SPEED, s.engine_speed_rpm.is_some())
                | bit(Self::GEAR, s.gear.is_some())
                | bit(Self::GRADIENT, s.gradient_permille.is_some()),
            gear: s.gear.unwrap_or(0),
            fuel_cm3_s: s.fuel_cm3_s.unwrap_or(0.0),
            speed_m_s: s.speed_m_s.unwrap_or(0.0),
            pedal_pct: s.pedal_pct.unwrap_or(0.0),
            engine_torque_nm: s.engine_torque_nm.unwrap_or(0.0),
            engine_speed_rpm: s.engine_speed_rpm.unwrap_or(0.0),
            gradient_permille: s.gradient_permille.unwrap_or(0.0),
        }
    }

    /// The sample at `time_s`, after checking that `present` names only known channels and that
    /// every present value is finite. Range checks and which channels are required are the
    /// estimator's business (its configuration decides).
    pub fn checked_sample(&self, time_s: f64) -> Result<railmon_fuel::VehicleSample, FrameError> {
        if self.present & !Self::ALL != 0 {
            return Err(FrameError::UnknownChannels { bits: self.present });
        }
        let value = |bit: u32, v: f64| (self.present & bit != 0).then_some(v);
        let sample = railmon_fuel::VehicleSample {
            time_s,
            fuel_cm3_s: value(Self::FUEL, self.fuel_cm3_s),
            speed_m_s: value(Self::SPEED, self.speed_m_s),
            pedal_pct: value(Self::PEDAL, self.pedal_pct),
            engine_torque_nm: value(Self::ENGINE_TORQUE, self.engine_torque_nm),
            engine_speed_rpm: value(Self::ENGINE_SPEED, self.engine_speed_rpm),
            gradient_permille: value(Self::GRADIENT, self.gradient_permille),
            gear: (self.present & Self::GEAR != 0).then_some(self.gear),
        };
        let present = |v: Option<f64>| v.unwrap_or(0.0);
        check_finite(
            || "vehicle".to_string(),
            [
                ("fuel_cm3_s", present(sample.fuel_cm3_s)),
                ("speed_m_s", present(sample.speed_m_s)),
                ("pedal_pct", present(sample.pedal_pct)),
                ("engine_torque_nm", present(sample.engine_torque_nm)),
                ("engine_speed_rpm", present(sample.engine_speed_rpm)),
                ("gradient_permille", present(sample.gradient_permille)),
            ],
        )?;
        Ok(sample)
    }
}

/// One 1 kHz sample of one bogie's five inertial sensors (damper monitoring), in the order of
/// the damper paper's eq. (4), the vehicle's forward speed (layout 3; the model depends on
/// it) and, when measured, the body mass above the bogie (layout 5, issue 24 item 1). A
/// vehicle has several bogies: each publishes its own frames on the one `bogie` stream, told
/// apart by `bogie_id`; the sample time is the header's.
///
/// The mass's presence is a bit in `present` ([`BogieFrame::HALF_BODY_MASS`]), as the drive
/// frame's train speed: a NaN from a faulty load sensor is refused (`not_finite`), not read as
/// "not measured".
#[derive(Clone, Copy, Debug, Default, PartialEq, ZeroCopySend)]
#[type_name("railmon::BogieFrame.v3")]
#[repr(C)]
pub struct BogieFrame {
    /// Which bogie of the vehicle (the ids the service is configured with, `[bogie] bogies`).
    pub bogie_id: u32,
    /// Bit set of the optional channels present: [`BogieFrame::HALF_BODY_MASS`] (v2:
    /// `reserved`, always 0, so "no mass"; the type name keeps them apart).
    pub present: u32,
    pub wheelset1_accel_m_s2: f64,
    pub wheelset2_accel_m_s2: f64,
    pub bogie_accel_m_s2: f64,
    pub bogie_yaw_rate_rad_s: f64,
    pub body_accel_m_s2: f64,
    /// Forward speed of the vehicle (m/s), in `0..=railmon_damper::sample::MAX_SPEED_M_S`.
    pub speed_m_s: f64,
    /// The measured body mass above this bogie (kg; its air springs' load,
    /// `railmon_damper::BogieSample::half_body_mass_kg`); valid with
    /// [`BogieFrame::HALF_BODY_MASS`], else 0 and ignored. Finite and positive here; its range
    /// about the design mass is the monitor's check (`mass_out_of_range`).
    pub half_body_mass_kg: f64,
}

impl Frame for BogieFrame {
    const STREAM: StreamKind = StreamKind::Bogie;
}

impl BogieFrame {
    /// `present` bit: the frame carries the measured body mass.
    pub const HALF_BODY_MASS: u32 = 1 << 0;
    const ALL: u32 = Self::HALF_BODY_MASS;

    pub fn from_sample(bogie_id: u32, s: &railmon_damper::BogieSample) -> Self {
        BogieFrame {
            bogie_id,
            present: if s.half_body_mass_kg.is_some() {
                Self::HALF_BODY_MASS
            } else {
                0
            },
            wheelset1_accel_m_s2: s.wheelset1_accel_m_s2,
            wheelset2_accel_m_s2: s.wheelset2_accel_m_s2,
            bogie_accel_m_s2: s.bogie_accel_m_s2,
            bogie_yaw_rate_rad_s: s.bogie_yaw_rate_rad_s,
            body_accel_m_s2: s.body_accel_m_s2,
            speed_m_s: s.speed_m_s,
            half_body_mass_kg: s.half_body_mass_kg.unwrap_or(0.0),
        }
    }

    /// The sample, after checking that `present` names only known channels, every value
    /// (a present mass too) is finite and the speed in `0..=MAX_SPEED_M_S` (which bogie ids
    /// are known is the service's configuration; whether the mass is within its range about
    /// the design mass, the monitor's: `mass_out_of_range`).
    pub fn checked_sample(&self) -> Result<railmon_damper::BogieSample, FrameError> {
        if self.present & !Self::ALL != 0 {
            return Err(FrameError::UnknownChannels { bits: self.present });
        }
        let half_body_mass_kg =
            (self.present & Self::HALF_BODY_MASS != 0).then_some(self.half_body_mass_kg);
        check_finite(
            || format!("bogie {}", self.bogie_id),
            [("half_body_mass_kg", half_body_mass_kg.unwrap_or(0.0))],
        )?;
        check_finite(
            || format!("bogie {}", self.bogie_id),
            [
                ("wheelset1_accel_m_s2", self.wheelset1_accel_m_s2),
                ("wheelset2_accel_m_s2", self.wheelset2_accel_m_s2),
                ("bogie_accel_m_s2", self.bogie_accel_m_s2),
                ("bogie_yaw_rate_rad_s", self.bogie_yaw_rate_rad_s),
                ("body_accel_m_s2", self.body_accel_m_s2),
                ("speed_m_s", self.speed_m_s),
            ],
        )?;
        let max = railmon_damper::sample::MAX_SPEED_M_S;
        if !(0.0..=max).contains(&self.speed_m_s) {
            return Err(FrameError::SpeedOutOfRange {
                bogie_id: self.bogie_id,
                speed_m_s: self.speed_m_s,
            });
        }
        Ok(railmon_damper::BogieSample {
            wheelset1_accel_m_s2: self.wheelset1_accel_m_s2,
            wheelset2_accel_m_s2: self.wheelset2_accel_m_s2,
            bogie_accel_m_s2: self.bogie_accel_m_s2,
            bogie_yaw_rate_rad_s: self.bogie_yaw_rate_rad_s,
            body_accel_m_s2: self.body_accel_m_s2,
            speed_m_s: self.speed_m_s,
            half_body_mass_kg,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn channels(n: usize) -> Vec<DriveChannels> {
        (0..n)
            .map(|i| DriveChannels {
                u_alpha_v: i as f64,
                u_beta_v: 1.0,
                i_alpha_a: 2.0,
                i_beta_a: 3.0,
            })
            .collect()
    }

    #[test]
    fn frame_round_trips_its_drives() {
        let frame = DriveFrame::new(125_000, &channels(3)).unwrap();
        assert_eq!(frame.checked_drives(MAX_DRIVES).unwrap(), &channels(3)[..]);
    }

    #[test]
    fn too_many_drives_for_the_frame_is_rejected_at_construction() {
        let err = DriveFrame::new(1, &channels(MAX_DRIVES + 1)).unwrap_err();
        assert_eq!(err.reason(), "too_many_drives");
    }

    #[test]
    fn count_above_configured_maximum_is_rejected() {
        let frame = DriveFrame::new(1, &channels(8)).unwrap();
        assert_eq!(
            frame.checked_drives(4).unwrap_err(),
            FrameError::TooManyDrives { count: 8, max: 4 }
        );
    }

    #[test]
    fn corrupt_count_beyond_capacity_is_rejected_without_indexing() {
        let mut frame = DriveFrame::new(1, &channels(2)).unwrap();
        frame.n_drives = u32::MAX;
        assert_eq!(
            frame.checked_drives(usize::MAX).unwrap_err().reason(),
            "too_many_drives"
        );
    }

    #[test]
    fn empty_frame_is_rejected() {
        let frame = DriveFrame::new(1, &[]).unwrap();
        assert_eq!(
            frame.checked_drives(MAX_DRIVES).unwrap_err(),
            FrameError::NoDrives
        );
    }

    #[test]
    fn nan_and_inf_are_rejected_naming_drive_and_channel() {
        let mut drives = channels(3);
        drives[1].i_beta_a = f64::NAN;
        let frame = DriveFrame::new(1, &drives).unwrap();
        let err = frame.checked_drives(MAX_DRIVES).unwrap_err();
        assert!(matches!(
            err,
            FrameError::NotFinite {
                channel: "i_beta_a",
                ..
            }
        ));
        assert!(err.to_string().starts_with("drive 2 i_beta_a"), "{err}");
        drives[1].i_beta_a = 0.0;
        drives[2].u_alpha_v = f64::NEG_INFINITY;
        let frame = DriveFrame::new(1, &drives).unwrap();
        assert_eq!(
            frame.checked_drives(MAX_DRIVES).unwrap_err().reason(),
            "not_finite"
        );
    }

    #[test]
    fn drive_frame_carries_an_optional_train_speed() {
        assert_eq!(std::mem::size_of::<DriveFrame>(), 1048);
        let frame = DriveFrame::new(1, &channels(2)).unwrap();
        assert_eq!(frame.checked_train_speed().unwrap(), None);
        let with = frame.with_train_speed(Some(12.5));
        assert_eq!(with.checked_train_speed().unwrap(), Some(12.5));
        assert_eq!(with.checked_drives(MAX_DRIVES).unwrap(), &channels(2)[..]);
        assert_eq!(with.with_train_speed(None), frame);
        for (v, reason) in [
            (f64::NAN, "not_finite"),
            (f64::INFINITY, "not_finite"),
            (-0.1, "train_speed_out_of_range"),
            (100.5, "train_speed_out_of_range"),
        ] {
            let err = frame
                .with_train_speed(Some(v))
                .checked_train_speed()
                .unwrap_err();
            assert_eq!(err.reason(), reason, "{v}");
            assert!(err.to_string().contains("train_speed_m_s is"), "{err}");
        }
        // Absent: the value is ignored, whatever it is.
        let mut absent = frame;
        absent.train_speed_m_s = f64::NAN;
        assert_eq!(absent.checked_train_speed().unwrap(), None);
        absent.present = 1 << 5;
        assert_eq!(
            absent.checked_train_speed().unwrap_err().reason(),
            "unknown_channels"
        );
    }

    #[test]
    fn header_with_other_layout_is_rejected() {
        let header = FrameHeader {
            layout_version: FRAME_LAYOUT_VERSION + 1,
            ..Default::default()
        };
        assert_eq!(header.check().unwrap_err().reason(), "layout_version");
    }

    fn camry_like() -> railmon_fuel::VehicleSample {
        railmon_fuel::VehicleSample {
            time_s: 7.0,
            fuel_cm3_s: Some(1.25),
            speed_m_s: Some(-0.0),
            ..Default::default()
        }
    }

    #[test]
    fn vehicle_frame_round_trips_present_and_absent_channels() {
        let sample = camry_like();
        let frame = VehicleFrame::from_sample(&sample);
        assert_eq!(frame.present, VehicleFrame::FUEL | VehicleFrame::SPEED);
        assert_eq!(frame.checked_sample(7.0).unwrap(), sample);
        let full = railmon_fuel::VehicleSample {
            pedal_pct: Some(12.0),
            engine_torque_nm: Some(-30.0),
            engine_speed_rpm: Some(2100.0),
            gradient_permille: Some(-12.5),
            gear: Some(-1),
            ..sample
        };
        assert_eq!(
            VehicleFrame::from_sample(&full)
                .checked_sample(7.0)
                .unwrap(),
            full
        );
    }

    #[test]
    fn vehicle_nan_is_rejected_only_in_a_present_channel() {
        let mut frame = VehicleFrame::from_sample(&camry_like());
        frame.pedal_pct = f64::NAN; // absent: ignored
        frame.checked_sample(0.0).unwrap();
        frame.speed_m_s = f64::INFINITY;
        let err = frame.checked_sample(0.0).unwrap_err();
        assert_eq!(err.reason(), "not_finite");
        assert!(
            err.to_string().contains("vehicle speed_m_s is inf"),
            "{err}"
        );
    }

    #[test]
    fn vehicle_unknown_channel_bits_are_rejected() {
        let mut frame = VehicleFrame::from_sample(&camry_like());
        frame.present |= 1 << 9;
        assert_eq!(
            frame.checked_sample(0.0).unwrap_err().reason(),
            "unknown_channels"
        );
    }

    #[test]
    fn bogie_frame_round_trips_and_rejects_nan_naming_bogie_and_channel() {
        let sample = railmon_damper::BogieSample {
            wheelset1_accel_m_s2: 0.1,
            wheelset2_accel_m_s2: -0.2,
            bogie_accel_m_s2: 0.3,
            bogie_yaw_rate_rad_s: -0.004,
            body_accel_m_s2: 0.05,
            speed_m_s: 31.5,
            half_body_mass_kg: None,
        };
        let frame = BogieFrame::from_sample(3, &sample);
        assert_eq!(std::mem::size_of::<BogieFrame>(), 64);
        assert_eq!(frame.checked_sample().unwrap(), sample);
        for (speed_m_s, reason) in [
            (f64::NAN, "not_finite"),
            (f64::INFINITY, "not_finite"),
            (-0.5, "speed_out_of_range"),
            (151.0, "speed_out_of_range"),
        ] {
            let bad = BogieFrame { speed_m_s, ..frame };
            let err = bad.checked_sample().unwrap_err();
            assert_eq!(err.reason(), reason, "{speed_m_s}");
            assert!(err.to_string().contains("bogie 3"), "{err}");
        }
        let standstill = BogieFrame {
            speed_m_s: 0.0,
            ..frame
        };
        assert_eq!(standstill.checked_sample().unwrap().speed_m_s, 0.0);
        let mut bad = frame;
        bad.bogie_yaw_rate_rad_s = f64::NAN;
        let err = bad.checked_sample().unwrap_err();
        assert_eq!(err.reason(), "not_finite");
        assert!(
            err.to_string()
                .contains("bogie 3 bogie_yaw_rate_rad_s is NaN"),
            "{err}"
        );
    }

    /// The measured mass travels with its bit; absent, the value is ignored; a NaN or
    /// infinite mass is refused by name (a non-positive one is left to the monitor, which
    /// refuses it as `mass_out_of_range`), as are unknown bits.
    #[test]
    fn bogie_frame_carries_an_optional_measured_mass() {
        let sample = railmon_damper::BogieSample {
            half_body_mass_kg: Some(15600.0),
            ..Default::default()
        };
        let frame = BogieFrame::from_sample(2, &sample);
        assert_eq!(frame.present, BogieFrame::HALF_BODY_MASS);
        assert_eq!(frame.checked_sample().unwrap(), sample);
        let without = BogieFrame::from_sample(2, &railmon_damper::BogieSample::default());
        assert_eq!((without.present, without.half_body_mass_kg), (0, 0.0));
        let ignored = BogieFrame {
            half_body_mass_kg: f64::NAN,
            ..without
        };
        assert_eq!(ignored.checked_sample().unwrap().half_body_mass_kg, None);
        for bad in [f64::NAN, f64::INFINITY] {
            let err = BogieFrame {
                half_body_mass_kg: bad,
                ..frame
            }
            .checked_sample()
            .unwrap_err();
            assert_eq!(err.reason(), "not_finite");
            assert!(
                err.to_string().contains("bogie 2 half_body_mass_kg is"),
                "{err}"
            );
        }
        let unknown = BogieFrame {
            present: 1 << 3,
            ..frame
        };
        assert_eq!(
            unknown.checked_sample().unwrap_err().reason(),
            "unknown_channels"
        );
        let negative = BogieFrame {
            half_body_mass_kg: -1.0,
            ..frame
        };
        assert_eq!(
            negative.checked_sample().unwrap().half_body_mass_kg,
            Some(-1.0)
        );
    }
}
