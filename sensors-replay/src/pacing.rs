//! When to send frame k: at `start + k dt / speed`, or at once for `--speed max`.

use std::str::FromStr;
use std::time::{Duration, Instant};

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Speed {
    /// Multiple of real time (1 = real time).
    Times(f64),
    /// As fast as the subscriber takes frames (lossless backpressure paces the publisher).
    Max,
}

impl FromStr for Speed {
    type Err = String;
    fn from_str(text: &str) -> Result<Self, String> {
        if text == "max" {
            return Ok(Speed::Max);
        }
        match text.parse::<f64>() {
            Ok(x) if x.is_finite() && x > 0.0 => Ok(Speed::Times(x)),
            _ => Err(format!(
                "`{text}`: expected a positive number (1 = real time) or `max`"
            )),
        }
    }
}

/// Absolute deadlines from the samples' own time stamps, so sleep overshoot never accumulates
/// (a late frame goes at once) and irregular recordings keep their rhythm.
pub struct Pacer {
    speed: Option<f64>,
    /// Wall-clock instant of stream time `origin`.
    start: Instant,
    origin: Duration,
}

impl Pacer {
    pub fn new(speed: Speed) -> Self {
        Self {
            speed: match speed {
                Speed::Times(x) => Some(x),
                Speed::Max => None,
            },
            start: Instant::now(),
            origin: Duration::ZERO,
        }
    }

    pub fn is_paced(&self) -> bool {
        self.speed.is_some()
    }

    /// Sleeps until the sample at stream time `time` is due (`start + (time - origin) / speed`).
    pub fn wait_until(&self, time: Duration) {
        if let Some(speed) = self.speed {
            let due = self.start + time.saturating_sub(self.origin).div_f64(speed);
            let now = Instant::now();
            if due > now {
                std::thread::sleep(due - now);
            }
        }
    }

    /// Restarts the schedule with stream time `time` due now (after waiting for a subscriber).
    pub fn reset(&mut self, time: Duration) {
        self.start = Instant::now();
        self.origin = time;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn speed_parses_numbers_and_max() {
        assert_eq!("1".parse::<Speed>().unwrap(), Speed::Times(1.0));
        assert_eq!("10".parse::<Speed>().unwrap(), Speed::Times(10.0));
        assert_eq!("max".parse::<Speed>().unwrap(), Speed::Max);
        assert!("0".parse::<Speed>().is_err());
        assert!("fast".parse::<Speed>().is_err());
        assert!("NaN".parse::<Speed>().is_err());
    }

    #[test]
    fn paced_frames_follow_the_schedule() {
        let pacer = Pacer::new(Speed::Times(2.0)); // samples 10 ms apart: one per 5 ms
        let start = Instant::now();
        for k in 0..11 {
            pacer.wait_until(Duration::from_millis(10 * k));
        }
        let elapsed = start.elapsed();
        assert!(elapsed >= Duration::from_millis(50), "{elapsed:?}");
        assert!(elapsed < Duration::from_millis(500), "{elapsed:?}");
    }

    #[test]
    fn reset_makes_the_given_time_due_now_and_max_never_waits() {
        let mut pacer = Pacer::new(Speed::Times(1.0));
        pacer.reset(Duration::from_secs(100));
        let start = Instant::now();
        pacer.wait_until(Duration::from_secs(100));
        pacer.wait_until(Duration::from_millis(100_020));
        let elapsed = start.elapsed();
        assert!(elapsed >= Duration::from_millis(20), "{elapsed:?}");
        assert!(elapsed < Duration::from_millis(500), "{elapsed:?}");
        let max = Pacer::new(Speed::Max);
        let start = Instant::now();
        max.wait_until(Duration::from_secs(3600));
        assert!(start.elapsed() < Duration::from_millis(100));
    }
}
