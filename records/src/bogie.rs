//! Bogie recordings (issue 4): the five lateral sensors of one or more bogies at 1 kHz, what
//! `sensors-replay bogie --record` and the bogie simulator write and `railmon analyze damper
//! --input` reads.
//!
//! One row per sample of one bogie, in time order:
//!
//! ```text
//! time_s[,bogie],wheelset1_accel_m_s2,wheelset2_accel_m_s2,bogie_accel_m_s2,bogie_yaw_rate_rad_s,body_accel_m_s2[,speed_m_s][,half_body_mass_kg][,true_csy_ns_per_m,true_csay_ns_per_m]
//! 0.001,1,0.213,-0.112,0.051,0.0031,0.0127,45.3,13000,16000,160000
//! 0.001,2,0.198,-0.087,0.047,0.0029,0.0131,45.3,,16000,160000
//! ```
//!
//! - `time_s`: time of the sample (s); never decreases from one row to the next, and strictly
//!   increases from one row of a bogie to the next row of the same bogie.
//! - `bogie` (optional): the bogie's id (1, 2, ...), so one file holds all bogies of a vehicle,
//!   interleaved as they were published. A file without it (the layout before several bogies
//!   were recorded, or `railmon analyze damper`'s own) holds bogie 1 only.
//! - the five sensors in the paper's order (eq. 4): lateral accelerations of the leading and
//!   trailing wheelsets, of the bogie frame, the bogie yaw rate, the lateral acceleration of
//!   the body above the bogie.
//! - `speed_m_s` (optional): the vehicle's forward speed (m/s, `0..=MAX_SPEED_M_S`), what the
//!   damper model depends on. Files written before it existed have none: their reader
//!   ([`BogieRecord::speed_m_s`] `None`) assumes the configured constant speed, with a warning.
//!   Written on every new file, after the sensors.
//! - `half_body_mass_kg` (optional): the measured mass of the body above the bogie (kg, its air
//!   springs' load, `railmon_damper::BogieSample::half_body_mass_kg`), after the speed. An
//!   absent column or an empty cell: not measured (the filter assumes the design mass). A
//!   value must be a finite positive number (its range about the design mass is the
//!   monitor's check, `mass_out_of_range`).
//! - Optional truth (simulated data): both damper coefficients (N s/m), both or neither.
//!
//! A NaN, an infinity, an empty field, a missing column, a bogie id that is not a positive
//! integer, a time that does not increase or a truncated last line is an error naming file,
//! line, field and value.
//!
//! One estimator runs on one bogie: [`BogieCsvReader::next_record`] reads a file of one bogie
//! (a row of a second bogie is an error, never silently mixed in) or, after
//! [`BogieCsvReader::only_bogie`], the rows of the chosen bogie;
//! [`BogieCsvReader::next_bogie_record`] reads every row with its bogie id.

use std::fs::File;
use std::io::Read;
use std::path::Path;

use railmon_damper::sample::MAX_SPEED_M_S;

use crate::{create_csv, finish_csv, AtomicFile, Column, CsvTable, RecordError};

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
/// The vehicle's speed (m/s), optional when reading, written after the sensors.
pub const BOGIE_SPEED_COLUMN: &str = "speed_m_s";
/// The measured body mass above the bogie (kg), optional (column and cell), after the speed.
pub const BOGIE_MASS_COLUMN: &str = "half_body_mass_kg";
/// The optional bogie id column (written after `time_s`).
pub const BOGIE_ID_COLUMN: &str = "bogie";
/// The bogie a file without a [`BOGIE_ID_COLUMN`] holds.
pub const DEFAULT_BOGIE_ID: u32 = 1;

/// One row.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BogieRecord {
    pub time_s: f64,
    /// The five sensors in the order of [`BOGIE_COLUMNS`]`[1..]`.
    pub sensors: [f64; 5],
    /// Forward speed (m/s); `None` when the file has no [`BOGIE_SPEED_COLUMN`].
    pub speed_m_s: Option<f64>,
    /// The measured body mass above the bogie (kg); `None`: no [`BOGIE_MASS_COLUMN`] or an
    /// empty cell (not measured).
    pub half_body_mass_kg: Option<f64>,
    /// `[C_sy, C_say]` (N s/m) when the file has truth.
    pub truth_ns_per_m: Option<[f64; 2]>,
}

/// Streams rows out of a bogie recording.
pub struct BogieCsvReader<R: Read> {
    table: CsvTable<R>,
    time: Column,
    bogie: Option<Column>,
    sensors: [Column; 5],
    speed: Option<Column>,
    mass: Option<Column>,
    truth: Option<[Column; 2]>,
    /// Time of the previous row, whichever bogie it was.
    previous_time_s: Option<f64>,
    /// Every bogie read so far, in order of first appearance, with its last time.
    last_time_s: Vec<(u32, f64)>,
    /// [`Self::only_bogie`]'s choice, and how many of its rows were returned.
    selected: Option<u32>,
    selected_rows: u64,
    /// Sensors and speed as recorded ([`Self::as_recorded`]).
    as_recorded: bool,
}

impl BogieCsvReader<File> {
    pub fn open(path: &Path) -> Result<Self, RecordError> {
        Self::new(CsvTable::open(path)?)
    }

    /// The bogies a recording holds, in increasing order ([`DEFAULT_BOGIE_ID`] alone for a
    /// file without a `bogie` column): one pass over the file, every row checked as
    /// [`Self::as_recorded`] reads it, so a file this accepts is one each bogie's run reads.
    pub fn bogies_in(path: &Path) -> Result<Vec<u32>, RecordError> {
        let mut reader = Self::open(path)?.as_recorded();
        if !reader.has_bogie_column() {
            return Ok(vec![DEFAULT_BOGIE_ID]);
        }
        while reader.next_bogie_record()?.is_some() {}
        let mut ids: Vec<u32> = reader.last_time_s.iter().map(|(id, _)| *id).collect();
        ids.sort_unstable();
        Ok(ids)
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
            bogie: table.optional_column(BOGIE_ID_COLUMN),
            speed: table.optional_column(BOGIE_SPEED_COLUMN),
            mass: table.optional_column(BOGIE_MASS_COLUMN),
            sensors: [
                table.column(BOGIE_COLUMNS[1])?,
                table.column(BOGIE_COLUMNS[2])?,
                table.column(BOGIE_COLUMNS[3])?,
                table.column(BOGIE_COLUMNS[4])?,
                table.column(BOGIE_COLUMNS[5])?,
            ],
            truth,
            table,
            previous_time_s: None,
            last_time_s: Vec::new(),
            selected: None,
            selected_rows: 0,
            as_recorded: false,
        })
    }

    /// Keeps the sensors and the speed as recorded (NaN, infinities, a speed beyond
    /// `MAX_SPEED_M_S`) for the estimator's plausibility check to refuse and count, as the
    /// service does (`railmon analyze damper`); the format, the bogie ids and the time are
    /// checked as without.
    pub fn as_recorded(mut self) -> Self {
        self.as_recorded = true;
        self
    }

    /// Reads only the rows of bogie `id` (1 for a file without a `bogie` column); the other
    /// rows are still checked. A file without a row of `id` is an error at its end.
    pub fn only_bogie(mut self, id: u32) -> Self {
        self.selected = Some(id);
        self
    }

    pub fn has_truth(&self) -> bool {
        self.truth.is_some()
    }

    /// Whether the file has the vehicle's speed (else the reader's user assumes one).
    pub fn has_speed(&self) -> bool {
        self.speed.is_some()
    }

    /// Whether the file names the bogie of each row (else it holds [`DEFAULT_BOGIE_ID`] only).
    pub fn has_bogie_column(&self) -> bool {
        self.bogie.is_some()
    }

    /// 1-based line of the row read last, for errors about it found by the caller.
    pub fn line(&self) -> u64 {
        self.table.line()
    }

    pub fn file(&self) -> &str {
        self.table.file()
    }

    /// The next row of the one bogie being read, `Ok(None)` at the end of the file: the bogie
    /// chosen by [`Self::only_bogie`], else the file's only bogie (a row of a second bogie is
    /// an error: one estimator must not see two bogies' samples).
    pub fn next_record(&mut self) -> Result<Option<BogieRecord>, RecordError> {
        Ok(self.next_row(true)?.map(|(_, record)| record))
    }

    /// The next row (of the bogie chosen by [`Self::only_bogie`], if any) with its bogie id,
    /// `Ok(None)` at the end of the file.
    pub fn next_bogie_record(&mut self) -> Result<Option<(u32, BogieRecord)>, RecordError> {
        self.next_row(false)
    }

    fn next_row(&mut self, one_bogie: bool) -> Result<Option<(u32, BogieRecord)>, RecordError> {
        loop {
            let Some((id, record)) = self.read_row(one_bogie && self.selected.is_none())? else {
                return match self.selected {
                    Some(id) if self.selected_rows == 0 => Err(RecordError::file(
                        self.table.file(),
                        format!("no row of bogie {id} (bogies in the file: {})", self.ids()),
                    )),
                    _ => Ok(None),
                };
            };
            if self.selected.is_none_or(|s| s == id) {
                self.selected_rows += 1;
                return Ok(Some((id, record)));
            }
        }
    }

    /// The ids read so far, for errors.
    fn ids(&self) -> String {
        let ids: Vec<String> = self
            .last_time_s
            .iter()
            .map(|(id, _)| id.to_string())
            .collect();
        match ids.is_empty() {
            true => "none".to_owned(),
            false => ids.join(", "),
        }
    }

    /// Reads and checks the next row, whichever bogie; `one_bogie`: a second bogie is an error.
    fn read_row(&mut self, one_bogie: bool) -> Result<Option<(u32, BogieRecord)>, RecordError> {
        let Some(row) = self.table.next_row()? else {
            return Ok(None);
        };
        let id = match &self.bogie {
            Some(column) => {
                let id = row
                    .u64(column)
                    .ok()
                    .and_then(|id| u32::try_from(id).ok())
                    .filter(|id| *id >= 1)
                    .ok_or_else(|| {
                        row.error(
                            column,
                            format!("not a bogie id (an integer 1..={})", u32::MAX),
                        )
                    })?;
                let other = self
                    .last_time_s
                    .first()
                    .filter(|(f, _)| one_bogie && *f != id);
                if let Some((first, _)) = other {
                    return Err(row.error(
                        column,
                        format!("a second bogie (the first rows are bogie {first}): choose one"),
                    ));
                }
                id
            }
            None => DEFAULT_BOGIE_ID,
        };
        let time_s = row.f64(&self.time)?;
        let last_of_bogie = self.last_time_s.iter().position(|(b, _)| *b == id);
        if let Some(k) = last_of_bogie {
            let last = self.last_time_s[k].1;
            if time_s <= last {
                return Err(row.error(
                    &self.time,
                    format!("time must increase (previous row of bogie {id}: {last})"),
                ));
            }
        }
        if let Some(previous) = self.previous_time_s.filter(|p| time_s < *p) {
            return Err(row.error(
                &self.time,
                format!("time goes back (previous row: {previous})"),
            ));
        }
        let mut sensors = [0.0; 5];
        for (v, c) in sensors.iter_mut().zip(&self.sensors) {
            *v = match self.as_recorded {
                true => row.f64_as_recorded(c)?,
                false => row.f64(c)?,
            };
        }
        let speed_m_s = match (&self.speed, self.as_recorded) {
            (Some(c), true) => Some(row.f64_as_recorded(c)?),
            (Some(c), false) => Some(row.f64_in(c, 0.0, MAX_SPEED_M_S, "m/s")?),
            (None, _) => None,
        };
        let half_body_mass_kg = match &self.mass {
            Some(c) if row.text(c).is_empty() => None,
            Some(c) if self.as_recorded => Some(row.f64_as_recorded(c)?),
            Some(c) => {
                let m = row.f64(c)?;
                if m <= 0.0 {
                    return Err(row.error(c, "must be positive (kg)"));
                }
                Some(m)
            }
            None => None,
        };
        let truth_ns_per_m = match &self.truth {
            Some([csy, csay]) => Some([
                row.f64_in(csy, 0.0, f64::MAX, "N s/m")?,
                row.f64_in(csay, 0.0, f64::MAX, "N s/m")?,
            ]),
            None => None,
        };
        // State changes only once the whole row is good.
        self.previous_time_s = Some(time_s);
        match last_of_bogie {
            Some(k) => self.last_time_s[k].1 = time_s,
            None => self.last_time_s.push((id, time_s)),
        }
        Ok(Some((
            id,
            BogieRecord {
                time_s,
                sensors,
                speed_m_s,
                half_body_mass_kg,
                truth_ns_per_m,
            },
        )))
    }
}

/// Writes a bogie recording.
pub struct BogieCsvWriter {
    writer: csv::Writer<AtomicFile>,
    file: String,
    with_truth: bool,
    bogie_column: bool,
}

impl BogieCsvWriter {
    /// A recording of one bogie (no `bogie` column: it is bogie 1 to a reader).
    pub fn create(path: &Path, with_truth: bool) -> Result<Self, RecordError> {
        Self::create_layout(path, with_truth, false)
    }

    /// A recording of any number of bogies, each row with its bogie id
    /// ([`Self::write_bogie`]).
    pub fn create_with_bogie_ids(path: &Path, with_truth: bool) -> Result<Self, RecordError> {
        Self::create_layout(path, with_truth, true)
    }

    fn create_layout(
        path: &Path,
        with_truth: bool,
        bogie_column: bool,
    ) -> Result<Self, RecordError> {
        let mut writer = create_csv(path)?;
        let file = path.display().to_string();
        let mut header: Vec<&str> = BOGIE_COLUMNS.to_vec();
        if bogie_column {
            header.insert(1, BOGIE_ID_COLUMN);
        }
        header.push(BOGIE_SPEED_COLUMN);
        header.push(BOGIE_MASS_COLUMN);
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
            bogie_column,
        })
    }

    /// A row of bogie [`DEFAULT_BOGIE_ID`].
    pub fn write(&mut self, record: &BogieRecord) -> Result<(), RecordError> {
        self.write_bogie(DEFAULT_BOGIE_ID, record)
    }

    /// A row of bogie `id` (any id with [`Self::create_with_bogie_ids`], else only bogie 1).
    pub fn write_bogie(&mut self, id: u32, record: &BogieRecord) -> Result<(), RecordError> {
        let mut fields: Vec<String> = Vec::with_capacity(11);
        fields.push(record.time_s.to_string());
        match self.bogie_column {
            true => fields.push(id.to_string()),
            false if id != DEFAULT_BOGIE_ID => {
                return Err(RecordError::file(
                    &self.file,
                    format!("bogie {id}: a recording without a bogie column holds bogie {DEFAULT_BOGIE_ID} only"),
                ))
            }
            false => {}
        }
        fields.extend(record.sensors.iter().map(|v| v.to_string()));
        let speed = record.speed_m_s.ok_or_else(|| {
            RecordError::file(&self.file, "a row without speed_m_s (every row needs it)")
        })?;
        fields.push(speed.to_string());
        fields.push(
            record
                .half_body_mass_kg
                .map_or(String::new(), |m| m.to_string()),
        );
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

    /// Completes the file and puts it in place (until then an existing file is untouched).
    pub fn finish(self) -> Result<(), RecordError> {
        finish_csv(self.writer)
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
                speed_m_s: Some(45.3),
                half_body_mass_kg: Some(13000.0),
                truth_ns_per_m: Some([16e3, 160e3]),
            },
            BogieRecord {
                time_s: 0.002,
                sensors: [1e-17, 2.5, -3.0, 0.0, 1.0 / 3.0],
                speed_m_s: Some(0.0),
                half_body_mass_kg: None,
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

    /// Without a `speed_m_s` column every row has none (the caller assumes its configured
    /// speed); with it, each row's speed, range-checked and named on error.
    #[test]
    fn speed_column_is_optional_and_checked() {
        let rows = read_all(&format!("{HEADER}\n0.001,1,2,3,4,5\n")).unwrap();
        assert_eq!(rows[0].speed_m_s, None);
        let header_only = format!("{HEADER}\n");
        let r = BogieCsvReader::from_reader("b.csv", header_only.as_bytes()).unwrap();
        assert!(!r.has_speed());
        let with = format!("{HEADER},speed_m_s\n0.001,1,2,3,4,5,12.5\n0.002,1,2,3,4,5,0\n");
        let rows = read_all(&with).unwrap();
        assert_eq!(
            rows.iter().map(|r| r.speed_m_s).collect::<Vec<_>>(),
            [Some(12.5), Some(0.0)]
        );
        for bad in ["NaN", "-1", "151", ""] {
            let err =
                read_all(&format!("{HEADER},speed_m_s\n0.001,1,2,3,4,5,{bad}\n")).unwrap_err();
            assert_eq!(
                (err.line, err.field.as_deref()),
                (Some(2), Some("speed_m_s")),
                "{bad}: {err}"
            );
        }
    }

    /// Without a `half_body_mass_kg` column, or with an empty cell, no mass; a value must be
    /// a finite positive number, else file, line, field and value (as recorded: kept for the
    /// monitor to refuse and count).
    #[test]
    fn mass_column_is_optional_per_column_and_cell_and_checked() {
        let rows = read_all(&format!("{HEADER},speed_m_s\n0.001,1,2,3,4,5,1\n")).unwrap();
        assert_eq!(rows[0].half_body_mass_kg, None);
        let with = format!(
            "{HEADER},speed_m_s,half_body_mass_kg\n0.001,1,2,3,4,5,1,15600.5\n0.002,1,2,3,4,5,1,\n"
        );
        let rows = read_all(&with).unwrap();
        assert_eq!(
            rows.iter().map(|r| r.half_body_mass_kg).collect::<Vec<_>>(),
            [Some(15600.5), None]
        );
        for bad in ["NaN", "-1", "0", "x", "inf"] {
            let err = read_all(&format!(
                "{HEADER},half_body_mass_kg\n0.001,1,2,3,4,5,13000\n0.002,1,2,3,4,5,{bad}\n"
            ))
            .unwrap_err();
            assert_eq!(
                (err.line, err.field.as_deref(), err.value.as_deref()),
                (Some(3), Some("half_body_mass_kg"), Some(bad)),
                "{bad}: {err}"
            );
            assert!(err.to_string().starts_with("bogie.csv:3:"), "{err}");
        }
        let text = format!("{HEADER},half_body_mass_kg\n0.001,1,2,3,4,5,-1\n");
        let mut r = BogieCsvReader::from_reader("b.csv", text.as_bytes())
            .unwrap()
            .as_recorded();
        assert_eq!(
            r.next_record().unwrap().unwrap().half_body_mass_kg,
            Some(-1.0)
        );
    }

    fn record(time_s: f64, k: f64) -> BogieRecord {
        BogieRecord {
            time_s,
            sensors: [0.1 * k, -0.2 * k, 1e-17 * k, 0.004, 1.0 / (3.0 + k)],
            speed_m_s: Some(30.0 + k),
            half_body_mass_kg: (k > 1.0).then_some(13000.0 + k),
            truth_ns_per_m: Some([16e3, 160e3 * (1.0 - 0.01 * k)]),
        }
    }

    /// Every row of a file with its bogie id.
    fn read_bogies(path: &Path) -> Vec<(u32, BogieRecord)> {
        let mut r = BogieCsvReader::open(path).unwrap();
        let mut out = vec![];
        while let Some(rec) = r.next_bogie_record().unwrap() {
            out.push(rec);
        }
        out
    }

    #[test]
    fn two_bogies_round_trip_and_one_bogie_is_read_at_a_time() {
        let dir = std::env::temp_dir().join(format!("railmon-bogies-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("bogies.csv");
        // Interleaved as the replay publishes them: both bogies at each time.
        let rows: Vec<(u32, BogieRecord)> = (1..=3)
            .flat_map(|k| [1, 2].map(|id| (id, record(1e-3 * k as f64, (k * id) as f64))))
            .collect();
        let mut w = BogieCsvWriter::create_with_bogie_ids(&path, true).unwrap();
        for (id, r) in &rows {
            w.write_bogie(*id, r).unwrap();
        }
        w.finish().unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(
            text.starts_with("time_s,bogie,wheelset1_accel_m_s2,"),
            "{text}"
        );
        assert_eq!(read_bogies(&path), rows);

        for id in [1, 2] {
            let mut r = BogieCsvReader::open(&path).unwrap().only_bogie(id);
            assert!(r.has_bogie_column() && r.has_truth());
            for (_, want) in rows.iter().filter(|(b, _)| *b == id) {
                assert_eq!(r.next_record().unwrap().as_ref(), Some(want));
            }
            assert_eq!(r.next_record().unwrap(), None);
        }
        // Without a choice, the second bogie's first row is an error, not a mixed-in sample.
        let mut r = BogieCsvReader::open(&path).unwrap();
        assert_eq!(r.next_record().unwrap(), Some(rows[0].1));
        let err = r.next_record().unwrap_err();
        assert_eq!(
            (err.line, err.field.as_deref(), err.value.as_deref()),
            (Some(3), Some("bogie"), Some("2"))
        );
        let err = BogieCsvReader::open(&path)
            .unwrap()
            .only_bogie(3)
            .next_record()
            .unwrap_err();
        assert!(
            err.reason
                .contains("no row of bogie 3 (bogies in the file: 1, 2)"),
            "{err}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_file_without_a_bogie_column_is_bogie_1() {
        let text = format!("{HEADER}\n0.001,1,2,3,4,5\n0.002,6,7,8,9,10\n");
        let mut r = BogieCsvReader::from_reader("old.csv", text.as_bytes()).unwrap();
        assert!(!r.has_bogie_column() && !r.has_truth());
        let (id, first) = r.next_bogie_record().unwrap().unwrap();
        assert_eq!(
            (id, first.time_s, first.sensors),
            (1, 0.001, [1.0, 2.0, 3.0, 4.0, 5.0])
        );
        assert_eq!(r.next_bogie_record().unwrap().map(|(id, _)| id), Some(1));
        assert_eq!(r.next_bogie_record().unwrap(), None);

        let mut r = BogieCsvReader::from_reader("old.csv", text.as_bytes())
            .unwrap()
            .only_bogie(1);
        assert_eq!(r.next_record().unwrap().map(|r| r.time_s), Some(0.001));
        let mut r = BogieCsvReader::from_reader("old.csv", text.as_bytes())
            .unwrap()
            .only_bogie(2);
        let err = r.next_record().unwrap_err();
        assert!(
            err.to_string()
                .starts_with("old.csv: no row of bogie 2 (bogies in the file: 1)"),
            "{err}"
        );

        // A one-bogie writer writes this layout, and only bogie 1.
        let dir = std::env::temp_dir().join(format!("railmon-bogie1-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("b.csv");
        let mut w = BogieCsvWriter::create(&path, true).unwrap();
        w.write(&record(0.001, 1.0)).unwrap();
        let err = w.write_bogie(2, &record(0.002, 1.0)).unwrap_err();
        assert!(err.reason.contains("bogie 2"), "{err}");
        w.write_bogie(1, &record(0.002, 2.0)).unwrap();
        w.finish().unwrap();
        assert_eq!(
            read_bogies(&path),
            vec![(1, record(0.001, 1.0)), (1, record(0.002, 2.0))]
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn bad_bogie_ids_and_times_name_line_field_and_value() {
        const IDS: &str = "time_s,bogie,wheelset1_accel_m_s2,wheelset2_accel_m_s2,bogie_accel_m_s2,bogie_yaw_rate_rad_s,body_accel_m_s2";
        let all = |rows: &str| -> Result<Vec<(u32, BogieRecord)>, RecordError> {
            let text = format!("{IDS}\n0.001,1,1,2,3,4,5\n{rows}");
            let mut r = BogieCsvReader::from_reader("b.csv", text.as_bytes())?;
            let mut out = vec![];
            while let Some(rec) = r.next_bogie_record()? {
                out.push(rec);
            }
            Ok(out)
        };
        for bad in ["0", "-1", "1.5", "x", "", "4294967296"] {
            let err = all(&format!("0.001,{bad},1,2,3,4,5\n")).unwrap_err();
            assert_eq!(
                (err.line, err.field.as_deref(), err.value.as_deref()),
                (Some(3), Some("bogie"), Some(bad)),
                "{bad}: {err}"
            );
        }
        // Same time on two bogies is fine; the same bogie twice at one time, or a row
        // earlier than the previous one, is not.
        assert_eq!(
            all("0.001,2,1,2,3,4,5\n0.002,1,1,2,3,4,5\n").unwrap().len(),
            3
        );
        let err = all("0.001,1,1,2,3,4,5\n").unwrap_err();
        assert_eq!((err.line, err.field.as_deref()), (Some(3), Some("time_s")));
        assert!(err.reason.contains("bogie 1"), "{err}");
        let err = all("0.002,2,1,2,3,4,5\n0.0015,1,1,2,3,4,5\n").unwrap_err();
        assert_eq!(
            (err.line, err.field.as_deref(), err.value.as_deref()),
            (Some(4), Some("time_s"), Some("0.0015"))
        );
    }
}
