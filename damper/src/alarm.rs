//! The damper health alarm: the rule that turns the RBPF's posterior into `damper_degraded` /
//! `damper_recovered` events. It lives next to the estimate it judges so that the service and
//! `railmon analyze damper` raise the same events from the same data.

use serde::{Deserialize, Serialize};

use crate::estimate::DamperEstimate;
use crate::faults::DamperId;
use crate::filter_model::FilterModel;
use crate::DamperError;

/// Thresholds of the health flag of each damper.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct DamperAlarmConfig {
    /// A damper is degraded when its whole 90% interval (the 95% quantile) lies below this
    /// ratio of nominal.
    #[schemars(extend("exclusiveMinimum" = 0.0, "exclusiveMaximum" = 1.0))]
    pub degraded_below_ratio: f64,
    /// A degraded damper recovers when its whole 90% interval (the 5% quantile) lies above
    /// this ratio of nominal. Above `degraded_below_ratio`: the gap is the hysteresis.
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = 1.0))]
    pub recovered_above_ratio: f64,
    /// The interval must stay beyond the threshold for this much judged stream time before
    /// the flag changes (s). A transient excursion of the posterior (a burst of track input,
    /// noise the filter did not expect) does not raise an alarm; a failed damper stays failed.
    #[schemars(range(min = 0.0))]
    pub hold_s: f64,
    /// No flag changes until the filter has been judged this long since it started from its
    /// prior (s of judged stream time; pauses do not count). The RBPF's first seconds can be
    /// confidently wrong: on the speed profile with stops, resuming from rest at 5 m/s, one
    /// seed's `C_say` interval lay below 0.7 x nominal from 4.7 s after the start, a false
    /// `damper_degraded` at 9.7 s (7.3 false per hour in the robustness matrix); it had
    /// recovered by the end of the warm-up.
    #[schemars(range(min = 0.0))]
    pub warmup_s: f64,
}

impl Default for DamperAlarmConfig {
    fn default() -> Self {
        DamperAlarmConfig {
            degraded_below_ratio: 0.7,
            recovered_above_ratio: 0.8,
            hold_s: 3.0,
            warmup_s: 10.0,
        }
    }
}

impl DamperAlarmConfig {
    pub fn validate(&self) -> Result<(), DamperError> {
        let (below, above) = (self.degraded_below_ratio, self.recovered_above_ratio);
        if !(below > 0.0 && below < 1.0) {
            return Err(DamperError::InvalidParameter {
                field: "alarm.degraded_below_ratio",
                value: below,
                reason: "must be in (0, 1)",
            });
        }
        if !(above > below && above <= 1.0) {
            return Err(DamperError::InvalidParameter {
                field: "alarm.recovered_above_ratio",
                value: above,
                reason: "must be in (degraded_below_ratio, 1]",
            });
        }
        crate::params::non_negative("alarm.hold_s", self.hold_s)?;
        crate::params::non_negative("alarm.warmup_s", self.warmup_s)
    }
}

/// What an alarm event says.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DamperEventKind {
    DamperDegraded,
    DamperRecovered,
}

impl DamperEventKind {
    /// The event kind as the service stores it and `events.csv` writes it.
    pub fn as_str(self) -> &'static str {
        match self {
            DamperEventKind::DamperDegraded => "damper_degraded",
            DamperEventKind::DamperRecovered => "damper_recovered",
        }
    }
}

/// A change of a damper's health flag.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DamperEvent {
    pub kind: DamperEventKind,
    pub damper: DamperId,
    /// The monitor's time of the estimate that changed the flag (s).
    pub time_s: f64,
    /// Posterior mean / nominal at that estimate.
    pub health_ratio: f64,
}

/// The health flag of one damper of one bogie, judged on each new estimate.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DamperAlarm {
    damper: DamperId,
    config: DamperAlarmConfig,
    nominal_ns_per_m: f64,
    /// Stream time one estimate stands for (the sample period).
    dt_s: f64,
    degraded: bool,
    /// Judged time the interval has been beyond the threshold that would change the flag.
    beyond_s: f64,
    /// Judged time since the filter started from its prior (for `warmup_s`).
    #[serde(default)]
    judged_s: f64,
}

impl DamperAlarm {
    /// A healthy flag for `damper` (`degraded` = the flag carried over from before, e.g. an
    /// alarm active when the service stopped: it stays until an estimate clears it), judging
    /// the estimates of a monitor on `filter_model` (its nominal dampers and sample period).
    pub fn new(
        damper: DamperId,
        config: &DamperAlarmConfig,
        filter_model: &FilterModel,
        degraded: bool,
    ) -> Self {
        let nominal = filter_model.nominal;
        DamperAlarm {
            damper,
            config: *config,
            nominal_ns_per_m: [nominal.csy_ns_per_m, nominal.csay_ns_per_m][damper.index()],
            dt_s: filter_model.dt_s,
            degraded,
            beyond_s: 0.0,
            judged_s: 0.0,
        }
    }

    /// The flags of both dampers of a bogie, in [`DamperId::ALL`] order.
    pub fn pair(
        config: &DamperAlarmConfig,
        filter_model: &FilterModel,
        degraded: [bool; 2],
    ) -> [Self; 2] {
        DamperId::ALL.map(|d| DamperAlarm::new(d, config, filter_model, degraded[d.index()]))
    }

    /// A new source (a restart of the replay, a new run): its monitor starts from the prior,
    /// so the time beyond the threshold starts again. The flag itself carries over: a
    /// degraded damper stays degraded until the new estimates clear it, with an event.
    pub fn restart(&mut self) {
        self.beyond_s = 0.0;
        self.judged_s = 0.0;
    }

    pub fn damper(&self) -> DamperId {
        self.damper
    }

    pub fn degraded(&self) -> bool {
        self.degraded
    }

    /// Judges `estimate`; an event when the flag changes: when the whole 90% interval has
    /// been beyond the threshold (below `degraded_below_ratio` for a healthy damper, above
    /// `recovered_above_ratio` for a degraded one) for `hold_s` of judged time. On the
    /// interval, not the mean alone: in its first ~0.1 s the RBPF's mean wanders from the prior
    /// by tens of percent while its interval is still wide (spurious degraded/recovered pairs
    /// at 0.05-0.12 s in the e2e test when the mean was judged). Not judged while the filter
    /// reports `model_mismatch` (its posterior is then of a model that is not the plant: a
    /// warning, not a damper fault) or is paused (`paused`, speed out of range); the time
    /// beyond the threshold holds meanwhile.
    pub fn update(&mut self, estimate: &DamperEstimate) -> Option<DamperEvent> {
        // Paused (speed outside the model's range): the posterior is held, not new evidence.
        if estimate.model_mismatch || estimate.paused.is_some() {
            return None;
        }
        self.judged_s += self.dt_s;
        if self.judged_s + 0.5 * self.dt_s < self.config.warmup_s {
            return None;
        }
        let posterior = match self.damper {
            DamperId::Csy => estimate.csy,
            DamperId::Csay => estimate.csay,
        };
        let beyond = if self.degraded {
            posterior.q05_ns_per_m / self.nominal_ns_per_m > self.config.recovered_above_ratio
        } else {
            posterior.q95_ns_per_m / self.nominal_ns_per_m < self.config.degraded_below_ratio
        };
        if !beyond {
            self.beyond_s = 0.0;
            return None;
        }
        self.beyond_s += self.dt_s;
        // Half a step of slack: `hold_s` is a whole number of steps summed in floating point.
        if self.beyond_s + 0.5 * self.dt_s < self.config.hold_s {
            return None;
        }
        self.degraded = !self.degraded;
        self.beyond_s = 0.0;
        Some(DamperEvent {
            kind: if self.degraded {
                DamperEventKind::DamperDegraded
            } else {
                DamperEventKind::DamperRecovered
            },
            damper: self.damper,
            time_s: estimate.time_s,
            health_ratio: posterior.health_ratio,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::Dampers;
    use crate::rbpf::DamperPosterior;
    use crate::speed::PauseReason;
    use crate::DamperMonitorConfig;

    fn estimate(time_s: f64, csay: [f64; 3]) -> DamperEstimate {
        let nominal = Dampers::NOMINAL;
        let post = |n: f64, r: [f64; 3]| DamperPosterior {
            mean_ns_per_m: n * r[0],
            q05_ns_per_m: n * r[1],
            q95_ns_per_m: n * r[2],
            health_ratio: r[0],
        };
        DamperEstimate {
            time_s,
            csy: post(nominal.csy_ns_per_m, [1.0, 0.98, 1.02]),
            csay: post(nominal.csay_ns_per_m, csay),
            effective_sample_size: 500.0,
            ekf: None,
            nis_window_mean: Some(5.0),
            model_mismatch: false,
            noise_std_ratio: [1.0; 5],
            paused: None,
            held_through_burst: false,
            speed_m_s: 45.3,
            measured_half_body_mass_kg: None,
        }
    }

    /// A config with a 10-step hold (dt 0.1 s, hold 1 s).
    fn config() -> DamperMonitorConfig {
        let mut c = DamperMonitorConfig {
            dt_s: 0.1,
            ..DamperMonitorConfig::default()
        };
        c.alarm.hold_s = 1.0;
        // The warm-up has its own test.
        c.alarm.warmup_s = 0.0;
        c
    }

    /// No flag change in the first `warmup_s` of judged time (paused time does not count),
    /// nor after a restart until the new filter has had its warm-up.
    #[test]
    fn no_flag_changes_during_the_warm_up() {
        let mut c = config();
        c.alarm.warmup_s = 2.0;
        let mut csay = DamperAlarm::new(DamperId::Csay, &c.alarm, &c.filter_model(), false);
        let paused = DamperEstimate {
            paused: Some(PauseReason::LowSpeed),
            ..estimate(0.0, [0.4, 0.35, 0.45])
        };
        for _ in 0..100 {
            assert_eq!(csay.update(&paused), None);
        }
        // 2 s of warm-up (steps 1-19 not judged), then 1 s of hold (steps 20-29).
        assert!(feed(&mut csay, 0.0, 28, [0.4, 0.35, 0.45]).is_empty());
        assert_eq!(feed(&mut csay, 2.8, 1, [0.4, 0.35, 0.45]).len(), 1);
        // A new source: the flag holds through the new filter's warm-up, then clears.
        csay.restart();
        assert!(feed(&mut csay, 0.0, 28, [1.0, 0.95, 1.05]).is_empty());
        assert!(csay.degraded());
        assert_eq!(feed(&mut csay, 2.8, 1, [1.0, 0.95, 1.05]).len(), 1);
    }

    /// Feeds `n` steps of `csay` from `t0`; the events.
    fn feed(alarm: &mut DamperAlarm, t0: f64, n: usize, csay: [f64; 3]) -> Vec<DamperEvent> {
        (0..n)
            .filter_map(|k| alarm.update(&estimate(t0 + 0.1 * k as f64, csay)))
            .collect()
    }

    #[test]
    fn degraded_after_the_whole_interval_stayed_below_for_the_hold_time() {
        let c = config();
        let [mut csy, mut csay] = DamperAlarm::pair(&c.alarm, &c.filter_model(), [false; 2]);
        // Mean below 0.7 but the interval reaching above it: never.
        assert!(feed(&mut csay, 0.0, 50, [0.6, 0.4, 0.75]).is_empty());
        // Below for 9 steps, then a step above: the hold starts again.
        assert!(feed(&mut csay, 5.0, 9, [0.4, 0.35, 0.45]).is_empty());
        assert!(feed(&mut csay, 5.9, 1, [0.6, 0.4, 0.75]).is_empty());
        assert!(feed(&mut csay, 6.0, 9, [0.4, 0.35, 0.45]).is_empty());
        let e = feed(&mut csay, 6.9, 1, [0.4, 0.35, 0.45]);
        assert_eq!(e.len(), 1, "{e:?}");
        assert_eq!(e[0].kind, DamperEventKind::DamperDegraded);
        assert_eq!(
            (e[0].damper, e[0].time_s, e[0].health_ratio),
            (DamperId::Csay, 6.9, 0.4)
        );
        assert!(feed(&mut csy, 0.0, 50, [0.4, 0.35, 0.45]).is_empty());
        // Between the thresholds: still degraded.
        assert!(feed(&mut csay, 7.0, 50, [0.85, 0.75, 0.95]).is_empty());
        assert!(csay.degraded());
        let e = feed(&mut csay, 12.0, 10, [0.9, 0.85, 0.95]);
        assert_eq!(e.len(), 1);
        assert_eq!(e[0].kind.as_str(), "damper_recovered");
        assert!(!csay.degraded());
    }

    #[test]
    fn model_mismatch_holds_the_judgement_and_a_restart_keeps_the_flag() {
        let c = config();
        let mut csay = DamperAlarm::new(DamperId::Csay, &c.alarm, &c.filter_model(), false);
        assert!(feed(&mut csay, 0.0, 5, [0.4, 0.35, 0.45]).is_empty());
        let mismatch = DamperEstimate {
            model_mismatch: true,
            ..estimate(0.5, [0.4, 0.35, 0.45])
        };
        for _ in 0..100 {
            assert_eq!(csay.update(&mismatch), None);
        }
        // The 5 steps before the mismatch still count: 5 more raise it.
        assert_eq!(feed(&mut csay, 1.0, 5, [0.4, 0.35, 0.45]).len(), 1);
        // A new source: the flag stays until the new estimates clear it, with an event.
        csay.restart();
        assert!(csay.degraded());
        assert!(feed(&mut csay, 0.0, 50, [1.0, 0.5, 1.5]).is_empty());
        assert!(csay.degraded());
        assert_eq!(feed(&mut csay, 5.0, 10, [1.0, 0.95, 1.05]).len(), 1);
    }

    /// Paused (low speed): the judgement holds, as with a mismatch.
    #[test]
    fn a_paused_filter_holds_the_judgement() {
        let c = config();
        let mut csay = DamperAlarm::new(DamperId::Csay, &c.alarm, &c.filter_model(), false);
        assert!(feed(&mut csay, 0.0, 9, [0.4, 0.35, 0.45]).is_empty());
        let paused = DamperEstimate {
            paused: Some(PauseReason::LowSpeed),
            speed_m_s: 2.0,
            ..estimate(0.9, [0.4, 0.35, 0.45])
        };
        for _ in 0..100 {
            assert_eq!(csay.update(&paused), None);
        }
        assert!(!csay.degraded());
        // The 9 steps before the pause still count: the 10th raises it.
        assert_eq!(feed(&mut csay, 11.0, 1, [0.4, 0.35, 0.45]).len(), 1);
    }

    #[test]
    fn thresholds_out_of_order_are_rejected_by_name() {
        let bad = DamperAlarmConfig {
            degraded_below_ratio: 0.8,
            recovered_above_ratio: 0.7,
            ..DamperAlarmConfig::default()
        };
        assert!(matches!(
            bad.validate(),
            Err(DamperError::InvalidParameter {
                field: "alarm.recovered_above_ratio",
                ..
            })
        ));
        let bad = DamperAlarmConfig {
            hold_s: -1.0,
            ..DamperAlarmConfig::default()
        };
        assert!(bad.validate().is_err());
        let bad = DamperAlarmConfig {
            warmup_s: f64::NAN,
            ..DamperAlarmConfig::default()
        };
        assert!(bad.validate().is_err());
    }
}
