//! What the subscribers took: each subscriber tells the publisher, after every batch it drained,
//! the range of the publisher's sequence numbers it has taken so far. The publisher keeps the
//! ranges ([`TakenLedger`]) and so knows what no subscriber took: the frames a service held in
//! its buffer when it was killed (up to a whole buffer, 1024 frames by default) were lost
//! without any counter showing it.
//!
//! Acknowledgements travel on the stream's `<service>/taken` publish-subscribe service with
//! safe overflow on: a replay that does not read them never slows the service down. Each one
//! is cumulative (the whole range so far), so an overwritten one loses nothing as long as the
//! publisher reads more often than the buffer fills ([`TAKEN_BUFFER`] acknowledgements).

use iceoryx2::prelude::ZeroCopySend;

/// Acknowledgements a publisher's buffer holds unread before the oldest is overwritten.
pub const TAKEN_BUFFER: usize = 256;

/// One subscriber's acknowledgement: from publisher `publisher_instance` it took every frame
/// numbered `first_sequence..=last_sequence` (frames arrive in order and a frame refused by
/// backpressure is re-sent under its own number, so what one subscriber takes is one range).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, ZeroCopySend)]
#[type_name("railmon::TakenFrames.v1")]
#[repr(C)]
pub struct TakenFrames {
    pub publisher_instance: u64,
    /// Tells subscribers apart (a restarted service is a new one).
    pub subscriber_instance: u64,
    pub first_sequence: u64,
    pub last_sequence: u64,
}

/// The publisher's account of what its subscribers took.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TakenLedger {
    /// Per subscriber instance, the range it took: `(subscriber, first, last)`.
    ranges: Vec<(u64, u64, u64)>,
}

/// Frames sent, split by what became of them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TakenReport {
    /// Sequence numbers used (`0..sent`).
    pub sent: u64,
    /// Taken by at least one subscriber.
    pub taken: u64,
    /// Never taken, though a later frame was: a subscriber died (or was cut off) holding them.
    pub lost: u64,
    /// After the last frame any subscriber acknowledged: not (yet) confirmed either way.
    pub unconfirmed: u64,
}

impl TakenLedger {
    /// Records an acknowledgement (from this publisher's subscribers).
    pub fn record(&mut self, ack: &TakenFrames) {
        match self
            .ranges
            .iter_mut()
            .find(|(s, _, _)| *s == ack.subscriber_instance)
        {
            Some(range) => {
                range.1 = range.1.min(ack.first_sequence);
                range.2 = range.2.max(ack.last_sequence);
            }
            None => self.ranges.push((
                ack.subscriber_instance,
                ack.first_sequence,
                ack.last_sequence,
            )),
        }
    }

    /// The highest sequence number any subscriber took.
    pub fn last_taken(&self) -> Option<u64> {
        self.ranges.iter().map(|r| r.2).max()
    }

    /// What became of the frames numbered `0..sent`.
    pub fn report(&self, sent: u64) -> TakenReport {
        let mut ranges: Vec<(u64, u64)> = self
            .ranges
            .iter()
            .filter(|r| r.1 < sent)
            .map(|r| (r.1, r.2.min(sent.saturating_sub(1))))
            .collect();
        ranges.sort_unstable();
        // Size of the union of the ranges.
        let (mut taken, mut covered_to) = (0u64, 0u64); // covered_to: one past the last counted
        for (first, last) in ranges {
            let start = first.max(covered_to);
            if last + 1 > start {
                taken += last + 1 - start;
                covered_to = last + 1;
            }
        }
        let unconfirmed = match self.last_taken() {
            Some(last) => sent.saturating_sub(last.saturating_add(1)),
            None => sent,
        };
        TakenReport {
            sent,
            taken,
            lost: sent - taken - unconfirmed,
            unconfirmed,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ack(subscriber: u64, first: u64, last: u64) -> TakenFrames {
        TakenFrames {
            publisher_instance: 7,
            subscriber_instance: subscriber,
            first_sequence: first,
            last_sequence: last,
        }
    }

    #[test]
    fn one_subscriber_that_took_everything_lost_nothing() {
        let mut ledger = TakenLedger::default();
        ledger.record(&ack(1, 0, 10));
        ledger.record(&ack(1, 0, 99));
        let report = ledger.report(100);
        assert_eq!(
            report,
            TakenReport {
                sent: 100,
                taken: 100,
                lost: 0,
                unconfirmed: 0
            }
        );
        // Not acknowledged yet: unconfirmed, not lost.
        assert_eq!(ledger.report(150).unconfirmed, 50);
        assert_eq!(ledger.report(150).lost, 0);
    }

    #[test]
    fn frames_a_dead_subscriber_held_are_lost_and_counted() {
        // Service A took 0..=399 and died with 400..=1423 in its buffer; service B took the
        // rest from 1424 on.
        let mut ledger = TakenLedger::default();
        ledger.record(&ack(1, 0, 399));
        ledger.record(&ack(2, 1424, 1999));
        assert_eq!(
            ledger.report(2000),
            TakenReport {
                sent: 2000,
                taken: 976,
                lost: 1024,
                unconfirmed: 0
            }
        );
    }

    #[test]
    fn overlapping_subscribers_count_a_frame_once() {
        let mut ledger = TakenLedger::default();
        ledger.record(&ack(1, 0, 50));
        ledger.record(&ack(2, 10, 30));
        ledger.record(&ack(3, 40, 60));
        let report = ledger.report(61);
        assert_eq!((report.taken, report.lost, report.unconfirmed), (61, 0, 0));
        assert_eq!(TakenLedger::default().report(5).unconfirmed, 5);
    }
}
