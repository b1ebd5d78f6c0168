//! Whether a stream's estimator keeps up with real time.

/// Whether a stream's estimator keeps up with the samples' own clock. Two measures, both
/// valid whether the source is paced (real time) or as fast as backpressure lets it go:
/// - load: estimator time over the advance of the sample time, per window of one second of
///   samples (several sources of one stream, e.g. the bogies, add their times);
/// - lag: (wall time - sample time) now minus its smallest value since the source started.
///   A source keeping up has a constant offset (its transport delay); an estimator falling
///   behind makes it grow (frames wait in the buffer, then backpressure slows the publisher,
///   whose samples then fall behind the wall clock).
#[derive(Clone, Debug, Default)]
pub struct RealTimeTracker {
    baseline_ns: Option<i128>,
    window_start_sample_ns: Option<u64>,
    window_busy_ns: u64,
}

impl RealTimeTracker {
    /// One second of sample time per load value.
    const WINDOW_NS: u64 = 1_000_000_000;

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
        let baseline = *self.baseline_ns.get_or_insert(offset);
        let baseline = baseline.min(offset);
        self.baseline_ns = Some(baseline);
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
}
