//! The damper filters' solved gain grids kept on disk (issue 28 item 1), so that a vehicle
//! model's speed nodes are solved once (0.3-0.5 s each, 50 nodes for 5-55 m/s) instead of at
//! every service start and every `railmon analyze damper` run.
//!
//! One file per speed node, `<dir>/<fingerprint>.gain`, named by the node's
//! [`GainTable::fingerprint`] (everything its solution is computed from, and the solution's
//! version): another vehicle model, grid or solver finds no file, never a wrong one. A file
//! is a header and the grid's values as their exact bits (little-endian):
//!
//! | bytes | field |
//! |-------|-------|
//! | 8     | magic `RMGAINGR` |
//! | 4     | file format version ([`FORMAT_VERSION`]) |
//! | 4     | zero |
//! | 16    | fingerprint (again: a file renamed by hand is not taken for another node) |
//! | 8     | number of values |
//! | 16    | FNV-1a 128 of the values' bytes |
//! | 8 n   | the values ([`railmon_damper::gain_table::GainGrid::values`]) |
//!
//! Loading checks all of it, reading at most the expected size, and then
//! [`GainTable::import`] solves the grid's centre point afresh and compares it to the bit: a
//! file that fails any check is never used, it is removed (so that the node, solved again, is
//! stored again) and the caller is told why. Files are written whole or not at all
//! ([`AtomicFile`]), mode 0600, in a directory created with mode 0700.

use std::io::Write;
use std::path::{Path, PathBuf};

use railmon_damper::fingerprint::Fnv128;
use railmon_damper::gain_table::GainTable;

use crate::bounded::read_regular_file;
use crate::{AtomicFile, RecordError};

const MAGIC: &[u8; 8] = b"RMGAINGR";
/// Raise when the layout above changes.
pub const FORMAT_VERSION: u32 = 1;
const HEADER_LEN: usize = 8 + 4 + 4 + 16 + 8 + 16;

/// The cache directory's name under the service's data directory (`storage.data_dir`).
pub const DIR_NAME: &str = "gain-cache";

/// A directory of stored gain grids.
#[derive(Debug, Clone)]
pub struct GainCache {
    dir: PathBuf,
}

/// What [`GainCache::load_all`] found.
#[derive(Debug, Default)]
pub struct LoadReport {
    /// Nodes taken from the cache.
    pub loaded: Vec<usize>,
    /// Files refused (and removed), each error naming the file and why.
    pub refused: Vec<RecordError>,
}

impl GainCache {
    /// The cache in `dir` (created when the first grid is stored).
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        GainCache { dir: dir.into() }
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The file of the node with fingerprint `fingerprint`.
    pub fn path_of(&self, fingerprint: u128) -> PathBuf {
        self.dir.join(format!("{fingerprint:032x}.gain"))
    }

    /// Takes node `node` of `table` from its file if there is one: `Ok(true)` loaded,
    /// `Ok(false)` no file (or the node was solved meanwhile). A file that fails a check is
    /// removed and the error names it and the check; the node stays unsolved.
    pub fn load(&self, table: &GainTable, node: usize) -> Result<bool, RecordError> {
        if table.is_solved(node) {
            return Ok(false);
        }
        let fingerprint = fingerprint(table, node)?;
        let path = self.path_of(fingerprint);
        let expected = table.values_per_node();
        let bytes = match read_regular_file(&path, (HEADER_LEN + 8 * expected) as u64) {
            Ok(bytes) => bytes,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(false),
            Err(e) => return Err(self.refuse(&path, format!("cannot read: {e}"))),
        };
        let values = match decode(&bytes, fingerprint, expected) {
            Ok(values) => values,
            Err(reason) => return Err(self.refuse(&path, reason)),
        };
        table
            .import(node, values)
            .map_err(|e| self.refuse(&path, e.to_string()))
    }

    /// [`GainCache::load`] of every node stored, the configured speed's first, then the design
    /// mass's, then the other masses' (those a run without a load signal, or at another
    /// measured mass, solved and stored).
    pub fn load_all(&self, table: &GainTable) -> LoadReport {
        let mut report = LoadReport::default();
        let first = table.configured_node();
        let all = table.n_nodes() * table.n_mass_nodes();
        let order = std::iter::once(first).chain((0..all).filter(|&n| n != first));
        for node in order {
            match self.load(table, node) {
                Ok(true) => report.loaded.push(node),
                Ok(false) => {}
                Err(e) => report.refused.push(e),
            }
        }
        report
    }

    /// Stores node `node` of `table` if it is solved and not stored yet: `Ok(true)` written.
    pub fn store(&self, table: &GainTable, node: usize) -> Result<bool, RecordError> {
        let Some(grid) = table.solved_grid(node) else {
            return Ok(false);
        };
        let fingerprint = fingerprint(table, node)?;
        let path = self.path_of(fingerprint);
        if path.exists() {
            return Ok(false);
        }
        let label = self.dir.display().to_string();
        crate::private_dir::make_private_dir(&self.dir)
            .map_err(|e| RecordError::file(&label, e))?;
        let mut file = AtomicFile::create_private(&path)?;
        let label = path.display().to_string();
        file.write_all(&encode(fingerprint, grid.values()))
            .map_err(|e| RecordError::file(&label, format!("write error: {e}")))?;
        file.commit()?;
        Ok(true)
    }

    /// Stores every solved node not stored yet; how many were written.
    pub fn store_all(&self, table: &GainTable) -> Result<usize, RecordError> {
        let mut written = 0;
        for node in 0..table.n_nodes() * table.n_mass_nodes() {
            if table.is_solved(node) && self.store(table, node)? {
                written += 1;
            }
        }
        Ok(written)
    }

    /// The error of a file not used, which is removed.
    fn refuse(&self, path: &Path, reason: String) -> RecordError {
        let removed = match std::fs::remove_file(path) {
            Ok(()) => "removed",
            Err(_) => "not removed",
        };
        RecordError::file(
            &path.display().to_string(),
            format!("stored gain grid not used ({reason}); {removed}, the node is solved again"),
        )
    }
}

fn fingerprint(table: &GainTable, node: usize) -> Result<u128, RecordError> {
    table
        .fingerprint(node)
        .map_err(|e| RecordError::file("gain table", e.to_string()))
}

fn checksum(values: &[u8]) -> u128 {
    Fnv128::default().bytes(values).finish()
}

fn encode(fingerprint: u128, values: &[f64]) -> Vec<u8> {
    let mut payload = Vec::with_capacity(8 * values.len());
    for v in values {
        payload.extend_from_slice(&v.to_bits().to_le_bytes());
    }
    let mut out = Vec::with_capacity(HEADER_LEN + payload.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    out.extend_from_slice(&fingerprint.to_le_bytes());
    out.extend_from_slice(&(values.len() as u64).to_le_bytes());
    out.extend_from_slice(&checksum(&payload).to_le_bytes());
    out.extend_from_slice(&payload);
    out
}

/// The values of a file's bytes, checked against the expected fingerprint and length.
fn decode(bytes: &[u8], fingerprint: u128, expected: usize) -> Result<Vec<f64>, String> {
    if bytes.len() < HEADER_LEN {
        return Err(format!("{} bytes, shorter than the header", bytes.len()));
    }
    let (header, payload) = bytes.split_at(HEADER_LEN);
    let field = |at: usize, len: usize| &header[at..at + len];
    if field(0, 8) != MAGIC {
        return Err("not a gain grid file (magic)".into());
    }
    let version = u32::from_le_bytes(field(8, 4).try_into().expect("4 bytes"));
    if version != FORMAT_VERSION {
        return Err(format!(
            "format version {version}, this build reads {FORMAT_VERSION}"
        ));
    }
    let stored = u128::from_le_bytes(field(16, 16).try_into().expect("16 bytes"));
    if stored != fingerprint {
        return Err(format!("fingerprint {stored:032x} is not its name's"));
    }
    let count = u64::from_le_bytes(field(32, 8).try_into().expect("8 bytes"));
    if count != expected as u64 || payload.len() != 8 * expected {
        return Err(format!(
            "{count} values in the header and {} bytes of them, expected {expected} values",
            payload.len()
        ));
    }
    let sum = u128::from_le_bytes(field(40, 16).try_into().expect("16 bytes"));
    if sum != checksum(payload) {
        return Err("checksum mismatch".into());
    }
    Ok(payload
        .chunks_exact(8)
        .map(|b| f64::from_bits(u64::from_le_bytes(b.try_into().expect("8 bytes"))))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use railmon_damper::{DamperMonitorConfig, Rbpf};
    use std::os::unix::fs::PermissionsExt;

    fn temp_dir(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("railmon-gain-cache-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        dir
    }

    fn config() -> DamperMonitorConfig {
        let mut c = DamperMonitorConfig::default();
        c.rbpf.gain_grid.points_per_axis = 5;
        c
    }

    fn unsolved(c: &DamperMonitorConfig) -> std::sync::Arc<GainTable> {
        Rbpf::unsolved_gain_table(&c.filter_model(), &c.rbpf, &c.speed).unwrap()
    }

    #[test]
    fn a_stored_node_loads_to_the_bit_and_the_file_is_private() {
        let dir = temp_dir("roundtrip");
        let cache = GainCache::new(dir.join(DIR_NAME));
        let c = config();
        let solved = Rbpf::gain_table(&c.filter_model(), &c.rbpf, &c.speed).unwrap();
        let k = solved.configured_node();
        solved.grid_at(k + 2).unwrap();
        assert_eq!(cache.store_all(&solved).unwrap(), 2);
        assert_eq!(cache.store_all(&solved).unwrap(), 0, "already stored");
        let path = cache.path_of(solved.fingerprint(k).unwrap());
        let mode = std::fs::metadata(&path).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o600);
        let dir_mode = std::fs::metadata(cache.dir()).unwrap().permissions().mode();
        assert_eq!(dir_mode & 0o777, 0o700);

        let loaded = unsolved(&c);
        let report = cache.load_all(&loaded);
        assert_eq!(report.loaded, [k, k + 2]);
        assert!(report.refused.is_empty(), "{:?}", report.refused);
        for node in [k, k + 2] {
            let (a, b) = (solved.solved_grid(node).unwrap(), loaded.solved_grid(node));
            let b = b.unwrap();
            assert!(a
                .values()
                .iter()
                .zip(b.values())
                .all(|(x, y)| x.to_bits() == y.to_bits()));
        }
        assert!(!loaded.is_solved(k + 1));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Each kind of damage is refused naming the file and the check, the file removed, the
    /// node left unsolved (to be solved and stored again).
    #[test]
    fn a_damaged_file_is_refused_removed_and_never_used() {
        let dir = temp_dir("damaged");
        let cache = GainCache::new(&dir);
        let c = config();
        let solved = Rbpf::gain_table(&c.filter_model(), &c.rbpf, &c.speed).unwrap();
        let k = solved.configured_node();
        cache.store(&solved, k).unwrap();
        let path = cache.path_of(solved.fingerprint(k).unwrap());
        let good = std::fs::read(&path).unwrap();
        let n = good.len();
        let mut other_node = {
            solved.grid_at(k + 1).unwrap();
            encode(
                solved.fingerprint(k).unwrap(),
                solved.solved_grid(k + 1).unwrap().values(),
            )
        };
        type Damage = Box<dyn Fn(&mut Vec<u8>)>;
        let damage: Vec<(&str, Damage)> = vec![
            ("magic", Box::new(|b| b[0] = b'X')),
            ("format version", Box::new(|b| b[8] = 9)),
            ("fingerprint", Box::new(|b| b[20] ^= 1)),
            ("expected", Box::new(move |b| b.truncate(n - 8))),
            ("checksum", Box::new(move |b| b[n - 3] ^= 0x10)),
            ("header", Box::new(|b| b.truncate(10))),
            ("cannot read", Box::new(|b| b.extend_from_slice(&[0; 8]))),
        ];
        for (check, damage) in damage.iter() {
            let mut bytes = good.clone();
            damage(&mut bytes);
            std::fs::write(&path, &bytes).unwrap();
            let table = unsolved(&c);
            let e = cache.load(&table, k).unwrap_err().to_string();
            assert!(
                e.contains(check) && e.contains(&*path.to_string_lossy()),
                "{e}"
            );
            assert!(!table.is_solved(k));
            assert!(!path.exists(), "{check}: removed");
        }
        // A well-formed file of another solution: the fresh centre point tells.
        std::fs::write(&path, &mut other_node).unwrap();
        let table = unsolved(&c);
        let e = cache.load(&table, k).unwrap_err().to_string();
        assert!(e.contains("fresh solution"), "{e}");
        assert!(!table.is_solved(k));
        // Solved again and stored again.
        table.grid_at(k).unwrap();
        assert!(cache.store(&table, k).unwrap());
        assert!(cache.load(&unsolved(&c), k).unwrap());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
