//! The bogie status as events: `damper_paused` / `damper_resumed` when the monitor stops or
//! starts learning (speed outside its valid range, `crate::speed::SpeedConfig`), and
//! `damper_model_mismatch` / `damper_model_ok` when its consistency check
//! (`crate::consistency`) starts or stops saying that its model does not explain the data.
//! Like the health alarm (`crate::alarm`) it lives next to the estimate it reads, so the
//! service and `railmon analyze damper` write the same events from the same data.

use serde::{Deserialize, Serialize};

use crate::estimate::DamperEstimate;
use crate::speed::PauseReason;

/// What a status event says.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BogieStatusEventKind {
    /// The monitor holds its posterior (`reason`: `low_speed` / `high_speed` / `gap`), or holds
    /// it for another reason than before.
    DamperPaused,
    /// The monitor learns again (the settling after a pause is over).
    DamperResumed,
    /// The consistency check says the filter's model does not explain the data (a wrong
    /// configuration, not a damper fault): the health alarm does not judge meanwhile.
    DamperModelMismatch,
    /// The consistency check is back inside its band.
    DamperModelOk,
}

impl BogieStatusEventKind {
    /// The event kind as the service stores it and `events.csv` writes it.
    pub fn as_str(self) -> &'static str {
        match self {
            BogieStatusEventKind::DamperPaused => "damper_paused",
            BogieStatusEventKind::DamperResumed => "damper_resumed",
            BogieStatusEventKind::DamperModelMismatch => "damper_model_mismatch",
            BogieStatusEventKind::DamperModelOk => "damper_model_ok",
        }
    }
}

/// A change of a bogie's status.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BogieStatusEvent {
    pub kind: BogieStatusEventKind,
    /// The monitor's time of the estimate that changed the status (s).
    pub time_s: f64,
    /// Why the monitor is paused (`damper_paused` only).
    pub reason: Option<PauseReason>,
    /// The speed of that estimate's sample (m/s).
    pub speed_m_s: f64,
    /// The consistency check's last window mean of the normalised innovation squared (5 when
    /// the model is the plant's; `None` before its first window).
    pub nis_window_mean: Option<f64>,
}

/// The detail of a status event, the same on every path (the service's event store and
/// `events.csv`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BogieStatusEventDetail {
    pub bogie: u32,
    /// `low_speed` / `high_speed` / `gap` for `damper_paused`, else absent.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reason: Option<&'static str>,
    pub speed_m_s: f64,
    /// Absent before the consistency check's first window (JSON has no NaN).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub nis_window_mean: Option<f64>,
}

impl BogieStatusEvent {
    /// Its detail for bogie `bogie`.
    pub fn detail(&self, bogie: u32) -> BogieStatusEventDetail {
        BogieStatusEventDetail {
            bogie,
            reason: self.reason.map(PauseReason::as_str),
            speed_m_s: self.speed_m_s,
            nis_window_mean: self.nis_window_mean.filter(|v| v.is_finite()),
        }
    }
}

/// The status last reported for one bogie; an event when an estimate reports another. Starts
/// learning and consistent (what a new monitor reports). A new source does not reset it: the
/// new monitor's first estimate reports its own status, and a change from the old source's
/// last one is an event, so the API's status never changes without one.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct BogieStatusWatch {
    paused: Option<PauseReason>,
    model_mismatch: bool,
}

impl BogieStatusWatch {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn paused(&self) -> Option<PauseReason> {
        self.paused
    }

    pub fn model_mismatch(&self) -> bool {
        self.model_mismatch
    }

    /// The events `estimate` raises (at most two: the pause first, then the model check), in
    /// the order they are to be stored.
    pub fn update(&mut self, estimate: &DamperEstimate) -> Vec<BogieStatusEvent> {
        let event = |kind, reason| BogieStatusEvent {
            kind,
            time_s: estimate.time_s,
            reason,
            speed_m_s: estimate.speed_m_s,
            nis_window_mean: estimate.nis_window_mean,
        };
        let mut events = Vec::new();
        if estimate.paused != self.paused {
            events.push(match estimate.paused {
                Some(reason) => event(BogieStatusEventKind::DamperPaused, Some(reason)),
                None => event(BogieStatusEventKind::DamperResumed, None),
            });
            self.paused = estimate.paused;
        }
        if estimate.model_mismatch != self.model_mismatch {
            events.push(event(
                if estimate.model_mismatch {
                    BogieStatusEventKind::DamperModelMismatch
                } else {
                    BogieStatusEventKind::DamperModelOk
                },
                None,
            ));
            self.model_mismatch = estimate.model_mismatch;
        }
        events
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::Dampers;
    use crate::rbpf::DamperPosterior;

    fn estimate(time_s: f64, paused: Option<PauseReason>, mismatch: bool) -> DamperEstimate {
        let post = |n: f64| DamperPosterior {
            mean_ns_per_m: n,
            q05_ns_per_m: 0.98 * n,
            q95_ns_per_m: 1.02 * n,
            health_ratio: 1.0,
        };
        DamperEstimate {
            time_s,
            csy: post(Dampers::NOMINAL.csy_ns_per_m),
            csay: post(Dampers::NOMINAL.csay_ns_per_m),
            effective_sample_size: 500.0,
            ekf: None,
            nis_window_mean: Some(if mismatch { 40.0 } else { 5.0 }),
            model_mismatch: mismatch,
            noise_std_ratio: [1.0; 5],
            paused,
            held_through_burst: false,
            speed_m_s: if paused.is_some() { 2.0 } else { 30.0 },
            measured_half_body_mass_kg: None,
        }
    }

    fn kinds(events: &[BogieStatusEvent]) -> Vec<&'static str> {
        events.iter().map(|e| e.kind.as_str()).collect()
    }

    /// One event per change, none while the status stays; a stop, a change of reason, a
    /// mismatch and its end each say so, in the order of the estimates.
    #[test]
    fn every_status_change_is_one_event_and_nothing_else_is() {
        use PauseReason::{HighSpeed, LowSpeed};
        let mut w = BogieStatusWatch::new();
        let script: [(Option<PauseReason>, bool, &[&str]); 9] = [
            (None, false, &[]),
            (None, false, &[]),
            (Some(LowSpeed), false, &["damper_paused"]),
            (Some(LowSpeed), false, &[]),
            (Some(HighSpeed), false, &["damper_paused"]),
            (None, false, &["damper_resumed"]),
            (None, true, &["damper_model_mismatch"]),
            (Some(LowSpeed), false, &["damper_paused", "damper_model_ok"]),
            (None, false, &["damper_resumed"]),
        ];
        for (k, (paused, mismatch, want)) in script.into_iter().enumerate() {
            let e = estimate(k as f64, paused, mismatch);
            let events = w.update(&e);
            assert_eq!(kinds(&events), want, "estimate {k}");
            for ev in &events {
                assert_eq!((ev.time_s, ev.speed_m_s), (e.time_s, e.speed_m_s));
                let paused_event = ev.kind == BogieStatusEventKind::DamperPaused;
                assert_eq!(ev.reason, if paused_event { paused } else { None });
            }
            assert_eq!((w.paused(), w.model_mismatch()), (paused, mismatch));
        }
    }

    /// A monitor paused from its first sample (a train at rest) says so at once.
    #[test]
    fn a_monitor_paused_from_the_start_raises_one_event_with_its_reason() {
        let mut w = BogieStatusWatch::new();
        let e = w.update(&estimate(0.001, Some(PauseReason::LowSpeed), false));
        assert_eq!(kinds(&e), ["damper_paused"]);
        let detail = serde_json::to_value(e[0].detail(3)).unwrap();
        assert_eq!(
            detail,
            serde_json::json!({"bogie": 3, "reason": "low_speed", "speed_m_s": 2.0, "nis_window_mean": 5.0})
        );
        let no_window = BogieStatusEvent {
            nis_window_mean: None,
            ..e[0]
        };
        assert!(serde_json::to_value(no_window.detail(3)).unwrap()["nis_window_mean"].is_null());
    }
}
