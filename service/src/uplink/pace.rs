//! Pure timing of the uplink: the rate limit of a draining backlog and the retry backoff.

use std::time::{Duration, Instant};

/// At most `rate` events per second on average, no burst: each event is due one interval after
/// the previous one, or now if the uplink was idle.
pub struct Pacer {
    interval: Duration,
    next: Option<Instant>,
}

impl Pacer {
    pub fn new(max_events_per_s: u32) -> Self {
        Self {
            interval: Duration::from_secs(1) / max_events_per_s.max(1),
            next: None,
        }
    }

    /// How long to wait before sending one event at `now` (then it is counted as sent).
    pub fn delay(&mut self, now: Instant) -> Duration {
        let due = self.next.map_or(now, |next| next.max(now));
        self.next = Some(due + self.interval);
        due - now
    }
}

/// Doubling delays from `min` to `max`; `reset` after a success.
pub struct Backoff {
    min: Duration,
    max: Duration,
    current: Duration,
}

impl Backoff {
    pub fn new(min: Duration, max: Duration) -> Self {
        Self {
            min,
            max,
            current: min,
        }
    }

    pub fn next_delay(&mut self) -> Duration {
        let delay = self.current;
        self.current = (self.current * 2).min(self.max);
        delay
    }

    pub fn reset(&mut self) {
        self.current = self.min;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pacer_holds_the_rate_and_does_not_save_up_idle_time() {
        let mut pacer = Pacer::new(100);
        let t0 = Instant::now();
        // 1000 events offered at once: the last is due 9.99 s later (100/s).
        let waits: Vec<Duration> = (0..1000).map(|_| pacer.delay(t0)).collect();
        assert_eq!(waits[0], Duration::ZERO);
        assert_eq!(waits[999], Duration::from_millis(9990));
        // After a long idle time the next event goes at once, the one after one interval later.
        let later = t0 + Duration::from_secs(60);
        assert_eq!(pacer.delay(later), Duration::ZERO);
        assert_eq!(pacer.delay(later), Duration::from_millis(10));
    }

    #[test]
    fn backoff_doubles_to_its_cap_and_resets() {
        let mut b = Backoff::new(Duration::from_millis(250), Duration::from_secs(1));
        let delays: Vec<u64> = (0..4).map(|_| b.next_delay().as_millis() as u64).collect();
        assert_eq!(delays, [250, 500, 1000, 1000]);
        b.reset();
        assert_eq!(b.next_delay(), Duration::from_millis(250));
    }
}
