//! The files around the event database, checked before SQLite opens it: whether the data
//! directory takes writes, whether `events.sqlite3` is an SQLite database at all (a 0-byte or
//! foreign file is moved aside, never silently recreated), and the high-water id
//! (`events.high-water-id`), which lets ids continue above every id a client may have seen
//! when the database had to be replaced.

use std::io::{Read, Write};
use std::path::{Path, PathBuf};

/// The file that holds an id at or above every id the database has given.
pub const HIGH_WATER_FILE: &str = "events.high-water-id";

/// The high-water id is raised in steps of this many ids (one small file write per step, not
/// per commit).
pub const ID_BLOCK: u64 = 10_000;

const SQLITE_MAGIC: &[u8; 16] = b"SQLite format 3\0";
/// An SQLite database file is at least its 100-byte header.
const SQLITE_HEADER: u64 = 100;

/// What is at the database's path.
#[derive(Clone, Debug, PartialEq)]
pub enum DatabaseFile {
    Missing,
    /// Starts with the SQLite header (SQLite itself judges the rest).
    Sqlite,
    /// Not an SQLite database: why.
    Damaged(String),
}

/// Judges a file from its first bytes (`head`) and its length. A 0-byte file is damaged: a
/// WAL database always has its first page in the main file (the WAL version bytes live
/// there), and SQLite discards the WAL of a 0-page database.
pub fn judge(head: &[u8], len: u64) -> DatabaseFile {
    if len == 0 {
        return DatabaseFile::Damaged("empty (0 bytes)".into());
    }
    if len < SQLITE_HEADER || !head.starts_with(SQLITE_MAGIC) {
        return DatabaseFile::Damaged(format!(
            "not an SQLite database ({len} bytes without the SQLite header)"
        ));
    }
    DatabaseFile::Sqlite
}

/// Reads the start of `path` and judges it; an unreadable file is an error (not damage: it
/// is not moved aside).
pub fn inspect(path: &Path) -> Result<DatabaseFile, std::io::Error> {
    let mut file = match std::fs::File::open(path) {
        Ok(file) => file,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(DatabaseFile::Missing),
        Err(e) => return Err(e),
    };
    let len = file.metadata()?.len();
    let mut head = [0u8; SQLITE_MAGIC.len()];
    let read = file.read(&mut head)?;
    Ok(judge(&head[..read], len))
}

/// Creates, writes, syncs and removes a file in `dir`: a directory that does not take writes
/// (permissions, a read-only or full file system) fails here, at start, not at the first event.
pub fn probe_writable(dir: &Path) -> Result<(), std::io::Error> {
    let probe = dir.join(format!(".write-probe-{}", std::process::id()));
    let written = (|| {
        let mut file = std::fs::File::options()
            .write(true)
            .create_new(true)
            .open(&probe)?;
        file.write_all(b"railmon write probe\n")?;
        file.sync_all()
    })();
    let removed = std::fs::remove_file(&probe);
    written?;
    match removed {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(e),
        _ => Ok(()),
    }
}

/// `2026-11-22T08:00:00.123Z` as `20261122T080000.123Z` (a file name suffix).
fn compact_utc(utc_ns: i64) -> String {
    railmon_bus::utc::format_rfc3339(utc_ns).replace([':', '-'], "")
}

/// Renames `path` (and its `-wal`, `-shm`) to `<path>.damaged-<utc>`; returns the new name.
pub fn move_aside(path: &Path, utc_ns: i64) -> Result<PathBuf, std::io::Error> {
    let target = PathBuf::from(format!(
        "{}.damaged-{}",
        path.display(),
        compact_utc(utc_ns)
    ));
    std::fs::rename(path, &target)?;
    for suffix in ["-wal", "-shm"] {
        let from = PathBuf::from(format!("{}{suffix}", path.display()));
        if from.exists() {
            std::fs::rename(&from, format!("{}{suffix}", target.display()))?;
        }
    }
    if let Some(dir) = path.parent() {
        std::fs::File::open(dir)?.sync_all()?;
    }
    Ok(target)
}

/// The high-water id in `path`: `None` if there is no file, an error if it does not hold one.
pub fn read_high_water(path: &Path) -> Result<Option<u64>, String> {
    match std::fs::read_to_string(path) {
        Ok(text) => text
            .trim()
            .parse()
            .map(Some)
            .map_err(|_| format!("{}: {:?} is not an id", path.display(), text.trim())),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(format!("{}: {e}", path.display())),
    }
}

/// Writes the high-water id whole (temporary file, fsync, rename, directory fsync).
pub fn write_high_water(path: &Path, id: u64) -> Result<(), String> {
    let mut out = railmon_records::AtomicFile::create_private(path).map_err(|e| e.to_string())?;
    out.write_all(format!("{id}\n").as_bytes())
        .map_err(|e| format!("{}: {e}", path.display()))?;
    out.commit().map_err(|e| e.to_string())
}

/// Where ids continue after the database had to be replaced: above the high-water id, or,
/// without one, above the UTC time in milliseconds (above any count of events a database
/// could have given unless the clock is decades behind).
pub fn id_floor(high_water: Option<u64>, utc_ns: i64) -> u64 {
    high_water.unwrap_or_else(|| (utc_ns.max(0) / 1_000_000) as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn empty_and_foreign_files_are_damaged_an_sqlite_header_is_not() {
        assert_eq!(
            judge(b"", 0),
            DatabaseFile::Damaged("empty (0 bytes)".into())
        );
        assert!(matches!(
            judge(b"hello world, not sqlite", 4096),
            DatabaseFile::Damaged(_)
        ));
        assert!(matches!(judge(SQLITE_MAGIC, 50), DatabaseFile::Damaged(_)));
        assert_eq!(judge(SQLITE_MAGIC, 4096), DatabaseFile::Sqlite);
    }

    #[test]
    fn the_floor_is_the_high_water_id_else_the_time_in_ms() {
        assert_eq!(id_floor(Some(12_345), 1_800_000_000_000_000_000), 12_345);
        assert_eq!(id_floor(None, 1_800_000_000_000_000_000), 1_800_000_000_000);
        assert_eq!(id_floor(None, -5), 0);
    }

    #[test]
    fn a_damaged_file_is_moved_aside_with_its_wal() {
        let dir = std::env::temp_dir().join(format!("railmon-files-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let db = dir.join("events.sqlite3");
        std::fs::write(&db, b"").unwrap();
        std::fs::write(dir.join("events.sqlite3-wal"), b"x").unwrap();
        assert_eq!(
            inspect(&db).unwrap(),
            DatabaseFile::Damaged("empty (0 bytes)".into())
        );
        let moved = move_aside(&db, 1_795_000_000_123_000_000).unwrap();
        assert_eq!(
            moved.file_name().unwrap().to_str().unwrap(),
            "events.sqlite3.damaged-20261118T110640.123Z"
        );
        assert!(!db.exists() && moved.exists());
        assert!(PathBuf::from(format!("{}-wal", moved.display())).exists());
        assert_eq!(inspect(&db).unwrap(), DatabaseFile::Missing);
        let hw = dir.join(HIGH_WATER_FILE);
        assert_eq!(read_high_water(&hw), Ok(None));
        write_high_water(&hw, 42).unwrap();
        assert_eq!(read_high_water(&hw), Ok(Some(42)));
        std::fs::write(&hw, "forty-two").unwrap();
        assert!(read_high_water(&hw).is_err());
        probe_writable(&dir).unwrap();
        assert!(probe_writable(&dir.join("no-such-dir")).is_err());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
