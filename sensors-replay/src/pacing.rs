//! When to send each frame: at the samples' own time stamps divided by the speed, starting at
//! the first sample whatever its time (time of day, the epoch), with gaps longer than
//! `max_gap` shortened to `max_gap`; or at once for `--speed max`. Waits end within
//! [`STOP_POLL`] of a stop request.

use std::str::FromStr;
use std::time::{Duration, Instant};

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Speed {
    /// Multiple of real time (1 = real time).
    Times(f64),
    /// As fast as the subscriber takes frames (lossless backpressure paces the publisher).
    Max,
}

/// The slowest and fastest paced speeds: below, a second of data would take over eleven days
/// (`1e-300` overflowed the schedule, a panic); above, use `max`.
pub const SPEED_RANGE: (f64, f64) = (1e-3, 1e6);

/// How often a wait looks at the stop flag: SIGINT / SIGTERM end a replay within 100 ms.
pub const STOP_POLL: Duration = Duration::from_millis(10);

impl FromStr for Speed {
    type Err = String;
    fn from_str(text: &str) -> Result<Self, String> {
        if text == "max" {
            return Ok(Speed::Max);
        }
        let (min, max) = SPEED_RANGE;
        match text.parse::<f64>() {
            Ok(x) if x.is_finite() && (min..=max).contains(&x) => Ok(Speed::Times(x)),
            _ => Err(format!(
                "`{text}`: expected a number in [{min}, {max}] (1 = real time) or `max`"
            )),
        }
    }
}

/// Absolute deadlines from the samples' own time stamps, so sleep overshoot never accumulates
/// (a late frame goes at once) and irregular recordings keep their rhythm. The schedule is
/// anchored at the first sample (due at once) and re-anchored after a gap longer than
/// `max_gap` (the rest of the gap is skipped) or a step back in time (due with the previous
/// sample): a recording stamped with the time of day used to wait hours before its first frame.
pub struct Pacer {
    speed: Option<f64>,
    max_gap: Duration,
    /// Wall-clock instant of stream time `origin`.
    start: Instant,
    origin: Duration,
    /// Stream time of the previous sample, once there is one.
    last: Option<Duration>,
}

impl Pacer {
    pub fn new(speed: Speed, max_gap: Duration) -> Self {
        Self {
            speed: match speed {
                Speed::Times(x) => Some(x),
                Speed::Max => None,
            },
            max_gap,
            start: Instant::now(),
            origin: Duration::ZERO,
            last: None,
        }
    }

    pub fn is_paced(&self) -> bool {
        self.speed.is_some()
    }

    /// When stream time `time` is due on the current anchor (`None`: beyond any clock).
    fn due(&self, speed: f64, time: Duration) -> Option<Instant> {
        self.start
            .checked_add(time.saturating_sub(self.origin).div_f64(speed))
    }

    /// Sleeps until the sample at stream time `time` is due; false when `stop()` said so first.
    pub fn wait_until(&mut self, time: Duration, stop: &dyn Fn() -> bool) -> bool {
        let Some(speed) = self.speed else {
            return true;
        };
        match self.last {
            None => self.reset(time),
            Some(last) if time < last => {
                // Due with the previous sample.
                self.start = self.due(speed, last).unwrap_or_else(Instant::now);
                self.origin = time;
            }
            Some(last) if time - last > self.max_gap => {
                // Due `max_gap` after the previous sample.
                let previous = self.due(speed, last).unwrap_or_else(Instant::now);
                self.start = previous
                    .checked_add(self.max_gap.div_f64(speed))
                    .unwrap_or(previous);
                self.origin = time;
            }
            Some(_) => {}
        }
        self.last = Some(time);
        let due = self.due(speed, time);
        loop {
            let now = Instant::now();
            let left = due.map_or(STOP_POLL, |due| due.saturating_duration_since(now));
            if left.is_zero() {
                return true;
            }
            if stop() {
                return false;
            }
            std::thread::sleep(left.min(STOP_POLL));
        }
    }

    /// Restarts the schedule with stream time `time` due now (after waiting for a subscriber).
    pub fn reset(&mut self, time: Duration) {
        self.start = Instant::now();
        self.origin = time;
        self.last = Some(time);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const NEVER: &dyn Fn() -> bool = &|| false;

    #[test]
    fn speed_parses_numbers_and_max() {
        assert_eq!("1".parse::<Speed>().unwrap(), Speed::Times(1.0));
        assert_eq!("10".parse::<Speed>().unwrap(), Speed::Times(10.0));
        assert_eq!("max".parse::<Speed>().unwrap(), Speed::Max);
        assert!("0".parse::<Speed>().is_err());
        assert!("fast".parse::<Speed>().is_err());
        assert!("NaN".parse::<Speed>().is_err());
        for bad in ["1e-300", "1e300", "inf", "-1"] {
            let err = bad.parse::<Speed>().unwrap_err();
            assert!(err.contains("[0.001, 1000000]"), "{bad}: {err}");
        }
    }

    #[test]
    fn paced_frames_follow_the_schedule() {
        let mut pacer = Pacer::new(Speed::Times(2.0), Duration::from_secs(1)); // 10 ms apart: one per 5 ms
        let start = Instant::now();
        for k in 0..11 {
            assert!(pacer.wait_until(Duration::from_millis(10 * k), NEVER));
        }
        let elapsed = start.elapsed();
        assert!(elapsed >= Duration::from_millis(50), "{elapsed:?}");
        assert!(elapsed < Duration::from_millis(500), "{elapsed:?}");
    }

    #[test]
    fn the_first_sample_is_due_at_once_whatever_its_time_and_long_gaps_are_shortened() {
        let mut pacer = Pacer::new(Speed::Times(1.0), Duration::from_millis(30));
        let start = Instant::now();
        // Epoch time stamps, then a gap of a million seconds.
        let epoch = Duration::from_secs(1_763_900_000);
        assert!(pacer.wait_until(epoch, NEVER));
        assert!(pacer.wait_until(epoch + Duration::from_millis(20), NEVER));
        assert!(pacer.wait_until(epoch + Duration::from_secs(1_000_000), NEVER));
        // A step back is due at once with the previous sample.
        assert!(pacer.wait_until(epoch, NEVER));
        let elapsed = start.elapsed();
        // 20 ms of data, then the gap shortened to 30 ms.
        assert!(elapsed >= Duration::from_millis(50), "{elapsed:?}");
        assert!(elapsed < Duration::from_millis(500), "{elapsed:?}");
    }

    #[test]
    fn a_stop_request_ends_a_long_wait_within_the_poll_interval() {
        let mut pacer = Pacer::new(Speed::Times(1e-3), Duration::from_secs(3600));
        assert!(pacer.wait_until(Duration::ZERO, NEVER));
        let start = Instant::now();
        let stop = || start.elapsed() > Duration::from_millis(30);
        assert!(!pacer.wait_until(Duration::from_secs(10), &stop));
        let elapsed = start.elapsed();
        assert!(elapsed < Duration::from_millis(100), "{elapsed:?}");
    }

    #[test]
    fn reset_makes_the_given_time_due_now_and_max_never_waits() {
        let mut pacer = Pacer::new(Speed::Times(1.0), Duration::from_secs(1));
        pacer.reset(Duration::from_secs(100));
        let start = Instant::now();
        pacer.wait_until(Duration::from_secs(100), NEVER);
        pacer.wait_until(Duration::from_millis(100_020), NEVER);
        let elapsed = start.elapsed();
        assert!(elapsed >= Duration::from_millis(20), "{elapsed:?}");
        assert!(elapsed < Duration::from_millis(500), "{elapsed:?}");
        let mut max = Pacer::new(Speed::Max, Duration::from_secs(1));
        let start = Instant::now();
        max.wait_until(Duration::from_secs(3600), NEVER);
        assert!(start.elapsed() < Duration::from_millis(100));
    }
}
