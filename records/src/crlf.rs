//! CRLF line endings read as LF, so that CSV errors name the right line.
//!
//! Why: the `csv` crate ends a record at the `\r` of a `\r\n` and consumes the `\n` only when
//! the next record starts, after it took that record's position: every row of a file saved
//! with Windows line endings was reported one line early (a bad value on line 5 named line
//! 4). Dropping the `\r` of each `\r\n` before the parser leaves every value as it was (fields
//! are trimmed anyway) and the line count right; a `\r` not followed by `\n` is kept.

use std::io::Read;

/// `inner` with every `\r\n` read as `\n`.
pub struct CrlfAsLf<R> {
    inner: R,
    buffer: Box<[u8]>,
    pos: usize,
    len: usize,
    /// A `\r` read last, not yet known to be followed by `\n`.
    held_cr: bool,
}

impl<R> CrlfAsLf<R> {
    pub fn new(inner: R) -> Self {
        CrlfAsLf {
            inner,
            buffer: vec![0; 8192].into_boxed_slice(),
            pos: 0,
            len: 0,
            held_cr: false,
        }
    }
}

impl<R: Read> Read for CrlfAsLf<R> {
    fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
        let mut written = 0;
        while written < out.len() {
            if self.pos == self.len {
                if written > 0 {
                    break;
                }
                self.len = self.inner.read(&mut self.buffer)?;
                self.pos = 0;
                if self.len == 0 {
                    if std::mem::take(&mut self.held_cr) {
                        out[0] = b'\r';
                        written = 1;
                    }
                    break;
                }
            }
            let byte = self.buffer[self.pos];
            self.pos += 1;
            if std::mem::take(&mut self.held_cr) && byte != b'\n' {
                out[written] = b'\r';
                written += 1;
                if written == out.len() {
                    // No room for `byte`: read it again next time.
                    self.pos -= 1;
                    break;
                }
            }
            if byte == b'\r' {
                self.held_cr = true;
            } else {
                out[written] = byte;
                written += 1;
            }
        }
        Ok(written)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Hands out one byte per read, so that every byte falls on a buffer's edge.
    struct ByteByByte<'a>(&'a [u8]);

    impl Read for ByteByByte<'_> {
        fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
            match (self.0.split_first(), out.is_empty()) {
                (Some((&b, rest)), false) => {
                    out[0] = b;
                    self.0 = rest;
                    Ok(1)
                }
                _ => Ok(0),
            }
        }
    }

    fn read_all(r: impl Read, out_len: usize) -> Vec<u8> {
        let mut r = r;
        let (mut all, mut chunk) = (Vec::new(), vec![0; out_len]);
        loop {
            let n = r.read(&mut chunk).unwrap();
            if n == 0 {
                return all;
            }
            all.extend_from_slice(&chunk[..n]);
        }
    }

    #[test]
    fn crlf_becomes_lf_and_a_lone_cr_stays_whatever_the_chunks() {
        let text = b"a,b\r\n1,2\r\n3,\r4\r\r\n5,6\r";
        let expected = b"a,b\n1,2\n3,\r4\r\n5,6\r".to_vec();
        for out_len in [1, 2, 3, 64] {
            assert_eq!(read_all(CrlfAsLf::new(&text[..]), out_len), expected);
            assert_eq!(read_all(CrlfAsLf::new(ByteByByte(text)), out_len), expected);
        }
    }
}
