//! What every stream pipeline shares with the HTTP side, and the bookkeeping behind it: one
//! piece for all three streams.
//!
//! The ingest thread owns a [`Track`]: stream time that continues across sources, history
//! decimation, history points and events waiting to be handed on, and whether the newest
//! estimate was published. [`Track::flush`] moves history into the [`Outbox`]'s ring (never
//! waiting for its lock), sends events to the event store (never waiting for the disk) and
//! says if a new snapshot is due.

use std::sync::Arc;

use arc_swap::ArcSwap;
use railmon_bus::{FrameHeader, StreamKind};
use serde::Serialize;

use crate::ring::Ring;
use crate::store::{EventStore, NewEvent};

/// A stream's results as the HTTP handlers read them: the latest view (`arc-swap`) and history
/// points (a bounded ring); its events are in the shared [`EventStore`].
pub struct Outbox<V, P> {
    pub snapshot: ArcSwap<V>,
    pub history: Ring<P>,
    pub store: Arc<EventStore>,
}

impl<V: Default, P: Clone> Outbox<V, P> {
    pub fn new(history_capacity: usize, store: Arc<EventStore>) -> Self {
        Self {
            snapshot: ArcSwap::from_pointee(V::default()),
            history: Ring::new(history_capacity),
            store,
        }
    }
}

/// The header's sample time in seconds. Division, not `* 1e-9`: whole seconds stay exact (a
/// 1 Hz source's `t` comes back as `t`, so its time differences are exactly 1).
pub fn run_time_s(header: &FrameHeader) -> f64 {
    header.sample_time_ns as f64 / 1e9
}

/// When a frame was estimated: its header, stream time (continuous over sources) and run time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stamp {
    pub header: FrameHeader,
    /// Stream time, s: continues where the previous source stopped.
    pub time_s: f64,
    /// Time within the run (the source's own clock), s.
    pub run_time_s: f64,
    /// When the sample was acquired, UTC ns since the epoch (the header's, or the service's
    /// clock at receipt when the publisher did not say).
    pub utc_ns: i64,
}

impl Stamp {
    /// The acquisition time as RFC 3339 UTC.
    pub fn time_utc(&self) -> String {
        railmon_bus::utc::format_rfc3339(self.utc_ns)
    }
}

/// A [`Stamp`] saved with an estimator whose estimates trail its frames (the drive stream's
/// fixed lag): the steps it still holds are dated from the last frame after a restart, as
/// they would have been before it. The header's fields that dating reads.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct SavedStamp {
    pub run: u32,
    pub publisher_instance: u64,
    pub sequence: u64,
    pub sample_time_ns: u64,
    pub acquired_utc_ns: i64,
    pub time_s: f64,
    pub run_time_s: f64,
    pub utc_ns: i64,
}

impl From<Stamp> for SavedStamp {
    fn from(s: Stamp) -> Self {
        SavedStamp {
            run: s.header.run,
            publisher_instance: s.header.publisher_instance,
            sequence: s.header.sequence,
            sample_time_ns: s.header.sample_time_ns,
            acquired_utc_ns: s.header.acquired_utc_ns,
            time_s: s.time_s,
            run_time_s: s.run_time_s,
            utc_ns: s.utc_ns,
        }
    }
}

impl From<SavedStamp> for Stamp {
    fn from(s: SavedStamp) -> Self {
        Stamp {
            header: FrameHeader {
                run: s.run,
                publisher_instance: s.publisher_instance,
                sequence: s.sequence,
                sample_time_ns: s.sample_time_ns,
                acquired_utc_ns: s.acquired_utc_ns,
                ..FrameHeader::default()
            },
            time_s: s.time_s,
            run_time_s: s.run_time_s,
            utc_ns: s.utc_ns,
        }
    }
}

/// Where a stream's time stands ([`Track::clock`]), saved with an estimator's state.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct TrackClock {
    pub run_offset_s: f64,
    pub last_time_s: Option<f64>,
    pub next_history_s: f64,
}

/// The ingest thread's side of an [`Outbox`]. See the module documentation.
#[derive(Clone, Debug)]
pub struct Track<P> {
    stream: StreamKind,
    /// Nominal step of the stream: a new source starts one step after the last frame.
    period_s: f64,
    history_interval_s: f64,
    run_offset_s: f64,
    last_time_s: Option<f64>,
    next_history_s: f64,
    pending_history: Vec<P>,
    pending_events: Vec<NewEvent>,
    last: Option<Stamp>,
    dirty: bool,
}

impl<P: Clone> Track<P> {
    pub fn new(stream: StreamKind, period_s: f64, history_interval_ms: u64) -> Self {
        Self {
            stream,
            period_s,
            history_interval_s: history_interval_ms as f64 * 1e-3,
            run_offset_s: 0.0,
            last_time_s: None,
            next_history_s: 0.0,
            pending_history: Vec::new(),
            pending_events: Vec::new(),
            last: None,
            dirty: false,
        }
    }

    /// Where stream time stands, to carry it over a restart of the service.
    pub fn clock(&self) -> TrackClock {
        TrackClock {
            run_offset_s: self.run_offset_s,
            last_time_s: self.last_time_s,
            next_history_s: self.next_history_s,
        }
    }

    /// Stream time goes on from `clock` (a resumed estimator).
    pub fn resume_clock(&mut self, clock: TrackClock) {
        self.run_offset_s = clock.run_offset_s;
        self.last_time_s = clock.last_time_s;
        self.next_history_s = clock.next_history_s;
    }

    /// The last frame before a restart of the service (saved with the estimator), so that
    /// what the estimator still holds is dated from it.
    pub fn resume_last(&mut self, last: Option<Stamp>) {
        self.last = last;
    }

    /// Marks the view as due at the next flush (estimates published without a new frame:
    /// the end of a stream's data).
    pub fn touch(&mut self) {
        self.dirty = self.last.is_some();
    }

    /// A new source: its run time 0 comes one step after the last frame of the previous one.
    pub fn restart(&mut self) {
        self.run_offset_s = self.last_time_s.map_or(0.0, |t| t + self.period_s);
        self.next_history_s = self.run_offset_s;
    }

    /// Stamps a frame the estimator accepted; marks the estimate as not yet published.
    pub fn stamp(&mut self, header: &FrameHeader) -> Stamp {
        let run_time_s = run_time_s(header);
        let stamp = Stamp {
            header: *header,
            time_s: self.run_offset_s + run_time_s,
            run_time_s,
            utc_ns: match header.acquired_utc_ns {
                0 => railmon_bus::utc_now_ns(),
                t => t,
            },
        };
        self.last_time_s = Some(stamp.time_s);
        self.last = Some(stamp);
        self.dirty = true;
        stamp
    }

    /// Whether a history point is due at `time_s` (one per history interval); if so, the
    /// caller pushes one ([`Self::push_history`]).
    /// The stamp of the newest frame, if one came since the start (or the last restart).
    pub fn last_stamp(&self) -> Option<Stamp> {
        self.last
    }

    pub fn history_due(&mut self, time_s: f64) -> bool {
        let due = time_s >= self.next_history_s;
        if due {
            let interval_s = self.history_interval_s;
            let next = ((time_s / interval_s).floor() + 1.0) * interval_s;
            // `time_s / interval_s` can round below a whole number (0.3 / 0.1 =
            // 2.9999999999999996): the next point must still come after `time_s`, or frames
            // of the same time (the bogies of one step) would each get a point.
            self.next_history_s = if next > time_s {
                next
            } else {
                next + interval_s
            };
        }
        due
    }

    pub fn push_history(&mut self, point: P) {
        self.pending_history.push(point);
    }

    /// Queues an event of this stream raised by the sample of `stamp`: its `kind`, `subject`
    /// (`1` for drive 1, `2/csay`, ...), the stream's own fields (`detail`, a struct that
    /// serialises to a JSON object) and the alarm it raises or clears.
    pub fn push_event(
        &mut self,
        stamp: &Stamp,
        kind: &str,
        subject: String,
        detail: &impl Serialize,
        alarm: Option<(&str, bool)>,
    ) {
        let detail = match serde_json::to_value(detail) {
            Ok(serde_json::Value::Object(map)) => map,
            other => {
                tracing::error!(kind, "event detail is not a JSON object: {other:?}");
                serde_json::Map::new()
            }
        };
        self.pending_events.push(NewEvent {
            stream: self.stream,
            kind: kind.into(),
            subject,
            time_utc_ns: stamp.utc_ns,
            time_s: stamp.time_s,
            run: stamp.header.run,
            run_time_s: stamp.run_time_s,
            detail,
            alarm: alarm.map(|(name, on)| (name.to_string(), on)),
        });
    }

    /// Moves pending history into `outbox`'s ring if its lock is free and events to the
    /// store; returns the stamp of the newest estimate if it has not been published yet (then
    /// publish it).
    pub fn flush<V>(&mut self, outbox: &Outbox<V, P>) -> Option<Stamp> {
        outbox.history.try_append(&mut self.pending_history);
        outbox
            .store
            .append(std::mem::take(&mut self.pending_events));
        std::mem::take(&mut self.dirty)
            .then_some(self.last)
            .flatten()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::StorageConfig;
    use crate::store::EventQuery;

    fn header(run: u32, sample_time_ns: u64) -> FrameHeader {
        FrameHeader {
            run,
            sample_time_ns,
            acquired_utc_ns: 1_000_000_000 + sample_time_ns as i64,
            ..Default::default()
        }
    }

    fn memory_store() -> Arc<EventStore> {
        let config = StorageConfig {
            data_dir: ":memory:".into(),
            ..StorageConfig::default()
        };
        EventStore::open(&config, &crate::config::Identity::default())
            .unwrap()
            .0
    }

    #[test]
    fn frames_of_the_same_time_get_one_history_point() {
        let mut track: Track<f64> = Track::new(StreamKind::Bogie, 0.001, 100);
        let mut points = 0;
        for k in 0..1000u64 {
            for _bogie in 0..2 {
                let stamp = track.stamp(&header(0, k * 1_000_000));
                points += usize::from(track.history_due(stamp.time_s));
            }
        }
        assert_eq!(points, 10);
    }

    #[derive(Serialize)]
    struct Detail {
        n: u64,
    }

    #[test]
    fn stream_time_continues_across_sources_and_history_is_decimated() {
        let outbox: Outbox<(), f64> = Outbox::new(100, memory_store());
        let mut track = Track::new(StreamKind::Vehicle, 1.0, 2000);
        track.restart();
        for k in 0..5 {
            let stamp = track.stamp(&header(0, k * 1_000_000_000));
            if track.history_due(stamp.time_s) {
                track.push_history(stamp.time_s);
            }
        }
        let last = track.last.unwrap();
        track.push_event(
            &last,
            "regime_changed",
            String::new(),
            &Detail { n: 1 },
            None,
        );
        assert_eq!(track.flush(&outbox).unwrap().time_s, 4.0);
        assert_eq!(track.flush(&outbox), None, "published once");
        track.restart(); // the next source's run time 0 is stream time 5
        let stamp = track.stamp(&header(1, 0));
        assert_eq!((stamp.time_s, stamp.run_time_s), (5.0, 0.0));
        assert!(track.history_due(stamp.time_s));
        track.push_history(stamp.time_s);
        track.push_event(
            &stamp,
            "regime_changed",
            String::new(),
            &Detail { n: 2 },
            None,
        );
        track.flush(&outbox);
        assert_eq!(outbox.history.collect(|_| true), vec![0.0, 2.0, 4.0, 5.0]);
        outbox.store.flush();
        let events = outbox
            .store
            .page(&EventQuery {
                limit: 10,
                ..EventQuery::default()
            })
            .unwrap();
        let got: Vec<(u64, f64, u64)> = events
            .iter()
            .map(|e| (e.id, e.time_s, e.detail["n"].as_u64().unwrap()))
            .collect();
        assert_eq!(got, vec![(1, 4.0, 1), (2, 5.0, 2)]);
        assert_eq!(events[1].time_utc, "1970-01-01T00:00:01.000Z");
    }
}
