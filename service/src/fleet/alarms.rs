//! Which alarms are active, derived from a vehicle's events as the store derives them
//! (`store::NewEvent::alarm`): `slip_started` raises the drive's `slipping` alarm and
//! `slip_ended` clears it (subject: the drive); `damper_degraded` raises the damper's
//! `degraded` alarm and `damper_recovered` clears it (subject: `<bogie>/<damper>`). The events
//! on the wire carry no alarm field, so the kind decides. Pure: no I/O.

use std::collections::BTreeMap;

use crate::store::ActiveAlarm;

/// The alarm an event kind raises (`true`) or clears: `(stream, alarm, raised)`.
pub fn alarm_of(kind: &str) -> Option<(&'static str, &'static str, bool)> {
    match kind {
        "slip_started" => Some(("drive", "slipping", true)),
        "slip_ended" => Some(("drive", "slipping", false)),
        "damper_degraded" => Some(("bogie", "degraded", true)),
        "damper_recovered" => Some(("bogie", "degraded", false)),
        _ => None,
    }
}

/// What of an event the alarms need.
#[derive(Clone, Debug, PartialEq)]
pub struct AlarmEvent {
    pub id: u64,
    pub kind: String,
    pub subject: String,
    pub time_utc: String,
}

/// One vehicle's active alarms, keyed as the store keys them (stream, subject, alarm).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AlarmState {
    alarms: BTreeMap<(String, String, String), ActiveAlarm>,
}

impl AlarmState {
    /// Starts from a snapshot (`GET /api/v1/alarms` of the vehicle).
    pub fn from_snapshot(alarms: &[ActiveAlarm]) -> Self {
        let alarms = alarms
            .iter()
            .map(|a| {
                let key = (a.stream.clone(), a.subject.clone(), a.alarm.clone());
                (key, a.clone())
            })
            .collect();
        Self { alarms }
    }

    /// Applies one event (in id order): the last event of an alarm decides, so events the
    /// snapshot already reflected change nothing when applied again.
    pub fn apply(&mut self, event: &AlarmEvent) {
        let Some((stream, alarm, raised)) = alarm_of(&event.kind) else {
            return;
        };
        let key = (stream.to_string(), event.subject.clone(), alarm.to_string());
        match raised {
            true => {
                // A raise of an alarm already active keeps the event that raised it first.
                self.alarms.entry(key).or_insert_with(|| ActiveAlarm {
                    stream: stream.into(),
                    subject: event.subject.clone(),
                    alarm: alarm.into(),
                    event_id: event.id,
                    since_utc: event.time_utc.clone(),
                });
            }
            false => {
                self.alarms.remove(&key);
            }
        }
    }

    /// The active alarms, ordered as the vehicle orders them (stream, subject, alarm).
    pub fn active(&self) -> Vec<ActiveAlarm> {
        self.alarms.values().cloned().collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn event(id: u64, kind: &str, subject: &str) -> AlarmEvent {
        AlarmEvent {
            id,
            kind: kind.into(),
            subject: subject.into(),
            time_utc: format!("2026-11-28T00:00:{id:02}Z"),
        }
    }

    #[test]
    fn an_alarm_raised_and_not_cleared_is_active() {
        let mut state = AlarmState::default();
        state.apply(&event(1, "slip_started", "1"));
        state.apply(&event(2, "damper_degraded", "2/csay"));
        state.apply(&event(3, "regime_changed", ""));
        state.apply(&event(4, "slip_ended", "1"));
        state.apply(&event(5, "slip_started", "2"));
        let active = state.active();
        let keys: Vec<_> = active
            .iter()
            .map(|a| {
                (
                    a.stream.as_str(),
                    a.subject.as_str(),
                    a.alarm.as_str(),
                    a.event_id,
                )
            })
            .collect();
        assert_eq!(
            keys,
            [
                ("bogie", "2/csay", "degraded", 2),
                ("drive", "2", "slipping", 5)
            ]
        );
        assert_eq!(active[0].since_utc, "2026-11-28T00:00:02Z");
    }

    #[test]
    fn events_the_snapshot_reflected_change_nothing_when_applied_again() {
        let events = [
            event(1, "damper_degraded", "1/csy"),
            event(2, "slip_started", "3"),
            event(3, "damper_recovered", "1/csy"),
        ];
        let mut all = AlarmState::default();
        events.iter().for_each(|e| all.apply(e));
        // A snapshot made after event 2, then events 2 and 3 again.
        let mut snapshot = AlarmState::default();
        events[..2].iter().for_each(|e| snapshot.apply(e));
        let mut resumed = AlarmState::from_snapshot(&snapshot.active());
        events[1..].iter().for_each(|e| resumed.apply(e));
        assert_eq!(resumed.active(), all.active());
        assert_eq!(all.active().len(), 1);
    }
}
