//! The slip alarm: the per-drive slip probability turned into a slipping flag and its
//! `slip_started` / `slip_ended` events. One rule, used by the service's drive stream and by
//! `railmon analyze adhesion` (`events.csv`, the alarm columns of `detection.csv`), so that what
//! the analysis reports is what the service raises.

use serde::{Deserialize, Serialize};

use crate::error::{check_in, SlipError};

/// Hysteresis on the slip probability: a drive is flagged when its probability reaches
/// `on_probability` and cleared when it falls to `off_probability`. The gap keeps a
/// probability that hovers near one threshold from raising an event per step.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SlipAlarmConfig {
    pub on_probability: f64,
    pub off_probability: f64,
}

impl Default for SlipAlarmConfig {
    fn default() -> Self {
        SlipAlarmConfig {
            on_probability: 0.8,
            off_probability: 0.2,
        }
    }
}

impl SlipAlarmConfig {
    pub fn validate(&self) -> Result<(), SlipError> {
        check_in(
            "alarm.on_probability",
            self.on_probability,
            f64::MIN_POSITIVE,
            1.0,
            "must be in (0, 1]",
        )?;
        check_in(
            "alarm.off_probability",
            self.off_probability,
            0.0,
            self.on_probability * (1.0 - f64::EPSILON),
            "must be in [0, alarm.on_probability)",
        )
    }

    /// How the rule reads in reports (`detection.csv`'s `alarm_rule`).
    pub fn describe(&self) -> String {
        format!(
            "on at p >= {}, off at p <= {}",
            self.on_probability, self.off_probability
        )
    }
}

/// What changed for one drive.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SlipAlarmKind {
    SlipStarted,
    SlipEnded,
}

impl SlipAlarmKind {
    /// The event kind the service stores and `events.csv` lists.
    pub fn name(self) -> &'static str {
        match self {
            SlipAlarmKind::SlipStarted => "slip_started",
            SlipAlarmKind::SlipEnded => "slip_ended",
        }
    }
}

/// One crossing of the hysteresis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlipAlarmEvent {
    pub kind: SlipAlarmKind,
    /// 1-based, as in the paper and the API.
    pub drive: usize,
    /// The probability that crossed the threshold.
    pub slip_probability: f64,
}

/// The slipping flag of every drive.
#[derive(Debug, Clone, PartialEq)]
pub struct SlipAlarm {
    config: SlipAlarmConfig,
    slipping: Vec<bool>,
}

impl SlipAlarm {
    pub fn new(config: SlipAlarmConfig, n_drives: usize) -> Result<Self, SlipError> {
        config.validate()?;
        Ok(SlipAlarm {
            config,
            slipping: vec![false; n_drives],
        })
    }

    /// Flags of every drive (index 0 is drive 1).
    pub fn slipping(&self) -> &[bool] {
        &self.slipping
    }

    /// Sets the flag of `drive` (1-based) without an event, e.g. restored from an event store;
    /// the drive count grows to hold it.
    pub fn restore(&mut self, drive: usize, slipping: bool) {
        if drive >= 1 {
            if self.slipping.len() < drive {
                self.slipping.resize(drive, false);
            }
            self.slipping[drive - 1] = slipping;
        }
    }

    /// Keeps the flags of the first `n_drives` drives (a new source may have more or fewer).
    pub fn resize(&mut self, n_drives: usize) {
        self.slipping.resize(n_drives, false);
    }

    /// One step of the probabilities of every drive; the crossings, in drive order, are
    /// appended to `events`. Drives beyond the flags' count are ignored.
    pub fn update(&mut self, slip_probability: &[f64], events: &mut Vec<SlipAlarmEvent>) {
        for (k, (flag, &p)) in self.slipping.iter_mut().zip(slip_probability).enumerate() {
            let kind = match *flag {
                false if p >= self.config.on_probability => SlipAlarmKind::SlipStarted,
                true if p <= self.config.off_probability => SlipAlarmKind::SlipEnded,
                _ => continue,
            };
            *flag = kind == SlipAlarmKind::SlipStarted;
            events.push(SlipAlarmEvent {
                kind,
                drive: k + 1,
                slip_probability: p,
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hysteresis_on_a_hand_made_sequence() {
        let mut alarm = SlipAlarm::new(SlipAlarmConfig::default(), 2).unwrap();
        let mut events = Vec::new();
        // Drive 1: 0.5 (nothing), 0.8 (on), 0.5 (stays on), 0.2 (off), 0.79 (stays off).
        // Drive 2: 0.9 (on) and stays above 0.2.
        for (p1, p2) in [(0.5, 0.9), (0.8, 0.3), (0.5, 0.21), (0.2, 0.9), (0.79, 0.5)] {
            alarm.update(&[p1, p2], &mut events);
        }
        let seen: Vec<(SlipAlarmKind, usize, f64)> = events
            .iter()
            .map(|e| (e.kind, e.drive, e.slip_probability))
            .collect();
        assert_eq!(
            seen,
            vec![
                (SlipAlarmKind::SlipStarted, 2, 0.9),
                (SlipAlarmKind::SlipStarted, 1, 0.8),
                (SlipAlarmKind::SlipEnded, 1, 0.2),
            ]
        );
        assert_eq!(alarm.slipping(), &[false, true]);
        assert_eq!(SlipAlarmKind::SlipEnded.name(), "slip_ended");
    }

    #[test]
    fn restored_flag_is_cleared_by_an_estimate_with_an_event() {
        let mut alarm = SlipAlarm::new(SlipAlarmConfig::default(), 0).unwrap();
        alarm.restore(3, true);
        assert_eq!(alarm.slipping(), &[false, false, true]);
        let mut events = Vec::new();
        alarm.update(&[0.0, 0.0, 0.1], &mut events);
        assert_eq!(events.len(), 1);
        assert_eq!(
            (events[0].kind, events[0].drive),
            (SlipAlarmKind::SlipEnded, 3)
        );
    }

    #[test]
    fn thresholds_out_of_order_are_rejected() {
        let bad = |on: f64, off: f64, field: &str| {
            let c = SlipAlarmConfig {
                on_probability: on,
                off_probability: off,
            };
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains(field), "{e}");
        };
        bad(1.5, 0.2, "alarm.on_probability");
        bad(0.0, 0.0, "alarm.on_probability");
        bad(0.8, 0.8, "alarm.off_probability");
        bad(0.8, -0.1, "alarm.off_probability");
        bad(0.8, f64::NAN, "alarm.off_probability");
    }
}
