//! `railmon analyze fuel`: the recursive mixture (issue 5) over a recorded vehicle CSV or a
//! simulated scenario, scored against persistence and a single recursive regression.
//!
//! Writes into `--out`:
//! - `predictions.csv`: per evaluated second, the measured fuel, the mixture's 0-step
//!   estimate, honest 1-step forecast and virtual sensor, the baselines, the regime
//!   probabilities and active regime (and the label, for simulated data);
//! - `summary.csv`: `method,horizon_s,rmse,mae,n` (horizon 0: estimates of the current sample);
//! - `events.csv`: the `regime_changed` events the service would raise on the same samples
//!   (`id,kind,stream_time_s,subject,detail`, detail the event's JSON fields);
//! - `regimes.csv` (labelled data only): per component its matched label, and the accuracy;
//! - `simulated.csv` (scenarios only): the simulated samples in the railmon vehicle layout;
//! - PNG plots after the paper's figures 1-3: `fuel_predictions.png` (+ a 300 s zoom),
//!   `regime_probabilities.png`, `clusters_fuel_speed.png` (+ `clusters_fuel_engine_speed.png`).

pub mod evaluate;
mod plots;
pub mod rls;

use std::path::Path;

use railmon_fuel::{FuelError, FuelMonitorConfig, RegimeName, VehicleSample, REGIME_CHANGED};
use railmon_records::vehicle::{read_vehicle_csv_as_recorded, write_vehicle_csv, VehicleRow};
use railmon_records::vehicle_scenario::simulate_vehicle_scenario;
use railmon_records::{write_csv_table, RecordError};

use crate::report::AnalysisError;
use crate::report::{create_out_dir, progress_bar, RunArgs};
pub use evaluate::{
    evaluate, Evaluation, NamedRegimeScore, PredictionRow, Refused, RegimeEvent, RegimeScore,
    ScoreRow,
};

/// Arguments of `railmon analyze fuel`.
#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    #[command(flatten)]
    pub run: RunArgs,
}

crate::many::analysis!(Evaluation, FuelAnalysisError);

/// Why `railmon analyze fuel` failed.
pub type FuelAnalysisError = AnalysisError<FuelError>;

/// Samples to analyse, with labels when simulated.
pub struct FuelInput {
    pub samples: Vec<VehicleSample>,
    pub labels: Option<(Vec<usize>, Vec<String>)>,
    pub config: FuelMonitorConfig,
    /// What the data is (file name), for titles and errors.
    pub name: String,
    /// Per sample, its 1-based line in `name` (empty: not from a file).
    pub lines: Vec<u64>,
}

fn read_text(path: &Path) -> Result<String, FuelAnalysisError> {
    railmon_records::read_text_file(path, railmon_records::MAX_SETTINGS_FILE_BYTES).map_err(|e| {
        FuelAnalysisError::Input {
            file: path.display().to_string(),
            reason: format!("cannot read: {e}"),
        }
    })
}

fn read_config(path: &Path) -> Result<FuelMonitorConfig, FuelAnalysisError> {
    let file = path.display().to_string();
    let input_error = |e: &dyn std::fmt::Display| FuelAnalysisError::Input {
        file: file.clone(),
        reason: e.to_string(),
    };
    // A `preset = "..."` key starts from that preset, as in the service's [vehicle.estimator].
    let table: toml::Table = toml::from_str(&read_text(path)?).map_err(|e| input_error(&e))?;
    let config: FuelMonitorConfig =
        railmon_settings::with_preset(table, "").map_err(|e| input_error(&e))?;
    config
        .validate()
        .map_err(|source| FuelAnalysisError::Estimator { file, source })?;
    Ok(config)
}

/// A recording as monitor samples.
pub fn samples_from_rows(rows: &[VehicleRow]) -> Vec<VehicleSample> {
    rows.iter().map(|r| r.sample).collect()
}

/// Reads a recording (labels from a `regime` column if it has one). Values are kept as
/// recorded (NaN, a time that does not increase): the estimator's checks refuse them.
pub fn load_recording(path: &Path) -> Result<FuelInput, FuelAnalysisError> {
    let (_, rows) = read_vehicle_csv_as_recorded(path)?;
    let labels = if rows.iter().all(|r| r.regime.is_some()) {
        let mut names: Vec<String> = Vec::new();
        let idx = rows
            .iter()
            .map(|r| {
                let name = r.regime.clone().unwrap_or_default();
                names.iter().position(|n| *n == name).unwrap_or_else(|| {
                    names.push(name);
                    names.len() - 1
                })
            })
            .collect();
        Some((idx, names))
    } else {
        None
    };
    Ok(FuelInput {
        samples: samples_from_rows(&rows),
        labels,
        config: FuelMonitorConfig::default(),
        name: path.file_name().map_or_else(
            || path.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        ),
        lines: rows.iter().map(|r| r.line).collect(),
    })
}

/// Runs a scenario's simulator (`railmon_records::vehicle_scenario`: drive cycles are read
/// from `drive_cycle_dir` relative to the scenario file).
pub fn simulate_scenario(path: &Path) -> Result<(FuelInput, Vec<VehicleRow>), FuelAnalysisError> {
    let run = simulate_vehicle_scenario(path)?;
    let input = FuelInput {
        samples: samples_from_rows(&run.rows),
        labels: Some((run.regimes, run.regime_names)),
        config: run.monitor,
        name: path.file_name().map_or(path.display().to_string(), |n| {
            n.to_string_lossy().into_owned()
        }),
        lines: Vec::new(),
    };
    Ok((input, run.rows))
}

/// `railmon analyze fuel`.
pub fn run(args: &Args) -> Result<Evaluation, FuelAnalysisError> {
    // Read everything first: a bad input leaves no half-written output directory.
    let (mut input, simulated) = match (&args.run.input, &args.run.scenario) {
        (Some(path), _) => (load_recording(path)?, None),
        (None, Some(path)) => {
            let (input, rows) = simulate_scenario(path)?;
            (input, Some(rows))
        }
        (None, None) => {
            return Err(FuelAnalysisError::Input {
                file: "<arguments>".into(),
                reason: "give --input CSV or --scenario FILE".into(),
            })
        }
    };
    if let Some(path) = &args.run.config {
        input.config = read_config(path)?;
    }
    create_out_dir(&args.run.out)?;
    if let Some(rows) = simulated {
        write_vehicle_csv(&args.run.out.join("simulated.csv"), &rows)?;
    }
    analyse(&input, &args.run.out, !args.run.no_plots, args.run.strict)
}

/// Evaluates `input` and writes the report files into `out`. A sample the estimator refuses
/// is counted (`refused.csv`) and skipped, or with `strict` an error naming its line.
pub fn analyse(
    input: &FuelInput,
    out: &Path,
    plots: bool,
    strict: bool,
) -> Result<Evaluation, FuelAnalysisError> {
    let bar = progress_bar(input.samples.len() as u64, "fuel");
    let labels = input
        .labels
        .as_ref()
        .map(|(l, names)| (l.as_slice(), names.as_slice()));
    let evaluation = evaluate(&input.config, &input.samples, labels, || bar.inc(1))
        .map_err(|source| refusal(input, None, source))?;
    bar.finish_and_clear();
    if let Some((index, first)) = &evaluation.first_refusal {
        let refused = evaluation.refused.total() as usize;
        // A file most of whose samples are refused is not glitches but another unit, rate
        // or layout: no answer on what is left of it.
        if strict || 2 * refused > evaluation.samples {
            let error = match first {
                Refused::Sample(e) => refusal(input, Some(*index), e.clone()),
                Refused::Time { time_s, rejection } => {
                    time_refusal(input, *index, *time_s, rejection)
                }
            };
            return Err(match strict {
                true => error,
                false => mostly_refused(error, &evaluation),
            });
        }
    }
    evaluation.refused.write_csv(&out.join("refused.csv"))?;
    let label_names: Option<&[String]> = input.labels.as_ref().map(|(_, n)| n.as_slice());
    write_predictions(&out.join("predictions.csv"), &evaluation, label_names)?;
    write_summary(&out.join("summary.csv"), &evaluation.scores)?;
    write_events(&out.join("events.csv"), &evaluation.events)?;
    if let (Some(score), Some(names)) = (&evaluation.regimes, label_names) {
        write_regimes(&out.join("regimes.csv"), score, names)?;
    }
    if let (Some(score), Some(names)) = (&evaluation.named_regimes, label_names) {
        write_named_regimes(&out.join("regime_names.csv"), score, names)?;
    }
    write_components(&out.join("components.csv"), &evaluation)?;
    if plots {
        plots::write_all(out, &input.name, &evaluation, label_names)?;
    }
    Ok(evaluation)
}

/// `error` (the first refused sample) with the counts: more than half the samples refused.
fn mostly_refused(error: FuelAnalysisError, evaluation: &Evaluation) -> FuelAnalysisError {
    let counts = format!(
        "{} of {} samples refused, {}; the first",
        evaluation.refused.total(),
        evaluation.samples,
        evaluation.refused.line()
    );
    match error {
        FuelAnalysisError::Record(mut e) => {
            e.reason = format!("{counts}: {}", e.reason);
            FuelAnalysisError::Record(e)
        }
        other => FuelAnalysisError::Input {
            file: "<samples>".into(),
            reason: format!("{counts}: {other}"),
        },
    }
}

/// The estimator's refusal of a sample (the `index`-th, or found by its time) as
/// `file:line: field "column" = "value": reason` when the sample came from a file;
/// otherwise as the estimator says it (with the time stamp).
fn refusal(input: &FuelInput, index: Option<usize>, source: FuelError) -> FuelAnalysisError {
    let index = index.or_else(|| {
        let t = source.time_s()?;
        input.samples.iter().position(|s| s.time_s == t)
    });
    let line = index.and_then(|i| input.lines.get(i).copied());
    match (line, source.field()) {
        (Some(line), Some((field, value))) => FuelAnalysisError::Record(RecordError {
            file: input.name.clone(),
            line: Some(line),
            field: Some(field.to_owned()),
            value: Some(value),
            reason: source.to_string(),
        }),
        _ => FuelAnalysisError::Estimator {
            file: input.name.clone(),
            source,
        },
    }
}

/// A sample refused for its time (the service's sample clock) as
/// `file:line: field "time_s" = "value": reason`, or with the time when not from a file.
fn time_refusal(
    input: &FuelInput,
    index: usize,
    time_s: f64,
    rejection: &railmon_records::sample_clock::Rejection,
) -> FuelAnalysisError {
    let reason = format!(
        "sample at t = {time_s} s: {} ({})",
        rejection.message, rejection.reason
    );
    match input.lines.get(index) {
        Some(&line) => FuelAnalysisError::Record(RecordError {
            file: input.name.clone(),
            line: Some(line),
            field: Some("time_s".to_owned()),
            value: Some(time_s.to_string()),
            reason,
        }),
        None => FuelAnalysisError::Input {
            file: input.name.clone(),
            reason,
        },
    }
}

fn write_predictions(
    path: &Path,
    ev: &Evaluation,
    labels: Option<&[String]>,
) -> Result<(), RecordError> {
    let mut header: Vec<String> = [
        "time_s",
        "fuel_cm3_s",
        "mixture_0step_cm3_s",
        "mixture_1step_cm3_s",
        "virtual_sensor_cm3_s",
        "single_regression_1step_cm3_s",
        "single_regression_virtual_sensor_cm3_s",
        "persistence_cm3_s",
        "active_regime",
        "regime",
        "rls_virtual_sensor_cm3_s",
        "mixture_1step_lower_90_cm3_s",
        "mixture_1step_upper_90_cm3_s",
        "virtual_sensor_lower_90_cm3_s",
        "virtual_sensor_upper_90_cm3_s",
        "active_regime_name",
        "regime_name",
    ]
    .map(String::from)
    .to_vec();
    header.extend((0..ev.components).map(|i| format!("p_regime_{i}")));
    if labels.is_some() {
        header.push("label".into());
    }
    let rows = ev.rows.iter().map(|r| {
        let mut f: Vec<String> = [
            r.time_s,
            r.fuel_cm3_s,
            r.zero_step_cm3_s,
            r.one_step_cm3_s,
            r.virtual_sensor_cm3_s,
            r.single_one_step_cm3_s,
            r.single_virtual_sensor_cm3_s,
            r.persistence_cm3_s,
        ]
        .iter()
        .map(|v| format!("{v:.6}"))
        .collect();
        f.push(r.active_regime.to_string());
        f.push(r.regime.to_string());
        f.extend(
            [
                r.rls_virtual_sensor_cm3_s,
                r.one_step_interval_cm3_s.lower,
                r.one_step_interval_cm3_s.upper,
                r.virtual_sensor_interval_cm3_s.lower,
                r.virtual_sensor_interval_cm3_s.upper,
            ]
            .iter()
            .map(|v| format!("{v:.6}")),
        );
        f.push(r.active_regime_name.to_string());
        f.push(r.regime_name.to_string());
        f.extend(r.regime_probabilities.iter().map(|p| format!("{p:.6}")));
        if let (Some(names), Some(l)) = (labels, r.label) {
            f.push(names[l].clone());
        }
        f
    });
    write_csv_table(path, &header, rows)
}

fn write_summary(path: &Path, scores: &[ScoreRow]) -> Result<(), RecordError> {
    let rows = scores.iter().map(|s| {
        vec![
            s.method.to_string(),
            s.horizon_s.to_string(),
            format!("{:.6}", s.rmse),
            format!("{:.6}", s.mae),
            s.n.to_string(),
            s.coverage_90.map_or(String::new(), |c| format!("{c:.4}")),
            s.diebold_mariano_vs_single
                .map_or(String::new(), |c| format!("{c:.3}")),
        ]
    });
    write_csv_table(
        path,
        &[
            "method",
            "horizon_s",
            "rmse",
            "mae",
            "n",
            "coverage_90",
            "diebold_mariano_vs_single",
        ],
        rows,
    )
}

/// `events.csv`: one row per event, ids from 1; `subject` is empty as in the service's
/// vehicle events (one vehicle per service); `detail` the event's fields as JSON, floats exact.
fn write_events(path: &Path, events: &[RegimeEvent]) -> Result<(), RecordError> {
    let rows = events.iter().enumerate().map(|(i, e)| {
        vec![
            (i + 1).to_string(),
            REGIME_CHANGED.to_string(),
            e.time_s.to_string(),
            String::new(),
            serde_json::to_string(&e.change).unwrap_or_default(),
        ]
    });
    write_csv_table(
        path,
        &["id", "kind", "stream_time_s", "subject", "detail"],
        rows,
    )
}

/// `regime_names.csv`: per regime name, the samples under each label for the active and the
/// reported regime (`n_<label>`, `confirmed_n_<label>`); last rows the accuracy of both.
fn write_named_regimes(
    path: &Path,
    score: &NamedRegimeScore,
    labels: &[String],
) -> Result<(), RecordError> {
    let mut header = vec!["name".to_string()];
    header.extend(labels.iter().map(|l| format!("n_{l}")));
    header.extend(labels.iter().map(|l| format!("confirmed_n_{l}")));
    let rows = RegimeName::ALL.iter().enumerate().map(|(i, name)| {
        let mut f = vec![name.to_string()];
        f.extend(score.confusion[i].iter().map(|v| v.to_string()));
        f.extend(score.confirmed_confusion[i].iter().map(|v| v.to_string()));
        f
    });
    let accuracy = |label: &str, value: f64| {
        let mut f = vec![label.to_string(), format!("{value:.4}")];
        f.extend((1..2 * labels.len()).map(|_| String::new()));
        f
    };
    let last = [
        accuracy("accuracy", score.accuracy()),
        accuracy("confirmed_accuracy", score.confirmed_accuracy()),
    ];
    write_csv_table(path, &header, rows.chain(last))
}

/// `components.csv`: each component's operating point, unique name and regime (the name
/// without qualifier) at the end of the run.
fn write_components(path: &Path, ev: &Evaluation) -> Result<(), RecordError> {
    let optional = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:.6}"));
    let rows = ev
        .operating_points
        .iter()
        .enumerate()
        .map(|(i, (p, name))| {
            vec![
                i.to_string(),
                name.to_string(),
                format!("{:.3}", p.samples),
                format!("{:.6}", p.fuel_cm3_s),
                optional(p.speed_m_s),
                optional(p.acceleration_m_s2),
                name.regime.to_string(),
            ]
        });
    write_csv_table(
        path,
        &[
            "component",
            "name",
            "samples",
            "fuel_cm3_s",
            "speed_m_s",
            "acceleration_m_s2",
            "regime",
        ],
        rows,
    )
}

fn write_regimes(path: &Path, score: &RegimeScore, names: &[String]) -> Result<(), RecordError> {
    let mut header = vec![
        "component".to_string(),
        "matched_label".into(),
        "n".into(),
        "correct".into(),
        "accuracy".into(),
    ];
    header.extend(names.iter().map(|n| format!("n_{n}")));
    let per_component = score.confusion.iter().enumerate().map(|(c, row)| {
        let n: usize = row.iter().sum();
        let correct = row[score.matched_label[c]];
        let mut f = vec![
            c.to_string(),
            names[score.matched_label[c]].clone(),
            n.to_string(),
            correct.to_string(),
            format!("{:.4}", correct as f64 / n.max(1) as f64),
        ];
        f.extend(row.iter().map(|v| v.to_string()));
        f
    });
    let mut all = vec![
        "all".to_string(),
        if score.one_to_one {
            "one_to_one"
        } else {
            "majority"
        }
        .to_string(),
        score.n.to_string(),
        score.correct.to_string(),
        format!("{:.4}", score.accuracy()),
    ];
    all.extend(names.iter().map(|_| String::new()));
    // The reported regime (confirmed over `regime_confirm_samples`), same matching.
    let mut confirmed = vec![
        "all_confirmed".to_string(),
        all[1].clone(),
        score.n.to_string(),
        score.confirmed_correct.to_string(),
        format!("{:.4}", score.confirmed_accuracy()),
    ];
    confirmed.extend(names.iter().map(|_| String::new()));
    write_csv_table(path, &header, per_component.chain([all, confirmed]))
}
