//! Bogie recordings (issue 4): the five lateral sensors of one bogie at 1 kHz, what the
//! bogie simulator writes and `railmon analyze damper --input` reads.
//!
//! One row per sample, in time order:
//!
//! ```text
//! time_s,wheelset1_accel_m_s2,wheelset2_accel_m_s2,bogie_accel_m_s2,bogie_yaw_rate_rad_s,body_accel_m_s2[,true_csy_ns_per_m,true_csay_ns_per_m]
//! 0.001,0.213,-0.112,0.051,0.0031,0.0127,16000,160000
//! ```
//!
//! - `time_s`: time of the sample (s); strictly increasing.
//! - the five sensors in the paper's order (eq. 4): lateral accelerations of the leading and
//!   trailing wheelsets, of the bogie frame, the bogie yaw rate, the lateral acceleration of
//!   the body above the bogie.
//! - Optional truth (simulated data): both damper coefficients (N s/m), both or neither.
//!
//! A NaN, an infinity, an empty field, a missing column, a time that does not increase or a
//! truncated last line is an error naming file, line, field and value.

use std::fs::File;
use std::io::{BufWriter, Read};
use std::path::Path;

use crate::{create_csv, Column, CsvTable, RecordError};

/// Time and sensor columns, in order.
pub const BOGIE_COLUMNS: [&str; 6] = [
    "time_s",
    "wheelset1_accel_m_s2",
    "wheelset2_accel_m_s2",
    "bogie_accel_m_s2",
    "bogie_yaw_rate_rad_s",
    "body_accel_m_s2",
];
/// Truth columns of simulated recordings.
pub const BOGIE_TRUTH_COLUMNS: [&str; 2] = ["true_csy_ns_per_m", "true_csay_ns_per_m"];

/// One row.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BogieRecord {
    pub time_s: f64,
    /// The five sensors in the order of [`BOGIE_COLUMNS`]`[1..]`.
    pub sensors: [f64; 5],
    /// `[C_sy, C_say]` (N s/m) when the file has truth.
    pub truth_ns_per_m: Option<[f64; 2]>,
}

/// Streams rows out of a bogie recording.
pub struct BogieCsvReader<R: Read> {
    table: CsvTable<R>,
    time: Column,
    sensors: [Column; 5],
    truth: Option<[Column; 2]>,
    last_time_s: Option<f64>,
}

impl BogieCsvReader<File> {
    pub fn open(path: &Path) -> Result<Self, RecordError> {
        Self::new(CsvTable::open(path)?)
    }
}

impl<R: Read> BogieCsvReader<R> {
    /// From any reader; `label` names it in errors.
    pub fn from_reader(label: &str, reader: R) -> Result<Self, RecordError> {
        Self::new(CsvTable::from_reader(label, reader)?)
    }

    fn new(table: CsvTable<R>) -> Result<Self, RecordError> {
        let truth = if BOGIE_TRUTH_COLUMNS.iter().any(|c| table.has_column(c)) {
            Some([
                table.column(BOGIE_TRUTH_COLUMNS[0])?,
                table.column(BOGIE_TRUTH_COLUMNS[1])?,
            ])
        } else {
            None
        };
        Ok(BogieCsvReader {
            time: table.column(BOGIE_COLUMNS[0])?,
            sensors: [
                table.column(BOGIE_COLUMNS[1])?,
                table.column(BOGIE_COLUMNS[2])?,
                table.column(BOGIE_COLUMNS[3])?,
                table.column(BOGIE_COLUMNS[4])?,
                table.column(BOGIE_COLUMNS[5])?,
            ],
            truth,
            table,
            last_time_s: None,
        })
    }

    pub fn has_truth(&self) -> bool {
        self.truth.is_some()
    }

    pub fn file(&self) -> &str {
        self.table.file()
    }

    /// The next row, `Ok(None)` at the end of the file.
    pub fn next_record(&mut self) -> Result<Option<BogieRecord>, RecordError> {
        let Some(row) = self.table.next_row()? else {
            return Ok(None);
        };
        let time_s = row.f64(&self.time)?;
        if let Some(last) = self.last_time_s {
            if time_s <= last {
                return Err(row.error(
                    &self.time,
                    format!("time must increase (previous row: {last})"),
                ));
            }
        }
        let mut sensors = [0.0; 5];
        for (v, c) in sensors.iter_mut().zip(&self.sensors) {
            *v = row.f64(c)?;
        }
        let truth_ns_per_m = match &self.truth {
            Some([csy, csay]) => Some([
                row.f64_in(csy, 0.0, f64::MAX, "N s/m")?,
                row.f64_in(csay, 0.0, f64::MAX, "N s/m")?,
            ]),
            None => None,
        };
        self.last_time_s = Some(time_s);
        Ok(Some(BogieRecord {
            time_s,
            sensors,
            truth_ns_per_m,
        }))
    }
}

/// Writes a bogie recording.
pub struct BogieCsvWriter {
    writer: csv::Writer<BufWriter<File>>,
    file: String,
    with_truth: bool,
}

impl BogieCsvWriter {
    pub fn create(path: &Path, with_truth: bool) -> Result<Self, RecordError> {
        let mut writer = create_csv(path)?;
        let file = path.display().to_string();
        let mut header: Vec<&str> = BOGIE_COLUMNS.to_vec();
        if with_truth {
            header.extend(BOGIE_TRUTH_COLUMNS);
        }
        writer
            .write_record(&header)
            .map_err(|e| RecordError::file(&file, format!("write error: {e}")))?;
        Ok(BogieCsvWriter {
            writer,
            file,
            with_truth,
        })
    }

    pub fn write(&mut self, record: &BogieRecord) -> Result<(), RecordError> {
        let mut fields: Vec<String> = Vec::with_capacity(8);
        fields.push(record.time_s.to_string());
        fields.extend(record.sensors.iter().map(|v| v.to_string()));
        if self.with_truth {
            let t = record.truth_ns_per_m.ok_or_else(|| {
                RecordError::file(
                    &self.file,
                    "a recording with truth needs truth on every row",
                )
            })?;
            fields.extend(t.iter().map(|v| v.to_string()));
        }
        self.writer
            .write_record(&fields)
            .map_err(|e| RecordError::file(&self.file, format!("write error: {e}")))
    }

    pub fn finish(mut self) -> Result<(), RecordError> {
        self.writer
            .flush()
            .map_err(|e| RecordError::file(&self.file, format!("write error: {e}")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read_all(text: &str) -> Result<Vec<BogieRecord>, RecordError> {
        let mut r = BogieCsvReader::from_reader("bogie.csv", text.as_bytes())?;
        let mut out = vec![];
        while let Some(rec) = r.next_record()? {
            out.push(rec);
        }
        Ok(out)
    }

    const HEADER: &str = "time_s,wheelset1_accel_m_s2,wheelset2_accel_m_s2,bogie_accel_m_s2,bogie_yaw_rate_rad_s,body_accel_m_s2";

    #[test]
    fn writes_and_reads_back() {
        let dir = std::env::temp_dir().join(format!("railmon-bogie-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("b.csv");
        let recs = [
            BogieRecord {
                time_s: 0.001,
                sensors: [0.1, -0.2, 0.3, 0.004, 0.05],
                truth_ns_per_m: Some([16e3, 160e3]),
            },
            BogieRecord {
                time_s: 0.002,
                sensors: [1e-17, 2.5, -3.0, 0.0, 1.0 / 3.0],
                truth_ns_per_m: Some([9.6e3, 64e3]),
            },
        ];
        let mut w = BogieCsvWriter::create(&path, true).unwrap();
        for r in &recs {
            w.write(r).unwrap();
        }
        w.finish().unwrap();
        let mut r = BogieCsvReader::open(&path).unwrap();
        assert!(r.has_truth());
        for want in &recs {
            assert_eq!(r.next_record().unwrap().as_ref(), Some(want));
        }
        assert_eq!(r.next_record().unwrap(), None);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn bad_input_names_file_line_field_and_value() {
        let err = read_all(&format!("{HEADER}\n0.001,1,2,3,4,5\n0.002,1,NaN,3,4,5\n")).unwrap_err();
        assert_eq!(
            (err.line, err.field.as_deref()),
            (Some(3), Some("wheelset2_accel_m_s2"))
        );
        assert_eq!(err.value.as_deref(), Some("NaN"));
        assert!(err.to_string().starts_with("bogie.csv:3:"), "{err}");

        let err = read_all(&format!("{HEADER}\n0.002,1,2,3,4,5\n0.002,1,2,3,4,5\n")).unwrap_err();
        assert_eq!((err.line, err.field.as_deref()), (Some(3), Some("time_s")));

        let err = read_all(&format!("{HEADER}\n0.001,1,2,3,4,5\n0.002,1,2,3\n")).unwrap_err();
        assert_eq!(err.line, Some(3));

        let err = read_all("time_s,wheelset1_accel_m_s2\n0.1,2\n").unwrap_err();
        assert_eq!(err.field.as_deref(), Some("wheelset2_accel_m_s2"));

        let err =
            read_all(&format!("{HEADER},true_csy_ns_per_m\n0.001,1,2,3,4,5,1\n")).unwrap_err();
        assert_eq!(err.field.as_deref(), Some("true_csay_ns_per_m"));

        let err = read_all(&format!(
            "{HEADER},true_csy_ns_per_m,true_csay_ns_per_m\n0.001,1,2,3,4,5,-1,2\n"
        ))
        .unwrap_err();
        assert_eq!(err.field.as_deref(), Some("true_csy_ns_per_m"));
        assert_eq!(
            read_all(&format!("{HEADER}\n0.001,1,2,3,4,inf\n"))
                .unwrap_err()
                .value
                .as_deref(),
            Some("inf")
        );
    }
}
