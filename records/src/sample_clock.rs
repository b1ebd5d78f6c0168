//! The samples' own clock: time stamps of a source must advance by whole multiples of the
//! stream's configured period. Data at another rate (100 Hz bogie data for a 1 kHz model),
//! in other units (ms for s), going backwards or jumping far ahead would otherwise be
//! estimated as if it were right.
//!
//! Across a restart of the service the gap is judged otherwise ([`resume_rule`]): the first
//! frame after a resumed snapshot may be far ahead of the snapshot's last sample time (frames
//! estimated after the snapshot, the subscriber's buffer, the time the service was down), and
//! the resumed estimator steps on from it as long as that gap is within a bounded catch-up.
//!
//! The service's ingest and `railmon analyze` judge sample times with the same clock.

/// Why a frame or sample was not used: a short label (`time_jump`, `not_finite`, ...: the
/// service's metric `reason` and `analyze`'s `refused.csv` row) and what was wrong, in words.
#[derive(Clone, Debug, PartialEq)]
pub struct Rejection {
    pub reason: &'static str,
    pub message: String,
}

impl Rejection {
    pub fn new(reason: &'static str, message: impl Into<String>) -> Self {
        Self {
            reason,
            message: message.into(),
        }
    }
}

/// What a frame's sample time says.
#[derive(Clone, Debug, PartialEq)]
pub enum ClockCheck {
    Ok,
    /// The source's clock jumped and the frames after the jump agree with each other: a new
    /// timeline, which the estimator starts afresh.
    NewTimeline,
    Reject(Rejection),
}

/// Follows one source's sample times. See the module documentation.
#[derive(Clone, Debug)]
pub struct SampleClock {
    period_ns: u64,
    /// Frames may repeat a time (the bogies of one step).
    repeats_allowed: bool,
    /// A larger advance is a jump (the frame is refused unless the next one confirms it).
    max_advance_ns: u64,
    last_ns: Option<u64>,
    /// The time of a refused jump: if the next frame continues from it, the jump was real.
    jumped_to_ns: Option<u64>,
    /// Set by [`SampleClock::resume`] until a frame is used or the estimator restarts: the
    /// largest forward gap (ns) across the restart the resumed estimator steps over.
    catch_up_ns: Option<u64>,
    /// The time of the last frame seen ([`SampleClock::observe`]), used or not.
    seen_ns: Option<u64>,
    /// How many frames in a row arrived more than one period after the frame before.
    skipping_in_a_row: u32,
}

/// The frame that arrives more than one period after the one before, for the
/// `RATE_MISMATCH_AFTER`-th time in a row, is refused as `rate_mismatch` (and every one after it
/// while the source keeps skipping): a source that never sends consecutive periods runs at
/// another rate (100 Hz stamps on a 1 kHz stream, every other sample missing), and its samples
/// stepped one period apart would be estimated as if time ran 10 or 2 times slower. A sample
/// lost now and then (a regular one between) is a gap, bridged by the estimator.
pub const RATE_MISMATCH_AFTER: u32 = 3;

/// How the first frame after a resumed snapshot is judged against the snapshot's last sample
/// time. See [`resume_rule`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResumeVerdict {
    /// The sample clock goes on: the resumed estimator steps from this frame;
    /// `skipped_periods` sample periods between the two were never estimated by it.
    Keep { skipped_periods: u64 },
    /// The resumed state does not fit this frame (`reason`): the estimator starts afresh.
    Restart { reason: &'static str },
}

/// The resume rule: from the snapshot's last sample time `last_ns`, a frame at `next_ns`
/// keeps the resumed estimator when it is at most `catch_up_ns` ahead by whole periods of
/// `period_ns` (or at the same time, where `repeats_allowed`). Backwards, beyond the bound or
/// off the period grid, the estimator restarts. The stream's live staleness rule does not
/// apply here: a restart always loses some frames (those after the snapshot, the subscriber's
/// buffer, the downtime), and a filter converged over minutes is worth more than the
/// seconds lost.
pub fn resume_rule(
    last_ns: u64,
    next_ns: u64,
    period_ns: u64,
    repeats_allowed: bool,
    catch_up_ns: u64,
) -> ResumeVerdict {
    let period_ns = period_ns.max(1);
    let Some(advance) = next_ns.checked_sub(last_ns) else {
        return ResumeVerdict::Restart {
            reason: "time_backwards",
        };
    };
    if advance == 0 {
        return match repeats_allowed {
            true => ResumeVerdict::Keep { skipped_periods: 0 },
            false => ResumeVerdict::Restart {
                reason: "time_repeated",
            },
        };
    }
    if advance > catch_up_ns {
        return ResumeVerdict::Restart {
            reason: "beyond_catch_up",
        };
    }
    let periods = advance as f64 / period_ns as f64;
    if periods.round() < 1.0 || (periods - periods.round()).abs() > PERIOD_TOLERANCE {
        return ResumeVerdict::Restart {
            reason: "period_mismatch",
        };
    }
    ResumeVerdict::Keep {
        skipped_periods: periods.round() as u64 - 1,
    }
}

/// How far a time difference may be from a whole number of periods, as a share of a period.
pub const PERIOD_TOLERANCE: f64 = 0.01;

/// The default `stale_after_ms` of the service's drive stream (`[drive]`): also its clock's
/// largest advance between two samples, which `railmon analyze adhesion` judges by.
pub const DRIVE_STALE_AFTER_MS: u64 = 500;
/// The default `stale_after_ms` of the service's bogie stream (`[bogie]`), as
/// [`DRIVE_STALE_AFTER_MS`] for `railmon analyze damper`.
pub const BOGIE_STALE_AFTER_MS: u64 = 500;
/// The default `stale_after_ms` of the service's vehicle stream (`[vehicle]`), as
/// [`DRIVE_STALE_AFTER_MS`] for `railmon analyze fuel`.
pub const VEHICLE_STALE_AFTER_MS: u64 = 3000;

impl SampleClock {
    pub fn new(period_ns: u64, repeats_allowed: bool, max_advance_ns: u64) -> Self {
        Self {
            period_ns: period_ns.max(1),
            repeats_allowed,
            max_advance_ns: max_advance_ns.max(period_ns),
            last_ns: None,
            jumped_to_ns: None,
            catch_up_ns: None,
            seen_ns: None,
            skipping_in_a_row: 0,
        }
    }

    /// The sample periods between the last frame used and a frame at `sample_time_ns` that
    /// no frame covered (0 for the next period, a repeated time, or before the first frame):
    /// what the estimator has to bridge before it steps on this frame.
    pub fn skipped_periods(&self, sample_time_ns: u64) -> u64 {
        let Some(last) = self.last_ns else { return 0 };
        let advance = sample_time_ns.saturating_sub(last);
        ((advance as f64 / self.period_ns as f64).round() as u64).saturating_sub(1)
    }

    /// Every frame whose time was judged ([`SampleClock::check`] or
    /// [`SampleClock::judge_resume`]) is observed, used or refused: the source's own rate is
    /// followed from the frames it sends ([`RATE_MISMATCH_AFTER`]).
    pub fn observe(&mut self, sample_time_ns: u64) {
        if let Some(seen) = self.seen_ns {
            match sample_time_ns.checked_sub(seen) {
                Some(0) => return,
                Some(advance) if advance as f64 / self.period_ns as f64 >= 1.5 => {
                    self.skipping_in_a_row = self.skipping_in_a_row.saturating_add(1)
                }
                _ => self.skipping_in_a_row = 0,
            }
        }
        self.seen_ns = Some(sample_time_ns);
    }

    /// The last sample time used.
    pub fn last(&self) -> Option<u64> {
        self.last_ns
    }

    /// Goes on from `last_ns` (a resumed estimator); the first frame used after it is judged
    /// by [`resume_rule`] with `catch_up_ns` ([`SampleClock::judge_resume`]).
    pub fn resume(&mut self, last_ns: Option<u64>, catch_up_ns: u64) {
        self.last_ns = last_ns;
        self.jumped_to_ns = None;
        self.catch_up_ns = last_ns.map(|_| catch_up_ns);
    }

    /// Whether the clock was resumed and no frame has been used since.
    pub fn resume_pending(&self) -> bool {
        self.catch_up_ns.is_some()
    }

    /// While a resume is pending, the resume rule's verdict on a frame at `sample_time_ns`
    /// (`None`: no resume pending, [`SampleClock::check`] judges).
    pub fn judge_resume(&self, sample_time_ns: u64) -> Option<ResumeVerdict> {
        let (Some(catch_up_ns), Some(last)) = (self.catch_up_ns, self.last_ns) else {
            return None;
        };
        Some(resume_rule(
            last,
            sample_time_ns,
            self.period_ns,
            self.repeats_allowed,
            catch_up_ns.max(self.max_advance_ns),
        ))
    }

    /// Forgets the timeline (the estimator restarts); the source's rate is still followed.
    pub fn restart(&mut self) {
        self.last_ns = None;
        self.jumped_to_ns = None;
        self.catch_up_ns = None;
    }

    /// `rate_mismatch` when a frame at `sample_time_ns` would be the
    /// [`RATE_MISMATCH_AFTER`]-th in a row to arrive more than one period after the one before.
    fn rate(&self, sample_time_ns: u64) -> Result<(), Rejection> {
        let Some(seen) = self.seen_ns else {
            return Ok(());
        };
        let advance = sample_time_ns.saturating_sub(seen);
        let periods = advance as f64 / self.period_ns as f64;
        if periods < 1.5 || self.skipping_in_a_row + 1 < RATE_MISMATCH_AFTER {
            return Ok(());
        }
        Err(Rejection::new(
            "rate_mismatch",
            format!(
                "samples arrive {:.6} s apart, {} times in a row; the configured period is {:.6} s \
                 (data at another rate, or every other sample lost)",
                advance as f64 * 1e-9,
                self.skipping_in_a_row + 1,
                self.period_ns as f64 * 1e-9
            ),
        ))
    }

    /// Whether `from -> to` is a regular advance (whole periods, within the limit).
    fn regular(&self, from: u64, to: u64) -> Result<(), Rejection> {
        let period_s = self.period_ns as f64 * 1e-9;
        if to < from {
            return Err(Rejection::new(
                "time_backwards",
                format!(
                    "sample time {:.6} s is before the previous {:.6} s",
                    to as f64 * 1e-9,
                    from as f64 * 1e-9
                ),
            ));
        }
        let advance = to - from;
        if advance == 0 {
            return match self.repeats_allowed {
                true => Ok(()),
                false => Err(Rejection::new(
                    "time_repeated",
                    format!("sample time {:.6} s repeated", to as f64 * 1e-9),
                )),
            };
        }
        if advance > self.max_advance_ns {
            return Err(Rejection::new(
                "time_jump",
                format!(
                    "sample time jumps {:.6} s ahead (at most {:.3} s between samples)",
                    advance as f64 * 1e-9,
                    self.max_advance_ns as f64 * 1e-9
                ),
            ));
        }
        let periods = advance as f64 / self.period_ns as f64;
        if periods.round() < 1.0 || (periods - periods.round()).abs() > PERIOD_TOLERANCE {
            return Err(Rejection::new(
                "period_mismatch",
                format!(
                    "samples {:.6} s apart, not a multiple of the configured period {period_s:.6} s",
                    advance as f64 * 1e-9
                ),
            ));
        }
        Ok(())
    }

    /// Judges a frame's sample time; `accept` it if the frame is then used.
    pub fn check(&self, sample_time_ns: u64) -> ClockCheck {
        let Some(last) = self.last_ns else {
            return match self.rate(sample_time_ns) {
                Ok(()) => ClockCheck::Ok,
                Err(rejection) => ClockCheck::Reject(rejection),
            };
        };
        match self
            .regular(last, sample_time_ns)
            .and_then(|()| self.rate(sample_time_ns))
        {
            Ok(()) => ClockCheck::Ok,
            Err(rejection) => match self.jumped_to_ns {
                Some(jumped)
                    if self.regular(jumped, sample_time_ns).is_ok() && sample_time_ns > jumped =>
                {
                    ClockCheck::NewTimeline
                }
                _ => ClockCheck::Reject(rejection),
            },
        }
    }

    /// The frame at `sample_time_ns` was used.
    pub fn accept(&mut self, sample_time_ns: u64) {
        self.last_ns = Some(sample_time_ns);
        self.jumped_to_ns = None;
        self.catch_up_ns = None;
    }

    /// The frame at `sample_time_ns` was refused for `rejection`: after a jump (ahead or
    /// back), remember where to, in case the source really moved there. Data at another rate
    /// (`period_mismatch`) never starts a new timeline: it stays refused.
    pub fn refused(&mut self, sample_time_ns: u64, rejection: &Rejection) {
        if matches!(rejection.reason, "time_jump" | "time_backwards") {
            self.jumped_to_ns = Some(sample_time_ns);
        }
    }
}

/// The service's handling of one source's sample times (`handle_frame` in the service's
/// ingest), for a recording read offline, so the same times get the same verdicts: judge the
/// time first ([`TimeJudge::time`]: refuse it, or restart the estimator on a confirmed new
/// timeline), then the sample's content (the caller's checks), then carry the estimator over
/// the periods no sample covered ([`TimeJudge::skipped_periods`]), step, [`TimeJudge::used`].
#[derive(Clone, Debug)]
pub struct TimeJudge {
    clock: SampleClock,
    period_ns: u64,
}

impl TimeJudge {
    /// A source sampled every `period_ns`, repeats allowed or not, at most `max_advance_ms`
    /// between samples (the stream's `stale_after_ms`).
    pub fn new(period_ns: u64, repeats_allowed: bool, max_advance_ms: u64) -> Self {
        Self {
            clock: SampleClock::new(
                period_ns,
                repeats_allowed,
                max_advance_ms.saturating_mul(1_000_000),
            ),
            period_ns: period_ns.max(1),
        }
    }

    /// A sample time in seconds as the bus carries it (ns, rounded, as `sensors-replay`
    /// stamps it); `None` for a negative or non-finite time, which no frame can carry.
    pub fn ns_of(time_s: f64) -> Option<u64> {
        (time_s.is_finite() && time_s >= 0.0 && time_s * 1e9 < u64::MAX as f64)
            .then(|| (time_s * 1e9).round() as u64)
    }

    /// Judges a sample's time: `Ok(true)` when it starts a new timeline (the source's clock
    /// jumped and this sample confirms it: restart the estimator), `Ok(false)` when it goes
    /// on, or why it is refused.
    pub fn time(&mut self, time_ns: u64) -> Result<bool, Rejection> {
        let check = self.clock.check(time_ns);
        self.clock.observe(time_ns);
        match check {
            ClockCheck::Ok => Ok(false),
            ClockCheck::NewTimeline => {
                self.clock.restart();
                Ok(true)
            }
            ClockCheck::Reject(rejection) => {
                self.clock.refused(time_ns, &rejection);
                Err(rejection)
            }
        }
    }

    /// The periods before a sample at `time_ns` (time and content judged good) that no sample
    /// covered: the estimator bridges them before it steps this sample, which it then stands
    /// one period before, whether its step succeeds or not.
    pub fn skipped_periods(&mut self, time_ns: u64) -> u64 {
        let skipped = self.clock.skipped_periods(time_ns);
        if skipped > 0 {
            self.clock.accept(time_ns.saturating_sub(self.period_ns));
        }
        skipped
    }

    /// The sample at `time_ns` was stepped.
    pub fn used(&mut self, time_ns: u64) {
        self.clock.accept(time_ns);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn reason(check: ClockCheck) -> &'static str {
        match check {
            ClockCheck::Reject(r) => r.reason,
            other => panic!("expected a rejection, got {other:?}"),
        }
    }

    #[test]
    fn whole_periods_pass_other_rates_and_backwards_time_do_not() {
        let mut c = SampleClock::new(MS, false, 500 * MS);
        assert_eq!(c.check(7 * MS), ClockCheck::Ok);
        c.accept(7 * MS);
        assert_eq!(c.check(8 * MS), ClockCheck::Ok);
        assert_eq!(
            c.check(10 * MS),
            ClockCheck::Ok,
            "two samples lost at the source"
        );
        assert_eq!(reason(c.check(7 * MS + MS / 2)), "period_mismatch");
        assert_eq!(reason(c.check(6 * MS)), "time_backwards");
        assert_eq!(reason(c.check(7 * MS)), "time_repeated");
        let mut hundred_hz = SampleClock::new(MS, false, 500 * MS);
        hundred_hz.accept(0);
        assert_eq!(
            reason(hundred_hz.check(10 * MS + MS / 3)),
            "period_mismatch"
        );
    }

    /// Judges and observes a frame as the ingest loop does; whether it was used.
    fn offer(c: &mut SampleClock, t: u64) -> Result<(), &'static str> {
        let check = c.check(t);
        c.observe(t);
        match check {
            ClockCheck::Ok => {
                c.accept(t);
                Ok(())
            }
            ClockCheck::Reject(r) => {
                c.refused(t, &r);
                Err(r.reason)
            }
            ClockCheck::NewTimeline => panic!("no jump here"),
        }
    }

    #[test]
    fn a_source_at_another_rate_is_refused_and_a_lost_sample_is_a_gap() {
        // 100 Hz stamps on a 1 kHz stream: the third frame in a row 10 periods apart is
        // refused, and every one after it.
        let mut c = SampleClock::new(MS, false, 500 * MS);
        let used: Vec<_> = (0..10).map(|k| offer(&mut c, 10 * k * MS)).collect();
        assert_eq!(used[..3], [Ok(()), Ok(()), Ok(())]);
        assert!(
            used[3..].iter().all(|u| *u == Err("rate_mismatch")),
            "{used:?}"
        );
        // Every other sample lost: the same.
        let mut c = SampleClock::new(MS, false, 500 * MS);
        let used: Vec<_> = (0..10).map(|k| offer(&mut c, 2 * k * MS)).collect();
        assert_eq!(used.iter().filter(|u| u.is_err()).count(), 7, "{used:?}");
        // A sample lost now and then is bridged: its period is skipped, nothing refused.
        let mut c = SampleClock::new(MS, false, 500 * MS);
        for t in [0, 1, 2, 4, 5, 7, 8, 9, 12, 13] {
            assert_eq!(
                c.skipped_periods(t * MS),
                if t == 0 {
                    0
                } else {
                    match t {
                        4 | 7 => 1,
                        12 => 2,
                        _ => 0,
                    }
                }
            );
            assert_eq!(offer(&mut c, t * MS), Ok(()), "at {t} ms");
        }
        // Two lost in a row then regular again: two skipping arrivals, not a rate.
        for t in [15, 17, 18, 19] {
            assert_eq!(offer(&mut c, t * MS), Ok(()), "at {t} ms");
        }
        // The bogies of one step share a time: repeats do not count as arrivals.
        let mut c = SampleClock::new(MS, true, 500 * MS);
        for t in [0, 0, 0, 2, 2, 2, 3, 3, 3, 5, 5, 5] {
            assert_eq!(offer(&mut c, t * MS), Ok(()), "at {t} ms");
        }
    }

    #[test]
    fn an_outlier_is_refused_and_a_confirmed_jump_is_a_new_timeline() {
        let mut c = SampleClock::new(MS, true, 500 * MS);
        c.accept(0);
        assert_eq!(
            c.check(0),
            ClockCheck::Ok,
            "bogies of one step share a time"
        );
        // One absurd stamp, then the old timeline goes on: only the outlier is refused.
        let outlier = c.check(u64::MAX);
        assert_eq!(reason(outlier.clone()), "time_jump");
        if let ClockCheck::Reject(r) = &outlier {
            c.refused(u64::MAX, r);
        }
        assert_eq!(c.check(MS), ClockCheck::Ok);
        c.accept(MS);
        // A real jump: the next frame continues from the new time.
        let ClockCheck::Reject(jump) = c.check(3_600_000 * MS) else {
            panic!("a jump of an hour passed")
        };
        assert_eq!(jump.reason, "time_jump");
        c.refused(3_600_000 * MS, &jump);
        assert_eq!(c.check(3_600_001 * MS), ClockCheck::NewTimeline);
        // A source at another rate stays refused, however consistent its own stamps.
        let mut off = SampleClock::new(MS, false, 500 * MS);
        off.accept(0);
        let ClockCheck::Reject(half) = off.check(MS / 2) else {
            panic!("half a period passed")
        };
        off.refused(MS / 2, &half);
        assert_eq!(reason(off.check(MS / 2 + MS)), "period_mismatch");
    }

    #[test]
    fn the_resume_rule_keeps_a_forward_gap_within_the_catch_up() {
        let s = 1_000 * MS;
        // 2 s lost at 1 kHz (the live rule would call it a jump past 500 ms): kept.
        assert_eq!(
            resume_rule(10 * s, 12 * s, MS, false, 600 * s),
            ResumeVerdict::Keep {
                skipped_periods: 1999
            }
        );
        assert_eq!(
            resume_rule(10 * s, 10 * s + MS, MS, false, 600 * s),
            ResumeVerdict::Keep { skipped_periods: 0 }
        );
        // The bound itself is kept, one period more is not.
        assert_eq!(
            resume_rule(0, 600 * s, MS, false, 600 * s),
            ResumeVerdict::Keep {
                skipped_periods: 599_999
            }
        );
        assert_eq!(
            resume_rule(0, 600 * s + MS, MS, false, 600 * s),
            ResumeVerdict::Restart {
                reason: "beyond_catch_up"
            }
        );
        // Backwards (a replay started over), repeated, off the grid: restart.
        assert_eq!(
            resume_rule(10 * s, 0, MS, false, 600 * s),
            ResumeVerdict::Restart {
                reason: "time_backwards"
            }
        );
        assert_eq!(
            resume_rule(10 * s, 10 * s, MS, false, 600 * s),
            ResumeVerdict::Restart {
                reason: "time_repeated"
            }
        );
        assert_eq!(
            resume_rule(10 * s, 10 * s, MS, true, 600 * s),
            ResumeVerdict::Keep { skipped_periods: 0 },
            "the other bogies of the last step"
        );
        assert_eq!(
            resume_rule(10 * s, 10 * s + 3 * MS / 2, MS, false, 600 * s),
            ResumeVerdict::Restart {
                reason: "period_mismatch"
            }
        );
    }

    #[test]
    fn a_resumed_clock_judges_its_first_used_frame_by_the_resume_rule_only() {
        let s = 1_000 * MS;
        let mut c = SampleClock::new(MS, false, 500 * MS);
        c.resume(Some(10 * s), 600 * s);
        assert!(c.resume_pending());
        assert_eq!(
            c.judge_resume(14 * s),
            Some(ResumeVerdict::Keep {
                skipped_periods: 3999
            })
        );
        // A frame refused for its content leaves the resume pending.
        assert!(c.resume_pending());
        c.accept(14 * s);
        assert!(!c.resume_pending());
        assert_eq!(c.judge_resume(20 * s), None);
        assert_eq!(reason(c.check(20 * s)), "time_jump", "the live rule again");
        // Nothing to go on from: no resume rule.
        let mut fresh = SampleClock::new(MS, false, 500 * MS);
        fresh.resume(None, 600 * s);
        assert!(!fresh.resume_pending());
        // The catch-up is never below the live limit.
        let mut small = SampleClock::new(MS, false, 500 * MS);
        small.resume(Some(0), 0);
        assert_eq!(
            small.judge_resume(400 * MS),
            Some(ResumeVerdict::Keep {
                skipped_periods: 399
            })
        );
        small.restart();
        assert!(!small.resume_pending());
    }

    #[test]
    fn the_offline_judge_refuses_other_rates_restarts_on_a_jump_and_bridges_a_gap() {
        // 100 Hz stamps on a 1 kHz stream: all but the first three refused as rate_mismatch.
        let mut j = TimeJudge::new(MS, true, BOGIE_STALE_AFTER_MS);
        let reasons: Vec<_> = (0..10u64)
            .map(|k| match j.time(10 * k * MS) {
                Ok(_) => {
                    j.skipped_periods(10 * k * MS);
                    j.used(10 * k * MS);
                    "used"
                }
                Err(r) => r.reason,
            })
            .collect();
        assert_eq!(reasons[..3], ["used"; 3]);
        assert!(
            reasons[3..].iter().all(|r| *r == "rate_mismatch"),
            "{reasons:?}"
        );
        // An hour's jump: the first sample after it refused, the next starts a new timeline.
        let mut j = TimeJudge::new(MS, false, DRIVE_STALE_AFTER_MS);
        for t in [0, MS, 2 * MS] {
            assert_eq!(j.time(t), Ok(false));
            j.used(t);
        }
        let hour = 3_600_000 * MS;
        assert_eq!(j.time(hour).map_err(|r| r.reason), Err("time_jump"));
        assert_eq!(j.time(hour + MS), Ok(true));
        assert_eq!(j.skipped_periods(hour + MS), 0);
        j.used(hour + MS);
        // One sample lost: one period bridged, and the clock goes on from the sample.
        assert_eq!(j.time(hour + 3 * MS), Ok(false));
        assert_eq!(j.skipped_periods(hour + 3 * MS), 1);
        j.used(hour + 3 * MS);
        assert_eq!(j.time(hour + 4 * MS), Ok(false));
        assert_eq!(j.skipped_periods(hour + 4 * MS), 0);
        assert_eq!(TimeJudge::ns_of(-0.001), None);
        assert_eq!(TimeJudge::ns_of(0.001), Some(MS));
    }
}
