//! The event database's schema, versioned with SQLite's `user_version`: migration `k` takes a
//! database from version `k` to `k + 1`, in one transaction. A database newer than this build
//! is refused rather than written.

use rusqlite::Connection;

use super::StoreError;

/// Every migration in order; the schema version is their count.
const MIGRATIONS: &[&str] = &[
    // 1: events of every stream, the alarms that are active, counters (pruned events).
    "CREATE TABLE events (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        vehicle_id TEXT NOT NULL,
        fleet TEXT NOT NULL,
        stream TEXT NOT NULL,
        kind TEXT NOT NULL,
        subject TEXT NOT NULL,
        time_utc_ns INTEGER NOT NULL,
        time_s REAL NOT NULL,
        run INTEGER NOT NULL,
        run_time_s REAL NOT NULL,
        detail TEXT NOT NULL,
        stored_utc_ns INTEGER NOT NULL
     );
     CREATE INDEX events_by_time ON events (time_utc_ns);
     CREATE INDEX events_by_stored_time ON events (stored_utc_ns);
     CREATE INDEX events_by_stream ON events (stream, id);
     CREATE TABLE active_alarms (
        stream TEXT NOT NULL,
        subject TEXT NOT NULL,
        alarm TEXT NOT NULL,
        event_id INTEGER NOT NULL,
        since_utc_ns INTEGER NOT NULL,
        PRIMARY KEY (stream, subject, alarm)
     );
     CREATE TABLE counters (name TEXT PRIMARY KEY, value INTEGER NOT NULL);",
];

pub const SCHEMA_VERSION: i64 = MIGRATIONS.len() as i64;

/// Brings `connection`'s database to [`SCHEMA_VERSION`].
pub fn migrate(connection: &mut Connection) -> Result<(), StoreError> {
    let version: i64 = connection.query_row("PRAGMA user_version", [], |r| r.get(0))?;
    if version > SCHEMA_VERSION {
        return Err(StoreError::NewerSchema {
            found: version,
            known: SCHEMA_VERSION,
        });
    }
    for (k, sql) in MIGRATIONS.iter().enumerate().skip(version as usize) {
        let tx = connection.transaction()?;
        tx.execute_batch(sql)?;
        tx.pragma_update(None, "user_version", k as i64 + 1)?;
        tx.commit()?;
        tracing::info!(version = k + 1, "event database migrated");
    }
    Ok(())
}
