//! What the ground's stream already holds of this vehicle's events above the cursor, and the
//! cursor that follows from it.
//!
//! The uplink publishes a page of events before it awaits their acknowledgements, so the
//! ground can hold a later event of a page and not an earlier one: a message written to a
//! connection that dropped is lost while the next ones go out on the new connection, or a
//! publish meets a stream without a leader (an election in the cluster) while the next one
//! meets the new leader. The cursor therefore moves only over events the stream is seen to
//! hold, in id order, and an event held beyond a hole is not sent again (it would be stored
//! twice once the duplicate window has passed). The hole is then filled after the events
//! beyond it: on the ground, the event id gives the order, not the stream sequence.

use std::collections::BTreeMap;
use std::time::Duration;

use async_nats::jetstream;
use futures_util::StreamExt;

use crate::store::UplinkCursor;

/// The cursor (as saved in the store), and what the stream is seen to hold of this vehicle's
/// events above it: event id -> stream sequence; and the highest stream sequence of this
/// vehicle's messages seen.
#[derive(Debug)]
pub(super) struct Cursor {
    saved: UplinkCursor,
    held: BTreeMap<u64, u64>,
    last_sequence: u64,
}

impl Cursor {
    /// Starts from the saved cursor: nothing is known above it yet.
    pub fn new(saved: UplinkCursor) -> Self {
        Self {
            saved,
            held: BTreeMap::new(),
            last_sequence: saved.stream_sequence,
        }
    }

    pub fn acked_id(&self) -> u64 {
        self.saved.acked_id
    }

    /// A new connection: what the stream holds is read again.
    pub fn forget_held(&mut self) {
        *self = Self::new(self.saved);
    }

    /// The stream holds event `id` at `sequence`.
    pub fn record(&mut self, id: u64, sequence: u64) {
        self.held.insert(id, sequence);
        self.last_sequence = self.last_sequence.max(sequence);
    }

    /// A message of this vehicle at `sequence` (acknowledged, or not one of its stored events).
    pub fn saw_sequence(&mut self, sequence: u64) {
        self.last_sequence = self.last_sequence.max(sequence);
    }

    pub fn holds(&self, id: u64) -> bool {
        self.held.contains_key(&id)
    }

    pub fn holds_nothing_above(&self) -> bool {
        self.held.is_empty()
    }

    /// The cursor to save at `acked_id`: its stream sequence below every message still held
    /// above it, so that a restart looks at those again.
    pub fn at(&self, acked_id: u64) -> UplinkCursor {
        let above = self.held.range(acked_id + 1..).map(|(_, s)| *s).min();
        UplinkCursor {
            acked_id,
            stream_sequence: above.map_or(self.last_sequence, |lowest| lowest - 1),
        }
    }

    /// `saved` ([`Self::at`]) is in the store: forgets what it covers.
    pub fn saved(&mut self, saved: UplinkCursor) {
        self.held = self.held.split_off(&(saved.acked_id + 1));
        self.saved = saved;
    }

    /// The last id of `ids_after_cursor` (the store's ids after the cursor, in order) up to
    /// which the stream holds every one, if it holds the first.
    pub fn contiguous_until(&self, ids_after_cursor: impl IntoIterator<Item = u64>) -> Option<u64> {
        ids_after_cursor
            .into_iter()
            .take_while(|id| self.holds(*id))
            .last()
    }
}

/// Reads the headers of this vehicle's messages after the saved cursor's stream sequence (an ordered,
/// headers-only consumer on `filter_subject`) and records those of events in
/// `(acked id, last_stored_id]`. Only what was sent since the cursor was saved is read;
/// a cursor saved without a sequence (0) reads this vehicle's whole history once.
pub(super) async fn read_above_cursor(
    stream: &jetstream::stream::Stream,
    filter_subject: String,
    last_stored_id: u64,
    event_id: impl Fn(&str) -> Option<u64>,
    timeout: Duration,
    cursor: &mut Cursor,
) -> Result<(), String> {
    use jetstream::consumer::{pull::OrderedConfig, DeliverPolicy};
    let consumer = stream
        .create_consumer(OrderedConfig {
            filter_subject,
            deliver_policy: DeliverPolicy::ByStartSequence {
                start_sequence: cursor.saved.stream_sequence + 1,
            },
            headers_only: true,
            ..Default::default()
        })
        .await
        .map_err(|e| format!("reading what the stream holds: {e}"))?;
    let pending = consumer.cached_info().num_pending;
    if pending == 0 {
        return Ok(());
    }
    let mut messages = consumer
        .messages()
        .await
        .map_err(|e| format!("reading what the stream holds: {e}"))?
        .take(pending as usize);
    loop {
        let next = tokio::time::timeout(timeout, messages.next())
            .await
            .map_err(|_| "reading what the stream holds: timed out".to_string())?;
        let Some(message) = next else { return Ok(()) };
        let message = message.map_err(|e| format!("reading what the stream holds: {e}"))?;
        let sequence = message
            .info()
            .map_err(|e| format!("reading what the stream holds: {e}"))?
            .stream_sequence;
        let id = message
            .headers
            .as_ref()
            .and_then(|h| h.get("Nats-Msg-Id"))
            .and_then(|v| event_id(v.as_str()));
        match id {
            Some(id) if id > cursor.acked_id() && id <= last_stored_id => {
                cursor.record(id, sequence)
            }
            _ => cursor.saw_sequence(sequence),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(acked_id: u64, stream_sequence: u64) -> UplinkCursor {
        UplinkCursor {
            acked_id,
            stream_sequence,
        }
    }

    #[test]
    fn the_cursor_stops_at_a_hole_and_the_events_beyond_it_are_not_sent_again() {
        // Cursor at 10 (sequence 50). A page of 11..=14 went out; the stream holds 11, 13 and
        // 14 (12 was lost with a connection), at sequences 51, 52, 53.
        let mut cursor = Cursor::new(at(10, 50));
        cursor.record(11, 51);
        cursor.record(13, 52);
        cursor.record(14, 53);
        let stored = [11, 12, 13, 14, 15];
        assert_eq!(cursor.contiguous_until(stored), Some(11));
        // A restart looks again from below 13's sequence: 13 and 14 are not sent twice.
        assert_eq!(cursor.at(11), at(11, 51));
        cursor.saved(at(11, 51));
        assert!(!cursor.holds(12) && cursor.holds(13) && cursor.holds(14));
        // 12 and 15 are sent (acknowledged at 54 and 55); the page's end becomes the cursor.
        cursor.saw_sequence(54);
        cursor.saw_sequence(55);
        assert_eq!(cursor.at(15), at(15, 55));
        cursor.saved(at(15, 55));
        assert!(cursor.holds_nothing_above());
        // A new connection reads from there.
        cursor.record(16, 56);
        cursor.forget_held();
        assert!(cursor.holds_nothing_above());
        assert_eq!(cursor.at(15), at(15, 55));
    }

    #[test]
    fn nothing_held_leaves_the_cursor_where_it_is() {
        let cursor = Cursor::new(at(10, 50));
        assert_eq!(cursor.contiguous_until([11, 12]), None);
        assert_eq!(cursor.at(10), at(10, 50));
    }

    #[test]
    fn pruned_ids_are_not_holes() {
        // The store no longer has 12 (retention): the ids after the cursor are the store's.
        let mut cursor = Cursor::new(at(10, 50));
        cursor.record(11, 51);
        cursor.record(13, 52);
        assert_eq!(cursor.contiguous_until([11, 13, 14]), Some(13));
    }
}
