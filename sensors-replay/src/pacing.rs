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

/// Absolute deadlines, so sleep overshoot never accumulates: a late frame goes at once.
pub struct Pacer {
    start: Instant,
    period: Option<Duration>,
    frames: u64,
}

impl Pacer {
    pub fn new(speed: Speed, dt_s: f64) -> Self {
        Self {
            start: Instant::now(),
            period: match speed {
                Speed::Times(x) => Some(Duration::from_secs_f64(dt_s / x)),
                Speed::Max => None,
            },
            frames: 0,
        }
    }

    pub fn is_paced(&self) -> bool {
        self.period.is_some()
    }

    /// Sleeps until the next frame is due.
    pub fn wait_next(&mut self) {
        if let Some(period) = self.period {
            let due = self.start + period.mul_f64(self.frames as f64);
            let now = Instant::now();
            if due > now {
                std::thread::sleep(due - now);
            }
        }
        self.frames += 1;
    }

    /// Restarts the schedule (after waiting for a subscriber).
    pub fn reset(&mut self) {
        self.start = Instant::now();
        self.frames = 0;
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
        let mut pacer = Pacer::new(Speed::Times(2.0), 0.01); // one frame per 5 ms
        let start = Instant::now();
        for _ in 0..11 {
            pacer.wait_next();
        }
        let elapsed = start.elapsed();
        assert!(elapsed >= Duration::from_millis(50), "{elapsed:?}");
        assert!(elapsed < Duration::from_millis(500), "{elapsed:?}");
    }
}
