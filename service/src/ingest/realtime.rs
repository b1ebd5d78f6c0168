//! Whether a stream's estimator keeps up with real time.

/// Whether a stream's estimator keeps up with the samples' own clock. Two measures, both
/// valid whether the source is paced (real time) or as fast as backpressure lets it go:
/// - load: estimator time over the advance of the sample time, per window of one second of
///   samples (several sources of one stream, e.g. the bogies, add their times);
/// - lag: (wall time - sample time) now minus its smallest value over the last
///   [`Self::BASELINE_WINDOW_NS`] to twice that of sample time. A source keeping up has a
///   constant offset (its transport delay); an estimator falling behind makes it grow (frames
///   wait in the buffer, then backpressure slows the publisher, whose samples then fall behind
///   the wall clock).
///
/// Why a window and not the smallest offset since the source started: a source whose clock
/// moved on (a publisher that waited out a stall under backpressure and went on from its new
/// start, as `sensors-replay` does; a device that re-anchored its clock) keeps a larger constant
/// offset ever after. Measured from the start, the lag then stayed at the stall's length, the
/// stream `lagging` and `/readyz` 503 until the source restarted, with the estimator at load
/// 0.2-0.5 (the docker soak of issue 13: 3.48 s for the whole run after one stall). Over the
/// window the lag shows the stall and then falls back; an estimator that stays behind keeps
/// its offset growing, and its load above 1.
#[derive(Clone, Debug, Default)]
pub struct RealTimeTracker {
    /// Smallest offset of the current baseline window and the one before it.
    baseline: OffsetMinimum,
    window_start_sample_ns: Option<u64>,
    window_busy_ns: u64,
}

/// The smallest (wall - sample time) offset over the current window of sample time and the
/// previous one.
#[derive(Clone, Debug, Default)]
struct OffsetMinimum {
    start_sample_ns: Option<u64>,
    current: Option<i128>,
    previous: Option<i128>,
}

impl OffsetMinimum {
    fn observe(&mut self, sample_time_ns: u64, offset: i128, window_ns: u64) -> i128 {
        let start = *self.start_sample_ns.get_or_insert(sample_time_ns);
        if sample_time_ns.saturating_sub(start) >= window_ns {
            self.previous = self.current.take();
            self.start_sample_ns = Some(sample_time_ns);
        }
        let current = self.current.map_or(offset, |m| m.min(offset));
        self.current = Some(current);
        self.previous.map_or(current, |p| p.min(current))
    }
}

impl RealTimeTracker {
    /// One second of sample time per load value.
    const WINDOW_NS: u64 = 1_000_000_000;
    /// The lag's baseline is the smallest offset over the last 30-60 s of sample time: a stall
    /// shows for at least that long (longer than the `for:` of the lagging alert), and a
    /// source's new constant offset is forgotten after it.
    pub const BASELINE_WINDOW_NS: u64 = 30_000_000_000;

    pub fn restart(&mut self) {
        *self = Self::default();
    }

    /// A frame of sample time `sample_time_ns` was estimated at `done_at_ns` (monotonic) in
    /// `step_ns`; returns the lag (ns) and the load when a window closed.
    pub fn observe(
        &mut self,
        sample_time_ns: u64,
        done_at_ns: u64,
        step_ns: u64,
    ) -> (u64, Option<f64>) {
        let offset = i128::from(done_at_ns) - i128::from(sample_time_ns);
        let baseline = self
            .baseline
            .observe(sample_time_ns, offset, Self::BASELINE_WINDOW_NS);
        let lag_ns = u64::try_from(offset - baseline).unwrap_or(u64::MAX);
        self.window_busy_ns += step_ns;
        let start = *self.window_start_sample_ns.get_or_insert(sample_time_ns);
        let advanced = sample_time_ns.saturating_sub(start);
        let load = (advanced >= Self::WINDOW_NS).then(|| {
            let load = self.window_busy_ns as f64 / advanced as f64;
            self.window_start_sample_ns = Some(sample_time_ns);
            self.window_busy_ns = 0;
            load
        });
        (lag_ns, load)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn realtime_tracker_sees_an_estimator_falling_behind() {
        let mut t = RealTimeTracker::default();
        // Keeping up: each 1 ms sample done 50 us after its time (+ a constant 7 s offset).
        let mut load = None;
        for k in 0..=1000u64 {
            let (lag, l) = t.observe(
                k * 1_000_000,
                7_000_000_000 + k * 1_000_000 + 50_000,
                50_000,
            );
            assert_eq!(lag, 0);
            load = l.or(load);
        }
        assert!((load.unwrap() - 0.05).abs() < 1e-3, "{load:?}");
        // Falling behind: 2 ms per 1 ms sample -> the lag grows by 1 ms per sample.
        t.restart();
        let mut last = (0, None);
        for k in 0..=1000u64 {
            last = t.observe(k * 1_000_000, k * 2_000_000, 2_000_000);
        }
        assert_eq!(last.0, 1_000_000_000);
        assert!((last.1.unwrap() - 2.0).abs() < 1e-2, "{last:?}");
    }

    /// A source that stalled once and went on from a new start (its offset 3.5 s larger ever
    /// after), estimated at load 0.05: lagging by 3.5 s for one to two baseline windows, then 0.
    #[test]
    fn a_source_that_moved_its_clock_is_not_lagging_forever() {
        let mut t = RealTimeTracker::default();
        let window_ms = RealTimeTracker::BASELINE_WINDOW_NS / 1_000_000;
        let stall_at_ms = 10_000;
        let mut lags = Vec::new();
        for k in 0..(stall_at_ms + 3 * window_ms) {
            let offset_ns = if k < stall_at_ms { 0 } else { 3_500_000_000 };
            let (lag, _) = t.observe(k * 1_000_000, k * 1_000_000 + 50_000 + offset_ns, 50_000);
            lags.push(lag);
        }
        let at = |ms: u64| lags[ms as usize] as f64 * 1e-9;
        assert_eq!(at(stall_at_ms - 1), 0.0);
        assert!((at(stall_at_ms) - 3.5).abs() < 1e-9);
        // Still shown a whole window after the stall...
        assert!((at(stall_at_ms + window_ms - 1) - 3.5).abs() < 1e-9);
        // ... and forgotten two windows after it.
        assert_eq!(at(stall_at_ms + 2 * window_ms + window_ms / 2), 0.0);
    }
}
