//! What a drive gives the monitor each time step, and the simulator's ground truth.

use crate::error::SlipError;

/// One drive, one time step: the applied (reconstructed) stator voltages over the step that
/// starts now and the stator currents measured now, both in the alpha-beta frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DriveSample {
    pub u_alpha_v: f64,
    pub u_beta_v: f64,
    pub i_alpha_a: f64,
    pub i_beta_a: f64,
}

impl DriveSample {
    /// The first non-finite field, if any, as `(name, value)`.
    pub fn first_non_finite(&self) -> Option<(&'static str, f64)> {
        [
            ("u_alpha_v", self.u_alpha_v),
            ("u_beta_v", self.u_beta_v),
            ("i_alpha_a", self.i_alpha_a),
            ("i_beta_a", self.i_beta_a),
        ]
        .into_iter()
        .find(|(_, v)| !v.is_finite())
    }
}

/// Plausible magnitudes of a drive's measured values: beyond them a value is in another unit
/// (currents in mA once gave a load torque of 13,320 N m with no complaint) or from a broken
/// sensor, and the frame is refused as `out_of_range`, not estimated. The service's
/// `drive.max_abs_current_a` / `max_abs_voltage_v` (these defaults); `railmon analyze
/// adhesion` applies the defaults.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DriveRanges {
    /// Stator currents, A.
    pub max_abs_current_a: f64,
    /// Stator voltages, V.
    pub max_abs_voltage_v: f64,
}

impl Default for DriveRanges {
    fn default() -> Self {
        DriveRanges {
            max_abs_current_a: 1_000.0,
            max_abs_voltage_v: 5_000.0,
        }
    }
}

/// A value beyond its plausible magnitude ([`DriveRanges::first_beyond`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OutOfRange {
    /// The drive, 0-based.
    pub drive: usize,
    pub field: &'static str,
    pub value: f64,
    /// The magnitude it exceeds, and the name of its setting.
    pub max: f64,
    pub key: &'static str,
}

impl DriveRanges {
    /// The first value of the frame beyond its magnitude, drive by drive in the CSV's column
    /// order.
    pub fn first_beyond(&self, samples: &[DriveSample]) -> Option<OutOfRange> {
        let (max_i, max_u) = (self.max_abs_current_a, self.max_abs_voltage_v);
        samples.iter().enumerate().find_map(|(drive, d)| {
            [
                ("u_alpha_v", d.u_alpha_v, max_u, "max_abs_voltage_v"),
                ("u_beta_v", d.u_beta_v, max_u, "max_abs_voltage_v"),
                ("i_alpha_a", d.i_alpha_a, max_i, "max_abs_current_a"),
                ("i_beta_a", d.i_beta_a, max_i, "max_abs_current_a"),
            ]
            .into_iter()
            .find(|c| c.1.abs() > c.2)
            .map(|(field, value, max, key)| OutOfRange {
                drive,
                field,
                value,
                max,
                key,
            })
        })
    }
}

/// Ground truth of one drive at one step (simulator only). `speed_rad_s` and `angle_rad` are
/// electrical; `torque_nm` is the true load torque.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DriveTruth {
    pub speed_rad_s: f64,
    pub angle_rad: f64,
    pub torque_nm: f64,
    /// True when the load departs from the drive's healthy load profile by more than
    /// [`SLIP_RULE_FRACTION`] of it: the definition every detection figure is scored against.
    pub slipping: bool,
}

/// The slip rule: a drive is slipping when
/// `|T_L - T_healthy| > max(SLIP_RULE_FRACTION * |T_healthy|, SLIP_RULE_FLOOR_NM)`.
/// Adhesion loss shows as the wheel no longer carrying its share of the load; 10 % is well
/// above the spread of healthy drives and well below the paper's events (drops to 0, a
/// one-third dip).
pub const SLIP_RULE_FRACTION: f64 = 0.1;

/// The slip rule's absolute floor: near zero torque (coasting, the passage between traction
/// and braking) 10 % of the load is below any torque estimate's resolution (the EKF's torque
/// noise is 0.2-0.5 N m), and a departure smaller than this is not a loss of adhesion that
/// matters. 0.5 N m is the 10 % rule at 5 N m, the lowest load of our scenarios, so that
/// every departure above 5 N m is judged by the relative rule alone.
pub const SLIP_RULE_FLOOR_NM: f64 = 0.5;

/// Applies the slip rule to one drive.
pub fn is_slipping(true_torque_nm: f64, healthy_torque_nm: f64) -> bool {
    (true_torque_nm - healthy_torque_nm).abs()
        > (SLIP_RULE_FRACTION * healthy_torque_nm.abs()).max(SLIP_RULE_FLOOR_NM)
}

/// Checks a frame before anything is changed: the right length and every value finite.
pub fn validate_frame(samples: &[DriveSample], n_drives: usize) -> Result<(), SlipError> {
    if samples.len() != n_drives {
        return Err(SlipError::WrongDriveCount {
            expected: n_drives,
            got: samples.len(),
        });
    }
    for (i, s) in samples.iter().enumerate() {
        if let Some((field, value)) = s.first_non_finite() {
            return Err(SlipError::NonFiniteSample {
                drive: i + 1,
                field,
                value,
            });
        }
    }
    Ok(())
}
