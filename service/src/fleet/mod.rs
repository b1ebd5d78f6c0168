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
    js: jetstream::Context,
    stream: jetstream::stream::Stream,
    /// `fleet.stream`.
    name: String,
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
            js,
            stream,
            name: config.stream.clone(),
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
        Ok(self
            .subject_counts(pattern)
            .await?
            .into_iter()
            .map(|(subject, _)| subject)
            .collect())
    }

    /// The subjects in the stream that match `pattern` and their message counts: one
    /// `STREAM.INFO` request per page of subjects (100,000 in a 2.9 server, so one). Not
    /// async-nats' `info_with_subjects`: it asks for one more page after the last (to learn that
    /// there is none), and the server computes the whole filtered list again for that empty
    /// page, which was half of this lookup's time (docs/fleet.md, "Measured").
    async fn subject_counts(&self, pattern: &str) -> Result<Vec<(String, u64)>, ReadError> {
        #[derive(Deserialize)]
        struct Page {
            state: PageState,
            /// The filter's subjects in all pages (absent when there are none).
            #[serde(default)]
            total: usize,
        }
        #[derive(Deserialize)]
        struct PageState {
            #[serde(default)]
            subjects: Option<std::collections::HashMap<String, u64>>,
        }
        let mut found = Vec::new();
        loop {
            let request = serde_json::json!({"subjects_filter": pattern, "offset": found.len()});
            let page: jetstream::response::Response<Page> = self
                .js
                .request(format!("STREAM.INFO.{}", self.name), &request)
                .await
                .map_err(|e| read_error("stream info", e))?;
            let page = match page {
                jetstream::response::Response::Ok(page) => page,
                jetstream::response::Response::Err { error } => {
                    return Err(read_error("stream info", error))
                }
            };
            let subjects = page.state.subjects.unwrap_or_default();
            let got = subjects.len();
            found.extend(subjects);
            if got == 0 || found.len() >= page.total {
                return Ok(found);
            }
        }
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
        let mut vehicles: BTreeMap<(String, String), BTreeMap<String, u64>> = BTreeMap::new();
        for (subject, count) in self.subject_counts(&filter).await? {
            if let Some((fleet, vehicle, rest)) = tokens(&self.prefix, &subject) {
                let stream = rest.strip_suffix(".events").unwrap_or(rest);
                vehicles
                    .entry((fleet.to_string(), vehicle.to_string()))
                    .or_default()
                    .insert(stream.to_string(), count);
            }
        }
        Ok(vehicles)
    }

    /// The alarms active on every vehicle (see the module documentation).
    ///
    /// Two chains of server requests run at once: the last alarm snapshot per vehicle, then
    /// the events stored since the oldest recent one; and the stream's event subjects (for the
    /// vehicles without a recent snapshot, whose events are read afterwards, subject by
    /// subject). Neither needs the other's answer: a vehicle that has events and no recent
    /// snapshot is never in the first chain's read (`recent` holds only vehicles with one).
    pub async fn active_alarms(&self) -> Result<Vec<VehicleAlarms>, ReadError> {
        let prefix = self.prefix.as_str();
        let from_snapshots = async {
            let (mut vehicles, mut bad) = self.alarm_snapshots().await?;
            let cutoff = time::OffsetDateTime::now_utc() - RECENT_WINDOW;
            let recent: BTreeSet<VehicleKey> = vehicles
                .iter()
                .filter(|(_, v)| v.start.is_some_and(|s| s >= cutoff))
                .map(|(k, _)| k.clone())
                .collect();
            let shared_start = recent.iter().filter_map(|k| vehicles[k].start).min();
            let mut found = Found::new();
            if let Some(start) = shared_start {
                self.read(
                    format!("{prefix}.*.*.*.events"),
                    DeliverPolicy::ByStartTime { start_time: start },
                    |m| {
                        if let Some(key) = vehicle_of(prefix, &m).filter(|k| recent.contains(k)) {
                            let after = vehicles[&key].after_id;
                            collect_alarm_event(key, after, &m, &mut found, &mut bad);
                        }
                        ControlFlow::Continue(())
                    },
                )
                .await?;
            }
            for (key, event) in found {
                if let Some(v) = vehicles.get_mut(&key) {
                    v.events.push(event);
                }
            }
            Ok::<_, ReadError>((vehicles, recent, bad))
        };
        // The event subjects on a connection's requests of their own would not make the server
        // answer them sooner: a 2.9 server handles a client's JetStream API requests one after
        // the other (in the connection's read loop); what runs at once here is the client's
        // waiting and decoding.
        let (from_snapshots, event_streams) = tokio::join!(from_snapshots, self.vehicles());
        let (mut vehicles, recent, mut bad) = from_snapshots?;
        let event_streams = event_streams?;
        for key in event_streams.keys() {
            vehicles.entry(key.clone()).or_default();
        }
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
                let streams = event_streams.get(key).into_iter().flat_map(|s| s.keys());
                streams.map(move |stream| {
                    let filter = format!("{prefix}.{fleet}.{vehicle}.{stream}.events");
                    (key.clone(), v.after_id, filter, deliver)
                })
            })
            .map(|(key, after, filter, deliver)| async move {
                let mut found = Found::new();
                let mut bad = 0;
                self.read(filter, deliver, |m| {
                    collect_alarm_event(key.clone(), after, &m, &mut found, &mut bad);
                    ControlFlow::Continue(())
                })
                .await?;
                Ok::<_, ReadError>((found, bad))
            })
            .collect();
        let alone = futures_util::stream::iter(alone)
            .buffer_unordered(PARALLEL_READS)
            .collect::<Vec<_>>()
            .await;
        for result in alone {
            let (found, n) = result?;
            bad += n;
            for (key, event) in found {
                if let Some(v) = vehicles.get_mut(&key) {
                    v.events.push(event);
                }
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
            .map(|((fleet, vehicle_id), mut v)| {
                // In id order: a vehicle's streams were read apart.
                v.events.sort_by_key(|e| e.id);
                v.events.iter().for_each(|e| v.state.apply(e));
                VehicleAlarms {
                    fleet,
                    vehicle_id,
                    alarms: v.state.active(),
                    snapshot_stored: v.snapshot_stored,
                }
            })
            .collect())
    }

    /// The last alarm snapshot of every vehicle that has one (`<prefix>.*.*.alarms`, one
    /// consumer delivering the last message per subject), and how many were not JSON.
    async fn alarm_snapshots(&self) -> Result<(BTreeMap<VehicleKey, Vehicle>, usize), ReadError> {
        let mut vehicles = BTreeMap::new();
        let mut bad = 0;
        let prefix = self.prefix.as_str();
        self.read(
            format!("{prefix}.*.*.alarms"),
            DeliverPolicy::LastPerSubject,
            |m| {
                let Some(key) = vehicle_of(prefix, &m) else {
                    return ControlFlow::Continue(());
                };
                match serde_json::from_slice::<AlarmSnapshot>(m.payload) {
                    Ok(snapshot) => {
                        vehicles.insert(
                            key,
                            Vehicle {
                                state: AlarmState::from_snapshot(&snapshot.alarms),
                                after_id: snapshot.last_event_id,
                                start: Some(m.stored - SNAPSHOT_MARGIN),
                                snapshot_stored: Some(m.stored),
                                events: Vec::new(),
                            },
                        );
                    }
                    Err(_) => bad += 1,
                }
                ControlFlow::Continue(())
            },
        )
        .await?;
        Ok((vehicles, bad))
    }
}

/// `(fleet, vehicle)`.
type VehicleKey = (String, String);

/// Alarm events and the vehicle each belongs to.
type Found = Vec<(VehicleKey, AlarmEvent)>;

/// A vehicle while its active alarms are derived.
#[derive(Default)]
struct Vehicle {
    /// From its snapshot (or none).
    state: AlarmState,
    /// Its snapshot's last event id: only later events change the state.
    after_id: u64,
    /// Read its events stored from here (None: all).
    start: Option<time::OffsetDateTime>,
    snapshot_stored: Option<time::OffsetDateTime>,
    /// Its alarm events after `after_id`, as read (not yet in id order).
    events: Vec<AlarmEvent>,
}

/// The vehicle a message under `prefix` belongs to.
fn vehicle_of(prefix: &str, m: &Read<'_>) -> Option<VehicleKey> {
    let (fleet, vehicle, _) = tokens(prefix, m.subject)?;
    Some((fleet.to_string(), vehicle.to_string()))
}

/// Adds the event of `m` to `found` if it raises or clears an alarm and is newer than `after`
/// (its vehicle's snapshot); counts it in `bad` if it is not an event.
fn collect_alarm_event(
    key: VehicleKey,
    after: u64,
    m: &Read<'_>,
    found: &mut Found,
    bad: &mut usize,
) {
    match serde_json::from_slice::<EventHead>(m.payload) {
        Ok(e) if e.id > after && alarms::alarm_of(&e.kind).is_some() => found.push((
            key,
            AlarmEvent {
                id: e.id,
                kind: e.kind.into_owned(),
                subject: e.subject.into_owned(),
                time_utc: e.time_utc.into_owned(),
            },
        )),
        Ok(_) => {}
        Err(_) => *bad += 1,
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
