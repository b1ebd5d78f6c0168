//! The embedded event store: every stream's events and the alarms that are active, in SQLite
//! (WAL) under `[storage] data_dir`, so that alarms and event ids survive a restart.
//!
//! Why SQLite (rusqlite, SQLite compiled in): pages by id, time, stream and kind are plain SQL
//! over indexes; WAL gives durable commits with concurrent readers; the file opens with the
//! `sqlite3` tool a maintainer already has; schema versions migrate in place ([`schema`]).
//! redb would serve the key-value part as well, but every page query would be ours to write.
//!
//! Writes are off the ingest threads' hot path: they send [`NewEvent`]s down a channel and a
//! writer thread commits each batch in one transaction, together with the change of the
//! alarms the events raise or clear: after a crash the active alarms agree with the events
//! stored. Ids come from SQLite (`AUTOINCREMENT`: never reused, also after pruning), so an
//! `after_id` cursor stays valid across restarts.

mod schema;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use railmon_bus::StreamKind;
use rusqlite::{params, Connection, OptionalExtension};
use serde::Serialize;
use utoipa::ToSchema;

use crate::config::{Identity, StorageConfig};
pub use schema::SCHEMA_VERSION;

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("event database: {0}")]
    Sqlite(#[from] rusqlite::Error),
    #[error("event database {path}: {reason}")]
    Open { path: String, reason: String },
    #[error("event database has schema version {found}, this build knows up to {known}: refusing to write to it")]
    NewerSchema { found: i64, known: i64 },
    #[error("event detail is not a JSON object: {0}")]
    Detail(String),
}

/// An event as a pipeline raises it; the store gives it its id.
#[derive(Clone, Debug, PartialEq)]
pub struct NewEvent {
    pub stream: StreamKind,
    /// `slip_started`, `damper_degraded`, `regime_changed`, ...
    pub kind: String,
    /// What it is about within the stream: `1` (drive 1), `2/csay` (bogie 2's anti-yaw
    /// damper), empty for the vehicle.
    pub subject: String,
    pub time_utc_ns: i64,
    pub time_s: f64,
    pub run: u32,
    pub run_time_s: f64,
    /// The stream's own fields (`drive`, `slip_probability`, ...), a JSON object.
    pub detail: serde_json::Map<String, serde_json::Value>,
    /// The alarm (`slipping`, `degraded`) this event raises (`Some(true)`) or clears.
    pub alarm: Option<(String, bool)>,
}

/// An event as the API returns it.
#[derive(Clone, Debug, PartialEq, Serialize, ToSchema)]
pub struct EventView {
    /// Increasing over the life of the database (also across restarts).
    pub id: u64,
    pub stream: String,
    pub kind: String,
    pub subject: String,
    /// When the sample that raised it was acquired, RFC 3339 UTC.
    pub time_utc: String,
    pub time_s: f64,
    pub run: u32,
    pub run_time_s: f64,
    /// The stream's own fields, e.g. `drive` and `slip_probability`.
    #[serde(flatten)]
    #[schema(value_type = Object)]
    pub detail: serde_json::Map<String, serde_json::Value>,
}

/// An alarm that is active, with the event that raised it.
#[derive(Clone, Debug, PartialEq, Serialize, ToSchema)]
pub struct ActiveAlarm {
    pub stream: String,
    pub subject: String,
    pub alarm: String,
    pub event_id: u64,
    pub since_utc: String,
}

/// Which events a page holds.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct EventQuery {
    pub after_id: u64,
    pub since_utc_ns: Option<i64>,
    pub stream: Option<StreamKind>,
    pub kind: Option<String>,
    pub subject: Option<String>,
    /// Subjects starting with this, or this without its last character (`2/`: both dampers
    /// of bogie 2, `2/csy` and `2/csay`, and the bogie's own status events, `2`).
    pub subject_prefix: Option<String>,
    pub limit: usize,
}

/// What the store did, for `/api/v1/status`.
#[derive(Debug, Default)]
pub struct StoreCounters {
    pub stored: AtomicU64,
    pub pruned: AtomicU64,
    pub write_errors: AtomicU64,
    pub last_id: AtomicU64,
    /// Events waiting to be written (sent, not yet committed).
    pub pending: AtomicU64,
}

/// `/api/v1/status`'s view of the store.
#[derive(Clone, Debug, Serialize, ToSchema)]
pub struct StoreStatus {
    /// The database file, or `:memory:`.
    pub database: String,
    pub schema_version: i64,
    pub events_stored: u64,
    pub events_pruned: u64,
    pub events_pending: u64,
    pub write_errors: u64,
    pub last_event_id: u64,
}

enum Command {
    Append(Vec<NewEvent>),
    /// Answer once everything sent before is committed.
    Flush(Sender<()>),
}

/// Handle on the store: send events, read pages. Cheap to share (`Arc`).
pub struct EventStore {
    identity: Identity,
    location: Location,
    writer: Mutex<Sender<Command>>,
    readers: Mutex<Vec<Connection>>,
    pub counters: Arc<StoreCounters>,
    config: StorageConfig,
}

#[derive(Clone, Debug)]
enum Location {
    File(PathBuf),
    /// `:memory:`: a throw-away database file in the temporary directory, removed when the
    /// store is dropped (so that readers and the writer share it exactly as with a file).
    Temporary(PathBuf),
}

impl Location {
    fn path(&self) -> &Path {
        match self {
            Location::File(path) | Location::Temporary(path) => path,
        }
    }

    fn open(&self) -> Result<Connection, StoreError> {
        let connection = Connection::open(self.path())?;
        connection.busy_timeout(Duration::from_secs(5))?;
        connection.pragma_update(None, "journal_mode", "WAL")?;
        // Durable at each commit (events are rare; an alarm must survive a power cut).
        connection.pragma_update(None, "synchronous", "FULL")?;
        Ok(connection)
    }

    fn describe(&self) -> String {
        match self {
            Location::File(path) => path.display().to_string(),
            Location::Temporary(_) => ":memory:".into(),
        }
    }
}

impl Drop for EventStore {
    fn drop(&mut self) {
        if let Location::Temporary(path) = &self.location {
            self.readers
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .clear();
            for suffix in ["", "-wal", "-shm"] {
                let _ = std::fs::remove_file(format!("{}{suffix}", path.display()));
            }
        }
    }
}

const NS_PER_DAY: i64 = 86_400 * 1_000_000_000;

impl EventStore {
    /// Opens (creating and migrating) the database and starts the writer thread.
    pub fn open(
        config: &StorageConfig,
        identity: &Identity,
    ) -> Result<(Arc<Self>, JoinHandle<()>), StoreError> {
        let location = match config.database_path() {
            Some(path) => {
                if let Some(dir) = path.parent() {
                    create_private_dir(dir).map_err(|reason| StoreError::Open {
                        path: dir.display().to_string(),
                        reason,
                    })?;
                }
                Location::File(path)
            }
            None => {
                static N: AtomicU64 = AtomicU64::new(0);
                Location::Temporary(std::env::temp_dir().join(format!(
                    "railmon-events-{}-{}.sqlite3",
                    std::process::id(),
                    N.fetch_add(1, Ordering::Relaxed)
                )))
            }
        };
        let mut connection = location.open().map_err(|e| StoreError::Open {
            path: location.describe(),
            reason: e.to_string(),
        })?;
        schema::migrate(&mut connection)?;
        let counters = Arc::new(StoreCounters::default());
        let last_id: Option<i64> = connection
            .query_row("SELECT max(id) FROM events", [], |r| r.get(0))
            .optional()?
            .flatten();
        counters
            .last_id
            .store(last_id.unwrap_or(0) as u64, Ordering::Relaxed);
        let pruned: Option<i64> = connection
            .query_row(
                "SELECT value FROM counters WHERE name = 'pruned'",
                [],
                |r| r.get(0),
            )
            .optional()?;
        counters
            .pruned
            .store(pruned.unwrap_or(0) as u64, Ordering::Relaxed);
        let (tx, rx) = channel();
        let writer = Writer {
            connection,
            identity: identity.clone(),
            counters: counters.clone(),
            config: config.clone(),
        };
        let thread = std::thread::Builder::new()
            .name("event-store".into())
            .spawn(move || writer.run(rx))
            .map_err(|e| StoreError::Open {
                path: location.describe(),
                reason: format!("writer thread: {e}"),
            })?;
        let store = Arc::new(Self {
            identity: identity.clone(),
            location,
            writer: Mutex::new(tx),
            readers: Mutex::new(Vec::new()),
            counters,
            config: config.clone(),
        });
        Ok((store, thread))
    }

    /// Queues `events` for the writer thread; never waits.
    pub fn append(&self, events: Vec<NewEvent>) {
        if events.is_empty() {
            return;
        }
        self.counters
            .pending
            .fetch_add(events.len() as u64, Ordering::Relaxed);
        let sender = self.writer.lock().unwrap_or_else(|p| p.into_inner());
        if sender.send(Command::Append(events)).is_err() {
            self.counters.write_errors.fetch_add(1, Ordering::Relaxed);
            tracing::error!("event store writer has stopped: events not stored");
        }
    }

    /// Waits until everything appended before is committed (shutdown, tests).
    pub fn flush(&self) {
        let (tx, rx) = channel();
        let sent = self
            .writer
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .send(Command::Flush(tx));
        if sent.is_ok() {
            let _ = rx.recv_timeout(Duration::from_secs(10));
        }
    }

    /// Stops the writer thread once the queue is written (it ends when every sender is gone).
    pub fn close(&self) {
        self.flush();
        let (dead, _) = channel();
        *self.writer.lock().unwrap_or_else(|p| p.into_inner()) = dead;
    }

    fn with_reader<T>(
        &self,
        read: impl FnOnce(&Connection) -> Result<T, StoreError>,
    ) -> Result<T, StoreError> {
        let pooled = self.readers.lock().unwrap_or_else(|p| p.into_inner()).pop();
        let connection = match pooled {
            Some(c) => c,
            None => self.location.open()?,
        };
        let result = read(&connection);
        self.readers
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .push(connection);
        result
    }

    /// A page of events, oldest first.
    pub fn page(&self, query: &EventQuery) -> Result<Vec<EventView>, StoreError> {
        self.with_reader(|c| {
            let mut statement = c.prepare_cached(
                "SELECT id, stream, kind, subject, time_utc_ns, time_s, run, run_time_s, detail
                 FROM events
                 WHERE id > ?1 AND time_utc_ns >= ?2
                   AND (?3 IS NULL OR stream = ?3) AND (?4 IS NULL OR kind = ?4)
                   AND (?5 IS NULL OR subject = ?5)
                   AND (?7 IS NULL OR substr(subject, 1, length(?7)) = ?7
                        OR subject || '/' = ?7)
                 ORDER BY id LIMIT ?6",
            )?;
            let rows = statement.query_map(
                params![
                    query.after_id as i64,
                    query.since_utc_ns.unwrap_or(i64::MIN),
                    query.stream.map(StreamKind::name),
                    query.kind,
                    query.subject,
                    query.limit as i64,
                    query.subject_prefix,
                ],
                |r| {
                    Ok((
                        r.get::<_, i64>(0)?,
                        r.get::<_, String>(1)?,
                        r.get::<_, String>(2)?,
                        r.get::<_, String>(3)?,
                        r.get::<_, i64>(4)?,
                        r.get::<_, f64>(5)?,
                        r.get::<_, i64>(6)?,
                        r.get::<_, f64>(7)?,
                        r.get::<_, String>(8)?,
                    ))
                },
            )?;
            let mut events = Vec::new();
            for row in rows {
                let (id, stream, kind, subject, utc, time_s, run, run_time_s, detail) = row?;
                let detail = match serde_json::from_str(&detail) {
                    Ok(serde_json::Value::Object(map)) => map,
                    _ => return Err(StoreError::Detail(detail)),
                };
                events.push(EventView {
                    id: id as u64,
                    stream,
                    kind,
                    subject,
                    time_utc: railmon_bus::utc::format_rfc3339(utc),
                    time_s,
                    run: run as u32,
                    run_time_s,
                    detail,
                });
            }
            Ok(events)
        })
    }

    /// The alarms that are active now (as of the last commit).
    pub fn active_alarms(&self) -> Result<Vec<ActiveAlarm>, StoreError> {
        self.with_reader(|c| {
            let mut statement = c.prepare_cached(
                "SELECT stream, subject, alarm, event_id, since_utc_ns FROM active_alarms
                 ORDER BY stream, subject, alarm",
            )?;
            let rows = statement.query_map([], |r| {
                Ok(ActiveAlarm {
                    stream: r.get(0)?,
                    subject: r.get(1)?,
                    alarm: r.get(2)?,
                    event_id: r.get::<_, i64>(3)? as u64,
                    since_utc: railmon_bus::utc::format_rfc3339(r.get(4)?),
                })
            })?;
            Ok(rows.collect::<Result<_, _>>()?)
        })
    }

    pub fn status(&self) -> StoreStatus {
        let c = &self.counters;
        StoreStatus {
            database: self.location.describe(),
            schema_version: SCHEMA_VERSION,
            events_stored: c.stored.load(Ordering::Relaxed),
            events_pruned: c.pruned.load(Ordering::Relaxed),
            events_pending: c.pending.load(Ordering::Relaxed),
            write_errors: c.write_errors.load(Ordering::Relaxed),
            last_event_id: c.last_id.load(Ordering::Relaxed),
        }
    }

    pub fn identity(&self) -> &Identity {
        &self.identity
    }

    pub fn config(&self) -> &StorageConfig {
        &self.config
    }
}

/// Creates `dir` (and parents) private to this user; refuses one another user owns.
fn create_private_dir(dir: &Path) -> Result<(), String> {
    use std::os::unix::fs::{DirBuilderExt, MetadataExt};
    std::fs::DirBuilder::new()
        .recursive(true)
        .mode(0o700)
        .create(dir)
        .map_err(|e| e.to_string())?;
    let meta = std::fs::metadata(dir).map_err(|e| e.to_string())?;
    // SAFETY: geteuid has no preconditions.
    let me = unsafe { libc::geteuid() };
    if meta.uid() != me {
        return Err(format!(
            "owned by uid {}, not by this user ({me})",
            meta.uid()
        ));
    }
    Ok(())
}

/// The writer thread's side.
struct Writer {
    connection: Connection,
    identity: Identity,
    counters: Arc<StoreCounters>,
    config: StorageConfig,
}

impl Writer {
    fn run(mut self, commands: Receiver<Command>) {
        // Events whose commit failed (disk full, ...) wait here and go with the next batch.
        let mut unwritten: Vec<NewEvent> = Vec::new();
        while let Ok(first) = commands.recv() {
            let mut flushes = Vec::new();
            for command in std::iter::once(first).chain(commands.try_iter()) {
                match command {
                    Command::Append(events) => unwritten.extend(events),
                    Command::Flush(done) => flushes.push(done),
                }
            }
            if !unwritten.is_empty() {
                match self.write(&unwritten) {
                    Ok(()) => {
                        self.counters
                            .pending
                            .fetch_sub(unwritten.len() as u64, Ordering::Relaxed);
                        unwritten.clear();
                    }
                    Err(e) => {
                        self.counters.write_errors.fetch_add(1, Ordering::Relaxed);
                        tracing::error!(
                            waiting = unwritten.len(),
                            "writing events failed, retrying with the next batch: {e}"
                        );
                        std::thread::sleep(Duration::from_millis(100));
                    }
                }
            }
            for done in flushes {
                let _ = done.send(());
            }
        }
    }

    fn write(&mut self, events: &[NewEvent]) -> Result<(), StoreError> {
        let tx = self.connection.transaction()?;
        let mut last_id = 0;
        {
            let mut insert = tx.prepare_cached(
                "INSERT INTO events (vehicle_id, fleet, stream, kind, subject, time_utc_ns,
                                     time_s, run, run_time_s, detail, stored_utc_ns)
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11)",
            )?;
            let mut raise = tx.prepare_cached(
                "INSERT OR REPLACE INTO active_alarms (stream, subject, alarm, event_id, since_utc_ns)
                 VALUES (?1, ?2, ?3, ?4, ?5)",
            )?;
            let mut clear = tx.prepare_cached(
                "DELETE FROM active_alarms WHERE stream = ?1 AND subject = ?2 AND alarm = ?3",
            )?;
            let stored_utc_ns = railmon_bus::utc_now_ns();
            for e in events {
                let detail = serde_json::Value::Object(e.detail.clone()).to_string();
                insert.execute(params![
                    self.identity.vehicle_id,
                    self.identity.fleet,
                    e.stream.name(),
                    e.kind,
                    e.subject,
                    e.time_utc_ns,
                    e.time_s,
                    e.run,
                    e.run_time_s,
                    detail,
                    stored_utc_ns,
                ])?;
                last_id = tx.last_insert_rowid();
                match &e.alarm {
                    Some((alarm, true)) => {
                        raise.execute(params![
                            e.stream.name(),
                            e.subject,
                            alarm,
                            last_id,
                            e.time_utc_ns
                        ])?;
                    }
                    Some((alarm, false)) => {
                        clear.execute(params![e.stream.name(), e.subject, alarm])?;
                    }
                    None => {}
                }
            }
        }
        let pruned = prune(&self.config, &tx)?;
        tx.commit()?;
        self.counters
            .stored
            .fetch_add(events.len() as u64, Ordering::Relaxed);
        self.counters
            .last_id
            .store(last_id as u64, Ordering::Relaxed);
        self.counters.pruned.fetch_add(pruned, Ordering::Relaxed);
        Ok(())
    }
}

/// Retention by age and by count; the count of pruned events is kept in the database.
fn prune(config: &StorageConfig, tx: &rusqlite::Transaction) -> Result<u64, StoreError> {
    {
        let mut pruned = 0;
        if config.max_age_days > 0 {
            let cutoff = railmon_bus::utc_now_ns()
                .saturating_sub(i64::from(config.max_age_days).saturating_mul(NS_PER_DAY));
            pruned += tx.execute("DELETE FROM events WHERE stored_utc_ns < ?1", [cutoff])? as u64;
        }
        pruned += tx.execute(
            "DELETE FROM events WHERE id <= (SELECT id FROM events ORDER BY id DESC LIMIT 1 OFFSET ?1)",
            [config.max_events as i64],
        )? as u64;
        if pruned > 0 {
            tx.execute(
                "INSERT INTO counters (name, value) VALUES ('pruned', ?1)
                 ON CONFLICT (name) DO UPDATE SET value = value + ?1",
                [pruned as i64],
            )?;
        }
        Ok(pruned)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn event(kind: &str, subject: &str, utc: i64, alarm: Option<(&str, bool)>) -> NewEvent {
        let mut detail = serde_json::Map::new();
        detail.insert("drive".into(), 1.into());
        NewEvent {
            stream: StreamKind::Drive,
            kind: kind.into(),
            subject: subject.into(),
            time_utc_ns: utc,
            time_s: 1.5,
            run: 0,
            run_time_s: 1.5,
            detail,
            alarm: alarm.map(|(a, on)| (a.to_string(), on)),
        }
    }

    fn identity() -> Identity {
        Identity {
            vehicle_id: "unit-1".into(),
            fleet: String::new(),
        }
    }

    fn temp_dir(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("railmon-store-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        dir
    }

    fn config(dir: &Path) -> StorageConfig {
        StorageConfig {
            data_dir: dir.display().to_string(),
            ..StorageConfig::default()
        }
    }

    fn all(store: &EventStore) -> Vec<EventView> {
        store
            .page(&EventQuery {
                limit: 1000,
                ..EventQuery::default()
            })
            .unwrap()
    }

    #[test]
    fn ids_and_active_alarms_survive_a_reopen() {
        let dir = temp_dir("reopen");
        let now = railmon_bus::utc_now_ns();
        {
            let (store, thread) = EventStore::open(&config(&dir), &identity()).unwrap();
            store.append(vec![
                event("slip_started", "1", now, Some(("slipping", true))),
                event("slip_started", "2", now, Some(("slipping", true))),
                event("slip_ended", "2", now, Some(("slipping", false))),
            ]);
            store.close();
            thread.join().unwrap();
        }
        let (store, _thread) = EventStore::open(&config(&dir), &identity()).unwrap();
        let alarms = store.active_alarms().unwrap();
        assert_eq!(alarms.len(), 1);
        assert_eq!((alarms[0].subject.as_str(), alarms[0].event_id), ("1", 1));
        store.append(vec![event(
            "slip_ended",
            "1",
            now,
            Some(("slipping", false)),
        )]);
        store.flush();
        let ids: Vec<u64> = all(&store).iter().map(|e| e.id).collect();
        assert_eq!(ids, vec![1, 2, 3, 4]);
        assert!(store.active_alarms().unwrap().is_empty());
        assert_eq!(store.status().last_event_id, 4);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn pages_filter_and_retention_prunes_by_count_and_age() {
        let dir = temp_dir("pages");
        let mut cfg = config(&dir);
        cfg.max_events = 5;
        let (store, _thread) = EventStore::open(&cfg, &identity()).unwrap();
        let now = railmon_bus::utc_now_ns();
        let old = now - 400 * NS_PER_DAY;
        store.append(vec![event("slip_started", "3", old, None)]);
        store.append(
            (0..8)
                .map(|k| event("slip_started", &k.to_string(), now + k, None))
                .collect(),
        );
        store.flush();
        let events = all(&store);
        let ids: Vec<u64> = events.iter().map(|e| e.id).collect();
        assert_eq!(ids, vec![5, 6, 7, 8, 9], "the oldest pruned, ids kept");
        assert_eq!(store.status().events_pruned, 4);
        assert_eq!(events[0].detail["drive"], 1);
        let page = store
            .page(&EventQuery {
                after_id: 6,
                subject: Some("7".into()),
                limit: 10,
                ..EventQuery::default()
            })
            .unwrap();
        assert_eq!(page.len(), 1);
        assert_eq!(page[0].id, 9);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_database_from_a_newer_build_is_refused() {
        let dir = temp_dir("newer");
        std::fs::create_dir_all(&dir).unwrap();
        let c = Connection::open(dir.join("events.sqlite3")).unwrap();
        c.pragma_update(None, "user_version", SCHEMA_VERSION + 1)
            .unwrap();
        drop(c);
        let err = EventStore::open(&config(&dir), &identity()).err().unwrap();
        assert!(matches!(err, StoreError::NewerSchema { .. }), "{err}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn the_memory_store_serves_reads_from_other_connections() {
        let cfg = StorageConfig {
            data_dir: ":memory:".into(),
            ..StorageConfig::default()
        };
        let (store, _thread) = EventStore::open(&cfg, &identity()).unwrap();
        store.append(vec![event(
            "slip_started",
            "1",
            0,
            Some(("slipping", true)),
        )]);
        store.flush();
        assert_eq!(all(&store).len(), 1);
        assert_eq!(store.active_alarms().unwrap().len(), 1);
    }
}
