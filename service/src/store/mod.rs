//! The embedded event store: every stream's events and the alarms that are active, in SQLite
//! (WAL) under `[storage] data_dir`, so that alarms and event ids survive a restart.
//!
//! Why SQLite (rusqlite, SQLite compiled in): pages by id, time, stream and kind are plain SQL
//! over indexes; WAL gives durable commits with one fsync; the file opens with the `sqlite3`
//! tool a maintainer already has (when the service is stopped); schema versions migrate in
//! place ([`schema`]). redb would serve the key-value part as well, but every page query would
//! be ours to write.
//!
//! One connection, `locking_mode = EXCLUSIVE` set before WAL is entered: SQLite then keeps the
//! WAL index in heap memory instead of the memory-mapped `-shm` file, whose pages a full or
//! failing file system turns into SIGBUS (the service died of it within 0.5 s of its data
//! directory going bad). The price: no other process can open the database while the
//! service runs (a second service on the same `data_dir` is refused), and readers share the
//! writer's connection (a page waits for a commit in progress).
//!
//! Writes are off the ingest threads' hot path: they send [`NewEvent`]s down a channel and a
//! writer thread ([`writer`]) commits each batch in one transaction, together with the change
//! of the alarms the events raise or clear: after a crash the active alarms agree with the
//! events stored. A failed commit is retried with backoff, the events waiting in a bounded
//! backlog; events dropped (backlog full, or still unwritten at shutdown) are counted.
//!
//! Ids come from SQLite (`AUTOINCREMENT`: never reused, also after pruning), so an `after_id`
//! cursor stays valid across restarts. A database that is not one (0 bytes, foreign bytes,
//! SQLite finds it corrupt) is moved aside ([`files`]) and a new one continues the ids above
//! the high-water id kept beside it, with an `event_database_replaced` event.

mod files;
mod schema;
pub mod writer;

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{channel, Sender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use railmon_bus::StreamKind;
use railmon_records::private_dir::{checked_private_dir, make_private_file};
use rusqlite::{params, Connection, OptionalExtension};
use serde::Serialize;
use utoipa::ToSchema;

use crate::config::{Identity, StorageConfig};
pub use files::{HIGH_WATER_FILE, ID_BLOCK};
pub use schema::SCHEMA_VERSION;
use writer::{Close, Command, Sink, Writer, Written};

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("event database: {0}")]
    Sqlite(#[from] rusqlite::Error),
    #[error("event database {path}: {reason}")]
    Open { path: String, reason: String },
    #[error("data directory {dir} does not take writes ({reason}): the event store needs it writable (storage.data_dir)")]
    Unwritable { dir: String, reason: String },
    #[error("event database {path} is in use by another process (another railmon serve on this storage.data_dir?): {reason}")]
    Locked { path: String, reason: String },
    #[error("event database has schema version {found}, this build knows up to {known}: refusing to write to it")]
    NewerSchema { found: i64, known: i64 },
    #[error("event detail is not a JSON object: {0}")]
    Detail(String),
}

impl StoreError {
    /// Whether SQLite says the file is not a database or is corrupt (then it is moved aside).
    fn is_damage(&self) -> bool {
        use rusqlite::ErrorCode::{DatabaseCorrupt, NotADatabase};
        matches!(self, StoreError::Sqlite(rusqlite::Error::SqliteFailure(e, _))
            if matches!(e.code, DatabaseCorrupt | NotADatabase))
    }

    fn is_busy(&self) -> bool {
        use rusqlite::ErrorCode::{DatabaseBusy, DatabaseLocked};
        matches!(self, StoreError::Sqlite(rusqlite::Error::SqliteFailure(e, _))
            if matches!(e.code, DatabaseBusy | DatabaseLocked))
    }
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
    /// `drive`, `bogie`, `vehicle`, or `service` (the store's own events, e.g.
    /// `event_database_replaced`).
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
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize, ToSchema)]
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

/// A page as read: the events, and the id of the last row read (also when that row could not
/// be read as an event and was skipped), where the next page starts.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ReadPage {
    pub events: Vec<EventView>,
    pub last_read_id: Option<u64>,
}

/// What the store did, for `/api/v1/status` and `/metrics`.
#[derive(Debug, Default)]
pub struct StoreCounters {
    pub stored: AtomicU64,
    pub pruned: AtomicU64,
    pub write_errors: AtomicU64,
    pub last_id: AtomicU64,
    /// Events waiting to be written (sent, not yet committed).
    pub pending: AtomicU64,
    /// Events dropped because the backlog of unwritten events was full.
    pub dropped_buffer_full: AtomicU64,
    /// Events dropped because the service stopped before they could be written.
    pub dropped_shutdown: AtomicU64,
    /// Stored rows that could not be read as events (skipped in pages; each counted once).
    pub unreadable: AtomicU64,
    pub last_write_error: Mutex<Option<String>>,
}

/// `/api/v1/status`'s view of the store.
#[derive(Clone, Debug, Serialize, ToSchema)]
pub struct StoreStatus {
    /// The database file, or `:memory:`.
    pub database: String,
    pub schema_version: i64,
    pub events_stored: u64,
    pub events_pruned: u64,
    /// Waiting to be written (while the database does not take writes, they wait here, at
    /// most 50,000).
    pub events_pending: u64,
    /// Dropped because 50,000 were already waiting (`railmon_events_dropped_total{reason="buffer_full"}`).
    pub events_dropped_buffer_full: u64,
    /// Dropped because the service stopped before they could be written (logged at shutdown).
    pub events_dropped_shutdown: u64,
    /// Stored rows skipped in pages because they could not be read (each logged with its id).
    pub events_unreadable: u64,
    pub write_errors: u64,
    /// The last failed commit's error (stays after writes succeed again).
    pub last_write_error: Option<String>,
    pub last_event_id: u64,
}

/// Handle on the store: send events, read pages. Cheap to share (`Arc`).
pub struct EventStore {
    identity: Identity,
    location: Location,
    writer: Mutex<Sender<Command>>,
    /// The one connection (see the module documentation), shared with the writer thread.
    connection: Arc<Mutex<Connection>>,
    /// Ids of rows found unreadable (each is logged and counted once; at most
    /// [`MAX_UNREADABLE_IDS`] remembered).
    unreadable_ids: Mutex<BTreeSet<u64>>,
    pub counters: Arc<StoreCounters>,
    config: StorageConfig,
}

const MAX_UNREADABLE_IDS: usize = 10_000;

/// The uplink's cursor's row in the `counters` table: no schema change, so a build without the
/// uplink opens the same database unchanged (a vehicle's software can be rolled back).
const UPLINK_CURSOR: &str = "uplink_acked_id";
const UPLINK_STREAM_SEQUENCE: &str = "uplink_stream_sequence";

/// Where the uplink stands: every stored event up to `acked_id` is on the ground, and every
/// message of this vehicle in the ground's stream with a higher event id has a stream sequence
/// above `stream_sequence` (where the uplink looks for what it sent but could not confirm).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UplinkCursor {
    pub acked_id: u64,
    pub stream_sequence: u64,
}

#[derive(Clone, Debug)]
enum Location {
    File(PathBuf),
    /// `:memory:`: a throw-away database file in the temporary directory, removed when the
    /// store is dropped.
    Temporary(PathBuf),
}

impl Location {
    fn describe(&self) -> String {
        match self {
            Location::File(path) => path.display().to_string(),
            Location::Temporary(_) => ":memory:".into(),
        }
    }

    /// The high-water id file (none for the in-memory store).
    fn high_water(&self) -> Option<PathBuf> {
        match self {
            Location::File(path) => Some(path.with_file_name(HIGH_WATER_FILE)),
            Location::Temporary(_) => None,
        }
    }
}

/// Opens `path` with the WAL index in heap memory (no `-shm` map) and durable commits.
fn connect(path: &Path) -> Result<Connection, StoreError> {
    let connection = Connection::open(path)?;
    connection.busy_timeout(Duration::from_secs(5))?;
    // Before WAL is entered: then SQLite never maps the -shm file (sqlite.org/wal.html, "Use
    // of WAL Without Shared-Memory"); the connection stays exclusive while in WAL mode.
    connection.pragma_update(None, "locking_mode", "EXCLUSIVE")?;
    let mode: String =
        connection.pragma_update_and_check(None, "journal_mode", "WAL", |r| r.get(0))?;
    if !mode.eq_ignore_ascii_case("wal") {
        return Err(StoreError::Open {
            path: path.display().to_string(),
            reason: format!("journal_mode stays {mode}, not wal"),
        });
    }
    // Durable at each commit (events are rare; an alarm must survive a power cut).
    connection.pragma_update(None, "synchronous", "FULL")?;
    // No memory-mapped reads either (SQLite's default; said so a build option cannot change it).
    connection.pragma_update(None, "mmap_size", 0)?;
    if connection.is_readonly(rusqlite::MAIN_DB)? {
        return Err(StoreError::Unwritable {
            dir: path.display().to_string(),
            reason: "SQLite opened it read-only".into(),
        });
    }
    // SQLite creates the files with the umask's mode (0644 typically: every local user could
    // read the events); a -wal file created later takes the database's mode.
    for file in [path.to_path_buf(), path.with_file_name(wal_name(path))] {
        if file.exists() {
            make_private_file(&file).map_err(|reason| StoreError::Open {
                path: file.display().to_string(),
                reason,
            })?;
        }
    }
    Ok(connection)
}

/// `connect`, then the schema brought up to date; any access error of SQLite's shows here.
fn connect_and_migrate(path: &Path) -> Result<Connection, StoreError> {
    let mut connection = connect(path)?;
    schema::migrate(&mut connection)?;
    // Reads the whole schema and the sequence: a torn file shows as corrupt here.
    connection.query_row("SELECT count(*) FROM sqlite_sequence", [], |r| {
        r.get::<_, i64>(0)
    })?;
    Ok(connection)
}

/// Why the database was replaced by a new one at this start.
#[derive(Clone, Debug)]
struct Replacement {
    reason: String,
    /// Where the old file went (none: it was missing).
    moved_to: Option<PathBuf>,
}

/// Opens the database at `path`; a damaged one is moved aside and a new one created.
fn open_file(path: &Path) -> Result<(Connection, Option<Replacement>), StoreError> {
    let open_error = |reason: String| StoreError::Open {
        path: path.display().to_string(),
        reason,
    };
    let damage = match files::inspect(path).map_err(|e| open_error(e.to_string()))? {
        files::DatabaseFile::Damaged(reason) => reason,
        files::DatabaseFile::Missing => {
            let connection = connect_and_migrate(path)?;
            let replacement = Replacement {
                reason: "the database file was missing".into(),
                moved_to: None,
            };
            return Ok((connection, Some(replacement)));
        }
        files::DatabaseFile::Sqlite => match connect_and_migrate(path) {
            Ok(connection) => return Ok((connection, None)),
            Err(e) if e.is_damage() => e.to_string(),
            Err(e) if e.is_busy() => {
                return Err(StoreError::Locked {
                    path: path.display().to_string(),
                    reason: e.to_string(),
                })
            }
            Err(e) => return Err(e),
        },
    };
    let moved_to = files::move_aside(path, railmon_bus::utc_now_ns())
        .map_err(|e| open_error(format!("{damage}, and it cannot be moved aside: {e}")))?;
    tracing::error!(
        "event database {} is damaged ({damage}): moved to {}, starting a new one",
        path.display(),
        moved_to.display()
    );
    let connection = connect_and_migrate(path)?;
    Ok((
        connection,
        Some(Replacement {
            reason: damage,
            moved_to: Some(moved_to),
        }),
    ))
}

/// The largest id the database has given (AUTOINCREMENT's sequence; 0 if none).
fn sequence(connection: &Connection) -> Result<u64, StoreError> {
    let seq: Option<i64> = connection
        .query_row(
            "SELECT seq FROM sqlite_sequence WHERE name = 'events'",
            [],
            |r| r.get(0),
        )
        .optional()?;
    Ok(seq.unwrap_or(0).max(0) as u64)
}

/// Makes the next id `floor + 1` (if the sequence is below it).
fn raise_sequence(connection: &Connection, floor: u64) -> Result<(), StoreError> {
    if sequence(connection)? >= floor {
        return Ok(());
    }
    let floor = floor as i64;
    let updated = connection.execute(
        "UPDATE sqlite_sequence SET seq = ?1 WHERE name = 'events'",
        [floor],
    )?;
    if updated == 0 {
        connection.execute(
            "INSERT INTO sqlite_sequence (name, seq) VALUES ('events', ?1)",
            [floor],
        )?;
    }
    Ok(())
}

impl Drop for EventStore {
    fn drop(&mut self) {
        if let Location::Temporary(path) = &self.location {
            for suffix in ["", "-wal", "-shm"] {
                let _ = std::fs::remove_file(format!("{}{suffix}", path.display()));
            }
        }
    }
}

const NS_PER_DAY: i64 = 86_400 * 1_000_000_000;

impl EventStore {
    /// Opens (creating and migrating) the database and starts the writer thread. Refuses a
    /// data directory that does not take writes and a database another process holds; moves
    /// a damaged database aside (see the module documentation).
    pub fn open(
        config: &StorageConfig,
        identity: &Identity,
    ) -> Result<(Arc<Self>, JoinHandle<()>), StoreError> {
        let location = match config.database_path() {
            Some(path) => {
                if let Some(dir) = path.parent() {
                    checked_private_dir(dir).map_err(|reason| StoreError::Open {
                        path: dir.display().to_string(),
                        reason,
                    })?;
                    files::probe_writable(dir).map_err(|e| StoreError::Unwritable {
                        dir: dir.display().to_string(),
                        reason: e.to_string(),
                    })?;
                }
                if path.exists() {
                    std::fs::File::options()
                        .read(true)
                        .write(true)
                        .open(&path)
                        .map_err(|e| StoreError::Unwritable {
                            dir: path.display().to_string(),
                            reason: e.to_string(),
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
        let (connection, replacement) = match &location {
            Location::File(path) => open_file(path)?,
            Location::Temporary(path) => (connect_and_migrate(path)?, None),
        };
        let high_water = location.high_water();
        let recorded = match &high_water {
            None => None,
            Some(file) => files::read_high_water(file).unwrap_or_else(|e| {
                tracing::warn!("ignoring the high-water id: {e}");
                None
            }),
        };
        // A new database where there was a history (damaged, or missing beside a high-water
        // id): ids continue above every id a client may have seen.
        let replacement = replacement.filter(|r| r.moved_to.is_some() || recorded.is_some());
        if let Some(replaced) = &replacement {
            let floor = files::id_floor(recorded, railmon_bus::utc_now_ns());
            raise_sequence(&connection, floor)?;
            let moved_to = replaced.moved_to.as_ref().map(|p| p.display().to_string());
            tracing::error!(
                high_water_id = recorded,
                "event database {} replaced ({}): ids continue above {floor}",
                location.describe(),
                replaced.reason
            );
            let mut detail = serde_json::Map::new();
            detail.insert("reason".into(), replaced.reason.clone().into());
            detail.insert("moved_to".into(), moved_to.into());
            detail.insert("ids_continue_above".into(), floor.into());
            detail.insert("high_water_id_known".into(), recorded.is_some().into());
            insert_service_event(&connection, identity, "event_database_replaced", detail)?;
        }
        let seq = sequence(&connection)?;
        let high_water = match high_water {
            None => None,
            Some(file) => {
                let mut known = recorded.unwrap_or(0);
                if recorded.is_none() || known < seq {
                    known = seq + ID_BLOCK;
                    files::write_high_water(&file, known).map_err(|reason| {
                        StoreError::Unwritable {
                            dir: file.display().to_string(),
                            reason,
                        }
                    })?;
                }
                Some((file, known))
            }
        };
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
        let connection = Arc::new(Mutex::new(connection));
        let (tx, rx) = channel();
        let sink = SqliteSink {
            connection: connection.clone(),
            identity: identity.clone(),
            config: config.clone(),
            high_water,
            sequence: seq,
        };
        let writer = Writer::new(sink, counters.clone(), writer::MAX_BACKLOG);
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
            connection,
            unreadable_ids: Mutex::new(BTreeSet::new()),
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
        let n = events.len() as u64;
        self.counters.pending.fetch_add(n, Ordering::Relaxed);
        let sender = self.writer.lock().unwrap_or_else(|p| p.into_inner());
        if sender.send(Command::Append(events)).is_err() {
            self.counters.pending.fetch_sub(n, Ordering::Relaxed);
            self.counters
                .dropped_shutdown
                .fetch_add(n, Ordering::Relaxed);
            tracing::error!(
                events = n,
                "event store writer has stopped: events not stored"
            );
        }
    }

    /// Waits until everything appended before is committed, or a commit of it failed
    /// (shutdown, tests).
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

    /// Writes what is queued (retrying for up to [`writer::CLOSE_DEADLINE`]) and stops the
    /// writer thread; returns how many events could not be written (counted and logged).
    pub fn close(&self) -> u64 {
        self.close_within(writer::CLOSE_DEADLINE)
    }

    /// [`Self::close`] with another deadline.
    pub fn close_within(&self, deadline: Duration) -> u64 {
        let (done, answer) = channel();
        let (dead, _) = channel();
        let sender = std::mem::replace(
            &mut *self.writer.lock().unwrap_or_else(|p| p.into_inner()),
            dead,
        );
        if sender
            .send(Command::Close(Close { deadline, done }))
            .is_err()
        {
            return 0;
        }
        answer
            .recv_timeout(deadline + Duration::from_secs(10))
            .unwrap_or(0)
    }

    fn with_connection<T>(
        &self,
        read: impl FnOnce(&Connection) -> Result<T, StoreError>,
    ) -> Result<T, StoreError> {
        let connection = self.connection.lock().unwrap_or_else(|p| p.into_inner());
        read(&connection)
    }

    /// A page of events, oldest first (rows that cannot be read are skipped: [`Self::read_page`]).
    pub fn page(&self, query: &EventQuery) -> Result<Vec<EventView>, StoreError> {
        Ok(self.read_page(query)?.events)
    }

    /// A page of events, oldest first, and where it ended. A row that cannot be read as an
    /// event (a `detail` that is not a JSON object, a value of the wrong type) is skipped,
    /// logged with its id and counted once; the rest of the page is served.
    pub fn read_page(&self, query: &EventQuery) -> Result<ReadPage, StoreError> {
        let rows = self.with_connection(|c| {
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
                |r| Ok((r.get::<_, i64>(0)? as u64, event_of_row(r))),
            )?;
            Ok(rows.collect::<Result<Vec<_>, _>>()?)
        })?;
        let mut page = ReadPage {
            events: Vec::with_capacity(rows.len()),
            last_read_id: rows.last().map(|(id, _)| *id),
        };
        for (id, event) in rows {
            match event {
                Ok(event) => page.events.push(event),
                Err(reason) => self.report_unreadable(id, &reason),
            }
        }
        Ok(page)
    }

    /// Logs and counts an unreadable row, once per row.
    fn report_unreadable(&self, id: u64, reason: &str) {
        let mut seen = self
            .unreadable_ids
            .lock()
            .unwrap_or_else(|p| p.into_inner());
        if seen.contains(&id) {
            return;
        }
        if seen.len() < MAX_UNREADABLE_IDS {
            seen.insert(id);
        }
        self.counters.unreadable.fetch_add(1, Ordering::Relaxed);
        tracing::error!(
            id,
            "stored event cannot be read, skipped in pages: {reason}"
        );
    }

    /// The alarms that are active now (as of the last commit).
    pub fn active_alarms(&self) -> Result<Vec<ActiveAlarm>, StoreError> {
        self.with_connection(|c| {
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
            events_dropped_buffer_full: c.dropped_buffer_full.load(Ordering::Relaxed),
            events_dropped_shutdown: c.dropped_shutdown.load(Ordering::Relaxed),
            events_unreadable: c.unreadable.load(Ordering::Relaxed),
            write_errors: c.write_errors.load(Ordering::Relaxed),
            last_write_error: c
                .last_write_error
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .clone(),
            last_event_id: c.last_id.load(Ordering::Relaxed),
        }
    }

    /// The uplink's cursor (zeros: nothing acknowledged yet).
    pub fn uplink_cursor(&self) -> Result<UplinkCursor, StoreError> {
        self.with_connection(|c| {
            let mut read = c.prepare_cached("SELECT value FROM counters WHERE name = ?1")?;
            let mut value = |name: &str| -> Result<u64, StoreError> {
                let v: Option<i64> = read.query_row([name], |r| r.get(0)).optional()?;
                Ok(v.unwrap_or(0).max(0) as u64)
            };
            Ok(UplinkCursor {
                acked_id: value(UPLINK_CURSOR)?,
                stream_sequence: value(UPLINK_STREAM_SEQUENCE)?,
            })
        })
    }

    /// Saves the uplink's cursor: its event id only forward (never back), its stream sequence
    /// as given (a stream created again on the ground starts its sequences at 1). Both in one
    /// transaction with a durable commit: after a crash the cursor is the old or the new one,
    /// never torn, and never ahead of what the ground holds.
    pub fn save_uplink_cursor(&self, cursor: UplinkCursor) -> Result<(), StoreError> {
        self.with_connection(|c| {
            let tx = c.unchecked_transaction()?;
            tx.prepare_cached(
                "INSERT INTO counters (name, value) VALUES (?1, ?2)
                 ON CONFLICT (name) DO UPDATE SET value = max(value, excluded.value)",
            )?
            .execute(params![UPLINK_CURSOR, cursor.acked_id as i64])?;
            tx.prepare_cached(
                "INSERT INTO counters (name, value) VALUES (?1, ?2)
                 ON CONFLICT (name) DO UPDATE SET value = excluded.value",
            )?
            .execute(params![
                UPLINK_STREAM_SEQUENCE,
                cursor.stream_sequence as i64
            ])?;
            tx.commit()?;
            Ok(())
        })
    }

    /// How many stored events have an id above `id` (the uplink's backlog).
    pub fn count_after(&self, id: u64) -> Result<u64, StoreError> {
        self.with_connection(|c| {
            let n: i64 = c
                .prepare_cached("SELECT count(*) FROM events WHERE id > ?1")?
                .query_row([id as i64], |r| r.get(0))?;
            Ok(n.max(0) as u64)
        })
    }

    pub fn identity(&self) -> &Identity {
        &self.identity
    }

    pub fn config(&self) -> &StorageConfig {
        &self.config
    }
}

/// The event of a row, or why it cannot be one.
fn event_of_row(r: &rusqlite::Row) -> Result<EventView, String> {
    let text = |k: usize| r.get::<_, String>(k).map_err(|e| e.to_string());
    let detail = text(8)?;
    let detail = match serde_json::from_str(&detail) {
        Ok(serde_json::Value::Object(map)) => map,
        _ => return Err(format!("detail is not a JSON object: {detail:.200}")),
    };
    Ok(EventView {
        id: r.get::<_, i64>(0).map_err(|e| e.to_string())? as u64,
        stream: text(1)?,
        kind: text(2)?,
        subject: text(3)?,
        time_utc: railmon_bus::utc::format_rfc3339(r.get::<_, i64>(4).map_err(|e| e.to_string())?),
        time_s: r.get(5).map_err(|e| e.to_string())?,
        run: u32::try_from(r.get::<_, i64>(6).map_err(|e| e.to_string())?)
            .map_err(|e| format!("run: {e}"))?,
        run_time_s: r.get(7).map_err(|e| e.to_string())?,
        detail,
    })
}

/// Stores an event of the service itself (stream `service`), at once.
fn insert_service_event(
    connection: &Connection,
    identity: &Identity,
    kind: &str,
    detail: serde_json::Map<String, serde_json::Value>,
) -> Result<(), StoreError> {
    let now = railmon_bus::utc_now_ns();
    connection.execute(
        "INSERT INTO events (vehicle_id, fleet, stream, kind, subject, time_utc_ns,
                             time_s, run, run_time_s, detail, stored_utc_ns)
         VALUES (?1, ?2, 'service', ?3, '', ?4, 0, 0, 0, ?5, ?4)",
        params![
            identity.vehicle_id,
            identity.fleet,
            kind,
            now,
            serde_json::Value::Object(detail).to_string()
        ],
    )?;
    Ok(())
}

/// `events.sqlite3-wal` for `events.sqlite3`.
fn wal_name(path: &Path) -> String {
    let name = path.file_name().unwrap_or_default().to_string_lossy();
    format!("{name}-wal")
}

/// The writer thread's side: commits into the shared connection.
struct SqliteSink {
    connection: Arc<Mutex<Connection>>,
    identity: Identity,
    config: StorageConfig,
    /// The high-water id file and the id it holds (none for the in-memory store).
    high_water: Option<(PathBuf, u64)>,
    /// The largest id given so far.
    sequence: u64,
}

impl Sink for SqliteSink {
    fn write(&mut self, events: &[NewEvent]) -> Result<Written, StoreError> {
        // The high-water id first: no id is committed above it.
        let needed = self.sequence + events.len() as u64;
        if let Some((file, known)) = &mut self.high_water {
            if needed > *known {
                let raised = needed + ID_BLOCK;
                files::write_high_water(file, raised).map_err(|reason| StoreError::Open {
                    path: file.display().to_string(),
                    reason,
                })?;
                *known = raised;
            }
        }
        let mut connection = self.connection.lock().unwrap_or_else(|p| p.into_inner());
        let written = write_events(&mut connection, &self.identity, &self.config, events)?;
        self.sequence = self.sequence.max(written.last_id);
        Ok(written)
    }
}

fn write_events(
    connection: &mut Connection,
    identity: &Identity,
    config: &StorageConfig,
    events: &[NewEvent],
) -> Result<Written, StoreError> {
    let tx = connection.transaction()?;
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
                identity.vehicle_id,
                identity.fleet,
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
    let pruned = prune(config, &tx)?;
    tx.commit()?;
    Ok(Written {
        last_id: last_id as u64,
        pruned,
    })
}

/// Retention by age and by count; the count of pruned events is kept in the database.
fn prune(config: &StorageConfig, tx: &rusqlite::Transaction) -> Result<u64, StoreError> {
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
    fn uplink_cursor_survives_a_reopen_and_never_moves_back() {
        let dir = temp_dir("uplink-cursor");
        let now = railmon_bus::utc_now_ns();
        {
            let (store, thread) = EventStore::open(&config(&dir), &identity()).unwrap();
            assert_eq!(store.uplink_cursor().unwrap(), UplinkCursor::default());
            store.append(
                (0..5)
                    .map(|_| event("slip_started", "1", now, None))
                    .collect(),
            );
            store.flush();
            assert_eq!(store.count_after(0).unwrap(), 5);
            let at = |acked_id, stream_sequence| UplinkCursor {
                acked_id,
                stream_sequence,
            };
            store.save_uplink_cursor(at(3, 40)).unwrap();
            // The id never moves back; the sequence follows the ground's stream.
            store.save_uplink_cursor(at(2, 7)).unwrap();
            assert_eq!(store.uplink_cursor().unwrap(), at(3, 7));
            assert_eq!(store.count_after(3).unwrap(), 2);
            store.close();
            thread.join().unwrap();
        }
        let (store, _thread) = EventStore::open(&config(&dir), &identity()).unwrap();
        assert_eq!(store.uplink_cursor().unwrap().acked_id, 3);
        assert_eq!(store.uplink_cursor().unwrap().stream_sequence, 7);
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

    /// Makes `path` refuse writes, also for root (`chattr +i`: immutable, even for open
    /// files); `None` where that is not possible (not root, or a file system without the flag).
    fn make_immutable(path: &Path) -> Option<ImmutableGuard> {
        // SAFETY: geteuid has no preconditions.
        if unsafe { libc::geteuid() } != 0 {
            return None;
        }
        let status = std::process::Command::new("chattr")
            .arg("+i")
            .arg(path)
            .status()
            .ok()?;
        status.success().then(|| ImmutableGuard(path.to_owned()))
    }

    struct ImmutableGuard(PathBuf);

    impl Drop for ImmutableGuard {
        fn drop(&mut self) {
            let _ = std::process::Command::new("chattr")
                .arg("-i")
                .arg(&self.0)
                .status();
        }
    }

    fn is_root() -> bool {
        // SAFETY: geteuid has no preconditions.
        unsafe { libc::geteuid() == 0 }
    }

    #[test]
    fn the_wal_index_is_in_heap_memory_and_a_second_process_is_refused() {
        let dir = temp_dir("no-shm");
        let (store, _thread) = EventStore::open(&config(&dir), &identity()).unwrap();
        store.append(vec![event("slip_started", "1", 0, None)]);
        store.flush();
        assert_eq!(store.status().events_stored, 1);
        assert!(dir.join("events.sqlite3-wal").exists(), "WAL mode");
        assert!(
            !dir.join("events.sqlite3-shm").exists(),
            "no shared-memory WAL index (its map is what died of SIGBUS)"
        );
        // Another connection (another service on the same data_dir) cannot use it.
        let other = connect(&dir.join("events.sqlite3")).and_then(|c| {
            c.query_row("SELECT count(*) FROM events", [], |r| r.get::<_, i64>(0))
                .map_err(StoreError::from)
        });
        assert!(other.as_ref().is_err_and(StoreError::is_busy), "{other:?}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// The events are this user's only (issue 26 item 8: a data directory of mode 0777 was
    /// accepted and the database was 0644): a directory others may write into is refused, one
    /// they may read is made 0700, the database and its WAL are 0600.
    #[test]
    fn the_data_directory_and_its_files_are_private() {
        use std::os::unix::fs::{MetadataExt, PermissionsExt};
        let dir = temp_dir("private");
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o777)).unwrap();
        let err = EventStore::open(&config(&dir), &identity()).err().unwrap();
        assert!(err.to_string().contains("world-writable"), "{err}");
        assert!(!dir.join("events.sqlite3").exists(), "nothing created");
        std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o755)).unwrap();
        let (store, writer) = EventStore::open(&config(&dir), &identity()).unwrap();
        let now = railmon_bus::utc_now_ns();
        store.append(vec![event("slip_started", "1", now, None)]);
        store.close();
        writer.join().unwrap();
        let mode = |name: &str| std::fs::metadata(dir.join(name)).unwrap().mode() & 0o777;
        assert_eq!(mode(""), 0o700);
        assert_eq!(mode("events.sqlite3"), 0o600);
        for name in ["events.sqlite3-wal", files::HIGH_WATER_FILE] {
            if dir.join(name).exists() {
                assert_eq!(mode(name), 0o600, "{name}");
            }
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_data_directory_that_takes_no_writes_is_refused_at_start_naming_it() {
        use std::os::unix::fs::PermissionsExt;
        let dir = temp_dir("read-only");
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o500)).unwrap();
        // Root ignores permission bits: make the directory immutable instead.
        let guard = match is_root() {
            true => Some(make_immutable(&dir).expect("chattr +i (root, ext4/xfs/btrfs)")),
            false => None,
        };
        let err = EventStore::open(&config(&dir), &identity()).err().unwrap();
        drop(guard);
        std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o700)).unwrap();
        let message = err.to_string();
        assert!(matches!(err, StoreError::Unwritable { .. }), "{message}");
        assert!(message.contains(&dir.display().to_string()), "{message}");
        assert!(message.contains("does not take writes"), "{message}");
        assert!(!dir.join("events.sqlite3").exists(), "nothing created");
        // A data directory under a regular file is refused too.
        std::fs::write(dir.join("file"), b"").unwrap();
        let err = EventStore::open(&config(&dir.join("file/sub")), &identity())
            .err()
            .unwrap();
        assert!(err.to_string().contains("file/sub"), "{err}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_database_that_stops_taking_writes_gives_errors_keeps_events_and_writes_them_later() {
        let dir = temp_dir("stops");
        let (store, thread) = EventStore::open(&config(&dir), &identity()).unwrap();
        store.append(vec![event("slip_started", "1", 0, None)]);
        store.flush();
        let db = dir.join("events.sqlite3");
        // The files themselves (open already) refuse writes: root needs chattr +i.
        let guards: Vec<_> = [db.clone(), dir.join("events.sqlite3-wal")]
            .iter()
            .filter_map(|p| make_immutable(p))
            .collect();
        if guards.len() < 2 {
            eprintln!("SKIPPED: cannot make open files unwritable here (not root / no chattr); tests/tests/store_disk.rs covers it with RLIMIT_FSIZE");
            return;
        }
        store.append(
            (2..12)
                .map(|k| event("slip_started", &k.to_string(), 0, None))
                .collect(),
        );
        store.flush();
        let status = store.status();
        assert_eq!(status.events_pending, 10, "{status:?}");
        assert!(status.write_errors >= 1, "{status:?}");
        assert!(status.last_write_error.is_some(), "{status:?}");
        // Reads still answer.
        assert_eq!(all(&store).len(), 1);
        drop(guards);
        let start = std::time::Instant::now();
        while store.status().events_pending > 0 {
            assert!(start.elapsed() < Duration::from_secs(10), "not retried");
            std::thread::sleep(Duration::from_millis(20));
        }
        assert_eq!(all(&store).len(), 11);
        assert_eq!(store.close(), 0);
        thread.join().unwrap();
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn events_unwritten_at_close_are_counted_as_dropped() {
        let dir = temp_dir("close-drop");
        let (store, thread) = EventStore::open(&config(&dir), &identity()).unwrap();
        store.append(vec![event("slip_started", "1", 0, None)]);
        store.flush();
        let guards: Vec<_> = [dir.join("events.sqlite3"), dir.join("events.sqlite3-wal")]
            .iter()
            .filter_map(|p| make_immutable(p))
            .collect();
        if guards.len() < 2 {
            eprintln!("SKIPPED: cannot make open files unwritable here (not root / no chattr)");
            return;
        }
        store.append(
            (0..38)
                .map(|k| event("slip_ended", &k.to_string(), 0, None))
                .collect(),
        );
        assert_eq!(store.close_within(Duration::from_millis(300)), 38);
        thread.join().unwrap();
        let status = store.status();
        assert_eq!(
            (status.events_dropped_shutdown, status.events_pending),
            (38, 0)
        );
        // Appended after the close: counted too.
        store.append(vec![event("slip_ended", "9", 0, None)]);
        assert_eq!(store.status().events_dropped_shutdown, 39);
        drop(guards);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn an_empty_database_is_moved_aside_and_ids_continue_above_the_high_water_id() {
        let dir = temp_dir("empty-db");
        let db = dir.join("events.sqlite3");
        {
            let (store, thread) = EventStore::open(&config(&dir), &identity()).unwrap();
            store.append(
                (0..3)
                    .map(|k| event("slip_started", &k.to_string(), 0, None))
                    .collect(),
            );
            store.close();
            thread.join().unwrap();
        }
        let high_water = files::read_high_water(&dir.join(HIGH_WATER_FILE))
            .unwrap()
            .unwrap();
        assert!(high_water >= 3, "{high_water}");
        std::fs::write(&db, b"").unwrap();
        let _ = std::fs::remove_file(dir.join("events.sqlite3-wal"));
        let (store, _thread) = EventStore::open(&config(&dir), &identity()).unwrap();
        let events = all(&store);
        assert_eq!(events.len(), 1, "{events:?}");
        let replaced = &events[0];
        assert_eq!(
            (replaced.stream.as_str(), replaced.kind.as_str()),
            ("service", "event_database_replaced")
        );
        assert_eq!(
            replaced.id,
            high_water + 1,
            "ids continue above every id given"
        );
        assert_eq!(replaced.detail["reason"], "empty (0 bytes)");
        let moved = replaced.detail["moved_to"].as_str().unwrap();
        assert!(moved.contains("events.sqlite3.damaged-"), "{moved}");
        assert_eq!(
            std::fs::metadata(moved).unwrap().len(),
            0,
            "the old file kept"
        );
        store.append(vec![event("slip_started", "1", 0, None)]);
        store.flush();
        assert_eq!(all(&store)[1].id, high_water + 2);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_foreign_or_missing_database_never_restarts_ids_at_1() {
        // Foreign bytes and no high-water id: ids continue above the time in ms.
        let dir = temp_dir("foreign-db");
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(
            dir.join("events.sqlite3"),
            b"this is not a database, just text
"
            .repeat(10),
        )
        .unwrap();
        let before_ms = (railmon_bus::utc_now_ns() / 1_000_000) as u64;
        let (store, thread) = EventStore::open(&config(&dir), &identity()).unwrap();
        let first = all(&store)[0].clone();
        assert_eq!(first.kind, "event_database_replaced");
        assert!(first.id > before_ms, "{} <= {before_ms}", first.id);
        assert_eq!(first.detail["high_water_id_known"], false);
        store.close();
        thread.join().unwrap();
        drop(store);
        // The database deleted, its high-water id kept: ids still continue.
        let high_water = files::read_high_water(&dir.join(HIGH_WATER_FILE))
            .unwrap()
            .unwrap();
        assert!(high_water >= first.id);
        for suffix in ["", "-wal"] {
            let _ =
                std::fs::remove_file(format!("{}{suffix}", dir.join("events.sqlite3").display()));
        }
        let (store, _thread) = EventStore::open(&config(&dir), &identity()).unwrap();
        let events = all(&store);
        assert_eq!(events.len(), 1);
        assert_eq!(events[0].id, high_water + 1);
        assert_eq!(events[0].detail["reason"], "the database file was missing");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_row_that_cannot_be_read_is_skipped_counted_once_and_the_page_goes_on() {
        let dir = temp_dir("bad-row");
        let (store, _thread) = EventStore::open(&config(&dir), &identity()).unwrap();
        store.append(
            (1..=4)
                .map(|k| event("slip_started", &k.to_string(), 0, None))
                .collect(),
        );
        store.flush();
        store
            .with_connection(|c| {
                c.execute("UPDATE events SET detail = 'not json {' WHERE id = 2", [])?;
                c.execute("UPDATE events SET kind = x'ff00' WHERE id = 3", [])?;
                Ok(())
            })
            .unwrap();
        let page = store
            .read_page(&EventQuery {
                limit: 10,
                ..EventQuery::default()
            })
            .unwrap();
        let ids: Vec<u64> = page.events.iter().map(|e| e.id).collect();
        assert_eq!(ids, vec![1, 4]);
        assert_eq!(page.last_read_id, Some(4));
        assert_eq!(store.status().events_unreadable, 2);
        // A page of only bad rows still moves the cursor on.
        let page = store
            .read_page(&EventQuery {
                after_id: 1,
                limit: 2,
                ..EventQuery::default()
            })
            .unwrap();
        assert!(page.events.is_empty());
        assert_eq!(page.last_read_id, Some(3));
        assert_eq!(store.status().events_unreadable, 2, "each row counted once");
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
