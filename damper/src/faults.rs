//! Damper faults of a simulated run: which damper, step or ramp, when, to what ratio.

use serde::{Deserialize, Serialize};

use crate::params::{non_negative, positive, Dampers};
use crate::DamperError;

/// Which damper a fault acts on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DamperId {
    Csy,
    Csay,
}

impl DamperId {
    pub const ALL: [DamperId; 2] = [DamperId::Csy, DamperId::Csay];

    pub fn name(self) -> &'static str {
        match self {
            DamperId::Csy => "csy",
            DamperId::Csay => "csay",
        }
    }

    pub fn index(self) -> usize {
        match self {
            DamperId::Csy => 0,
            DamperId::Csay => 1,
        }
    }
}

/// Shape of a fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FaultKind {
    /// Jumps to `ratio` at `at_s`.
    Step,
    /// Linear from its value at `at_s` to `ratio` at `end_s`.
    Ramp,
}

/// A damper fault: the coefficient becomes `ratio` times the scenario's initial value.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DamperFault {
    pub damper: DamperId,
    pub kind: FaultKind,
    pub at_s: f64,
    #[serde(default)]
    pub end_s: Option<f64>,
    pub ratio: f64,
}

impl DamperFault {
    pub fn validate(&self) -> Result<(), DamperError> {
        non_negative("faults.at_s", self.at_s)?;
        positive("faults.ratio", self.ratio)?;
        if self.kind == FaultKind::Ramp {
            let end = self.end_s.ok_or(DamperError::InvalidParameter {
                field: "faults.end_s",
                value: f64::NAN,
                reason: "a ramp needs end_s",
            })?;
            if !(end.is_finite() && end > self.at_s) {
                return Err(DamperError::InvalidParameter {
                    field: "faults.end_s",
                    value: end,
                    reason: "must be after at_s",
                });
            }
        }
        Ok(())
    }
}

/// The true dampers at time `t`: faults applied in the order given.
pub fn dampers_at(initial: &Dampers, faults: &[DamperFault], t_s: f64) -> Dampers {
    let mut ratio = [1.0, 1.0];
    for f in faults.iter().filter(|f| t_s >= f.at_s) {
        let r = &mut ratio[f.damper.index()];
        *r = match (f.kind, f.end_s) {
            (FaultKind::Ramp, Some(end)) => {
                *r + (f.ratio - *r) * ((t_s - f.at_s) / (end - f.at_s)).min(1.0)
            }
            _ => f.ratio,
        };
    }
    Dampers {
        csy_ns_per_m: initial.csy_ns_per_m * ratio[0],
        csay_ns_per_m: initial.csay_ns_per_m * ratio[1],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fault_schedule_steps_and_ramps() {
        let faults = [
            DamperFault {
                damper: DamperId::Csay,
                kind: FaultKind::Step,
                at_s: 30.0,
                end_s: None,
                ratio: 0.4,
            },
            DamperFault {
                damper: DamperId::Csy,
                kind: FaultKind::Ramp,
                at_s: 60.0,
                end_s: Some(120.0),
                ratio: 0.6,
            },
        ];
        let n = Dampers::NOMINAL;
        let at = |t| dampers_at(&n, &faults, t);
        assert_eq!(at(29.999), n);
        assert_eq!(at(30.0).csay_ns_per_m, 0.4 * 160e3);
        assert_eq!(at(60.0).csy_ns_per_m, 16e3);
        assert!((at(90.0).csy_ns_per_m - 0.8 * 16e3).abs() < 1e-9);
        assert!((at(500.0).csy_ns_per_m - 0.6 * 16e3).abs() < 1e-9);
        assert_eq!(at(500.0).csay_ns_per_m, 0.4 * 160e3);
    }
}
