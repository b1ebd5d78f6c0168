//! Every file railmon writes (recordings, reports, plots, snapshots) is written whole or not at
//! all: under a temporary name in the destination's own directory, then renamed over the
//! destination once complete. A run that fails, or is killed, never leaves a half-written file
//! under the real name, and an existing file stays as it was until the new one is complete
//! (`sensors-replay --record F` kept 110 of 151,097 bytes of F when no service answered).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use crate::RecordError;

/// A file being written under a temporary name next to `path`. [`AtomicFile::commit`] makes it
/// `path`; dropped without a commit (an error, an early return), the temporary file is removed
/// and `path` is untouched. A SIGKILL leaves the temporary file (`.tmp-<pid>-<n>-<name>`), never
/// a truncated `path`.
#[derive(Debug)]
pub struct AtomicFile {
    path: PathBuf,
    temporary: PathBuf,
    writer: Option<BufWriter<File>>,
}

impl AtomicFile {
    /// Starts writing `path` (its directory must exist).
    pub fn create(path: &Path) -> Result<Self, RecordError> {
        Self::create_with_mode(path, 0o666)
    }

    /// [`AtomicFile::create`] with the permission bits `mode` (less the umask), e.g. `0o600`
    /// for a file only its owner reads.
    pub fn create_with_mode(path: &Path, mode: u32) -> Result<Self, RecordError> {
        use std::os::unix::fs::OpenOptionsExt;
        static N: AtomicU64 = AtomicU64::new(0);
        let label = path.display().to_string();
        let name = path
            .file_name()
            .ok_or_else(|| RecordError::file(&label, "cannot create: not a file name"))?;
        // The destination's name last: encoders that pick the format by extension (PNG)
        // see the right one.
        let temporary = path.with_file_name(format!(
            ".tmp-{}-{}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed),
            name.to_string_lossy()
        ));
        let file = File::options()
            .write(true)
            .create_new(true)
            .mode(mode)
            .open(&temporary)
            .map_err(|e| RecordError::file(&label, format!("cannot create: {e}")))?;
        Ok(Self {
            path: path.to_owned(),
            temporary,
            writer: Some(BufWriter::new(file)),
        })
    }

    /// The destination.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The temporary file, for writers that open the file by name themselves (PNG encoders).
    pub fn temporary_path(&self) -> &Path {
        &self.temporary
    }

    /// Flushes, syncs and renames the temporary file to the destination (replacing it), then
    /// syncs the directory so the rename survives a power cut.
    pub fn commit(mut self) -> Result<(), RecordError> {
        let label = self.path.display().to_string();
        let err = |what: &str, e: std::io::Error| RecordError::file(&label, format!("{what}: {e}"));
        let writer = self
            .writer
            .take()
            .expect("an uncommitted file has its writer");
        let file = writer
            .into_inner()
            .map_err(|e| err("write error", e.into_error()))?;
        file.sync_all().map_err(|e| err("write error", e))?;
        drop(file);
        std::fs::rename(&self.temporary, &self.path).map_err(|e| err("cannot rename", e))?;
        let dir = match self.path.parent() {
            Some(dir) if !dir.as_os_str().is_empty() => dir,
            _ => Path::new("."),
        };
        // Not every file system lets a directory be opened for syncing; the data is written.
        if let Ok(dir) = File::open(dir) {
            let _ = dir.sync_all();
        }
        Ok(())
    }
}

impl Write for AtomicFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.writer
            .as_mut()
            .expect("an uncommitted file has its writer")
            .write(buf)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.writer
            .as_mut()
            .expect("an uncommitted file has its writer")
            .flush()
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if self.writer.take().is_some() {
            let _ = std::fs::remove_file(&self.temporary);
        }
    }
}

/// Refuses to write `output` when it is one of `inputs` (the same file by device and inode, or
/// the same path once resolved): `--csv X --record X` destroyed the recording it replayed.
pub fn refuse_output_that_is_an_input(
    output: &Path,
    inputs: &[&Path],
    what: &str,
) -> Result<(), RecordError> {
    for input in inputs {
        if same_file(output, input) {
            return Err(RecordError::file(
                &output.display().to_string(),
                format!(
                    "{what} is also an input ({}); choose another file",
                    input.display()
                ),
            ));
        }
    }
    Ok(())
}

fn same_file(a: &Path, b: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (std::fs::metadata(a), std::fs::metadata(b)) {
        (Ok(ma), Ok(mb)) => ma.dev() == mb.dev() && ma.ino() == mb.ino(),
        // The output does not exist yet: it cannot be an existing input.
        _ => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp_dir(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("records-output-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn entries(dir: &Path) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }

    #[test]
    fn the_destination_changes_only_at_commit() {
        let dir = temp_dir("commit");
        let path = dir.join("a.csv");
        std::fs::write(&path, "old").unwrap();
        let mut file = AtomicFile::create(&path).unwrap();
        file.write_all(b"new content").unwrap();
        file.flush().unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "old");
        assert_eq!(entries(&dir).len(), 2, "the temporary file sits beside it");
        file.commit().unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "new content");
        assert_eq!(entries(&dir), ["a.csv"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_file_dropped_without_commit_leaves_nothing_and_the_old_file_intact() {
        let dir = temp_dir("drop");
        let path = dir.join("a.csv");
        std::fs::write(&path, "old").unwrap();
        {
            let mut file = AtomicFile::create(&path).unwrap();
            file.write_all(b"partial").unwrap();
        }
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "old");
        assert_eq!(entries(&dir), ["a.csv"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn an_output_that_is_an_input_is_refused() {
        let dir = temp_dir("same");
        let input = dir.join("in.csv");
        std::fs::write(&input, "x").unwrap();
        let other = dir.join("sub/../in.csv");
        std::fs::create_dir_all(dir.join("sub")).unwrap();
        let err = refuse_output_that_is_an_input(&other, &[&input], "--record").unwrap_err();
        assert!(
            err.to_string().contains("--record is also an input"),
            "{err}"
        );
        refuse_output_that_is_an_input(&dir.join("new.csv"), &[&input], "--record").unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
