//! The event uplink (issue 29): store and forward of every stored event to a NATS JetStream
//! stream on the ground, for a vehicle whose link drops in every tunnel.
//!
//! One tokio task reads pages of events from the event store, oldest first, after a cursor
//! (the last id the ground acknowledged, kept in the store's database), and publishes each on
//! `<prefix>.<fleet>.<vehicle>.<stream>.events` with the JetStream message id
//! `<vehicle>:<event id>` (`Nats-Msg-Id`), at most `max_events_per_s`. A page's acknowledgements
//! are awaited in order; then the cursor moves to the page's end and is committed. The backlog
//! is the store's (bounded by its retention), never held in memory: at most one page is.
//!
//! Exactly once on the ground, also across a lost acknowledgement, a link loss, a restart or a
//! kill -9: events after the cursor are sent again, and
//! - on every (re)connection the uplink first reads the headers of what it sent since the
//!   cursor was saved (the cursor keeps the stream sequence to look after) and moves the cursor
//!   over the events the stream holds, in id order, up to the first it does not hold; those it
//!   holds beyond such a hole are not sent again (see `ground`), however long the link was down;
//! - a re-send within a connection (an acknowledgement timed out) carries the same message id,
//!   which the stream's duplicate window drops (counted: `railmon_uplink_duplicates_total`).
//!
//! A hole (a message lost with a dropped connection while the next ones were stored, or a
//! publish during a leader election) is filled after the events beyond it: per vehicle the
//! ground's order is the event id's, which the stream sequence follows except there.
//!
//! The stream is created if missing (subjects `<prefix>.>`, duplicate window 2 min, file
//! storage, one replica): a vehicle then also works against a plain `nats-server -js`. A
//! ground that creates it (replicas, limits) keeps its own settings: an existing stream is
//! used as it is.
//!
//! Never in the way of the estimators: the ingest threads only append to the store's channel;
//! the uplink reads the store in `spawn_blocking` (it shares the store's connection, so a page
//! waits for a commit in progress, never the other way round for longer than one page read).

pub mod config;
mod ground;
pub mod health;
mod pace;

use std::future::IntoFuture;
use std::sync::atomic::{AtomicI64, AtomicU64, Ordering::Relaxed};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use async_nats::jetstream::{self, context::PublishAckFuture};
use serde::Serialize;
use utoipa::ToSchema;

use crate::config::Identity;
use crate::store::{EventQuery, EventStore, EventView, ReadPage};
pub use config::UplinkConfig;
use ground::Cursor;
use pace::{Backoff, Pacer};

/// Events read and published per page; their acknowledgements are awaited before the next.
const PAGE_EVENTS: usize = 256;
/// How often a caught-up uplink looks for new events (the store's last id, an atomic).
const IDLE_POLL: Duration = Duration::from_millis(200);
/// How often the backlog is counted in the store while nothing is sent.
const BACKLOG_REFRESH: Duration = Duration::from_secs(5);
/// The duplicate window of a stream the uplink creates: longer than a page's acknowledgement
/// timeout plus a reconnection, the only re-sends the cursor reconciliation leaves.
const DUPLICATE_WINDOW: Duration = Duration::from_secs(120);
/// An acknowledgement not received within this is a failure (the page is sent again).
const ACK_TIMEOUT: Duration = Duration::from_secs(5);
/// Reconnection and retry backoff.
const BACKOFF_MIN: Duration = Duration::from_millis(250);
const BACKOFF_MAX: Duration = Duration::from_secs(5);
/// At most one log line per failure kind this often (a link that flaps in a cutting).
const LOG_EVERY: Duration = Duration::from_secs(10);

/// What went wrong, as `railmon_uplink_failures_total{kind}` counts it. `unreachable`: an
/// attempt on the stream (reach it, publish, await acknowledgements) failed while the client
/// had no connection to any server (none listening at start, or during an outage); `stream`,
/// `publish` and `ack` are the same failures with a server connected (a stream refused, a
/// permission, a leader election), so that a ground that is away does not read as a ground
/// that refuses.
pub const FAILURE_KINDS: [&str; 7] = [
    "disconnected",
    "unreachable",
    "stream",
    "publish",
    "ack",
    "store",
    "connect",
];

/// The uplink's counters, shared with `/api/v1/status` and `/metrics`.
#[derive(Debug, Default)]
pub struct UplinkCounters {
    pub sent: AtomicU64,
    pub acknowledged: AtomicU64,
    /// Acknowledged as duplicates (the stream already held that message id).
    pub duplicates: AtomicU64,
    /// Events stored with an id above the cursor.
    pub backlog: AtomicU64,
    pub cursor: AtomicU64,
    /// Unix time (ms) of the last acknowledgement; 0: none yet.
    pub last_ack_unix_ms: AtomicU64,
    /// 1 while connected to a server.
    pub link_up: AtomicI64,
    /// By [`FAILURE_KINDS`].
    pub failures: [AtomicU64; FAILURE_KINDS.len()],
}

impl UplinkCounters {
    fn fail(&self, kind: &str) {
        if let Some(i) = FAILURE_KINDS.iter().position(|k| *k == kind) {
            self.failures[i].fetch_add(1, Relaxed);
        }
    }

    pub fn status(&self) -> UplinkStatus {
        let last = self.last_ack_unix_ms.load(Relaxed);
        UplinkStatus {
            link_up: self.link_up.load(Relaxed) == 1,
            events_sent: self.sent.load(Relaxed),
            events_acknowledged: self.acknowledged.load(Relaxed),
            events_duplicate: self.duplicates.load(Relaxed),
            backlog_events: self.backlog.load(Relaxed),
            acknowledged_event_id: self.cursor.load(Relaxed),
            last_ack_utc: (last > 0).then(|| {
                railmon_bus::utc::format_rfc3339(i64::try_from(last).unwrap_or(0) * 1_000_000)
            }),
            failures: FAILURE_KINDS
                .iter()
                .zip(&self.failures)
                .map(|(k, n)| (k.to_string(), n.load(Relaxed)))
                .collect(),
        }
    }
}

/// `/api/v1/status`'s view of the uplink (absent when `uplink.url` is empty).
#[derive(Clone, Debug, Serialize, ToSchema)]
pub struct UplinkStatus {
    /// Connected to a NATS server.
    pub link_up: bool,
    pub events_sent: u64,
    pub events_acknowledged: u64,
    /// Acknowledged as already stored (a re-send the duplicate window dropped).
    pub events_duplicate: u64,
    /// Stored events not yet acknowledged by the ground.
    pub backlog_events: u64,
    /// The cursor: every event up to this id is on the ground.
    pub acknowledged_event_id: u64,
    /// RFC 3339 UTC; none before the first acknowledgement.
    pub last_ack_utc: Option<String>,
    /// Failures by kind (each logged, at most once per 10 s per kind).
    pub failures: std::collections::BTreeMap<String, u64>,
}

/// The subjects of one vehicle.
#[derive(Clone, Debug)]
struct Subjects {
    /// `<prefix>.<fleet>.<vehicle>`
    base: String,
    vehicle_id: String,
}

impl Subjects {
    fn new(prefix: &str, identity: &Identity) -> Self {
        let fleet = match identity.fleet.is_empty() {
            true => "_",
            false => identity.fleet.as_str(),
        };
        Self {
            base: format!("{prefix}.{fleet}.{}", identity.vehicle_id),
            vehicle_id: identity.vehicle_id.clone(),
        }
    }

    fn events(&self, stream: &str) -> String {
        format!("{}.{stream}.events", self.base)
    }

    /// Every event subject of this vehicle.
    fn all_events(&self) -> String {
        self.events("*")
    }

    fn message_id(&self, event_id: u64) -> String {
        format!("{}:{event_id}", self.vehicle_id)
    }

    /// The event id of a message id of this vehicle.
    fn event_id(&self, message_id: &str) -> Option<u64> {
        let (vehicle, id) = message_id.rsplit_once(':')?;
        (vehicle == self.vehicle_id).then(|| id.parse().ok())?
    }
}

/// Refuses an identity whose resolved vehicle id (the host name when `identity.vehicle_id` is
/// empty) would split a subject token.
pub fn check_identity(identity: &Identity) -> Result<(), String> {
    if identity.vehicle_id.contains('.') {
        return Err(format!(
            "the vehicle id `{}` (the host name?) contains `.`, which would split the uplink's \
             NATS subject tokens: set identity.vehicle_id",
            identity.vehicle_id
        ));
    }
    Ok(())
}

/// One log line per kind at most every [`LOG_EVERY`], saying how many were not logged.
struct RateLimitedLog {
    last: Mutex<Vec<(&'static str, Instant, u64)>>,
}

impl RateLimitedLog {
    fn new() -> Self {
        Self {
            last: Mutex::new(Vec::new()),
        }
    }

    fn warn(&self, kind: &'static str, message: &str) {
        let mut last = self.last.lock().unwrap_or_else(|p| p.into_inner());
        let now = Instant::now();
        match last.iter_mut().find(|(k, _, _)| *k == kind) {
            Some((_, at, suppressed)) if now.duration_since(*at) < LOG_EVERY => *suppressed += 1,
            Some((_, at, suppressed)) => {
                tracing::warn!(kind, not_logged = *suppressed, "uplink: {message}");
                *at = now;
                *suppressed = 0;
            }
            None => {
                tracing::warn!(kind, "uplink: {message}");
                last.push((kind, now, 0));
            }
        }
    }
}

/// A failure of one attempt: its kind ([`FAILURE_KINDS`]) and what happened.
struct Failure(&'static str, String);

/// The uplink task: runs until the runtime stops (the cursor is committed after every page,
/// so stopping at any point loses nothing).
pub async fn run(store: Arc<EventStore>, config: UplinkConfig, counters: Arc<UplinkCounters>) {
    let identity = store.identity().clone();
    let subjects = Subjects::new(&config.subject_prefix, &identity);
    let log = Arc::new(RateLimitedLog::new());
    let mut backoff = Backoff::new(BACKOFF_MIN, BACKOFF_MAX);
    let mut cursor = loop {
        match blocking(&store, |s| s.uplink_cursor()).await {
            Ok(saved) => break Cursor::new(saved),
            Err(e) => {
                counters.fail("store");
                log.warn("store", &format!("cannot read the cursor: {e}"));
                tokio::time::sleep(backoff.next_delay()).await;
            }
        }
    };
    counters.cursor.store(cursor.acked_id(), Relaxed);
    refresh_backlog(&store, cursor.acked_id(), &counters).await;
    // The backlog is counted apart from the forwarding, which may wait on a dead link.
    tokio::spawn(count_backlog(store.clone(), counters.clone()));
    let client = loop {
        match connect(&config, &counters, &log).await {
            Ok(client) => break client,
            Err(e) => {
                counters.fail("connect");
                log.warn("connect", &e);
                tokio::time::sleep(backoff.next_delay()).await;
            }
        }
    };
    tracing::info!(
        url = %config.url,
        subjects = %format!("{}.*.events", subjects.base),
        stream = %config.stream,
        cursor = cursor.acked_id(),
        "uplink started"
    );
    let js = jetstream::ContextBuilder::new()
        .timeout(ACK_TIMEOUT)
        .build(client.clone());
    let mut pacer = Pacer::new(config.max_events_per_s);
    loop {
        let attempt = async {
            let stream = ensure_stream(&js, &config).await?;
            // The stream answered: the link is up (also if the client's `Connected` event came
            // before the callback was in place).
            counters.link_up.store(1, Relaxed);
            // What the stream holds above the cursor is read again on every connection.
            cursor.forget_held();
            reconcile(&stream, &subjects, &store, &mut cursor, &counters).await?;
            forward(
                &js,
                &store,
                &subjects,
                &mut cursor,
                &counters,
                &mut pacer,
                &mut backoff,
            )
            .await
        };
        let Failure(kind, message) = match attempt.await {
            Ok(()) => continue,
            Err(failure) => failure,
        };
        let connected = client.connection_state() == async_nats::connection::State::Connected;
        let kind = match (connected, kind) {
            (false, "stream" | "publish" | "ack") => "unreachable",
            _ => kind,
        };
        counters.fail(kind);
        counters.link_up.store(i64::from(connected), Relaxed);
        log.warn(kind, &message);
        tokio::time::sleep(backoff.next_delay()).await;
    }
}

/// Runs a store call off the async workers.
async fn blocking<T: Send + 'static>(
    store: &Arc<EventStore>,
    call: impl FnOnce(&EventStore) -> Result<T, crate::store::StoreError> + Send + 'static,
) -> Result<T, String> {
    let store = store.clone();
    match tokio::task::spawn_blocking(move || call(&store)).await {
        Ok(result) => result.map_err(|e| e.to_string()),
        Err(e) => Err(format!("store task: {e}")),
    }
}

async fn refresh_backlog(store: &Arc<EventStore>, cursor: u64, counters: &UplinkCounters) {
    match blocking(store, move |s| s.count_after(cursor)).await {
        Ok(n) => counters.backlog.store(n, Relaxed),
        Err(e) => tracing::warn!("uplink: cannot count the backlog: {e}"),
    }
}

/// Counts the backlog every second while the store or the cursor moved.
async fn count_backlog(store: Arc<EventStore>, counters: Arc<UplinkCounters>) {
    let mut counted = (u64::MAX, u64::MAX);
    loop {
        tokio::time::sleep(Duration::from_secs(1)).await;
        let now = (
            store.counters.last_id.load(Relaxed),
            counters.cursor.load(Relaxed),
        );
        if now != counted {
            refresh_backlog(&store, now.1, &counters).await;
            counted = now;
        }
    }
}

/// The client: reconnects by itself (for ever, with backoff) after a link loss; publishes
/// made meanwhile wait in its bounded buffer or fail, and are sent again from the cursor.
async fn connect(
    config: &UplinkConfig,
    counters: &Arc<UplinkCounters>,
    log: &Arc<RateLimitedLog>,
) -> Result<async_nats::Client, String> {
    let mut options = async_nats::ConnectOptions::new()
        .name("railmon-uplink")
        .retry_on_initial_connect()
        .connection_timeout(Duration::from_secs(5))
        .reconnect_delay_callback(|attempts| {
            let mut backoff = Backoff::new(BACKOFF_MIN, BACKOFF_MAX);
            (0..attempts.min(16)).fold(BACKOFF_MIN, |_, _| backoff.next_delay())
        });
    if !config.user.is_empty() {
        options = options.user_and_password(config.user.clone(), config.password.clone());
    }
    if !config.token.is_empty() {
        options = options.token(config.token.clone());
    }
    if !config.creds_file.is_empty() {
        options = options
            .credentials_file(&config.creds_file)
            .await
            .map_err(|e| format!("uplink.creds_file {}: {e}", config.creds_file))?;
    }
    if !config.tls_ca_file.is_empty() {
        options = options
            .add_root_certificates(config.tls_ca_file.clone().into())
            .require_tls(true);
    }
    let events = (counters.clone(), log.clone());
    options = options.event_callback(move |event| {
        let (counters, log) = events.clone();
        async move {
            match event {
                async_nats::Event::Connected => {
                    counters.link_up.store(1, Relaxed);
                    tracing::info!("uplink: connected");
                }
                async_nats::Event::Disconnected => {
                    counters.link_up.store(0, Relaxed);
                    counters.fail("disconnected");
                    log.warn("disconnected", "link lost, reconnecting");
                }
                other => log.warn("client", &format!("client event: {other}")),
            }
        }
    });
    let servers: Vec<async_nats::ServerAddr> = config
        .url
        .split(',')
        .filter(|s| !s.trim().is_empty())
        .map(|s| {
            s.trim()
                .parse()
                .map_err(|e| format!("uplink.url `{s}`: {e}"))
        })
        .collect::<Result<_, _>>()?;
    options
        .connect(servers)
        .await
        .map_err(|e| format!("connecting to {}: {e}", config.url))
}

/// The stream a vehicle's uplink creates when the server has none (one replica: a vehicle
/// cannot know the ground's cluster), and `railmon fleet --create-stream` with the ground's
/// replicas: subjects `<subject_prefix>.>`, file storage, the duplicate window.
pub fn stream_config(
    stream: &str,
    subject_prefix: &str,
    replicas: usize,
) -> jetstream::stream::Config {
    jetstream::stream::Config {
        name: stream.to_string(),
        subjects: vec![format!("{subject_prefix}.>")],
        duplicate_window: DUPLICATE_WINDOW,
        storage: jetstream::stream::StorageType::File,
        num_replicas: replicas,
        ..Default::default()
    }
}

async fn ensure_stream(
    js: &jetstream::Context,
    config: &UplinkConfig,
) -> Result<jetstream::stream::Stream, Failure> {
    js.get_or_create_stream(stream_config(&config.stream, &config.subject_prefix, 1))
        .await
        .map_err(|e| Failure("stream", format!("stream {}: {e}", config.stream)))
}

/// Moves the cursor over the events the stream already holds (see the module documentation
/// and `ground`): what was stored but not acknowledged, or acknowledged but not committed, is
/// not sent again, however long ago it was sent.
async fn reconcile(
    stream: &jetstream::stream::Stream,
    subjects: &Subjects,
    store: &Arc<EventStore>,
    cursor: &mut Cursor,
    counters: &UplinkCounters,
) -> Result<(), Failure> {
    let last_stored_id = store.counters.last_id.load(Relaxed);
    ground::read_above_cursor(
        stream,
        subjects.all_events(),
        last_stored_id,
        |message_id| subjects.event_id(message_id),
        ACK_TIMEOUT,
        cursor,
    )
    .await
    .map_err(|e| Failure("stream", e))?;
    let from = cursor.acked_id();
    while !cursor.holds_nothing_above() {
        let page = page_after(store, cursor.acked_id()).await?;
        let Some(held_until) = cursor.contiguous_until(page.events.iter().map(|e| e.id)) else {
            break;
        };
        commit_cursor(store, held_until, cursor, counters).await?;
        if page.events.last().is_some_and(|e| e.id != held_until) {
            break;
        }
    }
    if cursor.acked_id() > from {
        tracing::info!(
            from,
            to = cursor.acked_id(),
            held_beyond = !cursor.holds_nothing_above(),
            "uplink: the stream already holds events after the cursor; cursor moved"
        );
    }
    Ok(())
}

/// The next page of stored events after `after_id`, oldest first.
async fn page_after(store: &Arc<EventStore>, after_id: u64) -> Result<ReadPage, Failure> {
    blocking(store, move |s| {
        s.read_page(&EventQuery {
            after_id,
            limit: PAGE_EVENTS,
            ..EventQuery::default()
        })
    })
    .await
    .map_err(|e| Failure("store", format!("reading events: {e}")))
}

async fn commit_cursor(
    store: &Arc<EventStore>,
    acked_id: u64,
    cursor: &mut Cursor,
    counters: &UplinkCounters,
) -> Result<(), Failure> {
    let next = cursor.at(acked_id);
    blocking(store, move |s| s.save_uplink_cursor(next))
        .await
        .map_err(|e| Failure("store", format!("cannot save the cursor: {e}")))?;
    cursor.saved(next);
    counters.cursor.store(acked_id, Relaxed);
    Ok(())
}

/// Sends pages after the cursor until a failure.
async fn forward(
    js: &jetstream::Context,
    store: &Arc<EventStore>,
    subjects: &Subjects,
    cursor: &mut Cursor,
    counters: &UplinkCounters,
    pacer: &mut Pacer,
    backoff: &mut Backoff,
) -> Result<(), Failure> {
    let mut backlog_counted = Instant::now();
    loop {
        if store.counters.last_id.load(Relaxed) <= cursor.acked_id() {
            if backlog_counted.elapsed() >= BACKLOG_REFRESH {
                refresh_backlog(store, cursor.acked_id(), counters).await;
                backlog_counted = Instant::now();
            }
            tokio::time::sleep(IDLE_POLL).await;
            continue;
        }
        let page = page_after(store, cursor.acked_id()).await?;
        let Some(last_read_id) = page.last_read_id else {
            // The store's last id is ahead of its rows (pruned): nothing left to send.
            tokio::time::sleep(IDLE_POLL).await;
            refresh_backlog(store, cursor.acked_id(), counters).await;
            continue;
        };
        let mut in_flight: Vec<(u64, PublishAckFuture)> = Vec::with_capacity(page.events.len());
        for event in page.events.iter().filter(|e| !cursor.holds(e.id)) {
            let wait = pacer.delay(Instant::now());
            if wait >= Duration::from_millis(1) {
                tokio::time::sleep(wait).await;
            }
            let payload = payload(event, store.identity())
                .map_err(|e| Failure("publish", format!("event {}: {e}", event.id)))?;
            let publish = js.send_publish(
                subjects.events(&event.stream),
                jetstream::message::PublishMessage::build()
                    .message_id(subjects.message_id(event.id))
                    .payload(payload.into()),
            );
            // Bounded also while the client's buffer is full on a dead link.
            let ack = tokio::time::timeout(ACK_TIMEOUT, publish)
                .await
                .map_err(|_| Failure("publish", format!("event {}: timed out", event.id)))?
                .map_err(|e| Failure("publish", format!("event {}: {e}", event.id)))?;
            counters.sent.fetch_add(1, Relaxed);
            in_flight.push((event.id, ack));
        }
        for (id, ack) in in_flight {
            let ack = tokio::time::timeout(ACK_TIMEOUT, ack.into_future())
                .await
                .map_err(|_| Failure("ack", format!("event {id}: timed out")))?
                .map_err(|e| Failure("ack", format!("event {id}: {e}")))?;
            counters.acknowledged.fetch_add(1, Relaxed);
            cursor.saw_sequence(ack.sequence);
            if ack.duplicate {
                counters.duplicates.fetch_add(1, Relaxed);
            }
        }
        let now_ms = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_millis() as u64)
            .unwrap_or(0);
        counters.last_ack_unix_ms.store(now_ms, Relaxed);
        commit_cursor(store, last_read_id, cursor, counters).await?;
        refresh_backlog(store, cursor.acked_id(), counters).await;
        backlog_counted = Instant::now();
        backoff.reset();
    }
}

/// The message: the event as the API shows it, with the vehicle it is from.
fn payload(event: &EventView, identity: &Identity) -> Result<Vec<u8>, serde_json::Error> {
    let mut value = serde_json::to_value(event)?;
    if let Some(object) = value.as_object_mut() {
        object.insert("vehicle_id".into(), identity.vehicle_id.clone().into());
        object.insert("fleet".into(), identity.fleet.clone().into());
    }
    serde_json::to_vec(&value)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn subjects_and_message_ids_name_fleet_vehicle_and_stream() {
        let identity = Identity {
            vehicle_id: "unit-4711".into(),
            fleet: String::new(),
        };
        let s = Subjects::new("railmon", &identity);
        assert_eq!(s.events("bogie"), "railmon._.unit-4711.bogie.events");
        assert_eq!(s.message_id(42), "unit-4711:42");
        assert_eq!(s.event_id("unit-4711:42"), Some(42));
        assert_eq!(s.event_id("unit-4712:42"), None);
        assert_eq!(s.event_id("unit-4711:x"), None);
        let fleet = Identity {
            fleet: "north".into(),
            ..identity
        };
        assert_eq!(
            Subjects::new("a.b", &fleet).events("drive"),
            "a.b.north.unit-4711.drive.events"
        );
    }

    #[test]
    fn a_dotted_vehicle_id_is_refused() {
        let identity = Identity {
            vehicle_id: "host.example".into(),
            fleet: String::new(),
        };
        assert!(check_identity(&identity)
            .unwrap_err()
            .contains("identity.vehicle_id"));
    }
}
