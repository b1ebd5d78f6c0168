//! Traction-drive recordings (issue 2): what the drive simulator writes and
//! `railmon analyze adhesion --input` reads.
//!
//! Long layout, one row per time step and drive, drives numbered from 1 (as in the paper):
//!
//! ```text
//! step[,time_s],drive,u_alpha_v,u_beta_v,i_alpha_a,i_beta_a[,true_speed_rad_s,true_angle_rad,true_torque_nm,true_slipping][,train_speed_m_s]
//! 0,0,1,12.5,-40.1,3.2,7.9,200.0,-0.9,10.0,0,5.75
//! 0,0,2,...
//! ```
//!
//! - `step`: sample index (0, 1, 2, ... at the monitor's sampling period); every step lists
//!   drives `1..=N` in order. Without a `time_s` column steps increase by one (the samples are
//!   consecutive); with it they increase (a sample lost at the source leaves a step out).
//! - `time_s` (optional on reading, always written): the sample time of the step (s), the
//!   time the bus carried (whole nanoseconds); the same on every drive's row of a step.
//!   `railmon analyze adhesion` judges it as the service judges a frame's sample time
//!   (`crate::sample_clock`): a lost sample is bridged, data at another rate refused. Files
//!   without it are stepped as consecutive samples.
//! - `u_alpha_v, u_beta_v`: stator voltage applied over the step starting now (alpha-beta
//!   frame); `i_alpha_a, i_beta_a`: stator currents measured now.
//! - Optional truth (simulated data): electrical speed and angle, load torque, and the slip
//!   flag (`0/1`): all four or none.
//! - Optional `train_speed_m_s` (issue 23 item 2): the train's own measured speed at the step
//!   (radar, GNSS, an unpowered axle), m/s, a magnitude in
//!   [`railmon_slip::TRAIN_SPEED_RANGE_M_S`] (0..=100); the same on every drive's row of a
//!   step; an empty field: no train speed at that step. Outside the range, NaN or infinite:
//!   an error naming file, line, field and value (a sensor fault, not a speed).
//!
//! N is taken from the first step unless the caller knows it; a drive number outside
//! `1..=N`, a missing drive, a repeated or skipped step, a NaN, an infinity, an empty field, a
//! missing column or a truncated last line is an error naming file, line, field and value.

use std::fs::File;
use std::io::{Read, Write};
use std::path::Path;

// The row types are the estimator's own: a recording holds exactly what the monitor consumes.
pub use railmon_slip::{DriveSample, DriveTruth};

use crate::{create_csv, finish_csv, AtomicFile, Column, CsvTable, RecordError, Row};

/// Columns every drive recording has, in order.
pub const DRIVE_COLUMNS: [&str; 6] = [
    "step",
    "drive",
    "u_alpha_v",
    "u_beta_v",
    "i_alpha_a",
    "i_beta_a",
];
/// Truth columns of simulated recordings, in order.
pub const DRIVE_TRUTH_COLUMNS: [&str; 4] = [
    "true_speed_rad_s",
    "true_angle_rad",
    "true_torque_nm",
    "true_slipping",
];

/// The optional train-speed column (m/s).
pub const DRIVE_TRAIN_SPEED_COLUMN: &str = "train_speed_m_s";
/// The sample-time column (s): optional on reading, always written (after `step`).
pub const DRIVE_TIME_COLUMN: &str = "time_s";

/// All drives at one step.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DriveFrame {
    pub step: u64,
    /// The step's sample time (s), when the file has the `time_s` column.
    pub time_s: Option<f64>,
    /// The 1-based line of the step's first row.
    pub line: u64,
    pub drives: Vec<DriveSample>,
    /// Present when the file has the truth columns.
    pub truth: Option<Vec<DriveTruth>>,
    /// The train's measured speed at this step, m/s (the `train_speed_m_s` column, when the
    /// file has it and the field is not empty).
    pub train_speed_m_s: Option<f64>,
}

struct Columns {
    step: Column,
    time: Option<Column>,
    drive: Column,
    u_alpha: Column,
    u_beta: Column,
    i_alpha: Column,
    i_beta: Column,
    truth: Option<[Column; 4]>,
    train_speed: Option<Column>,
}

/// One parsed row.
struct ParsedRow {
    line: u64,
    step: u64,
    time_s: Option<f64>,
    drive: u64,
    measurement: DriveSample,
    truth: Option<DriveTruth>,
    train_speed_m_s: Option<f64>,
}

/// Streams frames out of a drive recording.
pub struct DriveCsvReader<R: Read> {
    table: CsvTable<R>,
    columns: Columns,
    n_drives: Option<usize>,
    /// First row of the next frame, read while finishing the previous one.
    pending: Option<ParsedRow>,
    /// The error in the row after a complete frame: reported by the next call, so the frame
    /// before a bad row is still handed out (a replay sends every good frame).
    pending_error: Option<RecordError>,
    next_step: Option<u64>,
    /// The last step read (a file with times: steps increase, by one or more).
    last_step: Option<u64>,
    /// Voltages and currents as recorded ([`Self::as_recorded`]).
    as_recorded: bool,
}

impl DriveCsvReader<File> {
    /// Opens `path`; `n_drives` when the caller knows how many drives there must be.
    pub fn open(path: &Path, n_drives: Option<usize>) -> Result<Self, RecordError> {
        Self::new(CsvTable::open(path)?, n_drives)
    }
}

impl<R: Read> DriveCsvReader<R> {
    /// From any reader; `label` names it in errors.
    pub fn from_reader(
        label: &str,
        reader: R,
        n_drives: Option<usize>,
    ) -> Result<Self, RecordError> {
        Self::new(CsvTable::from_reader(label, reader)?, n_drives)
    }

    fn new(table: CsvTable<R>, n_drives: Option<usize>) -> Result<Self, RecordError> {
        let has_truth = DRIVE_TRUTH_COLUMNS.iter().any(|c| table.has_column(c));
        let truth = if has_truth {
            // Any truth column asks for all four: a missing one is named.
            Some([
                table.column(DRIVE_TRUTH_COLUMNS[0])?,
                table.column(DRIVE_TRUTH_COLUMNS[1])?,
                table.column(DRIVE_TRUTH_COLUMNS[2])?,
                table.column(DRIVE_TRUTH_COLUMNS[3])?,
            ])
        } else {
            None
        };
        let columns = Columns {
            step: table.column("step")?,
            time: table.optional_column(DRIVE_TIME_COLUMN),
            drive: table.column("drive")?,
            u_alpha: table.column("u_alpha_v")?,
            u_beta: table.column("u_beta_v")?,
            i_alpha: table.column("i_alpha_a")?,
            i_beta: table.column("i_beta_a")?,
            truth,
            train_speed: table.optional_column(DRIVE_TRAIN_SPEED_COLUMN),
        };
        if n_drives == Some(0) {
            return Err(RecordError::file(
                table.file(),
                "the number of drives must be at least 1",
            ));
        }
        Ok(DriveCsvReader {
            table,
            columns,
            n_drives,
            pending: None,
            pending_error: None,
            next_step: None,
            last_step: None,
            as_recorded: false,
        })
    }

    /// Keeps the voltages and currents as recorded (NaN, infinities) for the caller to refuse
    /// and count, as the service refuses such a frame (`railmon analyze adhesion`); the
    /// format, the steps and the times are checked as without.
    pub fn as_recorded(mut self) -> Self {
        self.as_recorded = true;
        self
    }

    /// Whether the file has the `time_s` column.
    pub fn has_time(&self) -> bool {
        self.columns.time.is_some()
    }

    /// Whether the file has the truth columns.
    pub fn has_truth(&self) -> bool {
        self.columns.truth.is_some()
    }

    /// Whether the file has the `train_speed_m_s` column.
    pub fn has_train_speed(&self) -> bool {
        self.columns.train_speed.is_some()
    }

    /// Number of drives: known after the first frame unless given.
    pub fn n_drives(&self) -> Option<usize> {
        self.n_drives
    }

    fn parse(&mut self) -> Result<Option<ParsedRow>, RecordError> {
        let c = &self.columns;
        let Some(row) = self.table.next_row()? else {
            return Ok(None);
        };
        let truth = match &c.truth {
            Some([speed, angle, torque, slipping]) => Some(DriveTruth {
                speed_rad_s: row.f64(speed)?,
                angle_rad: row.f64(angle)?,
                torque_nm: row.f64(torque)?,
                slipping: row.bool(slipping)?,
            }),
            None => None,
        };
        let train_speed_m_s = match &c.train_speed {
            Some(column) if !row.text(column).is_empty() => {
                let (min, max) = railmon_slip::TRAIN_SPEED_RANGE_M_S;
                Some(row.f64_in(column, min, max, "m/s")?)
            }
            _ => None,
        };
        let time_s = match &c.time {
            Some(column) => Some(row.f64_in(column, 0.0, f64::MAX, "s")?),
            None => None,
        };
        let value = |column: &Column| match self.as_recorded {
            true => row.f64_as_recorded(column),
            false => row.f64(column),
        };
        Ok(Some(ParsedRow {
            line: row.line(),
            step: row.u64(&c.step)?,
            time_s,
            drive: checked_drive(&row, &c.drive, self.n_drives)?,
            measurement: DriveSample {
                u_alpha_v: value(&c.u_alpha)?,
                u_beta_v: value(&c.u_beta)?,
                i_alpha_a: value(&c.i_alpha)?,
                i_beta_a: value(&c.i_beta)?,
            },
            truth,
            train_speed_m_s,
        }))
    }

    fn row_error(
        &self,
        line: u64,
        column: &Column,
        value: impl ToString,
        reason: String,
    ) -> RecordError {
        RecordError {
            file: self.table.file().to_owned(),
            line: Some(line),
            field: Some(column.name().to_owned()),
            value: Some(value.to_string()),
            reason,
        }
    }

    /// The next frame, `Ok(None)` at the end of the file.
    pub fn next_frame(&mut self) -> Result<Option<DriveFrame>, RecordError> {
        if let Some(e) = self.pending_error.take() {
            return Err(e);
        }
        let first = match self.pending.take() {
            Some(r) => r,
            None => match self.parse()? {
                Some(r) => r,
                None => return Ok(None),
            },
        };
        match (self.next_step, self.last_step) {
            (Some(expected), _) if self.columns.time.is_none() && first.step != expected => {
                let reason = format!("expected step {expected}: steps must increase by one");
                return Err(self.row_error(first.line, &self.columns.step, first.step, reason));
            }
            (_, Some(last)) if first.step <= last => {
                let reason = format!("step {last} before: steps must increase");
                return Err(self.row_error(first.line, &self.columns.step, first.step, reason));
            }
            _ => {}
        }
        if first.drive != 1 {
            let reason = format!("step {} must start with drive 1", first.step);
            return Err(self.row_error(first.line, &self.columns.drive, first.drive, reason));
        }
        let step = first.step;
        let (time_s, line) = (first.time_s, first.line);
        let train_speed_m_s = first.train_speed_m_s;
        let mut drives = vec![first.measurement];
        let mut truth = first.truth.map(|t| vec![t]);
        loop {
            let row = match self.parse() {
                Ok(Some(row)) => row,
                Ok(None) => break,
                // Every drive of this step is in: the bad row is the next step's business.
                Err(e) if self.n_drives == Some(drives.len()) => {
                    self.pending_error = Some(e);
                    break;
                }
                Err(e) => return Err(e),
            };
            if row.step != step {
                self.pending = Some(row);
                break;
            }
            let expected = drives.len() as u64 + 1;
            if row.drive != expected {
                let reason = format!("expected drive {expected} of step {step}: drives must be listed 1..=N in order");
                return Err(self.row_error(row.line, &self.columns.drive, row.drive, reason));
            }
            if row.time_s.map(f64::to_bits) != time_s.map(f64::to_bits) {
                let column = self.columns.time.as_ref().expect("a value came from it");
                let value = row.time_s.map_or(String::new(), |v| v.to_string());
                let reason = format!(
                    "step {step}: drive 1 has {}: the time is one per step, the same on every drive's row",
                    time_s.map_or(String::new(), |v| v.to_string())
                );
                return Err(self.row_error(row.line, column, value, reason));
            }
            if row.train_speed_m_s.map(f64::to_bits) != train_speed_m_s.map(f64::to_bits) {
                let column = self
                    .columns
                    .train_speed
                    .as_ref()
                    .expect("a value came from it");
                let value = row.train_speed_m_s.map_or(String::new(), |v| v.to_string());
                let first = train_speed_m_s.map_or("empty".to_owned(), |v| v.to_string());
                let reason = format!(
                    "step {step}: drive 1 has {first}: the train speed is one per step, the same on every drive's row"
                );
                return Err(self.row_error(row.line, column, value, reason));
            }
            drives.push(row.measurement);
            if let (Some(t), Some(r)) = (truth.as_mut(), row.truth) {
                t.push(r);
            }
        }
        match self.n_drives {
            Some(n) if drives.len() != n => {
                // The first row of the next step (or the end) is where a drive is missing.
                let line = self.pending.as_ref().map_or(0, |r| r.line);
                let reason = format!("step {step} has {} drives, expected {n}", drives.len());
                let value = self.pending.as_ref().map_or(0, |r| r.drive);
                let mut e = self.row_error(line, &self.columns.drive, value, reason);
                if self.pending.is_none() {
                    e.line = None;
                    e.value = None;
                }
                return Err(e);
            }
            Some(_) => {}
            None => self.n_drives = Some(drives.len()),
        }
        self.next_step = Some(step + 1);
        self.last_step = Some(step);
        Ok(Some(DriveFrame {
            step,
            time_s,
            line,
            drives,
            truth,
            train_speed_m_s,
        }))
    }
}

fn checked_drive(
    row: &Row<'_>,
    column: &Column,
    n_drives: Option<usize>,
) -> Result<u64, RecordError> {
    let drive = row.u64(column)?;
    let max = n_drives.map_or(u64::MAX, |n| n as u64);
    if drive == 0 || drive > max {
        let range = n_drives.map_or("1..".to_owned(), |n| format!("1..={n}"));
        return Err(row.error(column, format!("drive number out of range {range}")));
    }
    Ok(drive)
}

/// Writes a drive recording frame by frame.
pub struct DriveCsvWriter<W: Write> {
    label: String,
    writer: csv::Writer<W>,
    with_truth: bool,
    with_train_speed: bool,
}

impl DriveCsvWriter<AtomicFile> {
    /// Starts `path` (in place only at [`DriveCsvWriter::finish`]); `with_truth` adds the truth
    /// columns, `with_train_speed` the `train_speed_m_s` column.
    pub fn create(
        path: &Path,
        with_truth: bool,
        with_train_speed: bool,
    ) -> Result<Self, RecordError> {
        let writer = create_csv(path)?;
        Self::new(
            &path.display().to_string(),
            writer,
            with_truth,
            with_train_speed,
        )
    }

    /// Completes the file and puts it in place (until then an existing file is untouched).
    pub fn finish(self) -> Result<(), RecordError> {
        finish_csv(self.writer)
    }
}

impl<W: Write> DriveCsvWriter<W> {
    /// Over any writer; `label` names it in errors.
    pub fn from_writer(
        label: &str,
        writer: W,
        with_truth: bool,
        with_train_speed: bool,
    ) -> Result<Self, RecordError> {
        Self::new(
            label,
            csv::Writer::from_writer(writer),
            with_truth,
            with_train_speed,
        )
    }

    fn new(
        label: &str,
        mut writer: csv::Writer<W>,
        with_truth: bool,
        with_train_speed: bool,
    ) -> Result<Self, RecordError> {
        let mut header: Vec<&str> = DRIVE_COLUMNS.to_vec();
        header.insert(1, DRIVE_TIME_COLUMN);
        if with_truth {
            header.extend(DRIVE_TRUTH_COLUMNS);
        }
        if with_train_speed {
            header.push(DRIVE_TRAIN_SPEED_COLUMN);
        }
        writer
            .write_record(&header)
            .map_err(|e| RecordError::file(label, format!("write error: {e}")))?;
        Ok(DriveCsvWriter {
            label: label.to_owned(),
            writer,
            with_truth,
            with_train_speed,
        })
    }

    /// Writes all drives of one step at its sample time `time_s` (`truth` is required when
    /// the writer has truth columns; a train speed needs the `train_speed_m_s` column, which
    /// is left empty without one).
    pub fn write_frame(
        &mut self,
        step: u64,
        time_s: f64,
        drives: &[DriveSample],
        truth: Option<&[DriveTruth]>,
        train_speed_m_s: Option<f64>,
    ) -> Result<(), RecordError> {
        if train_speed_m_s.is_some() && !self.with_train_speed {
            return Err(RecordError::file(
                &self.label,
                format!("step {step}: a train speed but no train_speed_m_s column"),
            ));
        }
        if self.with_truth && truth.is_none_or(|t| t.len() != drives.len()) {
            return Err(RecordError::file(
                &self.label,
                format!("step {step}: truth missing for the truth columns"),
            ));
        }
        for (k, d) in drives.iter().enumerate() {
            let mut fields = vec![
                step.to_string(),
                time_s.to_string(),
                (k + 1).to_string(),
                d.u_alpha_v.to_string(),
                d.u_beta_v.to_string(),
                d.i_alpha_a.to_string(),
                d.i_beta_a.to_string(),
            ];
            if let (true, Some(t)) = (self.with_truth, truth) {
                let t = t[k];
                fields.extend([
                    t.speed_rad_s.to_string(),
                    t.angle_rad.to_string(),
                    t.torque_nm.to_string(),
                    u8::from(t.slipping).to_string(),
                ]);
            }
            if self.with_train_speed {
                fields.push(train_speed_m_s.map_or(String::new(), |v| v.to_string()));
            }
            self.writer
                .write_record(&fields)
                .map_err(|e| RecordError::file(&self.label, format!("write error: {e}")))?;
        }
        Ok(())
    }

    /// Flushes and hands back the writer (a file: [`DriveCsvWriter::finish`]).
    pub fn into_inner(self) -> Result<W, RecordError> {
        self.writer
            .into_inner()
            .map_err(|e| RecordError::file(&self.label, format!("write error: {}", e.error())))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_complete_frame_before_a_bad_row_is_handed_out_first() {
        let text = "step,drive,u_alpha_v,u_beta_v,i_alpha_a,i_beta_a\n\
                    0,1,1,2,3,4\n0,2,5,6,7,8\n1,1,1,2,3,4\n1,2,5,6,7,8\n2,1,NaN,2,3,4\n";
        let mut r = DriveCsvReader::from_reader("d.csv", text.as_bytes(), None).unwrap();
        assert_eq!(r.next_frame().unwrap().unwrap().step, 0);
        assert_eq!(r.next_frame().unwrap().unwrap().step, 1);
        let err = r.next_frame().unwrap_err();
        assert_eq!(
            err.to_string(),
            "d.csv:6: field \"u_alpha_v\" = \"NaN\": not a finite number"
        );
    }

    const GOOD: &str = "step,drive,u_alpha_v,u_beta_v,i_alpha_a,i_beta_a\n\
                        0,1,1,2,3,4\n0,2,5,6,7,8\n1,1,1.5,2,3,4\n1,2,5,6,7,8.5\n";

    fn read_all(text: &str, n: Option<usize>) -> Result<Vec<DriveFrame>, RecordError> {
        let mut r = DriveCsvReader::from_reader("d.csv", text.as_bytes(), n)?;
        let mut frames = Vec::new();
        while let Some(f) = r.next_frame()? {
            frames.push(f);
        }
        Ok(frames)
    }

    #[test]
    fn reads_frames_and_infers_the_drive_count() {
        let frames = read_all(GOOD, None).unwrap();
        assert_eq!(frames.len(), 2);
        assert_eq!(frames[1].step, 1);
        assert_eq!(
            frames[1].drives[1],
            DriveSample {
                u_alpha_v: 5.0,
                u_beta_v: 6.0,
                i_alpha_a: 7.0,
                i_beta_a: 8.5
            }
        );
        assert!(frames[0].truth.is_none());
    }

    #[test]
    fn round_trip_with_truth_is_exact() {
        let drives = [
            DriveSample {
                u_alpha_v: 0.1 + 0.2,
                u_beta_v: -1e-17,
                i_alpha_a: 1.0 / 3.0,
                i_beta_a: 12345.678,
            },
            DriveSample {
                u_alpha_v: 2.0,
                u_beta_v: 3.0,
                i_alpha_a: 4.0,
                i_beta_a: 5.0,
            },
        ];
        let truth = [
            DriveTruth {
                speed_rad_s: 200.1,
                angle_rad: -3.1,
                torque_nm: 10.0,
                slipping: true,
            },
            DriveTruth {
                speed_rad_s: 199.9,
                angle_rad: 0.5,
                torque_nm: 9.5,
                slipping: false,
            },
        ];
        let mut buf = Vec::new();
        let mut w = DriveCsvWriter::from_writer("mem", &mut buf, true, false).unwrap();
        w.write_frame(0, 0.0, &drives, Some(&truth), None).unwrap();
        w.write_frame(1, 1.25e-4, &drives, Some(&truth), None)
            .unwrap();
        w.into_inner().unwrap();
        let text = String::from_utf8(buf).unwrap();
        let frames = read_all(&text, Some(2)).unwrap();
        assert_eq!(frames.len(), 2);
        assert_eq!(frames[1].drives, drives.to_vec());
        assert_eq!(frames[1].truth.as_deref(), Some(&truth[..]));
    }

    #[test]
    fn nan_names_file_line_and_field() {
        let text = GOOD.replace("1,2,5,6,7,8.5", "1,2,5,6,NaN,8.5");
        let e = read_all(&text, None).unwrap_err();
        assert_eq!(
            e.to_string(),
            "d.csv:5: field \"i_alpha_a\" = \"NaN\": not a finite number"
        );
    }

    #[test]
    fn missing_column_is_named() {
        let text = GOOD.replace(",i_beta_a", ",i_b");
        let e = read_all(&text, None).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("d.csv:1: field \"i_beta_a\": missing column"),
            "{e}"
        );
    }

    #[test]
    fn truncated_last_line_is_an_error() {
        let text = format!("{GOOD}2,1,1,2");
        let e = read_all(&text, None).unwrap_err();
        assert_eq!(e.line, Some(6));
        assert!(e.to_string().contains("truncated"), "{e}");
    }

    #[test]
    fn drive_out_of_range_is_an_error() {
        let text = GOOD.replace("1,2,5,6,7,8.5", "1,3,5,6,7,8.5");
        let e = read_all(&text, Some(2)).unwrap_err();
        assert_eq!(
            e.to_string(),
            "d.csv:5: field \"drive\" = \"3\": drive number out of range 1..=2"
        );
        // Inferred count: the second step may not have a third drive either.
        let e = read_all(&format!("{GOOD}1,3,1,1,1,1\n"), None).unwrap_err();
        assert!(
            e.to_string()
                .contains("d.csv:6: field \"drive\" = \"3\": drive number out of range 1..=2"),
            "{e}"
        );
        let e = read_all(&GOOD.replace("0,2,5", "0,0,5"), None).unwrap_err();
        assert!(
            e.to_string()
                .contains("field \"drive\" = \"0\": drive number out of range"),
            "{e}"
        );
    }

    #[test]
    fn missing_drive_and_skipped_step_are_errors() {
        let text = "step,drive,u_alpha_v,u_beta_v,i_alpha_a,i_beta_a\n0,1,1,2,3,4\n0,2,1,2,3,4\n1,1,1,2,3,4\n2,1,1,2,3,4\n";
        let e = read_all(text, None).unwrap_err();
        assert_eq!(e.line, Some(5), "{e}");
        assert!(
            e.to_string().contains("step 1 has 1 drives, expected 2"),
            "{e}"
        );
        let text = "step,drive,u_alpha_v,u_beta_v,i_alpha_a,i_beta_a\n0,1,1,2,3,4\n2,1,1,2,3,4\n";
        let e = read_all(text, None).unwrap_err();
        assert_eq!(
            e.to_string(),
            "d.csv:3: field \"step\" = \"2\": expected step 1: steps must increase by one"
        );
    }

    #[test]
    fn the_train_speed_column_is_optional_one_per_step_and_checked() {
        let drives = [DriveSample::default(); 2];
        let mut buf = Vec::new();
        let mut w = DriveCsvWriter::from_writer("mem", &mut buf, false, true).unwrap();
        w.write_frame(0, 0.0, &drives, None, Some(5.75)).unwrap();
        w.write_frame(1, 1e-3, &drives, None, None).unwrap();
        w.write_frame(2, 2e-3, &drives, None, Some(0.1 + 0.2))
            .unwrap();
        w.into_inner().unwrap();
        let text = String::from_utf8(buf).unwrap();
        assert!(text.starts_with(
            "step,time_s,drive,u_alpha_v,u_beta_v,i_alpha_a,i_beta_a,train_speed_m_s\n"
        ));
        let mut r = DriveCsvReader::from_reader("d.csv", text.as_bytes(), None).unwrap();
        assert!(r.has_train_speed());
        let speeds: Vec<Option<f64>> = std::iter::from_fn(|| r.next_frame().unwrap())
            .map(|f| f.train_speed_m_s)
            .collect();
        assert_eq!(speeds, [Some(5.75), None, Some(0.1 + 0.2)]);
        // Without the column: none, and the writer refuses to drop one.
        assert_eq!(read_all(GOOD, None).unwrap()[0].train_speed_m_s, None);
        let mut w = DriveCsvWriter::from_writer("mem", Vec::new(), false, false).unwrap();
        assert!(w.write_frame(0, 0.0, &drives, None, Some(1.0)).is_err());

        let with = |a: &str, b: &str| {
            format!(
                "step,drive,u_alpha_v,u_beta_v,i_alpha_a,i_beta_a,train_speed_m_s\n\
                 0,1,1,2,3,4,5\n0,2,5,6,7,8,5\n1,1,1,2,3,4,{a}\n1,2,5,6,7,8,{b}\n"
            )
        };
        assert_eq!(
            read_all(&with("6", "6"), None).unwrap()[1].train_speed_m_s,
            Some(6.0)
        );
        for (a, b, expected) in [
            ("-1", "-1", "d.csv:4: field \"train_speed_m_s\" = \"-1\": out of range [0, 100] m/s"),
            ("360", "360", "d.csv:4: field \"train_speed_m_s\" = \"360\": out of range [0, 100] m/s"),
            ("NaN", "NaN", "d.csv:4: field \"train_speed_m_s\" = \"NaN\": not a finite number"),
            ("inf", "inf", "d.csv:4: field \"train_speed_m_s\" = \"inf\": not a finite number"),
            ("6", "7", "d.csv:5: field \"train_speed_m_s\" = \"7\": step 1: drive 1 has 6: the train speed is one per step, the same on every drive's row"),
        ] {
            let e = read_all(&with(a, b), None).unwrap_err();
            assert_eq!(e.to_string(), expected);
        }
    }

    #[test]
    fn partial_truth_columns_are_an_error() {
        let text =
            "step,drive,u_alpha_v,u_beta_v,i_alpha_a,i_beta_a,true_torque_nm\n0,1,1,2,3,4,5\n";
        let e = read_all(text, None).unwrap_err();
        assert!(
            e.to_string()
                .contains("field \"true_speed_rad_s\": missing column"),
            "{e}"
        );
    }

    #[test]
    fn the_time_column_is_optional_one_per_step_and_lets_a_step_be_lost() {
        let drives = [DriveSample::default(); 2];
        let mut buf = Vec::new();
        let mut w = DriveCsvWriter::from_writer("mem", &mut buf, false, false).unwrap();
        w.write_frame(0, 0.0, &drives, None, None).unwrap();
        w.write_frame(1, 1.25e-4, &drives, None, None).unwrap();
        w.into_inner().unwrap();
        let text = String::from_utf8(buf).unwrap();
        let frames = read_all(&text, None).unwrap();
        let times: Vec<_> = frames.iter().map(|f| (f.step, f.time_s, f.line)).collect();
        assert_eq!(times, [(0, Some(0.0), 2), (1, Some(1.25e-4), 4)]);
        assert_eq!(read_all(GOOD, None).unwrap()[1].time_s, None);
        // With times, a lost step is the clock's business; without, an error (see above).
        let h = "step,time_s,drive,u_alpha_v,u_beta_v,i_alpha_a,i_beta_a\n";
        let lost = format!("{h}0,0,1,1,2,3,4\n2,0.00025,1,1,2,3,4\n");
        assert_eq!(read_all(&lost, None).unwrap()[1].step, 2);
        let back = format!("{h}1,0,1,1,2,3,4\n0,0.000125,1,1,2,3,4\n");
        assert_eq!(
            read_all(&back, None).unwrap_err().to_string(),
            "d.csv:3: field \"step\" = \"0\": step 1 before: steps must increase"
        );
        let two = format!("{h}0,0,1,1,2,3,4\n0,0.1,2,1,2,3,4\n");
        let e = read_all(&two, None).unwrap_err().to_string();
        assert!(
            e.starts_with("d.csv:3: field \"time_s\" = \"0.1\": step 0"),
            "{e}"
        );
        let nan_time = format!("{h}0,NaN,1,1,2,3,4\n");
        let e = read_all(&nan_time, None).unwrap_err().to_string();
        assert!(e.contains("field \"time_s\" = \"NaN\""), "{e}");
        // As recorded: a NaN current is handed out for the caller to refuse and count.
        let nan = format!("{h}0,0,1,1,2,NaN,4\n");
        let mut r = DriveCsvReader::from_reader("d.csv", nan.as_bytes(), None)
            .unwrap()
            .as_recorded();
        assert!(r.next_frame().unwrap().unwrap().drives[0]
            .i_alpha_a
            .is_nan());
    }
}
