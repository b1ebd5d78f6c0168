//! Vehicle recordings (issue 5): the 1 Hz channels of a car, in two layouts.
//!
//! - **railmon layout** (what `sensors-replay --record` and `railmon analyze fuel` write):
//!   `time_s,fuel_cm3_s,speed_m_s[,pedal_pct][,engine_torque_nm][,engine_speed_rpm]
//!   [,gradient_permille][,gear][,regime]`. Only `time_s` is required; absent channels are
//!   absent columns (not empty fields). `gear` is the categorical channel, an integer (a car's
//!   gear: -1 reverse, 0 neutral, 1..6; a railcar's throttle notch 0..8), `regime` a label
//!   (simulated data only).
//! - **ANL Camry layout**, as the dynamometer files ship:
//!   `Time[s],Eng_FuelFlow_Direct_DI[ccps],Dyno_Spd[mph]`. Fuel is cm^3/s already; speed is
//!   converted from mph to m/s. The first time stamp is written `-0.0`, which is 0.
//!
//! Both: a UTF-8 byte-order mark and CRLF line ends are accepted, empty lines are skipped, any
//! NaN, infinity, empty or non-numeric field is an error naming file, line, field and value,
//! and so is a time that does not increase. Drive-cycle speed traces
//! (`cycSecs,cycMps,cycGrade[,cycRoadType]`) are read by [`read_drive_cycle`].

use std::io::Read;
use std::path::Path;

use crate::{create_csv, finish_csv, CsvTable, RecordError};

/// m/s per mph (exact: 1 mph = 0.44704 m/s).
pub const M_S_PER_MPH: f64 = 0.44704;

// The sample type is the estimator's own: a recording holds exactly what the monitor consumes.
pub use railmon_fuel::VehicleSample;

/// One row of a vehicle recording: the sample (channels the source lacks are `None`) and, for
/// simulated data, the regime label written beside it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct VehicleRow {
    pub sample: VehicleSample,
    pub regime: Option<String>,
    /// 1-based line of the row in the file it was read from (the header is line 1; for rows
    /// not read from a file, the line [`write_vehicle_csv`] writes it on), so an estimator that
    /// refuses the sample can name the line.
    pub line: u64,
}

/// Which layout a file turned out to have.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VehicleLayout {
    Railmon,
    AnlCamry,
}

/// Column names of the railmon layout, in order.
pub const RAILMON_COLUMNS: [&str; 9] = [
    "time_s",
    "fuel_cm3_s",
    "speed_m_s",
    "pedal_pct",
    "engine_torque_nm",
    "engine_speed_rpm",
    "gradient_permille",
    "gear",
    "regime",
];

const CAMRY_TIME: &str = "Time[s]";
const CAMRY_FUEL: &str = "Eng_FuelFlow_Direct_DI[ccps]";
const CAMRY_SPEED: &str = "Dyno_Spd[mph]";

/// Reads a vehicle recording from a file, recognising the layout from the header.
pub fn read_vehicle_csv(path: &Path) -> Result<(VehicleLayout, Vec<VehicleRow>), RecordError> {
    let table = CsvTable::open(path)?;
    read_vehicle_table(table, Values::Finite)
}

/// As [`read_vehicle_csv`], with the values as recorded: NaN and infinite values and times
/// that do not increase are kept, for the estimator to refuse sample by sample and count as
/// the service does (`railmon analyze fuel`); the format (numbers, columns, gears) is
/// checked as there.
pub fn read_vehicle_csv_as_recorded(
    path: &Path,
) -> Result<(VehicleLayout, Vec<VehicleRow>), RecordError> {
    read_vehicle_table(CsvTable::open(path)?, Values::AsRecorded)
}

/// Whether a reader refuses implausible values itself or keeps them.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Values {
    /// Every value finite and time increasing, else an error (a replay publishes what it reads).
    Finite,
    /// Any number, any time order: the estimator's checks judge them.
    AsRecorded,
}

/// As [`read_vehicle_csv`], from any reader (`label` names it in errors).
pub fn read_vehicle_from(
    label: &str,
    reader: impl Read,
) -> Result<(VehicleLayout, Vec<VehicleRow>), RecordError> {
    read_vehicle_table(CsvTable::from_reader(label, reader)?, Values::Finite)
}

fn read_vehicle_table<R: Read>(
    mut table: CsvTable<R>,
    values: Values,
) -> Result<(VehicleLayout, Vec<VehicleRow>), RecordError> {
    let camry = table.has_column(CAMRY_TIME);
    let layout = if camry {
        VehicleLayout::AnlCamry
    } else {
        VehicleLayout::Railmon
    };
    let (time, fuel, speed) = if camry {
        (
            table.column(CAMRY_TIME)?,
            Some(table.column(CAMRY_FUEL)?),
            Some(table.column(CAMRY_SPEED)?),
        )
    } else {
        (
            table.column("time_s")?,
            table.optional_column("fuel_cm3_s"),
            table.optional_column("speed_m_s"),
        )
    };
    let optional = |name: &str| {
        if camry {
            None
        } else {
            table.optional_column(name)
        }
    };
    let (pedal, torque, rpm, gradient, gear, regime) = (
        optional("pedal_pct"),
        optional("engine_torque_nm"),
        optional("engine_speed_rpm"),
        optional("gradient_permille"),
        optional("gear"),
        optional("regime"),
    );
    let speed_factor = if camry { M_S_PER_MPH } else { 1.0 };
    let mut rows = Vec::new();
    let mut previous_time: Option<f64> = None;
    let as_recorded = values == Values::AsRecorded;
    while let Some(row) = table.next_row()? {
        let number = |c: &crate::Column| match as_recorded {
            true => row.f64_as_recorded(c),
            false => row.f64(c),
        };
        let time_s = number(&time)? + 0.0; // `-0.0 + 0.0` is `+0.0`: the Camry's first stamp.
        if !as_recorded && previous_time.is_some_and(|p| time_s <= p) {
            return Err(row.error(
                &time,
                format!(
                    "time does not increase (previous {})",
                    previous_time.unwrap_or_default()
                ),
            ));
        }
        previous_time = Some(time_s);
        let opt = |c: &Option<crate::Column>| c.as_ref().map(number).transpose();
        let gear = match &gear {
            Some(c) => Some(
                row.text(c)
                    .parse::<i32>()
                    .ok()
                    .filter(|g| (-1..=12).contains(g))
                    .ok_or_else(|| row.error(c, "not a gear (an integer in -1..=12)"))?,
            ),
            None => None,
        };
        rows.push(VehicleRow {
            sample: VehicleSample {
                time_s,
                fuel_cm3_s: opt(&fuel)?,
                speed_m_s: opt(&speed)?.map(|v| v * speed_factor),
                pedal_pct: opt(&pedal)?,
                engine_torque_nm: opt(&torque)?,
                engine_speed_rpm: opt(&rpm)?,
                gradient_permille: opt(&gradient)?,
                gear,
            },
            regime: regime.as_ref().map(|c| row.text(c).to_owned()),
            line: row.line(),
        });
    }
    if rows.is_empty() {
        return Err(RecordError::file(table.file(), "no data rows"));
    }
    Ok((layout, rows))
}

/// Writes rows in the railmon layout, with the columns of the channels the first row has.
pub fn write_vehicle_csv(path: &Path, rows: &[VehicleRow]) -> Result<(), RecordError> {
    let label = path.display().to_string();
    let err = |e: csv::Error| RecordError::file(&label, format!("write error: {e}"));
    let mut w = create_csv(path)?;
    let first = rows.first().cloned().unwrap_or_default();
    let present = [
        true,
        first.sample.fuel_cm3_s.is_some(),
        first.sample.speed_m_s.is_some(),
        first.sample.pedal_pct.is_some(),
        first.sample.engine_torque_nm.is_some(),
        first.sample.engine_speed_rpm.is_some(),
        first.sample.gradient_permille.is_some(),
        first.sample.gear.is_some(),
        first.regime.is_some(),
    ];
    let header: Vec<&str> = RAILMON_COLUMNS
        .iter()
        .zip(present)
        .filter(|(_, p)| *p)
        .map(|(c, _)| *c)
        .collect();
    w.write_record(&header).map_err(err)?;
    for r in rows {
        let num = |v: Option<f64>| v.map_or(String::new(), |x| x.to_string());
        let fields = [
            r.sample.time_s.to_string(),
            num(r.sample.fuel_cm3_s),
            num(r.sample.speed_m_s),
            num(r.sample.pedal_pct),
            num(r.sample.engine_torque_nm),
            num(r.sample.engine_speed_rpm),
            num(r.sample.gradient_permille),
            r.sample.gear.map_or(String::new(), |g| g.to_string()),
            r.regime.clone().unwrap_or_default(),
        ];
        let out: Vec<&String> = fields
            .iter()
            .zip(present)
            .filter(|(_, p)| *p)
            .map(|(f, _)| f)
            .collect();
        w.write_record(out).map_err(err)?;
    }
    finish_csv(w)
}

/// A drive-cycle speed trace (fastsim layout: `cycSecs,cycMps,cycGrade[,cycRoadType]`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DriveCycleTrace {
    pub time_s: Vec<f64>,
    pub speed_m_s: Vec<f64>,
    pub grade_rad: Vec<f64>,
}

/// Reads a drive cycle; times must increase by 1 s (the simulator steps at 1 Hz), speeds
/// must be in [0, 100] m/s and grades in [-0.5, 0.5] rad.
pub fn read_drive_cycle(path: &Path) -> Result<DriveCycleTrace, RecordError> {
    read_drive_cycle_table(CsvTable::open(path)?)
}

/// As [`read_drive_cycle`], from any reader.
pub fn read_drive_cycle_from(
    label: &str,
    reader: impl Read,
) -> Result<DriveCycleTrace, RecordError> {
    read_drive_cycle_table(CsvTable::from_reader(label, reader)?)
}

fn read_drive_cycle_table<R: Read>(mut table: CsvTable<R>) -> Result<DriveCycleTrace, RecordError> {
    let (time, speed, grade) = (
        table.column("cycSecs")?,
        table.column("cycMps")?,
        table.column("cycGrade")?,
    );
    let mut out = DriveCycleTrace::default();
    while let Some(row) = table.next_row()? {
        let t = row.f64(&time)? + 0.0;
        let expected = out.time_s.last().map_or(t, |p| p + 1.0);
        if (t - expected).abs() > 1e-9 {
            return Err(row.error(
                &time,
                format!("expected {expected}: the trace must be at 1 Hz"),
            ));
        }
        out.time_s.push(t);
        out.speed_m_s.push(row.f64_in(&speed, 0.0, 100.0, "m/s")?);
        out.grade_rad.push(row.f64_in(&grade, -0.5, 0.5, "rad")?);
    }
    if out.time_s.is_empty() {
        return Err(RecordError::file(table.file(), "no data rows"));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camry(text: &str) -> Result<Vec<VehicleRow>, RecordError> {
        read_vehicle_from("camry.csv", text.as_bytes()).map(|(l, r)| {
            assert_eq!(l, VehicleLayout::AnlCamry);
            r
        })
    }

    #[test]
    fn camry_layout_with_bom_crlf_minus_zero_and_empty_lines() {
        let text = "\u{feff}Time[s],Eng_FuelFlow_Direct_DI[ccps],Dyno_Spd[mph]\r\n-0.0,0.023,0.0\r\n\r\n1.0,1.158,10.0\r\n";
        let rows = camry(text).unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!(
            rows[0].sample.time_s.to_bits(),
            0f64.to_bits(),
            "-0.0 is read as +0.0"
        );
        assert_eq!(rows[1].sample.fuel_cm3_s, Some(1.158));
        assert!((rows[1].sample.speed_m_s.unwrap() - 4.4704).abs() < 1e-12);
        assert_eq!(rows[0].sample.pedal_pct, None);
    }

    #[test]
    fn camry_nan_names_file_line_field_value() {
        let e = camry("Time[s],Eng_FuelFlow_Direct_DI[ccps],Dyno_Spd[mph]\n0,0.1,0\n1,NaN,0\n")
            .unwrap_err();
        assert_eq!(
            (e.line, e.field.as_deref(), e.value.as_deref()),
            (Some(3), Some(CAMRY_FUEL), Some("NaN"))
        );
        assert!(e.to_string().starts_with("camry.csv:3:"), "{e}");
    }

    #[test]
    fn camry_missing_column_and_time_going_back_are_errors() {
        let e = camry("Time[s],Dyno_Spd[mph]\n0,0\n").unwrap_err();
        assert_eq!(e.field.as_deref(), Some(CAMRY_FUEL));
        let e = camry("Time[s],Eng_FuelFlow_Direct_DI[ccps],Dyno_Spd[mph]\n0,0.1,0\n0,0.1,0\n")
            .unwrap_err();
        assert_eq!((e.line, e.field.as_deref()), (Some(3), Some(CAMRY_TIME)));
    }

    #[test]
    fn truncated_line_is_an_error() {
        let e = camry("Time[s],Eng_FuelFlow_Direct_DI[ccps],Dyno_Spd[mph]\n0,0.1,0\n1,0.2\n")
            .unwrap_err();
        assert_eq!(e.line, Some(3));
    }

    #[test]
    fn railmon_layout_round_trips() {
        let rows = vec![
            VehicleRow {
                sample: VehicleSample {
                    time_s: 0.0,
                    fuel_cm3_s: Some(0.5),
                    speed_m_s: Some(3.0),
                    pedal_pct: Some(10.0),
                    engine_torque_nm: Some(-12.5),
                    engine_speed_rpm: Some(1500.0),
                    gradient_permille: Some(4.5),
                    gear: Some(2),
                },
                regime: Some("city".into()),
                line: 2,
            },
            VehicleRow {
                sample: VehicleSample {
                    time_s: 1.0,
                    fuel_cm3_s: Some(0.0),
                    speed_m_s: Some(3.5),
                    pedal_pct: Some(0.0),
                    engine_torque_nm: Some(-20.0),
                    engine_speed_rpm: Some(1600.0),
                    gradient_permille: Some(-2.0),
                    gear: Some(0),
                },
                regime: Some("city".into()),
                line: 3,
            },
        ];
        let dir = std::env::temp_dir().join(format!("railmon-vehicle-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("v.csv");
        write_vehicle_csv(&path, &rows).unwrap();
        let (layout, back) = read_vehicle_csv(&path).unwrap();
        assert_eq!(layout, VehicleLayout::Railmon);
        assert_eq!(back, rows);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn railmon_layout_bad_gear_is_an_error() {
        let e = read_vehicle_from("v.csv", "time_s,fuel_cm3_s,gear\n0,0.1,2.5\n".as_bytes())
            .unwrap_err();
        assert_eq!(
            (e.line, e.field.as_deref(), e.value.as_deref()),
            (Some(2), Some("gear"), Some("2.5"))
        );
    }

    #[test]
    fn drive_cycle_with_bom_and_crlf() {
        let t = read_drive_cycle_from(
            "wltc.csv",
            "\u{feff}cycSecs,cycMps,cycGrade,cycRoadType\r\n0,0,0,0\r\n1,0.5,0,0\r\n".as_bytes(),
        )
        .unwrap();
        assert_eq!(t.speed_m_s, vec![0.0, 0.5]);
        let e = read_drive_cycle_from(
            "c.csv",
            "cycSecs,cycMps,cycGrade\n0,0,0\n2,1,0\n".as_bytes(),
        )
        .unwrap_err();
        assert_eq!(e.line, Some(3));
    }

    /// The real files, as they ship (`data/`, see its README).
    #[test]
    fn reads_the_shipped_files() {
        let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data");
        for (file, n) in [
            ("61811011.csv", 3378),
            ("61811013.csv", 1575),
            ("61811014.csv", 1320),
        ] {
            let (layout, rows) = read_vehicle_csv(&data.join("anl-camry-2018").join(file)).unwrap();
            assert_eq!((layout, rows.len()), (VehicleLayout::AnlCamry, n), "{file}");
            assert!(rows.iter().all(|r| r.sample.fuel_cm3_s.unwrap() >= 0.0));
        }
        for (file, n) in [
            ("udds.csv", 1370),
            ("hwfet.csv", 766),
            ("us06.csv", 601),
            ("wltc_3b.csv", 1801),
        ] {
            let t = read_drive_cycle(&data.join("drive-cycles").join(file)).unwrap();
            assert_eq!(t.speed_m_s.len(), n, "{file}");
        }
    }
}
