//! Sequence numbers of one publisher: in order, a gap, stale, or a new source.

use railmon_bus::FrameHeader;

/// What a frame's header says about the sequence of its publisher.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SequenceCheck {
    /// The next frame of the current source.
    InOrder,
    /// A new publisher or a new run: the estimator restarts.
    NewSource,
    /// `missing` frames of the current source never arrived.
    Gap { missing: u64 },
    /// Older than or equal to the frame `last` already seen.
    Stale { last: u64 },
}

/// Follows one publisher's sequence numbers. A subscriber joining a running publisher starts
/// counting at the first frame it sees (earlier frames were not meant for it).
#[derive(Clone, Debug, Default)]
pub struct SequenceTracker {
    current: Option<(u64, u32)>,
    next: u64,
}

impl SequenceTracker {
    pub fn check(&self, header: &FrameHeader) -> SequenceCheck {
        if self.current != Some((header.publisher_instance, header.run)) {
            return SequenceCheck::NewSource;
        }
        match header.sequence.cmp(&self.next) {
            std::cmp::Ordering::Equal => SequenceCheck::InOrder,
            std::cmp::Ordering::Greater => SequenceCheck::Gap {
                missing: header.sequence - self.next,
            },
            std::cmp::Ordering::Less => SequenceCheck::Stale {
                last: self.next.saturating_sub(1),
            },
        }
    }

    pub fn accept(&mut self, header: &FrameHeader) {
        self.current = Some((header.publisher_instance, header.run));
        self.next = header.sequence + 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header(instance: u64, run: u32, sequence: u64) -> FrameHeader {
        FrameHeader {
            layout_version: railmon_bus::FRAME_LAYOUT_VERSION,
            publisher_instance: instance,
            run,
            sequence,
            ..Default::default()
        }
    }

    #[test]
    fn tracker_counts_gaps_and_sees_new_sources() {
        let mut t = SequenceTracker::default();
        assert_eq!(t.check(&header(7, 0, 5)), SequenceCheck::NewSource);
        t.accept(&header(7, 0, 5));
        assert_eq!(t.check(&header(7, 0, 6)), SequenceCheck::InOrder);
        t.accept(&header(7, 0, 6));
        assert_eq!(
            t.check(&header(7, 0, 10)),
            SequenceCheck::Gap { missing: 3 }
        );
        t.accept(&header(7, 0, 10));
        assert_eq!(
            t.check(&header(7, 0, 10)),
            SequenceCheck::Stale { last: 10 }
        );
        assert_eq!(t.check(&header(7, 1, 11)), SequenceCheck::NewSource);
        assert_eq!(t.check(&header(8, 0, 0)), SequenceCheck::NewSource);
    }
}
