//! CSV formats of recorded sensor data, and the generic reader they share.
//!
//! Recorded data comes from outside (a drive logger, a dynamometer, `sensors-replay --record`),
//! so every value is checked on the way in. A bad value is an error that names the file, the
//! line (1-based, counting the header as line 1), the column and the value, e.g.
//! `drives.csv:1203: field "i_alpha_a" = "NaN": not a finite number`; nothing is skipped
//! silently.
//!
//! The format modules (`drive`, `bogie`, `vehicle`) describe their columns and use
//! [`CsvTable`] to read them.

use std::fmt;
use std::fs::File;
use std::io::Read;
use std::path::Path;

pub use bounded::{read_regular_file, read_text_file, MAX_SETTINGS_FILE_BYTES};
pub use output::{refuse_output_that_is_an_input, AtomicFile};

pub mod bogie;
pub mod bounded;
mod crlf;
pub mod drive;
pub mod gain_cache;
pub mod output;
pub mod private_dir;
pub mod sample_clock;
pub mod vehicle;
pub mod vehicle_scenario;

/// What went wrong, and where, when reading or writing a record file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub struct RecordError {
    /// File name as given by the caller (or a label such as `<stdin>`).
    pub file: String,
    /// 1-based line number; `None` when the error is not about one line (e.g. cannot open).
    pub line: Option<u64>,
    /// Column name, when the error is about one field.
    pub field: Option<String>,
    /// The offending text, when there is one.
    pub value: Option<String>,
    /// What is wrong, in words.
    pub reason: String,
}

impl fmt::Display for RecordError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file)?;
        if let Some(line) = self.line {
            write!(f, ":{line}")?;
        }
        write!(f, ":")?;
        if let Some(field) = &self.field {
            write!(f, " field \"{field}\"")?;
            if let Some(value) = &self.value {
                write!(f, " = \"{}\"", shortened(value))?;
            }
            write!(f, ":")?;
        }
        write!(f, " {}", self.reason)
    }
}

/// `value` as an error shows it: whole up to 80 bytes, else its first 60 and its length (a
/// 200 MB field was once echoed whole into the error).
fn shortened(value: &str) -> std::borrow::Cow<'_, str> {
    if value.len() <= 80 {
        return value.into();
    }
    let mut end = 60;
    while !value.is_char_boundary(end) {
        end -= 1;
    }
    format!("{}... ({} bytes)", &value[..end], value.len()).into()
}

impl RecordError {
    /// An error about the file as a whole.
    pub fn file(file: &str, reason: impl Into<String>) -> Self {
        RecordError {
            file: file.to_owned(),
            line: None,
            field: None,
            value: None,
            reason: reason.into(),
        }
    }
}

/// A column of a [`CsvTable`], resolved once from the header so rows are read by index.
#[derive(Debug, Clone)]
pub struct Column {
    index: usize,
    name: String,
}

impl Column {
    pub fn name(&self) -> &str {
        &self.name
    }
}

/// A CSV file with a header row, read row by row with checked field access.
///
/// Empty lines are skipped (the `csv` crate does so); a UTF-8 byte-order mark before the
/// header is removed; a row with a different number of fields than the header (a truncated
/// last line, a stray comma) is an error naming its line.
pub struct CsvTable<R: Read> {
    file: String,
    header: Vec<String>,
    reader: csv::Reader<bounded::LineBounded<crlf::CrlfAsLf<R>>>,
    record: csv::StringRecord,
    /// Line of the row read last (1: the header).
    line: u64,
}

impl CsvTable<File> {
    /// Opens `path` (a regular file: `/dev/zero` would be read without end) and reads its
    /// header.
    pub fn open(path: &Path) -> Result<Self, RecordError> {
        let label = path.display().to_string();
        let (file, _) = bounded::open_regular_file(path)
            .map_err(|e| RecordError::file(&label, format!("cannot open: {e}")))?;
        Self::from_reader(&label, file)
    }
}

impl<R: Read> CsvTable<R> {
    /// Reads the header of `reader`; `label` names the source in errors.
    pub fn from_reader(label: &str, reader: R) -> Result<Self, RecordError> {
        let mut reader = csv::ReaderBuilder::new()
            .has_headers(true)
            .flexible(false)
            .trim(csv::Trim::All)
            .from_reader(bounded::LineBounded::new(crlf::CrlfAsLf::new(reader)));
        let header = reader
            .headers()
            .map_err(|e| csv_error(label, e))?
            .iter()
            .enumerate()
            .map(|(i, h)| {
                let h = if i == 0 {
                    h.trim_start_matches('\u{feff}')
                } else {
                    h
                };
                h.to_owned()
            })
            .collect::<Vec<_>>();
        if header.iter().all(|h| h.is_empty()) {
            return Err(RecordError::file(label, "empty file: no header line"));
        }
        // A column named twice would be read from its first copy only, whatever the second
        // holds: refused, naming it.
        if let Some((i, name)) = header
            .iter()
            .enumerate()
            .find(|(i, h)| !h.is_empty() && header[..*i].contains(h))
        {
            let first = header.iter().position(|h| h == name).unwrap_or(0);
            return Err(RecordError {
                file: label.to_owned(),
                line: Some(1),
                field: Some(name.clone()),
                value: None,
                reason: format!(
                    "column named twice (columns {} and {}): which one holds the data?",
                    first + 1,
                    i + 1
                ),
            });
        }
        Ok(CsvTable {
            file: label.to_owned(),
            header,
            reader,
            record: csv::StringRecord::new(),
            line: 1,
        })
    }

    /// The file label used in errors.
    pub fn file(&self) -> &str {
        &self.file
    }

    /// 1-based line of the row read last (1 before any data row), for errors found later.
    pub fn line(&self) -> u64 {
        self.line
    }

    /// Column names as found in the header.
    pub fn header(&self) -> &[String] {
        &self.header
    }

    /// Whether the header has a column `name`.
    pub fn has_column(&self, name: &str) -> bool {
        self.header.iter().any(|h| h == name)
    }

    /// Resolves a required column; the error lists the columns the file does have.
    pub fn column(&self, name: &str) -> Result<Column, RecordError> {
        self.optional_column(name).ok_or_else(|| RecordError {
            file: self.file.clone(),
            line: Some(1),
            field: Some(name.to_owned()),
            value: None,
            reason: format!(
                "missing column (the header has: {})",
                self.header.join(", ")
            ),
        })
    }

    /// Resolves a column that may be absent.
    pub fn optional_column(&self, name: &str) -> Option<Column> {
        self.header
            .iter()
            .position(|h| h == name)
            .map(|index| Column {
                index,
                name: name.to_owned(),
            })
    }

    /// Reads the next data row; `Ok(None)` at the end of the file.
    pub fn next_row(&mut self) -> Result<Option<Row<'_>>, RecordError> {
        match self.reader.read_record(&mut self.record) {
            Ok(false) => Ok(None),
            Ok(true) => {
                let line = self.record.position().map_or(0, |p| p.line());
                self.line = line;
                Ok(Some(Row {
                    file: &self.file,
                    line,
                    record: &self.record,
                }))
            }
            Err(e) => Err(csv_error(&self.file, e)),
        }
    }
}

/// One data row of a [`CsvTable`], with typed, checked access to its fields.
pub struct Row<'a> {
    file: &'a str,
    line: u64,
    record: &'a csv::StringRecord,
}

impl Row<'_> {
    /// 1-based line number of this row in its file.
    pub fn line(&self) -> u64 {
        self.line
    }

    /// An error about `column` on this row.
    pub fn error(&self, column: &Column, reason: impl Into<String>) -> RecordError {
        RecordError {
            file: self.file.to_owned(),
            line: Some(self.line),
            field: Some(column.name.clone()),
            value: Some(self.text(column).to_owned()),
            reason: reason.into(),
        }
    }

    /// The raw text of a field.
    pub fn text(&self, column: &Column) -> &str {
        self.record.get(column.index).unwrap_or("")
    }

    /// A finite floating-point field. NaN, infinities and empty fields are errors.
    pub fn f64(&self, column: &Column) -> Result<f64, RecordError> {
        let text = self.text(column);
        if text.is_empty() {
            return Err(self.error(column, "empty field"));
        }
        match text.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            Ok(_) => Err(self.error(column, "not a finite number")),
            Err(_) => Err(self.error(column, "not a number")),
        }
    }

    /// A floating-point field as recorded: NaN and infinities (`NaN`, `inf`, `1e400`) are
    /// values, kept for the estimator's plausibility check to refuse and count (as the
    /// service counts them); empty and non-numeric fields are errors.
    pub fn f64_as_recorded(&self, column: &Column) -> Result<f64, RecordError> {
        let text = self.text(column);
        if text.is_empty() {
            return Err(self.error(column, "empty field"));
        }
        text.parse::<f64>()
            .map_err(|_| self.error(column, "not a number"))
    }

    /// A finite floating-point field within `[min, max]` (inclusive); `unit` is named in the
    /// error so a value in the wrong unit is recognisable as such.
    pub fn f64_in(
        &self,
        column: &Column,
        min: f64,
        max: f64,
        unit: &str,
    ) -> Result<f64, RecordError> {
        let v = self.f64(column)?;
        if v < min || v > max {
            return Err(self.error(column, format!("out of range [{min}, {max}] {unit}")));
        }
        Ok(v)
    }

    /// A non-negative integer field.
    pub fn u64(&self, column: &Column) -> Result<u64, RecordError> {
        self.text(column)
            .parse::<u64>()
            .map_err(|_| self.error(column, "not a non-negative integer"))
    }

    /// A boolean field written as `0`/`1` or `false`/`true`.
    pub fn bool(&self, column: &Column) -> Result<bool, RecordError> {
        match self.text(column) {
            "1" | "true" => Ok(true),
            "0" | "false" => Ok(false),
            _ => Err(self.error(column, "not a boolean (0/1/true/false)")),
        }
    }
}

fn csv_error(file: &str, e: csv::Error) -> RecordError {
    let line = e.position().map(|p| p.line());
    let reason = match e.kind() {
        csv::ErrorKind::UnequalLengths {
            expected_len, len, ..
        } => {
            format!("truncated or malformed line: {len} fields where the header has {expected_len}")
        }
        csv::ErrorKind::Utf8 { .. } => "not valid UTF-8".to_owned(),
        csv::ErrorKind::Io(io) => format!("read error: {io}"),
        _ => e.to_string(),
    };
    RecordError {
        file: file.to_owned(),
        line,
        field: None,
        value: None,
        reason,
    }
}

/// Starts a CSV file, written whole or not at all ([`AtomicFile`]): [`finish_csv`] puts it in
/// place; dropped unfinished, it leaves nothing and an existing file untouched.
pub fn create_csv(path: &Path) -> Result<csv::Writer<AtomicFile>, RecordError> {
    Ok(csv::Writer::from_writer(AtomicFile::create(path)?))
}

/// Completes a file started by [`create_csv`]: flushes it and renames it into place.
pub fn finish_csv(writer: csv::Writer<AtomicFile>) -> Result<(), RecordError> {
    writer
        .into_inner()
        .map_err(|e| RecordError::file("<csv>", format!("write error: {}", e.error())))?
        .commit()
}

/// Writes a whole CSV file: the header, then the rows; errors name the file.
pub fn write_csv_table<S: AsRef<str>>(
    path: &Path,
    header: &[S],
    rows: impl IntoIterator<Item = Vec<String>>,
) -> Result<(), RecordError> {
    let err = |e: &dyn std::fmt::Display| {
        RecordError::file(&path.display().to_string(), format!("write error: {e}"))
    };
    let mut w = create_csv(path)?;
    w.write_record(header.iter().map(|h| h.as_ref()))
        .map_err(|e| err(&e))?;
    for row in rows {
        w.write_record(&row).map_err(|e| err(&e))?;
    }
    w.flush().map_err(|e| err(&e))?;
    finish_csv(w)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_long_value_is_cut_in_the_error() {
        let e = RecordError {
            file: "a.csv".into(),
            line: Some(2),
            field: Some("x".into()),
            value: Some("é".repeat(1_000)),
            reason: "not a number".into(),
        };
        let text = e.to_string();
        assert!(
            text.len() < 120 && text.contains("... (2000 bytes)"),
            "{text}"
        );
        let short = RecordError {
            value: Some("abc".into()),
            ..e
        };
        assert_eq!(
            short.to_string(),
            "a.csv:2: field \"x\" = \"abc\": not a number"
        );
    }

    fn table(text: &str) -> CsvTable<&[u8]> {
        CsvTable::from_reader("t.csv", text.as_bytes()).unwrap()
    }

    fn read_all(text: &str) -> Result<Vec<(f64, f64)>, RecordError> {
        let mut t = table(text);
        let a = t.column("a")?;
        let b = t.column("b")?;
        let mut out = Vec::new();
        while let Some(row) = t.next_row()? {
            out.push((row.f64(&a)?, row.f64(&b)?));
        }
        Ok(out)
    }

    /// A file saved with Windows line endings names the same lines as one saved with `\n`
    /// (the `csv` crate alone named every row of it one line early).
    #[test]
    fn a_bad_value_is_named_on_its_line_whatever_the_line_endings() {
        for newline in ["\n", "\r\n"] {
            let text = ["a,b", "1,2", "", "3,4", "5,x", ""].join(newline);
            let e = read_all(&text).unwrap_err().to_string();
            assert_eq!(
                e, "t.csv:5: field \"b\" = \"x\": not a number",
                "{newline:?}"
            );
            let good = ["a,b", "1,2", "3,4"].join(newline);
            assert_eq!(read_all(&good).unwrap(), vec![(1.0, 2.0), (3.0, 4.0)]);
        }
    }

    /// A regular file of one endless line is refused at the bound, naming the line, instead of
    /// buffered whole (issue 26 item 5); a line just within the bound is read.
    #[test]
    fn an_endless_line_is_refused_at_the_bound() {
        let mut text = String::from("a,b\n1,2\n");
        text.push_str(&"9".repeat(bounded::MAX_CSV_LINE_BYTES + 10));
        let e = read_all(&text).unwrap_err().to_string();
        assert!(e.contains("line 3 is longer than 1048576 bytes"), "{e}");
        let within = format!("a,b\n1,{}\n", "0".repeat(bounded::MAX_CSV_LINE_BYTES - 3));
        assert_eq!(read_all(&within).unwrap(), vec![(1.0, 0.0)]);
    }

    #[test]
    fn reads_values_skips_empty_lines_and_strips_bom() {
        let rows = read_all("\u{feff}a,b\n-0.0,2\n\n3, 4\n").unwrap();
        assert_eq!(rows, vec![(-0.0, 2.0), (3.0, 4.0)]);
    }

    #[test]
    fn nan_names_file_line_field_and_value() {
        let err = read_all("a,b\n1,2\n3,NaN\n").unwrap_err();
        assert_eq!(
            err.to_string(),
            "t.csv:3: field \"b\" = \"NaN\": not a finite number"
        );
    }

    #[test]
    fn truncated_last_line_is_an_error_with_its_line() {
        let err = read_all("a,b\n1,2\n3").unwrap_err();
        assert_eq!(err.line, Some(3));
        assert!(err.reason.contains("truncated"), "{err}");
    }

    #[test]
    fn missing_column_lists_the_header() {
        let err = read_all("a,c\n1,2\n").unwrap_err();
        assert_eq!(
            err.to_string(),
            "t.csv:1: field \"b\": missing column (the header has: a, c)"
        );
    }

    #[test]
    fn range_and_integer_checks() {
        let mut t = table("x,n\n500,-1\n");
        let x = t.column("x").unwrap();
        let n = t.column("n").unwrap();
        let row = t.next_row().unwrap().unwrap();
        let err = row.f64_in(&x, 0.0, 100.0, "m/s").unwrap_err();
        assert!(
            err.to_string().contains("out of range [0, 100] m/s"),
            "{err}"
        );
        assert!(row.u64(&n).is_err());
    }

    #[test]
    fn a_column_named_twice_is_refused_naming_it() {
        let Err(err) = CsvTable::from_reader("t.csv", "a,b,a\n1,2,3\n".as_bytes()) else {
            panic!("a duplicate column was accepted");
        };
        assert_eq!(err.line, Some(1));
        assert_eq!(err.field.as_deref(), Some("a"));
        assert!(
            err.to_string()
                .starts_with("t.csv:1: field \"a\": column named twice"),
            "{err}"
        );
    }

    #[test]
    fn as_recorded_keeps_non_finite_values_and_refuses_text() {
        let mut t = table("x\nNaN\n1e400\nabc\n");
        let x = t.column("x").unwrap();
        assert!(t
            .next_row()
            .unwrap()
            .unwrap()
            .f64_as_recorded(&x)
            .unwrap()
            .is_nan());
        assert_eq!(
            t.next_row().unwrap().unwrap().f64_as_recorded(&x).unwrap(),
            f64::INFINITY
        );
        let row = t.next_row().unwrap().unwrap();
        assert!(row
            .f64_as_recorded(&x)
            .unwrap_err()
            .to_string()
            .contains("not a number"));
    }

    #[test]
    fn empty_input_is_an_error() {
        assert!(CsvTable::from_reader("e.csv", "".as_bytes()).is_err());
    }
}
