//! Reading a file from outside without trusting its kind or size: only a regular file (a FIFO
//! would block the reader, a device such as `/dev/zero` never ends), and at most a bound the
//! caller names, checked before and while reading. `/dev/zero` as `--config` once grew a
//! process to ~10 GB in 20 s (issue 26 item 5).

use std::fs::{File, OpenOptions};
use std::io::Read;
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
use std::path::Path;

/// Largest settings or scenario file read (bytes): the shipped ones are a few kB.
pub const MAX_SETTINGS_FILE_BYTES: u64 = 16 << 20;

/// The bytes of the regular file `path`, at most `max_bytes` of them; else why not, in words
/// (the caller adds the file's name).
pub fn read_regular_file(path: &Path, max_bytes: u64) -> Result<Vec<u8>, std::io::Error> {
    let (file, meta) = open_regular_file(path)?;
    if meta.len() > max_bytes {
        return Err(too_large(meta.len(), max_bytes));
    }
    read_at_most(file, max_bytes)
}

/// `path` opened for reading if it is a regular file, with its metadata; else why not.
pub fn open_regular_file(path: &Path) -> Result<(File, std::fs::Metadata), std::io::Error> {
    // Non-blocking, so that opening a FIFO with no writer returns at once; the kind is then
    // checked on the opened file, not on a name that could change in between.
    let file = OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(path)?;
    let meta = file.metadata()?;
    let kind = meta.file_type();
    if !kind.is_file() {
        let what = if kind.is_dir() {
            "a directory"
        } else if kind.is_fifo() {
            "a FIFO"
        } else if kind.is_char_device() || kind.is_block_device() {
            "a device"
        } else if kind.is_socket() {
            "a socket"
        } else {
            "not a file"
        };
        return Err(invalid(format!("{what}, not a regular file")));
    }
    Ok((file, meta))
}

/// [`read_regular_file`] as UTF-8 text.
pub fn read_text_file(path: &Path, max_bytes: u64) -> Result<String, std::io::Error> {
    String::from_utf8(read_regular_file(path, max_bytes)?)
        .map_err(|e| invalid(format!("not UTF-8 text ({e})")))
}

/// The file's bytes, refused once more than `max_bytes` come (a file growing while read).
/// Longest line a CSV reader takes: real rows are well under a kilobyte, and a regular file
/// of one endless line (no newline in gigabytes) would otherwise be buffered whole.
pub const MAX_CSV_LINE_BYTES: usize = 1 << 20;

/// A reader that fails (`InvalidData`, naming the line) once a line exceeds
/// [`MAX_CSV_LINE_BYTES`], so a parser above it never buffers more than that.
#[derive(Debug)]
pub struct LineBounded<R> {
    inner: R,
    /// Bytes since the last newline.
    line_bytes: usize,
    /// Newlines seen.
    newlines: u64,
}

impl<R> LineBounded<R> {
    pub fn new(inner: R) -> Self {
        LineBounded {
            inner,
            line_bytes: 0,
            newlines: 0,
        }
    }
}

impl<R: Read> Read for LineBounded<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        // Never hand out more than the rest of the allowance, so the bound is exact.
        let room = MAX_CSV_LINE_BYTES - self.line_bytes;
        let want = buf.len().min(room.max(1));
        let n = self.inner.read(&mut buf[..want])?;
        for &byte in &buf[..n] {
            if byte == b'\n' {
                self.newlines += 1;
                self.line_bytes = 0;
            } else {
                self.line_bytes += 1;
                if self.line_bytes > MAX_CSV_LINE_BYTES {
                    return Err(invalid(format!(
                        "line {} is longer than {MAX_CSV_LINE_BYTES} bytes (no line break)",
                        self.newlines + 1
                    )));
                }
            }
        }
        Ok(n)
    }
}

fn read_at_most(file: File, max_bytes: u64) -> Result<Vec<u8>, std::io::Error> {
    let mut bytes = Vec::new();
    file.take(max_bytes.saturating_add(1))
        .read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max_bytes {
        return Err(too_large(bytes.len() as u64, max_bytes));
    }
    Ok(bytes)
}

fn too_large(len: u64, max_bytes: u64) -> std::io::Error {
    invalid(format!(
        "{len} bytes or more, larger than the {max_bytes} bytes read at most"
    ))
}

fn invalid(reason: String) -> std::io::Error {
    std::io::Error::new(std::io::ErrorKind::InvalidInput, reason)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> std::path::PathBuf {
        let dir =
            std::env::temp_dir().join(format!("railmon-bounded-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    /// A regular file within the bound is read whole; one over it, a device, a FIFO without a
    /// writer (without blocking) and a directory are refused, naming what they are.
    #[test]
    fn only_regular_files_within_the_bound_are_read() {
        let dir = scratch("kinds");
        let file = dir.join("a.toml");
        std::fs::write(&file, "x = 1\n").unwrap();
        assert_eq!(read_text_file(&file, 6).unwrap(), "x = 1\n");
        let e = read_text_file(&file, 5).unwrap_err();
        assert!(e.to_string().contains("larger than the 5 bytes"), "{e}");
        let e = read_regular_file(Path::new("/dev/zero"), 1 << 20).unwrap_err();
        assert!(e.to_string().contains("a device"), "{e}");
        let link = dir.join("zero.toml");
        std::os::unix::fs::symlink("/dev/zero", &link).unwrap();
        let e = read_regular_file(&link, 1 << 20).unwrap_err();
        assert!(e.to_string().contains("a device"), "{e}");
        let fifo = dir.join("fifo");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        if made.is_ok_and(|s| s.success()) {
            let e = read_regular_file(&fifo, 1 << 20).unwrap_err();
            assert!(e.to_string().contains("a FIFO"), "{e}");
        }
        let e = read_regular_file(&dir, 1 << 20).unwrap_err();
        assert!(e.to_string().contains("directory"), "{e}");
        std::fs::write(&file, [0xff, 0xfe]).unwrap();
        assert!(read_text_file(&file, 10)
            .unwrap_err()
            .to_string()
            .contains("UTF-8"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
