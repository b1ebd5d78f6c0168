//! `railmon fleet` (issue 29 item 3): answers fleet queries from the JetStream stream the
//! vehicles' uplinks write, and nothing else: no database, no state between requests, so any
//! number of replicas can answer behind a load balancer.
//!
//! What it reads (subjects under `fleet.subject_prefix`, `<fleet>.<vehicle>` as the uplink
//! writes them):
//! - a vehicle's events: its subjects `<prefix>.<fleet>.<vehicle>.<stream>.events` from the
//!   stream's subject counts, then an ephemeral pull consumer on each (a literal filter: the
//!   server jumps to the subject's messages, see [`Fleet::events`]), starting at the page's
//!   stream sequence or at the range's start time (minus a clock margin), merged and paged by
//!   stream sequence;
//! - a vehicle's latest health summary: the last message of `<prefix>.*.<vehicle>.health`;
//! - the active alarms of every vehicle: the last alarm snapshot of each vehicle
//!   (`<prefix>.*.*.alarms`, one consumer delivering the last message per subject), then only
//!   the events stored since each snapshot (one consumer over every vehicle's events from the
//!   oldest recent snapshot, and one per event subject of a vehicle whose snapshot is old or
//!   missing), applied
//!   with [`alarms::AlarmState`]. Replaying every event ever sent would grow with the stream;
//!   this grows with the vehicles and the last minutes' events (docs/fleet.md, measured).

pub mod alarms;
pub mod config;
pub mod routes;

use std::collections::{BTreeMap, BTreeSet};
use std::ops::ControlFlow;
use std::time::Duration;

use async_nats::jetstream::{self, consumer::pull, consumer::AckPolicy, consumer::DeliverPolicy};
use futures_util::StreamExt;
use serde::Deserialize;

use crate::store::ActiveAlarm;
use crate::uplink::health::AlarmSnapshot;
use alarms::{AlarmEvent, AlarmState};
pub use config::FleetConfig;

/// Messages asked for per pull request.
const FETCH_BATCH: usize = 1000;
/// A time range's start is looked up this much earlier in the stream's (server) time: an
/// event is stored after it was acquired, unless the vehicle's clock is ahead of the server's
/// by more than this.
const CLOCK_MARGIN: Duration = Duration::from_secs(300);
/// Events stored this long before an alarm snapshot are read too: an event newer than the
/// snapshot's last id is published after the snapshot was made, and the snapshot is stored
/// within the health publisher's acknowledgement timeout (5 s) of being made, or not at all.
const SNAPSHOT_MARGIN: Duration = Duration::from_secs(30);
/// Vehicles whose snapshot is younger than this share one read of every vehicle's recent
/// events; an older snapshot (a vehicle offline, or the fleet's first minutes) gets a read of
/// its vehicle's events alone, so one old snapshot does not make every query read hours.
const RECENT_WINDOW: Duration = Duration::from_secs(600);
/// Per-vehicle reads in flight at once.
const PARALLEL_READS: usize = 16;
/// Unused consumers (a request that was cut) are removed by the server after this.
const CONSUMER_INACTIVE: Duration = Duration::from_secs(30);
/// `--create-stream`: how long a missing stream's creation is retried (a cluster's first leader
/// election takes seconds; the tests' three nodes took up to 11 s, docs/fleet.md).
pub const CREATE_PATIENCE: Duration = Duration::from_secs(60);

/// The stream could not be read (the server is down, the stream is missing, ...).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct ReadError(pub String);

fn read_error(what: &str, e: impl std::fmt::Display) -> ReadError {
    ReadError(format!("{what}: {e}"))
}

/// A message as read: subject, stream sequence, when the server stored it, payload.
pub struct Read<'a> {
    pub subject: &'a str,
    pub sequence: u64,
    pub stored: time::OffsetDateTime,
    pub payload: &'a [u8],
}

/// `<fleet>.<vehicle>` and the rest of a subject under `prefix`.
fn tokens<'a>(prefix: &str, subject: &'a str) -> Option<(&'a str, &'a str, &'a str)> {
    let rest = subject.strip_prefix(prefix)?.strip_prefix('.')?;
    let mut parts = rest.splitn(3, '.');
    Some((parts.next()?, parts.next()?, parts.next()?))
}

/// The fields of an event the fleet needs (the payload is the vehicle's `EventView` with
/// `vehicle_id` and `fleet`).
#[derive(Deserialize)]
struct EventHead<'a> {
    id: u64,
    #[serde(borrow)]
    kind: std::borrow::Cow<'a, str>,
    #[serde(borrow)]
    subject: std::borrow::Cow<'a, str>,
    #[serde(borrow)]
    time_utc: std::borrow::Cow<'a, str>,
}

/// A page of one vehicle's events.
pub struct EventsRequest {
    pub vehicle_id: String,
    /// `drive`, `bogie`, `vehicle`, `service`; None: every stream.
    pub stream: Option<String>,
    pub since_utc_ns: Option<i64>,
    pub until_utc_ns: Option<i64>,
    pub kind: Option<String>,
    pub after_seq: u64,
    pub limit: usize,
}

/// A vehicle's events as stored (JSON objects with `stream_sequence` added), and where the
/// next page starts.
pub struct EventsAnswer {
    pub events: Vec<serde_json::Value>,
    pub next_after_seq: u64,
}

/// One vehicle with an alarm snapshot or events in the stream, and its alarms now.
pub struct VehicleAlarms {
    pub fleet: String,
    pub vehicle_id: String,
    pub alarms: Vec<ActiveAlarm>,
    /// When the server stored the snapshot the answer starts from (None: from every event).
    pub snapshot_stored: Option<time::OffsetDateTime>,
}

/// The stream, through one NATS connection.
#[derive(Clone)]
pub struct Fleet {
    stream: jetstream::stream::Stream,
    prefix: String,
}

impl Fleet {
    /// Connects and looks the stream up: it must exist (the vehicles' uplinks create it), unless
    /// `create_replicas` is given: then a missing stream is created as the uplink would create
    /// it but with that many replicas (`railmon fleet --create-stream`: a ground whose vehicles
    /// may not create streams), retrying for up to [`CREATE_PATIENCE`] while a cluster elects
    /// its leader. An existing stream is used as it is.
    pub async fn connect(
        config: &FleetConfig,
        create_replicas: Option<usize>,
    ) -> Result<Self, ReadError> {
        let login = crate::nats_client::NatsLogin::from(config);
        let client = crate::nats_client::connect(&login, "railmon-fleet", true)
            .await
            .map_err(ReadError)?;
        let js = jetstream::ContextBuilder::new()
            .timeout(Duration::from_secs(5))
            .build(client);
        let what = format!("stream {} (fleet.stream)", config.stream);
        let stream = match create_replicas {
            None => js
                .get_stream(&config.stream)
                .await
                .map_err(|e| read_error(&what, e))?,
            Some(replicas) => {
                let wanted =
                    crate::uplink::stream_config(&config.stream, &config.subject_prefix, replicas);
                let start = std::time::Instant::now();
                loop {
                    match js.get_or_create_stream(wanted.clone()).await {
                        Ok(stream) => break stream,
                        Err(e) if start.elapsed() < CREATE_PATIENCE => {
                            tracing::info!("{what}: not created yet ({e}); retrying");
                            tokio::time::sleep(Duration::from_secs(1)).await;
                        }
                        Err(e) => return Err(read_error(&what, e)),
                    }
                }
            }
        };
        Ok(Self {
            stream,
            prefix: config.subject_prefix.clone(),
        })
    }

    /// Visits the messages of `filter` from `deliver` in stream order until `visit` breaks or
    /// none is left; an ephemeral consumer, deleted afterwards.
    pub async fn read(
        &self,
        filter: String,
        deliver: DeliverPolicy,
        visit: impl FnMut(Read<'_>) -> ControlFlow<()>,
    ) -> Result<(), ReadError> {
        self.read_in_batches(filter, deliver, FETCH_BATCH, visit)
            .await
    }

    /// [`Fleet::read`] asking for `batch` messages per pull request (1..=[`FETCH_BATCH`]): a
    /// page of `limit` events that `visit` ends early is not sent a full batch.
    pub async fn read_in_batches(
        &self,
        filter: String,
        deliver: DeliverPolicy,
        batch: usize,
        mut visit: impl FnMut(Read<'_>) -> ControlFlow<()>,
    ) -> Result<(), ReadError> {
        let batch = batch.clamp(1, FETCH_BATCH);
        let consumer: jetstream::consumer::Consumer<pull::Config> = self
            .stream
            .create_consumer(pull::Config {
                filter_subject: filter.clone(),
                deliver_policy: deliver,
                ack_policy: AckPolicy::None,
                inactive_threshold: CONSUMER_INACTIVE,
                memory_storage: true,
                num_replicas: 1,
                ..Default::default()
            })
            .await
            .map_err(|e| read_error(&format!("consumer on {filter}"), e))?;
        let result = async {
            if consumer.cached_info().num_pending == 0 {
                return Ok(());
            }
            loop {
                let batch = consumer
                    .fetch()
                    .max_messages(batch)
                    .messages()
                    .await
                    .map_err(|e| read_error(&format!("reading {filter}"), e))?;
                let mut batch = std::pin::pin!(batch);
                let mut got = 0;
                while let Some(message) = batch.next().await {
                    let message =
                        message.map_err(|e| read_error(&format!("reading {filter}"), e))?;
                    let info = message
                        .info()
                        .map_err(|e| read_error(&format!("reading {filter}"), e))?;
                    got += 1;
                    let read = Read {
                        subject: message.subject.as_str(),
                        sequence: info.stream_sequence,
                        stored: info.published,
                        payload: &message.payload[..],
                    };
                    let pending = info.pending;
                    if visit(read).is_break() || pending == 0 {
                        return Ok(());
                    }
                }
                if got == 0 {
                    return Ok(());
                }
            }
        }
        .await;
        // Off the answer's path; the inactivity threshold removes it if this fails.
        let (stream, name) = (self.stream.clone(), consumer.cached_info().name.clone());
        tokio::spawn(async move {
            let _ = stream.delete_consumer(&name).await;
        });
        result
    }

    /// The subjects in the stream that match `pattern` (wildcards allowed), from the stream's
    /// per-subject counts: no message is read.
    pub async fn subjects(&self, pattern: &str) -> Result<Vec<String>, ReadError> {
        let subjects = self
            .stream
            .info_with_subjects(pattern)
            .await
            .map_err(|e| read_error("stream info", e))?;
        let mut subjects = std::pin::pin!(subjects);
        let mut found = Vec::new();
        while let Some(subject) = subjects.next().await {
            found.push(subject.map_err(|e| read_error("stream info", e))?.0);
        }
        Ok(found)
    }

    /// A page of one vehicle's events, in stream order (= id order per vehicle).
    ///
    /// One consumer per literal subject of the vehicle (`<prefix>.<fleet>.<vehicle>.<stream>.events`,
    /// looked up in the stream's subject counts), each read to `limit` events, merged by
    /// stream sequence; not one consumer on `<prefix>.*.<vehicle>.*.events`. Why: a 2.9 server
    /// finds the next message of a filter with wildcards by reading every message of a block
    /// holding more than 32 subjects (`firstMatching`'s linear scan), i.e. every vehicle's
    /// events from the start position, while for a literal subject it jumps to the subject's
    /// first message in each block; at 1,000 vehicles that was most of a day query's time
    /// (docs/fleet.md, "Measured").
    pub async fn events(&self, q: &EventsRequest) -> Result<EventsAnswer, ReadError> {
        let stream = q.stream.as_deref().unwrap_or("*");
        let pattern = format!("{}.*.{}.{stream}.events", self.prefix, q.vehicle_id);
        let subjects = self.subjects(&pattern).await?;
        let deliver = match (q.after_seq, q.since_utc_ns) {
            (0, None) => DeliverPolicy::All,
            (0, Some(since)) => DeliverPolicy::ByStartTime {
                start_time: utc(since) - CLOCK_MARGIN,
            },
            (after, _) => DeliverPolicy::ByStartSequence {
                start_sequence: after + 1,
            },
        };
        // Per subject: its events in range (stream sequence, event), the last sequence read,
        // and a payload that is not JSON.
        let reads = subjects.into_iter().map(|filter| async move {
            let mut events = Vec::new();
            let mut last_read = 0;
            let mut bad = None;
            self.read_in_batches(filter, deliver, q.limit, |m| {
                last_read = m.sequence;
                match in_page(q, m.payload) {
                    Ok(Some(event)) => {
                        events.push((m.sequence, event));
                        if events.len() >= q.limit {
                            return ControlFlow::Break(());
                        }
                    }
                    Ok(None) => {}
                    Err(e) => bad = Some(format!("stream sequence {}: {e}", m.sequence)),
                }
                ControlFlow::Continue(())
            })
            .await?;
            Ok::<_, ReadError>((events, last_read, bad))
        });
        let parts = futures_util::future::try_join_all(reads).await?;
        let mut events = Vec::new();
        let mut last_read = q.after_seq;
        for (part, last, bad) in parts {
            events.extend(part);
            last_read = last_read.max(last);
            if let Some(bad) = bad {
                tracing::warn!("an event that is not JSON skipped: {bad}");
            }
        }
        events.sort_unstable_by_key(|(sequence, _)| *sequence);
        // A full page ends at its last event: each subject was read up to its `limit`-th
        // event, so every message of every subject before that one was read. A short page
        // read every subject to its end.
        let next_after_seq = match events.len() >= q.limit {
            true => {
                events.truncate(q.limit);
                events.last().map_or(last_read, |(sequence, _)| *sequence)
            }
            false => last_read,
        };
        let events = events
            .into_iter()
            .map(|(sequence, mut event)| {
                event.insert("stream_sequence".into(), sequence.into());
                serde_json::Value::Object(event)
            })
            .collect();
        Ok(EventsAnswer {
            events,
            next_after_seq,
        })
    }

    /// The last health summary of `vehicle_id` (of any fleet): stream sequence, when stored,
    /// the summary.
    pub async fn health(
        &self,
        vehicle_id: &str,
    ) -> Result<Option<(u64, time::OffsetDateTime, serde_json::Value)>, ReadError> {
        let filter = format!("{}.*.{vehicle_id}.health", self.prefix);
        let mut last = None;
        let mut bad = None;
        self.read(filter, DeliverPolicy::LastPerSubject, |m| {
            match serde_json::from_slice(m.payload) {
                Ok(summary) => last = Some((m.sequence, m.stored, summary)),
                Err(e) => bad = Some(format!("stream sequence {}: {e}", m.sequence)),
            }
            ControlFlow::Continue(())
        })
        .await?;
        if let (None, Some(bad)) = (&last, bad) {
            return Err(ReadError(format!("the health summary is not JSON: {bad}")));
        }
        Ok(last)
    }

    /// Every vehicle with events in the stream: `(fleet, vehicle)` and its messages per
    /// event stream (`drive`, ...).
    pub async fn vehicles(
        &self,
    ) -> Result<BTreeMap<(String, String), BTreeMap<String, u64>>, ReadError> {
        let filter = format!("{}.*.*.*.events", self.prefix);
        let subjects = self
            .stream
            .info_with_subjects(&filter)
            .await
            .map_err(|e| read_error("stream info", e))?;
        let mut subjects = std::pin::pin!(subjects);
        let mut vehicles: BTreeMap<(String, String), BTreeMap<String, u64>> = BTreeMap::new();
        while let Some(subject) = subjects.next().await {
            let (subject, count) = subject.map_err(|e| read_error("stream info", e))?;
            if let Some((fleet, vehicle, rest)) = tokens(&self.prefix, &subject) {
                let stream = rest.strip_suffix(".events").unwrap_or(rest);
                vehicles
                    .entry((fleet.to_string(), vehicle.to_string()))
                    .or_default()
                    .insert(stream.to_string(), count as u64);
            }
        }
        Ok(vehicles)
    }

    /// The alarms active on every vehicle (see the module documentation).
    pub async fn active_alarms(&self) -> Result<Vec<VehicleAlarms>, ReadError> {
        struct Vehicle {
            state: AlarmState,
            after_id: u64,
            /// Read its events stored from here (None: all).
            start: Option<time::OffsetDateTime>,
            snapshot_stored: Option<time::OffsetDateTime>,
        }
        let mut vehicles: BTreeMap<(String, String), Vehicle> = BTreeMap::new();
        let mut bad = 0usize;
        let prefix = self.prefix.clone();
        self.read(
            format!("{prefix}.*.*.alarms"),
            DeliverPolicy::LastPerSubject,
            |m| {
                let Some((fleet, vehicle, _)) = tokens(&prefix, m.subject) else {
                    return ControlFlow::Continue(());
                };
                match serde_json::from_slice::<AlarmSnapshot>(m.payload) {
                    Ok(snapshot) => {
                        vehicles.insert(
                            (fleet.to_string(), vehicle.to_string()),
                            Vehicle {
                                state: AlarmState::from_snapshot(&snapshot.alarms),
                                after_id: snapshot.last_event_id,
                                start: Some(m.stored - SNAPSHOT_MARGIN),
                                snapshot_stored: Some(m.stored),
                            },
                        );
                    }
                    Err(_) => bad += 1,
                }
                ControlFlow::Continue(())
            },
        )
        .await?;
        // The event streams of each vehicle: its literal subjects for the reads of its own.
        let event_streams = self.vehicles().await?;
        for key in event_streams.keys().cloned() {
            vehicles.entry(key).or_insert(Vehicle {
                state: AlarmState::default(),
                after_id: 0,
                start: None,
                snapshot_stored: None,
            });
        }
        let cutoff = time::OffsetDateTime::now_utc() - RECENT_WINDOW;
        let recent: BTreeSet<(String, String)> = vehicles
            .iter()
            .filter(|(_, v)| v.start.is_some_and(|s| s >= cutoff))
            .map(|(k, _)| k.clone())
            .collect();
        let shared_start = vehicles
            .iter()
            .filter(|(k, _)| recent.contains(*k))
            .filter_map(|(_, v)| v.start)
            .min();
        // (fleet, vehicle) and the events after its snapshot, in stream order.
        type Found = Vec<((String, String), AlarmEvent)>;
        let after: BTreeMap<(String, String), u64> = vehicles
            .iter()
            .map(|(k, v)| (k.clone(), v.after_id))
            .collect();
        let collect = |found: &mut Found,
                       bad: &mut usize,
                       m: Read<'_>,
                       only: Option<&BTreeSet<(String, String)>>| {
            let Some((fleet, vehicle, _)) = tokens(&prefix, m.subject) else {
                return;
            };
            let key = (fleet.to_string(), vehicle.to_string());
            if only.is_some_and(|only| !only.contains(&key)) {
                return;
            }
            match serde_json::from_slice::<EventHead>(m.payload) {
                Ok(e)
                    if e.id > after.get(&key).copied().unwrap_or(0)
                        && alarms::alarm_of(&e.kind).is_some() =>
                {
                    found.push((
                        key,
                        AlarmEvent {
                            id: e.id,
                            kind: e.kind.into_owned(),
                            subject: e.subject.into_owned(),
                            time_utc: e.time_utc.into_owned(),
                        },
                    ))
                }
                Ok(_) => {}
                Err(_) => *bad += 1,
            }
        };
        let shared = async {
            let mut found = Found::new();
            let mut bad = 0;
            if let Some(start) = shared_start {
                self.read(
                    format!("{prefix}.*.*.*.events"),
                    DeliverPolicy::ByStartTime { start_time: start },
                    |m| {
                        collect(&mut found, &mut bad, m, Some(&recent));
                        ControlFlow::Continue(())
                    },
                )
                .await?;
            }
            Ok::<_, ReadError>((found, bad))
        };
        // A read per literal subject, not one on `<fleet>.<vehicle>.*.events`: see `events`.
        let alone: Vec<_> = vehicles
            .iter()
            .filter(|(k, _)| !recent.contains(*k))
            .flat_map(|(key, v)| {
                let deliver = match v.start {
                    Some(start) => DeliverPolicy::ByStartTime { start_time: start },
                    None => DeliverPolicy::All,
                };
                let (fleet, vehicle) = key;
                let prefix = &prefix;
                let streams = event_streams.get(key).into_iter().flat_map(|s| s.keys());
                streams.map(move |stream| {
                    (
                        format!("{prefix}.{fleet}.{vehicle}.{stream}.events"),
                        deliver,
                    )
                })
            })
            .map(|(filter, deliver)| {
                let collect = &collect;
                async move {
                    let mut found = Found::new();
                    let mut bad = 0;
                    self.read(filter, deliver, |m| {
                        collect(&mut found, &mut bad, m, None);
                        ControlFlow::Continue(())
                    })
                    .await?;
                    Ok::<_, ReadError>((found, bad))
                }
            })
            .collect();
        let alone = futures_util::stream::iter(alone)
            .buffer_unordered(PARALLEL_READS)
            .collect::<Vec<_>>();
        let (shared, alone) = tokio::join!(shared, alone);
        let mut all = Found::new();
        for result in std::iter::once(shared).chain(alone) {
            let (found, n) = result?;
            bad += n;
            all.extend(found);
        }
        // Each vehicle's events in id order: its streams were read apart.
        all.sort_by(|(a, x), (b, y)| a.cmp(b).then(x.id.cmp(&y.id)));
        for (key, event) in all {
            if let Some(v) = vehicles.get_mut(&key) {
                v.state.apply(&event);
            }
        }
        if bad > 0 {
            tracing::warn!(
                messages = bad,
                "active alarms: messages that are not JSON skipped"
            );
        }
        Ok(vehicles
            .into_iter()
            .map(|((fleet, vehicle_id), v)| VehicleAlarms {
                fleet,
                vehicle_id,
                alarms: v.state.active(),
                snapshot_stored: v.snapshot_stored,
            })
            .collect())
    }
}

/// Nanoseconds since 1970 as a time.
pub fn utc(ns: i64) -> time::OffsetDateTime {
    time::OffsetDateTime::from_unix_timestamp_nanos(i128::from(ns))
        .unwrap_or(time::OffsetDateTime::UNIX_EPOCH)
}

/// An event of `payload` if it is in the request's time range and of its kind (None if not).
fn in_page(
    q: &EventsRequest,
    payload: &[u8],
) -> Result<Option<serde_json::Map<String, serde_json::Value>>, serde_json::Error> {
    let event: serde_json::Map<String, serde_json::Value> = serde_json::from_slice(payload)?;
    let time_ns = event
        .get("time_utc")
        .and_then(|t| t.as_str())
        .and_then(|t| railmon_bus::utc::parse_rfc3339(t).ok());
    let in_range = match time_ns {
        Some(t) => q.since_utc_ns.is_none_or(|s| t >= s) && q.until_utc_ns.is_none_or(|u| t < u),
        None => q.since_utc_ns.is_none() && q.until_utc_ns.is_none(),
    };
    let kind_ok = q
        .kind
        .as_deref()
        .is_none_or(|k| event.get("kind").and_then(|v| v.as_str()) == Some(k));
    Ok((in_range && kind_ok).then_some(event))
}

/// RFC 3339 UTC of a time.
pub fn rfc3339(t: time::OffsetDateTime) -> String {
    let ns = i64::try_from(t.unix_timestamp_nanos()).unwrap_or(0);
    railmon_bus::utc::format_rfc3339(ns)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn subjects_split_into_fleet_vehicle_and_the_rest() {
        assert_eq!(
            tokens("railmon", "railmon.north.unit-7.drive.events"),
            Some(("north", "unit-7", "drive.events"))
        );
        assert_eq!(
            tokens("a.b", "a.b._.unit-7.alarms"),
            Some(("_", "unit-7", "alarms"))
        );
        assert_eq!(tokens("railmon", "other.north.unit-7.health"), None);
        assert_eq!(tokens("railmon", "railmonx.north.unit-7.health"), None);
    }
}
