//! Estimator snapshots: every few seconds and at shutdown, each stream's estimator state is
//! written to `<data_dir>/snapshots/<stream>.snapshot`, atomically (temporary file, fsync,
//! rename), versioned and checksummed; at start a snapshot of the same settings and recent
//! enough is resumed, so a restart does not cost the filters their convergence (the damper
//! RBPF needed ~30 s of data, the fuel mixture 150 samples). A snapshot that does not fit
//! (another version, other settings, too old, corrupt) is refused with a log line, and the
//! estimator starts from its prior.
//!
//! File: a first line `railmon-snapshot v1` and a JSON header line (stream, settings
//! fingerprint, when saved, payload length and FNV-1a checksum), then the payload: the
//! [`IngestState`] in bincode (binary: the states hold NaN at times, which JSON cannot).

use std::io::Write;
use std::path::{Path, PathBuf};

use railmon_records::AtomicFile;
use serde::{Deserialize, Serialize};

use crate::config::StorageConfig;

/// Where and how often the ingest loop saves its pipeline's state, and how old a snapshot may
/// be to be resumed.
#[derive(Clone, Debug)]
pub struct SnapshotPolicy {
    pub data_dir: PathBuf,
    pub interval: std::time::Duration,
    pub max_age_s: f64,
}

impl SnapshotPolicy {
    /// The policy of `[storage]` (`None`: never; also with the in-memory store).
    pub fn of(storage: &StorageConfig) -> Option<Self> {
        let dir = storage.database_path()?.parent()?.to_path_buf();
        (storage.snapshot_interval_s > 0.0).then(|| SnapshotPolicy {
            data_dir: dir,
            interval: std::time::Duration::from_secs_f64(storage.snapshot_interval_s),
            max_age_s: storage.snapshot_max_age_s,
        })
    }
}

const MAGIC: &str = "railmon-snapshot v1";

/// Largest snapshot file read (bytes): a bogie's state is ~200 B per particle (N = 1000:
/// ~0.2 MB), so this holds dozens of bogies at the largest particle counts, and stops a file
/// that is not a snapshot from growing the process without end.
const MAX_SNAPSHOT_BYTES: u64 = 1 << 30;

/// What the ingest loop saves: where the source stood and the pipeline's own state.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct IngestState {
    pub publisher_instance: u64,
    pub run: u32,
    /// The sequence number the next frame of that source should carry.
    pub next_sequence: u64,
    /// The last sample time estimated (the sample clock goes on from it).
    pub last_sample_time_ns: Option<u64>,
    /// `Pipeline::save_state`.
    pub pipeline: Vec<u8>,
}

#[derive(Debug, Serialize, Deserialize)]
struct Header {
    stream: String,
    /// FNV-1a of the estimator settings (a snapshot of other settings does not fit).
    settings: String,
    saved_utc_ns: i64,
    payload_bytes: usize,
    /// FNV-1a 64 of the payload.
    checksum: String,
}

/// FNV-1a 64 (a checksum against torn or corrupted files, not against tampering).
pub fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// Where one stream's snapshot lives.
#[derive(Clone, Debug)]
pub struct SnapshotFile {
    path: PathBuf,
    stream: String,
    settings: String,
}

impl SnapshotFile {
    /// The snapshot of `stream` under `data_dir`, for estimator settings `settings` (their
    /// serialised text: only its fingerprint is kept).
    pub fn new(data_dir: &Path, stream: &str, settings: &str) -> Self {
        Self {
            path: data_dir
                .join("snapshots")
                .join(format!("{stream}.snapshot")),
            stream: stream.to_string(),
            settings: format!("{:016x}", fnv1a(settings.as_bytes())),
        }
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Writes `state` atomically.
    pub fn save(&self, state: &IngestState) -> Result<(), String> {
        let payload = bincode::serialize(state).map_err(|e| e.to_string())?;
        let header = Header {
            stream: self.stream.clone(),
            settings: self.settings.clone(),
            saved_utc_ns: railmon_bus::utc_now_ns(),
            payload_bytes: payload.len(),
            checksum: format!("{:016x}", fnv1a(&payload)),
        };
        let dir = self.path.parent().expect("snapshots/<stream>.snapshot");
        // Private (0700, files 0600): a snapshot is resumed as the estimator's own state, so no
        // other local user may read or replace one (the data directory itself is checked at
        // start: `store::EventStore::open`).
        railmon_records::private_dir::make_private_dir(dir)?;
        let mut file = AtomicFile::create_private(&self.path).map_err(|e| e.to_string())?;
        let write = |file: &mut AtomicFile| -> std::io::Result<()> {
            writeln!(file, "{MAGIC}")?;
            writeln!(file, "{}", serde_json::to_string(&header)?)?;
            file.write_all(&payload)
        };
        write(&mut file).map_err(|e| format!("{}: {e}", self.path.display()))?;
        file.commit().map_err(|e| e.to_string())
    }

    /// The saved state if it fits: this format, this stream, these settings, saved at most
    /// `max_age_s` ago, intact. `Ok(None)`: there is none; `Err`: there is one that does not
    /// fit, and why.
    pub fn load(&self, max_age_s: f64) -> Result<Option<IngestState>, String> {
        // A regular file of bounded size only: a FIFO there would block the stream, a link to
        // a device such as /dev/zero grow the process without end (issue 26 item 5).
        let bytes = match railmon_records::read_regular_file(&self.path, MAX_SNAPSHOT_BYTES) {
            Ok(bytes) => bytes,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(format!("{}: {e}", self.path.display())),
        };
        let mut lines = bytes.splitn(3, |&b| b == b'\n');
        let (Some(magic), Some(header), Some(payload)) = (lines.next(), lines.next(), lines.next())
        else {
            return Err("truncated".into());
        };
        if magic != MAGIC.as_bytes() {
            return Err(format!(
                "not a {MAGIC} file (starts {:?})",
                String::from_utf8_lossy(&magic[..magic.len().min(40)])
            ));
        }
        let header: Header = serde_json::from_slice(header).map_err(|e| format!("header: {e}"))?;
        if header.stream != self.stream {
            return Err(format!("a snapshot of stream {}", header.stream));
        }
        if header.settings != self.settings {
            return Err("made with other estimator settings".into());
        }
        // Checked: a forged `saved_utc_ns` (i64::MAX) must not wrap into a young age.
        let age_s = railmon_bus::utc_now_ns()
            .checked_sub(header.saved_utc_ns)
            .map(|ns| ns as f64 * 1e-9);
        match age_s {
            // A clock stepped back by more than a minute since the save is no age to trust.
            Some(age_s) if (-60.0..=max_age_s).contains(&age_s) => {}
            Some(age_s) => {
                return Err(format!(
                    "{age_s:.0} s old, at most {max_age_s} s resumed (and not from the future)"
                ))
            }
            None => return Err(format!("saved at {} ns: not a time", header.saved_utc_ns)),
        }
        if payload.len() != header.payload_bytes
            || format!("{:016x}", fnv1a(payload)) != header.checksum
        {
            return Err("checksum mismatch (torn or corrupted)".into());
        }
        bincode::deserialize(payload)
            .map(Some)
            .map_err(|e| format!("payload: {e}"))
    }
}

/// The layout of one pipeline's saved state (its `Pipeline::save_state` bytes): a magic
/// string, the format version of the pipeline's own part (`u32`, little endian), the format
/// version of the estimator's state inside it (`u32`, the estimator crate's
/// `STATE_FORMAT_VERSION`, beside its state type), then the bincode. Bincode has no schema: a
/// state of another layout would fail to decode with a message about bytes, or worse decode
/// into other numbers; the versions say which layout it is before anything is read. Raise a
/// pipeline's `version` with every change of what it holds around the estimator's state (each
/// pipeline's test `state_layout_golden_...` pins that part, the estimator crate's test the
/// rest). States written before versions existed are bare bincode (format 1).
#[derive(Clone, Copy, Debug)]
pub struct StateFormat {
    pub magic: &'static [u8],
    pub version: u32,
    pub estimator_version: u32,
    /// What it is, for messages: `bogie state`.
    pub what: &'static str,
}

impl StateFormat {
    pub fn encode<T: Serialize>(&self, state: &T) -> Option<Vec<u8>> {
        let mut bytes = self.magic.to_vec();
        bytes.extend_from_slice(&self.version.to_le_bytes());
        bytes.extend_from_slice(&self.estimator_version.to_le_bytes());
        bincode::serialize_into(&mut bytes, state).ok()?;
        Some(bytes)
    }

    /// The state in `bytes` if it is of this build's formats; else why not, with the versions.
    pub fn decode<T: serde::de::DeserializeOwned>(&self, bytes: &[u8]) -> Result<T, String> {
        let what = self.what;
        let Some(rest) = bytes.strip_prefix(self.magic) else {
            return Err(format!(
                "{what} without a format version (format 1, written before versions); \
                 this build reads format {}",
                self.version
            ));
        };
        let Some((version, rest)) = rest.split_first_chunk::<4>() else {
            return Err(format!("{what} truncated in its format version"));
        };
        refuse_other(what, "format", u32::from_le_bytes(*version), self.version)?;
        let Some((version, payload)) = rest.split_first_chunk::<4>() else {
            return Err(format!(
                "{what} truncated in its estimator's format version"
            ));
        };
        let estimator_version = u32::from_le_bytes(*version);
        refuse_other(
            what,
            "estimator format",
            estimator_version,
            self.estimator_version,
        )?;
        bincode::deserialize(payload).map_err(|e| {
            let ours = (self.version, self.estimator_version);
            format!("{what} format {}, estimator format {}: {e}", ours.0, ours.1)
        })
    }
}

/// `Err` naming both versions unless `version` is `ours`.
fn refuse_other(what: &str, which_format: &str, version: u32, ours: u32) -> Result<(), String> {
    if version == ours {
        return Ok(());
    }
    let which = if version > ours { "newer" } else { "older" };
    Err(format!(
        "{what} {which_format} {version} ({which} than this build's); this build reads \
         {which_format} {ours}"
    ))
}

/// The `snapshot_refused` event of `stream`: the snapshot found at start in `file` did not fit
/// (`reason`), so its estimator starts from its prior. Stored before the first frame: no
/// stream time yet, subject empty.
pub fn refused_event(
    stream: railmon_bus::StreamKind,
    file: &Path,
    reason: &str,
) -> crate::store::NewEvent {
    let mut detail = serde_json::Map::new();
    detail.insert("file".into(), file.display().to_string().into());
    detail.insert("reason".into(), reason.into());
    crate::store::NewEvent {
        stream,
        kind: "snapshot_refused".into(),
        subject: String::new(),
        time_utc_ns: railmon_bus::utc_now_ns(),
        time_s: 0.0,
        run: 0,
        run_time_s: 0.0,
        detail,
        alarm: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state() -> IngestState {
        IngestState {
            publisher_instance: 7,
            run: 2,
            next_sequence: 1234,
            last_sample_time_ns: Some(99),
            pipeline: vec![1, 2, 3, 255],
        }
    }

    fn dir(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("railmon-snap-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        dir
    }

    #[test]
    fn a_saved_state_comes_back_and_a_mismatched_or_corrupt_one_is_refused() {
        let d = dir("roundtrip");
        let file = SnapshotFile::new(&d, "drive", "settings A");
        assert_eq!(file.load(60.0), Ok(None));
        file.save(&state()).unwrap();
        assert_eq!(file.load(60.0), Ok(Some(state())));
        let other = SnapshotFile::new(&d, "drive", "settings B");
        assert!(other
            .load(60.0)
            .unwrap_err()
            .contains("other estimator settings"));
        std::thread::sleep(std::time::Duration::from_millis(20));
        assert!(file.load(0.01).unwrap_err().contains("old"));
        let mut bytes = std::fs::read(file.path()).unwrap();
        let last = bytes.len() - 1;
        bytes[last] ^= 0xff;
        std::fs::write(file.path(), &bytes).unwrap();
        assert!(file.load(60.0).unwrap_err().contains("checksum"));
        std::fs::write(file.path(), b"railmon-snapshot v1\n").unwrap();
        assert!(file.load(60.0).unwrap_err().contains("truncated"));
        let _ = std::fs::remove_dir_all(&d);
    }

    /// A save time far in the future (a forged `saved_utc_ns` of i64::MAX, or a clock stepped
    /// back) is refused, not taken for a young snapshot by a wrapping subtraction.
    #[test]
    fn a_snapshot_from_the_future_is_refused() {
        let d = dir("future");
        let file = SnapshotFile::new(&d, "drive", "settings A");
        file.save(&state()).unwrap();
        let text = std::fs::read(file.path()).unwrap();
        let now = railmon_bus::utc_now_ns();
        for saved in [i64::MAX, now + 3_600_000_000_000, i64::MIN] {
            let forged = String::from_utf8_lossy(&text).replacen(
                "\"saved_utc_ns\":",
                &format!("\"saved_utc_ns\":{saved},\"was\":"),
                1,
            );
            std::fs::write(file.path(), forged.as_bytes()).unwrap();
            let e = file.load(600.0).unwrap_err();
            assert!(
                e.contains("future") || e.contains("not a time"),
                "{saved}: {e}"
            );
        }
        let _ = std::fs::remove_dir_all(&d);
    }

    /// This build's format comes back; a newer or older version of the pipeline's part or of
    /// the estimator's, or a state written before versions (bare bincode), is refused with its
    /// version named, before its bytes are read.
    #[test]
    fn a_state_of_another_format_version_is_refused_by_its_version() {
        const FORMAT: StateFormat = StateFormat {
            magic: b"railmon-test\0",
            version: 3,
            estimator_version: 7,
            what: "test state",
        };
        let bytes = FORMAT.encode(&state()).unwrap();
        assert_eq!(FORMAT.decode::<IngestState>(&bytes), Ok(state()));
        let at = FORMAT.magic.len();
        for (version, which) in [(4, "newer"), (u32::MAX, "newer"), (1, "older")] {
            let mut other = bytes.clone();
            other[at..at + 4].copy_from_slice(&u32::to_le_bytes(version));
            let e = FORMAT.decode::<IngestState>(&other).unwrap_err();
            assert!(
                e.contains(&format!("test state format {version} ({which}"))
                    && e.contains("reads format 3"),
                "{e}"
            );
        }
        for (version, which) in [(8, "newer"), (6, "older")] {
            let mut other = bytes.clone();
            other[at + 4..at + 8].copy_from_slice(&u32::to_le_bytes(version));
            let e = FORMAT.decode::<IngestState>(&other).unwrap_err();
            assert!(
                e.contains(&format!("test state estimator format {version} ({which}"))
                    && e.contains("reads estimator format 7"),
                "{e}"
            );
        }
        let unversioned = bincode::serialize(&state()).unwrap();
        let e = FORMAT.decode::<IngestState>(&unversioned).unwrap_err();
        assert!(e.contains("test state without a format version"), "{e}");
        for cut in [at + 2, at + 6] {
            let e = FORMAT.decode::<IngestState>(&bytes[..cut]).unwrap_err();
            assert!(e.contains("truncated"), "{e}");
        }
        let e = FORMAT
            .decode::<IngestState>(&bytes[..bytes.len() - 2])
            .unwrap_err();
        assert!(
            e.starts_with("test state format 3, estimator format 7: "),
            "{e}"
        );
    }
}
