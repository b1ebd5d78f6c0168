//! The slip alarm: the per-drive slip probability turned into a slipping flag and its
//! `slip_started` / `slip_ended` events. One rule, used by the service's drive stream and by
//! `railmon analyze adhesion` (`events.csv`, the alarm columns of `detection.csv`), so that what
//! the analysis reports is what the service raises.

use serde::{Deserialize, Serialize};

use crate::error::{check_in, SlipError};

/// Hysteresis on the slip probability: a drive is flagged when its probability reaches
/// `on_probability` and cleared when it falls to `off_probability`. The gap keeps a
/// probability that hovers near one threshold from raising an event per step.
///
/// Two holds in time on top (issue 10, docs/adhesion.md "Alarm episodes"): the flag rises
/// only once the probability has been at or above `on_probability` for `confirm_steps`
/// consecutive steps (1: at once), and a flagged drive whose probability falls to
/// `off_probability` stays flagged for `release_hold_steps` more steps, during which a return
/// to `on_probability` continues the same episode (0: cleared at once).
///
/// The default confirms for 8 steps (1 ms at 8 kHz): over the whole scenario matrix it removes
/// every false alarm episode on healthy drives (3 -> 0, each a 7-8-step run of the estimate
/// about 5 `s_i` out on a flat load) at 7.5 steps more median onset delay; the alarm F1 it
/// costs (0.04-0.05) falls on the four short losses the information bound already caps. A
/// monitor that cries wolf is not read, so the false episodes weigh more.
/// Bounds of the alarm's step counts (declared to the settings reference and checked): at
/// most 10 s of 8 kHz steps, longer than any confirmation or hold that still reports slip.
const CONFIRM_STEPS: std::ops::RangeInclusive<usize> = 1..=80_000;
const RELEASE_HOLD_STEPS: std::ops::RangeInclusive<usize> = 0..=80_000;

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct SlipAlarmConfig {
    /// A drive is flagged once its slip probability reaches this (for `confirm_steps`).
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = 1.0))]
    pub on_probability: f64,
    /// A flagged drive is cleared when its slip probability falls to this.
    #[schemars(range(min = 0.0), extend("exclusiveMaximum" = 1.0))]
    pub off_probability: f64,
    /// Consecutive steps at or above `on_probability` before the flag rises (1: at once).
    #[schemars(range(min = *CONFIRM_STEPS.start(), max = *CONFIRM_STEPS.end()))]
    pub confirm_steps: usize,
    /// Steps a cleared drive stays flagged, a return to `on_probability` continuing the
    /// episode (0: cleared at once).
    #[schemars(range(min = *RELEASE_HOLD_STEPS.start(), max = *RELEASE_HOLD_STEPS.end()))]
    pub release_hold_steps: usize,
}

impl Default for SlipAlarmConfig {
    fn default() -> Self {
        SlipAlarmConfig {
            on_probability: 0.8,
            off_probability: 0.2,
            confirm_steps: 8,
            release_hold_steps: 0,
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
        )?;
        if !CONFIRM_STEPS.contains(&self.confirm_steps) {
            return Err(SlipError::invalid(
                "alarm.confirm_steps",
                self.confirm_steps,
                "must be in 1..=80000",
            ));
        }
        if !RELEASE_HOLD_STEPS.contains(&self.release_hold_steps) {
            return Err(SlipError::invalid(
                "alarm.release_hold_steps",
                self.release_hold_steps,
                "must be in 0..=80000",
            ));
        }
        Ok(())
    }

    /// How the rule reads in reports (`detection.csv`'s `alarm_rule`).
    pub fn describe(&self) -> String {
        let mut rule = format!(
            "on at p >= {}, off at p <= {}",
            self.on_probability, self.off_probability
        );
        if self.confirm_steps > 1 {
            rule += &format!(", on after {} steps", self.confirm_steps);
        }
        if self.release_hold_steps > 0 {
            rule += &format!(", off after {} steps", self.release_hold_steps);
        }
        rule
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
    /// Per drive: while not flagged, the consecutive steps at or above `on_probability`;
    /// while flagged, the steps since the probability fell to `off_probability` (0: not
    /// releasing).
    held_steps: Vec<usize>,
}

impl SlipAlarm {
    pub fn new(config: SlipAlarmConfig, n_drives: usize) -> Result<Self, SlipError> {
        config.validate()?;
        Ok(SlipAlarm {
            config,
            slipping: vec![false; n_drives],
            held_steps: vec![0; n_drives],
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
                self.resize(drive);
            }
            self.slipping[drive - 1] = slipping;
            self.held_steps[drive - 1] = 0;
        }
    }

    /// Keeps the flags of the first `n_drives` drives (a new source may have more or fewer).
    pub fn resize(&mut self, n_drives: usize) {
        self.slipping.resize(n_drives, false);
        self.held_steps.resize(n_drives, 0);
    }

    /// One step of the probabilities of every drive; the crossings, in drive order, are
    /// appended to `events`. Drives beyond the flags' count are ignored.
    pub fn update(&mut self, slip_probability: &[f64], events: &mut Vec<SlipAlarmEvent>) {
        let c = &self.config;
        let drives = self.slipping.iter_mut().zip(&mut self.held_steps);
        for (k, ((flag, held), &p)) in drives.zip(slip_probability).enumerate() {
            let kind = if !*flag {
                *held = if p >= c.on_probability { *held + 1 } else { 0 };
                if *held < c.confirm_steps {
                    continue;
                }
                SlipAlarmKind::SlipStarted
            } else {
                if p >= c.on_probability {
                    *held = 0;
                } else if *held > 0 || p <= c.off_probability {
                    *held += 1;
                }
                if *held == 0 || *held <= c.release_hold_steps {
                    continue;
                }
                SlipAlarmKind::SlipEnded
            };
            *held = 0;
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

    /// The hysteresis alone, without the holds in time.
    fn without_holds() -> SlipAlarmConfig {
        SlipAlarmConfig {
            confirm_steps: 1,
            release_hold_steps: 0,
            ..SlipAlarmConfig::default()
        }
    }

    #[test]
    fn hysteresis_on_a_hand_made_sequence() {
        let mut alarm = SlipAlarm::new(without_holds(), 2).unwrap();
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

    /// The steps (0-based) of the events of one drive over `ps`.
    fn event_steps(config: SlipAlarmConfig, ps: &[f64]) -> Vec<(usize, SlipAlarmKind)> {
        let mut alarm = SlipAlarm::new(config, 1).unwrap();
        let mut events = Vec::new();
        let mut seen = Vec::new();
        for (step, &p) in ps.iter().enumerate() {
            events.clear();
            alarm.update(&[p], &mut events);
            seen.extend(events.iter().map(|e| (step, e.kind)));
        }
        seen
    }

    #[test]
    fn confirmation_and_release_hold_on_a_hand_made_sequence() {
        use SlipAlarmKind::{SlipEnded, SlipStarted};
        let ps = [0.9, 0.5, 0.9, 0.9, 0.1, 0.5, 0.85, 0.1, 0.1, 0.1, 0.1];
        // Without holds: on at 0, off at 4, on at 6, off at 7.
        let plain = without_holds();
        assert_eq!(
            event_steps(plain, &ps),
            vec![
                (0, SlipStarted),
                (4, SlipEnded),
                (6, SlipStarted),
                (7, SlipEnded)
            ]
        );
        // Confirmed after 2 consecutive steps at or above 0.8: the lone 0.9 at 0 is not
        // enough, 2-3 is (on at 3); the lone 0.85 at 6 does not restart after the end at 4.
        let confirm = SlipAlarmConfig {
            confirm_steps: 2,
            ..plain
        };
        assert_eq!(
            event_steps(confirm, &ps),
            vec![(3, SlipStarted), (4, SlipEnded)]
        );
        // Released 2 steps after the fall to 0.2: the fall at 4 is followed by 0.85 at 6
        // (within the hold: the same episode), the fall at 7 by nothing (off at 9).
        let hold = SlipAlarmConfig {
            release_hold_steps: 2,
            ..plain
        };
        assert_eq!(
            event_steps(hold, &ps),
            vec![(0, SlipStarted), (9, SlipEnded)]
        );
        // A hold of 1 is too short to bridge the gap of 4-6: two episodes.
        let short_hold = SlipAlarmConfig {
            release_hold_steps: 1,
            ..plain
        };
        assert_eq!(
            event_steps(short_hold, &ps),
            vec![
                (0, SlipStarted),
                (5, SlipEnded),
                (6, SlipStarted),
                (8, SlipEnded)
            ]
        );
        assert_eq!(
            hold.describe(),
            "on at p >= 0.8, off at p <= 0.2, off after 2 steps"
        );
    }

    #[test]
    fn restored_flag_is_cleared_by_an_estimate_with_an_event() {
        let mut alarm = SlipAlarm::new(without_holds(), 0).unwrap();
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
                ..SlipAlarmConfig::default()
            };
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains(field), "{e}");
        };
        bad(1.5, 0.2, "alarm.on_probability");
        bad(0.0, 0.0, "alarm.on_probability");
        bad(0.8, 0.8, "alarm.off_probability");
        bad(0.8, -0.1, "alarm.off_probability");
        bad(0.8, f64::NAN, "alarm.off_probability");
        let no_confirmation = SlipAlarmConfig {
            confirm_steps: 0,
            ..SlipAlarmConfig::default()
        };
        let e = no_confirmation.validate().unwrap_err().to_string();
        assert!(e.contains("alarm.confirm_steps"), "{e}");
    }
}
