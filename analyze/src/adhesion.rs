//! `railmon analyze adhesion`: the drive EKFs and every adhesion-loss method (issue 2) over a
//! simulated scenario or a recorded drive CSV.
//!
//! Every method runs behind the fixed lag (`railmon_slip::fixed_lag`, as the service): the
//! values of step `t` come out at frame `t + FIXED_LAG_STEPS` (111), the run's last steps
//! drained at its end (and before a gap the EKFs relock after), so every row, score and event
//! is of the step it names.
//!
//! Writes into `--out`:
//! - `estimates.csv`: per step and drive (numbered from 1): EKF speed and torque, the truth
//!   when known, and per method the global torque `M_z^(G)` and the slip probability, all of
//!   that step; `published_step` (added with the fixed lag) the frame that published them;
//! - `table1.csv`: `method,drive,min,q1,median,q3,max,mean,std,iqr` of `M_z,i - M_z^(G)`,
//!   the paper's Table 1;
//! - `detection.csv` (when the truth is known): per method and drive, precision, recall and
//!   F1 of "probability > 0.5" against the true slip flag, and the median detection delay;
//!   then the same for the alarm rule (`railmon_slip::SlipAlarm`, what the service raises) in
//!   the `alarm_*` columns; `rule` and `alarm_rule` say which rule each group scores;
//!   `reference` (added by issue 23 item 2) what the method's last step was judged against,
//!   `group` or `train_speed`; `fixed_lag_steps` (added with the fixed lag) how many frames
//!   after its step each probability was published (scored at its step);
//! - `events.csv`: the `slip_started` / `slip_ended` events the configured method's alarm
//!   raises (the service's events on the same data): `id,kind,stream_time_s,subject,detail,
//!   step,method`, stream time `step x dt` in whole nanoseconds as on the bus, of the step
//!   the event names (111 sample periods before the frame that raised it);
//! - `drives.csv` (scenarios only): the simulated record, in the layout `--input` reads
//!   (`railmon_records::drive`), so a scenario run can be replayed from its file;
//! - PNG plots after the paper's figures 5-9 (see [`plots`]).
//!
//! The train's measured speed (a scenario's `[train_speed]`, a recording's `train_speed_m_s`
//! column) goes to every method with its frame, as the service's drive stream takes it from
//! the bus: each method's probability is then its train-speed test's for the drives the test
//! judges (`railmon_slip::MultiMethodPipeline::step_with_train_speed`), in `estimates.csv`,
//! the scores and the events alike. The test's geometry is the scenario's `[train_speed]`
//! (`gear_ratio`, `wheel_radius_m`); for `--input`, `railmon_slip::SpeedReferenceConfig`'s
//! default, the service's `drive.speed_reference` default.

pub mod plots;

use std::path::Path;

use railmon_filter::stats::Summary;
use railmon_records::drive::{DriveCsvReader, DriveCsvWriter, DriveTruth};
use railmon_records::{create_csv, finish_csv, RecordError};
use railmon_slip::fixed_lag::FIXED_LAG_STEPS;
use railmon_slip::model::idx;
use railmon_slip::{
    AdhesionMethod, AdhesionScenario, DetectionCounter, DetectionScore, DriveRanges, DriveSample,
    DriveSimulator, MultiMethodPipeline, SlipAlarmEvent, SlipError, SlipMonitorConfig,
    SpeedReference, SpeedReferenceConfig,
};

use crate::report::{create_out_dir, progress_bar, ReportError, RunArgs, RunSize};
use crate::report::{AnalysisError, Refusals, Timeline};
use railmon_records::sample_clock::{Rejection, TimeJudge, DRIVE_STALE_AFTER_MS};

/// The reasons a drive frame of a recording or scenario is refused for, the labels of the
/// service's drive stream: its sample clock's (`railmon_records::sample_clock`) and its
/// frame check's (`not_finite`, `railmon_bus::FrameError::reason`).
pub const REFUSAL_REASONS: [&str; 6] = [
    "time_backwards",
    "time_repeated",
    "time_jump",
    "period_mismatch",
    "rate_mismatch",
    "not_finite",
];

/// Run the drive EKFs and every adhesion-loss method (VB, VMP, k-means, median, temporal) over
/// a scenario or a recorded drive CSV; write estimates, Table 1, detection scores and plots.
#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    #[command(flatten)]
    pub run: RunArgs,
    /// Leave the first N steps (the EKFs locking on) out of `table1.csv`; 0 (the paper's
    /// way) takes every step. Detection is always scored over every step.
    #[arg(long, default_value_t = 0)]
    pub table1_skip_steps: usize,
}

crate::many::analysis!(AdhesionReport, AdhesionAnalysisError);

/// Why `railmon analyze adhesion` failed.
pub type AdhesionAnalysisError = AnalysisError<SlipError>;

/// Where the frames come from.
enum Source {
    Simulator(Box<DriveSimulator>),
    Recording(Box<DriveCsvReader<std::fs::File>>),
}

/// One frame: samples of every drive and, when known, the truth and the train's speed.
struct Frame {
    /// The sample time the file gives (`time_s`), if it has one.
    time_s: Option<f64>,
    /// The line of the step's first row (recordings).
    line: Option<u64>,
    samples: Vec<DriveSample>,
    truth: Option<Vec<DriveTruth>>,
    train_speed_m_s: Option<f64>,
}

impl Source {
    fn next(&mut self) -> Result<Option<Frame>, RecordError> {
        match self {
            Source::Simulator(sim) => {
                Ok(sim
                    .step_with_train_speed()
                    .map(|(samples, truth, train_speed_m_s)| Frame {
                        time_s: None,
                        line: None,
                        samples: samples.to_vec(),
                        truth: Some(truth.to_vec()),
                        train_speed_m_s,
                    }))
            }
            Source::Recording(reader) => Ok(reader.next_frame()?.map(|f| Frame {
                time_s: f.time_s,
                line: Some(f.line),
                samples: f
                    .drives
                    .iter()
                    .map(|d| DriveSample {
                        u_alpha_v: d.u_alpha_v,
                        u_beta_v: d.u_beta_v,
                        i_alpha_a: d.i_alpha_a,
                        i_beta_a: d.i_beta_a,
                    })
                    .collect(),
                truth: f.truth,
                train_speed_m_s: f.train_speed_m_s,
            })),
        }
    }
}

/// Everything the run produced, kept for the tables and plots.
#[derive(Debug, Clone)]
pub struct AdhesionRun {
    /// What was analysed (file name), for titles.
    pub name: String,
    pub n_drives: usize,
    pub dt_s: f64,
    /// `[drive][step]` EKF torque estimates.
    pub ekf_torque_nm: Vec<Vec<f64>>,
    /// `[drive][step]` true load torque and slip flag, when known.
    pub truth: Option<Vec<Vec<(f64, bool)>>>,
    /// Per method: `[step]` global torque and `[drive][step]` slip probability.
    pub methods: Vec<MethodTrace>,
    /// The configured method (the one the service runs) and its alarm's events.
    pub method: AdhesionMethod,
    pub events: Vec<EventRow>,
    /// The alarm rule, as `detection.csv` names it.
    pub alarm_rule: String,
    /// Frames refused (the service's checks, its reasons) and skipped.
    pub refused: Refusals,
    pub timeline: Timeline,
}

/// An alarm event at a step.
#[derive(Debug, Clone, PartialEq)]
pub struct EventRow {
    pub step: usize,
    pub event: SlipAlarmEvent,
}

/// Stream time of `step`, as the bus stamps it: `step x dt` in whole nanoseconds.
pub fn stream_time_s(step: usize, dt_s: f64) -> f64 {
    (step as u64 * (dt_s * 1e9).round() as u64) as f64 / 1e9
}

#[derive(Debug, Clone)]
pub struct MethodTrace {
    pub method: AdhesionMethod,
    pub global_torque_nm: Vec<f64>,
    pub slip_probability: Vec<Vec<f64>>,
    /// `[drive][step]` the alarm's slipping flag.
    pub alarm_slipping: Vec<Vec<bool>>,
    /// What the last step's probabilities were judged against.
    pub reference: SpeedReference,
}

/// A row of `table1.csv`.
#[derive(Debug, Clone, PartialEq)]
pub struct Table1Row {
    pub method: AdhesionMethod,
    /// 1-based.
    pub drive: usize,
    pub summary: Summary,
}

/// A row of `detection.csv`.
#[derive(Debug, Clone, PartialEq)]
pub struct DetectionRow {
    pub method: AdhesionMethod,
    /// What the method's last step was judged against.
    pub reference: SpeedReference,
    /// 1-based.
    pub drive: usize,
    /// "probability > 0.5".
    pub score: DetectionScore,
    /// The alarm rule's flag.
    pub alarm: DetectionScore,
}

/// The result of `run`: the tables it wrote.
#[derive(Debug, Clone)]
pub struct AdhesionReport {
    pub table1: Vec<Table1Row>,
    pub detection: Vec<DetectionRow>,
    pub n_steps: usize,
    /// Frames refused (the service's checks, its reasons) and skipped (`refused.csv`).
    pub refused: Refusals,
    /// Periods bridged and new timelines, as the service's sample clock judges the times.
    pub timeline: Timeline,
    /// Table 1 and the detection scores as the terminal shows them (`railmon analyze` prints
    /// them; the library writes nothing to stdout).
    pub tables_text: String,
}

fn input_error(path: &Path, reason: impl ToString) -> AdhesionAnalysisError {
    AdhesionAnalysisError::Input {
        file: path.display().to_string(),
        reason: reason.to_string(),
    }
}

fn read_text(path: &Path) -> Result<String, AdhesionAnalysisError> {
    railmon_records::read_text_file(path, railmon_records::MAX_SETTINGS_FILE_BYTES)
        .map_err(|e| input_error(path, format!("cannot read: {e}")))
}

fn estimator_error(path: &Path) -> impl Fn(SlipError) -> AdhesionAnalysisError + '_ {
    move |source| AdhesionAnalysisError::Estimator {
        file: path.display().to_string(),
        source,
    }
}

/// Runs the analysis the arguments ask for and writes every report file.
pub fn run(args: &Args) -> Result<AdhesionReport, AdhesionAnalysisError> {
    create_out_dir(&args.run.out)?;
    let (name, mut config, speed_reference, source, n_drives, n_steps_hint, record) =
        match (&args.run.input, &args.run.scenario) {
            (Some(path), _) => {
                let reader = DriveCsvReader::open(path, None)?.as_recorded();
                let name = path.display().to_string();
                (
                    name,
                    SlipMonitorConfig::default(),
                    SpeedReferenceConfig::default(),
                    Source::Recording(Box::new(reader)),
                    None,
                    0,
                    None,
                )
            }
            (None, Some(path)) => {
                // Its [monitor] (absent: the default, as for --input).
                let scenario = AdhesionScenario::from_toml_str(&read_text(path)?)
                    .map_err(estimator_error(path))?;
                let sim = DriveSimulator::new(&scenario).map_err(estimator_error(path))?;
                let train_speed = scenario.train_speed.as_ref();
                let writer = DriveCsvWriter::create(
                    &args.run.out.join("drives.csv"),
                    true,
                    train_speed.is_some(),
                )?;
                let name = path.display().to_string();
                let n = scenario.n_drives();
                (
                    name,
                    scenario.monitor_config(),
                    train_speed.map_or_else(SpeedReferenceConfig::default, |t| t.speed_reference()),
                    Source::Simulator(Box::new(sim)),
                    Some(n),
                    scenario.n_steps(),
                    Some(writer),
                )
            }
            (None, None) => {
                return Err(input_error(
                    Path::new("<arguments>"),
                    "give --input CSV or --scenario FILE",
                ))
            }
        };
    if let Some(path) = &args.run.config {
        config =
            SlipMonitorConfig::from_toml_str(&read_text(path)?).map_err(estimator_error(path))?;
    }
    if let Some(n) = n_drives {
        // Per drive-step, measured (`analyze adhesion --no-plots`, adhesion-seed at 200,000
        // steps, 3 and 12 drives, against 20,000): 73-88 B of peak RSS, 264 B of CSV.
        RunSize::of((n_steps_hint * n) as u64, 100, 270).check_fits(&args.run.out, "this run")?;
    }
    let run = analyse(
        &name,
        &config,
        speed_reference,
        source,
        n_drives,
        n_steps_hint,
        record,
        &args.run.out,
        args.run.strict,
    )?;
    run.refused.write_csv(&args.run.out.join("refused.csv"))?;
    let mut report = write_tables(&run, args.table1_skip_steps, &args.run.out)?;
    write_events(&run, &args.run.out)?;
    if !args.run.no_plots {
        plots::write_all(&run, &report, &args.run.out)?;
    }
    report.tables_text = tables_text(&run, &report);
    Ok(report)
}

/// Steps every frame through the EKFs and all methods, writing `estimates.csv` (and the
/// simulated record) as it goes.
#[allow(clippy::too_many_arguments)]
fn analyse(
    name: &str,
    config: &SlipMonitorConfig,
    speed_reference: SpeedReferenceConfig,
    mut source: Source,
    n_drives: Option<usize>,
    n_steps_hint: usize,
    mut record: Option<DriveCsvWriter<railmon_records::AtomicFile>>,
    out: &Path,
    strict: bool,
) -> Result<AdhesionRun, AdhesionAnalysisError> {
    let est_path = out.join("estimates.csv");
    let mut est = create_csv(&est_path)?;
    let write_err = |e: csv::Error| write_error(&est_path, e);
    let bar = progress_bar(n_steps_hint as u64, "adhesion");
    let label = name.to_owned();
    let mut pipeline: Option<MultiMethodPipeline> = None;
    let mut run = AdhesionRun {
        name: name.to_owned(),
        n_drives: n_drives.unwrap_or(0),
        dt_s: config.dt_s,
        ekf_torque_nm: Vec::new(),
        truth: None,
        methods: Vec::new(),
        method: config.method,
        events: Vec::new(),
        alarm_rule: config.alarm.describe(),
        refused: Refusals::new(&REFUSAL_REASONS),
        timeline: Timeline::default(),
    };
    // The service's drive stream clock: the estimator's period, one frame per time, at most
    // the stream's default `stale_after_ms` between frames. A file without times is stepped
    // as consecutive samples (as `sensors-replay` stamps it: frame k at k periods).
    let period_ns = (config.dt_s * 1e9).round() as u64;
    let mut clock = TimeJudge::new(period_ns, false, DRIVE_STALE_AFTER_MS);
    let mut first_refusal: Option<AdhesionAnalysisError> = None;
    let mut read = 0u64;
    let mut step = 0usize;
    // The run's step of the current pipeline's step 0 (a new timeline starts a new one).
    let mut base = 0usize;
    while let Some(frame) = source.next()? {
        let time_ns = match frame.time_s {
            Some(t) => TimeJudge::ns_of(t).ok_or_else(|| {
                let r = Rejection::new("time_backwards", "not a time a frame can carry");
                time_error(&label, frame.line, t, &r)
            })?,
            None => read * period_ns,
        };
        read += 1;
        let time_s = frame.time_s.unwrap_or(time_ns as f64 / 1e9);
        // The service's order: the frame's time first (refused, or a confirmed jump that
        // restarts the estimator), then its content.
        let refusal = match clock.time(time_ns) {
            Ok(new_timeline) => {
                let old = if new_timeline { pipeline.take() } else { None };
                if let Some(mut old) = old {
                    // The steps still behind the fixed lag are published, not dropped.
                    while old.drain().map_err(pipeline_error(&label))? {
                        publish(&old, base, &mut run, &mut est).map_err(write_err)?;
                    }
                    run.timeline.new_timelines_s.push(time_s);
                    eprintln!(
                        "railmon analyze adhesion: {label}: the sample clock jumped to {time_s} s \
                         (line {}): estimator restarted",
                        frame.line.map_or("-".to_owned(), |l| l.to_string())
                    );
                }
                refusal_of(&label, frame.line, &frame.samples)
            }
            Err(r) => Some((r.reason, time_error(&label, frame.line, time_s, &r))),
        };
        if let Some((reason, error)) = refusal {
            if strict {
                return Err(error);
            }
            run.refused.add(reason);
            first_refusal.get_or_insert(error);
            continue;
        }
        if pipeline.is_none() && step == 0 {
            // First frame: now the drive count and the presence of truth are known.
            let n = frame.samples.len();
            run.n_drives = n;
            run.ekf_torque_nm = vec![Vec::with_capacity(n_steps_hint); n];
            run.truth = frame
                .truth
                .as_ref()
                .map(|_| vec![Vec::with_capacity(n_steps_hint); n]);
            run.methods = AdhesionMethod::ALL
                .iter()
                .map(|&method| MethodTrace {
                    method,
                    global_torque_nm: Vec::with_capacity(n_steps_hint),
                    slip_probability: vec![Vec::with_capacity(n_steps_hint); n],
                    alarm_slipping: vec![Vec::with_capacity(n_steps_hint); n],
                    reference: SpeedReference::Group,
                })
                .collect();
            est.write_record(estimates_header(run.truth.is_some()))
                .map_err(write_err)?;
        }
        let pipe = match &mut pipeline {
            Some(p) => p,
            None => {
                // The first frame, or the first of a new timeline: a fresh estimator (the
                // traces go on).
                let estimator_error = |source| AdhesionAnalysisError::Estimator {
                    file: label.clone(),
                    source,
                };
                let mut p =
                    MultiMethodPipeline::new(config, run.n_drives).map_err(estimator_error)?;
                // The pipeline numbers its steps from 0: this run's step of its first.
                base = step;
                p.set_speed_reference(speed_reference)
                    .map_err(estimator_error)?;
                pipeline.insert(p)
            }
        };
        // Periods no frame covered: the EKFs are carried over them, as the service does.
        let skipped = clock.skipped_periods(time_ns);
        if skipped > 0 {
            // Before a gap the EKFs relock after, the steps behind the lag are published.
            if pipe.relocks_after(skipped) {
                while pipe.drain().map_err(pipeline_error(&label))? {
                    publish(pipe, base, &mut run, &mut est).map_err(write_err)?;
                }
            }
            pipe.bridge(skipped).map_err(pipeline_error(&label))?;
            run.timeline.skipped_periods += skipped;
        }
        if let Some(w) = record.as_mut() {
            w.write_frame(
                step as u64,
                time_ns as f64 / 1e9,
                &frame.samples,
                frame.truth.as_deref(),
                frame.train_speed_m_s,
            )?;
        }
        let published = pipe
            .step_with_train_speed(&frame.samples, frame.train_speed_m_s)
            .map_err(|source| AdhesionAnalysisError::Estimator {
                file: format!("{label}: step {step}"),
                source,
            })?;
        clock.used(time_ns);
        // The truth of this frame's step, for the estimate that names it later.
        if let (Some(truth), Some(t)) = (run.truth.as_mut(), frame.truth.as_ref()) {
            for (k, t) in t.iter().enumerate() {
                truth[k].push((t.torque_nm, t.slipping));
            }
        }
        if published {
            publish(pipe, base, &mut run, &mut est).map_err(write_err)?;
        }
        step += 1;
        bar.inc(1);
    }
    bar.finish_and_clear();
    // The end of the run: the last steps behind the fixed lag are published, not dropped.
    if let Some(pipe) = pipeline.as_mut() {
        while pipe.drain().map_err(pipeline_error(&label))? {
            publish(pipe, base, &mut run, &mut est).map_err(write_err)?;
        }
    }
    if let Some(mut error) = first_refusal.filter(|_| run.refused.total() > step as u64) {
        // Mostly refused: not glitches but another rate, other units or a broken file.
        let counts = format!(
            "{} of {read} frames refused, {}; the first",
            run.refused.total(),
            run.refused.line()
        );
        match &mut error {
            AdhesionAnalysisError::Record(r) => r.reason = format!("{counts}: {}", r.reason),
            AdhesionAnalysisError::Input { reason, .. } => *reason = format!("{counts}: {reason}"),
            _ => {}
        }
        return Err(error);
    }
    if step == 0 {
        return Err(AdhesionAnalysisError::Input {
            file: label,
            reason: "no data rows".into(),
        });
    }
    finish_csv(est)?;
    if let Some(w) = record {
        w.finish()?;
    }
    Ok(run)
}

/// An estimator error of the run named `label`.
fn pipeline_error(label: &str) -> impl Fn(SlipError) -> AdhesionAnalysisError + '_ {
    move |source| AdhesionAnalysisError::Estimator {
        file: label.to_owned(),
        source,
    }
}

/// The step `pipe` just published (`base` + its own step number: the step its values name,
/// `FIXED_LAG_STEPS` frames before the one that published it): its rows of `estimates.csv`
/// and the traces, the configured method's events dated at it.
fn publish<W: std::io::Write>(
    pipe: &MultiMethodPipeline,
    base: usize,
    run: &mut AdhesionRun,
    est: &mut csv::Writer<W>,
) -> Result<(), csv::Error> {
    let step = base + pipe.step_index() as usize;
    let published_step = step + pipe.lag_steps() as usize;
    for (k, x) in pipe.published_states().iter().enumerate() {
        let (speed, torque) = (x[idx::OMEGA], x[idx::TORQUE]);
        run.ekf_torque_nm[k].push(torque);
        let mut fields = vec![
            step.to_string(),
            (k + 1).to_string(),
            fmt(speed),
            fmt(torque),
        ];
        if let Some(truth) = &run.truth {
            let (t, slipping) = truth[k][step];
            fields.push(fmt(t));
            fields.push(u8::from(slipping).to_string());
        }
        for ((_, g), (_, p)) in pipe.global_torque_nm().zip(pipe.slip_probability()) {
            fields.push(fmt(g));
            fields.push(fmt(p[k]));
        }
        fields.push(published_step.to_string());
        est.write_record(&fields)?;
    }
    for ((((trace, (_, global)), (_, flags)), (_, probability)), (_, reference)) in run
        .methods
        .iter_mut()
        .zip(pipe.global_torque_nm())
        .zip(pipe.slipping())
        .zip(pipe.slip_probability())
        .zip(pipe.references())
    {
        trace.global_torque_nm.push(global);
        trace.reference = reference;
        for (p, &v) in trace.slip_probability.iter_mut().zip(probability) {
            p.push(v);
        }
        for (a, &f) in trace.alarm_slipping.iter_mut().zip(flags) {
            a.push(f);
        }
    }
    if let Some((_, events)) = pipe.events().find(|(m, _)| *m == run.method) {
        run.events
            .extend(events.iter().map(|&event| EventRow { step, event }));
    }
    Ok(())
}

/// A frame refused for its time as an error: `file:line: field "time_s" = "value": reason`
/// for a recording with times, the clock's words (with the time) otherwise.
fn time_error(label: &str, line: Option<u64>, time_s: f64, r: &Rejection) -> AdhesionAnalysisError {
    match line {
        Some(line) => AdhesionAnalysisError::Record(RecordError {
            file: label.to_owned(),
            line: Some(line),
            field: Some(railmon_records::drive::DRIVE_TIME_COLUMN.to_owned()),
            value: Some(time_s.to_string()),
            reason: format!("{} ({})", r.message, r.reason),
        }),
        None => input_error(
            Path::new(label),
            format!("frame at {time_s} s: {} ({})", r.message, r.reason),
        ),
    }
}

/// The service's frame checks: a NaN or infinite voltage or current refuses the frame
/// (`not_finite`, `railmon_bus::DriveFrame::checked_drives`), so does a value beyond the
/// default plausible magnitudes (`out_of_range`, [`DriveRanges`]: currents in mA); the error
/// names the step's line (the drive's row), field and value.
fn refusal_of(
    label: &str,
    line: Option<u64>,
    samples: &[DriveSample],
) -> Option<(&'static str, AdhesionAnalysisError)> {
    let non_finite = samples.iter().enumerate().find_map(|(k, d)| {
        let (field, value) = d.first_non_finite()?;
        let why = format!("drive {}: not a finite number (not_finite)", k + 1);
        Some(("not_finite", k, field, value, why))
    });
    let beyond = || {
        DriveRanges::default().first_beyond(samples).map(|r| {
            let why = format!(
                "drive {}: beyond +-{} (the service's drive.{}; wrong units?) (out_of_range)",
                r.drive + 1,
                r.max,
                r.key
            );
            ("out_of_range", r.drive, r.field, r.value, why)
        })
    };
    let (reason, k, field, value, why) = non_finite.or_else(beyond)?;
    let error = match line {
        Some(line) => AdhesionAnalysisError::Record(RecordError {
            file: label.to_owned(),
            // Rows of a step are consecutive, drive 1 first.
            line: Some(line + k as u64),
            field: Some(field.to_owned()),
            value: Some(value.to_string()),
            reason: why,
        }),
        None => input_error(Path::new(label), format!("{field} = {value}: {why}")),
    };
    Some((reason, error))
}

fn write_error(path: &Path, e: impl std::fmt::Display) -> ReportError {
    ReportError::new(path, format!("write error: {e}"))
}

fn fmt(v: f64) -> String {
    format!("{v:.6}")
}

fn estimates_header(with_truth: bool) -> Vec<String> {
    let mut h: Vec<String> = ["step", "drive", "ekf_speed_rad_s", "ekf_torque_nm"]
        .map(String::from)
        .to_vec();
    if with_truth {
        h.extend(["true_torque_nm", "true_slipping"].map(String::from));
    }
    for m in AdhesionMethod::ALL {
        h.push(format!("{m}_global_torque_nm"));
        h.push(format!("{m}_slip_probability"));
    }
    // Added with the fixed lag: the frame that published this step's values (`step` +
    // FIXED_LAG_STEPS in a run, fewer for the last steps, drained at its end or a long gap).
    h.push("published_step".to_owned());
    h
}

/// Table 1 (statistics of `M_z,i - M_z^(G)` from step `skip` on) and the detection scores.
pub fn tables(run: &AdhesionRun, skip: usize) -> AdhesionReport {
    let mut table1 = Vec::new();
    let mut detection = Vec::new();
    for trace in &run.methods {
        for k in 0..run.n_drives {
            let diff: Vec<f64> = run.ekf_torque_nm[k]
                .iter()
                .zip(&trace.global_torque_nm)
                .skip(skip)
                .map(|(x, g)| x - g)
                .collect();
            if let Some(summary) = Summary::of(&diff) {
                table1.push(Table1Row {
                    method: trace.method,
                    drive: k + 1,
                    summary,
                });
            }
            if let Some(truth) = &run.truth {
                let mut counter = DetectionCounter::default();
                let mut alarm = DetectionCounter::default();
                for (step, ((&p, &flag), &(_, slipping))) in trace.slip_probability[k]
                    .iter()
                    .zip(&trace.alarm_slipping[k])
                    .zip(&truth[k])
                    .enumerate()
                {
                    counter.push(step, p > 0.5, slipping);
                    alarm.push(step, flag, slipping);
                }
                detection.push(DetectionRow {
                    method: trace.method,
                    reference: trace.reference,
                    drive: k + 1,
                    score: counter.score(),
                    alarm: alarm.score(),
                });
            }
        }
    }
    AdhesionReport {
        table1,
        detection,
        n_steps: run.ekf_torque_nm.first().map_or(0, Vec::len),
        refused: run.refused.clone(),
        timeline: run.timeline.clone(),
        tables_text: String::new(),
    }
}

fn write_tables(
    run: &AdhesionRun,
    skip: usize,
    out: &Path,
) -> Result<AdhesionReport, AdhesionAnalysisError> {
    let report = tables(run, skip);
    let path = out.join("table1.csv");
    let mut w = create_csv(&path)?;
    w.write_record([
        "method", "drive", "min", "q1", "median", "q3", "max", "mean", "std", "iqr",
    ])
    .map_err(|e| write_error(&path, e))?;
    for r in &report.table1 {
        let s = r.summary;
        let fields = [s.min, s.q1, s.median, s.q3, s.max, s.mean, s.std, s.iqr].map(fmt);
        let mut row = vec![r.method.to_string(), r.drive.to_string()];
        row.extend(fields);
        w.write_record(&row).map_err(|e| write_error(&path, e))?;
    }
    finish_csv(w)?;
    if run.truth.is_some() {
        let path = out.join("detection.csv");
        let mut w = create_csv(&path)?;
        w.write_record([
            "method",
            "drive",
            "precision",
            "recall",
            "f1",
            "median_delay_steps",
            "true_pos",
            "false_pos",
            "false_neg",
            "events",
            "missed_events",
            // Added by issue 8 (the columns above keep their names and meaning).
            "rule",
            "alarm_rule",
            "alarm_precision",
            "alarm_recall",
            "alarm_f1",
            "alarm_median_delay_steps",
            "alarm_true_pos",
            "alarm_false_pos",
            "alarm_false_neg",
            "alarm_missed_events",
            // Added by issue 10: the alarm's episodes (`slip_started` events) and those with
            // no true slip step in them.
            "alarm_episodes",
            "alarm_false_episodes",
            // Added by issue 23 item 2: `group` or `train_speed`, the method's last step's.
            "reference",
            // Added with the fixed lag: every step is scored at the step its probability
            // names, published this many frames after it.
            "fixed_lag_steps",
        ])
        .map_err(|e| write_error(&path, e))?;
        for r in &report.detection {
            // One score's columns, in the order of the header: the probability rule's first
            // (with its event count), the alarm rule's after the two rule names.
            let mut row = vec![r.method.to_string(), r.drive.to_string()];
            row.extend(score_columns(&r.score));
            row.extend([
                r.score.events.to_string(),
                r.score.missed_events.to_string(),
            ]);
            row.extend([PROBABILITY_RULE.to_owned(), run.alarm_rule.clone()]);
            row.extend(score_columns(&r.alarm));
            row.extend([
                r.alarm.missed_events.to_string(),
                r.alarm.detection_episodes.to_string(),
                r.alarm.false_episodes.to_string(),
                r.reference.name().to_owned(),
                FIXED_LAG_STEPS.to_string(),
            ]);
            w.write_record(&row).map_err(|e| write_error(&path, e))?;
        }
        finish_csv(w)?;
    }
    Ok(report)
}

/// precision, recall, f1, median delay, true / false positives, false negatives.
fn score_columns(s: &DetectionScore) -> [String; 7] {
    let opt = |v: Option<f64>| v.map_or(String::new(), fmt);
    [
        opt(s.precision),
        opt(s.recall),
        opt(s.f1),
        opt(s.median_delay_steps),
        s.true_pos.to_string(),
        s.false_pos.to_string(),
        s.false_neg.to_string(),
    ]
}

/// What the first score columns of `detection.csv` count as a detection.
pub const PROBABILITY_RULE: &str = "p > 0.5";

/// `events.csv`: the configured method's alarm events.
fn write_events(run: &AdhesionRun, out: &Path) -> Result<(), AdhesionAnalysisError> {
    let path = out.join("events.csv");
    let mut w = create_csv(&path)?;
    w.write_record([
        "id",
        "kind",
        "stream_time_s",
        "subject",
        "detail",
        "step",
        "method",
    ])
    .map_err(|e| write_error(&path, e))?;
    for (id, e) in run.events.iter().enumerate() {
        // The service's event detail (`SlipEventDetail`), as JSON; `{}` of an f64 is its
        // shortest round-trip form.
        let detail = format!(
            "{{\"drive\":{},\"slip_probability\":{}}}",
            e.event.drive, e.event.slip_probability
        );
        w.write_record([
            (id + 1).to_string(),
            e.event.kind.name().to_owned(),
            stream_time_s(e.step, run.dt_s).to_string(),
            e.event.drive.to_string(),
            detail,
            e.step.to_string(),
            run.method.to_string(),
        ])
        .map_err(|e| write_error(&path, e))?;
    }
    finish_csv(w)?;
    Ok(())
}

/// The Table 1 and detection tables as the terminal shows them (the binary prints them).
fn tables_text(run: &AdhesionRun, report: &AdhesionReport) -> String {
    use std::fmt::Write;
    // Writing to a String cannot fail.
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{}: {} drives, {} steps",
        run.name, run.n_drives, report.n_steps
    );
    if let Some(trace) = run.methods.iter().find(|t| t.method == run.method) {
        let _ = writeln!(
            out,
            "reference ({}, last step): {}{}",
            run.method,
            trace.reference,
            match trace.reference {
                SpeedReference::Group =>
                    " (the other drives: blind to every drive losing adhesion at once)",
                SpeedReference::TrainSpeed => " (the train's measured speed)",
            }
        );
    }
    let _ = writeln!(
        out,
        "{:<9} {:>5} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8}",
        "method", "drive", "min", "median", "max", "mean", "std", "iqr"
    );
    for r in &report.table1 {
        let s = r.summary;
        let _ = writeln!(
            out,
            "{:<9} {:>5} {:>8.2} {:>8.2} {:>8.2} {:>8.2} {:>8.2} {:>8.2}",
            r.method.to_string(),
            r.drive,
            s.min,
            s.median,
            s.max,
            s.mean,
            s.std,
            s.iqr
        );
    }
    if !report.detection.is_empty() {
        let _ = writeln!(
            out,
            "{:<9} {:>5} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9}",
            "method", "drive", "precision", "recall", "f1", "delay", "false_pos", "alarm_f1"
        );
        let opt = |v: Option<f64>| v.map_or("-".to_owned(), |x| format!("{x:.4}"));
        for r in &report.detection {
            let s = &r.score;
            let _ = writeln!(
                out,
                "{:<9} {:>5} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9}",
                r.method.to_string(),
                r.drive,
                opt(s.precision),
                opt(s.recall),
                opt(s.f1),
                opt(s.median_delay_steps),
                s.false_pos,
                opt(r.alarm.f1)
            );
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    const SEED: &str = include_str!("../../config/scenarios/adhesion-seed.toml");

    struct TempDir(PathBuf);
    impl TempDir {
        fn new(tag: &str) -> Self {
            let dir =
                std::env::temp_dir().join(format!("railmon-adhesion-{tag}-{}", std::process::id()));
            let _ = std::fs::remove_dir_all(&dir);
            std::fs::create_dir_all(&dir).unwrap();
            TempDir(dir)
        }
    }
    impl Drop for TempDir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    fn args(
        input: Option<PathBuf>,
        scenario: Option<PathBuf>,
        config: Option<PathBuf>,
        out: PathBuf,
        no_plots: bool,
    ) -> Args {
        Args {
            run: RunArgs {
                input,
                scenario,
                config,
                out,
                no_plots,
                strict: false,
            },
            table1_skip_steps: 0,
        }
    }

    #[test]
    fn seed_scenario_report_and_replay_from_its_record_agree() {
        let tmp = TempDir::new("seed");
        let scenario_path = tmp.0.join("seed.toml");
        std::fs::write(&scenario_path, SEED).unwrap();
        let out = tmp.0.join("sim");
        let report = run(&args(None, Some(scenario_path), None, out.clone(), true)).unwrap();
        assert_eq!(report.n_steps, 20_000);
        assert_eq!(report.table1.len(), 15);
        // The paper's shape: drive 1 has a large negative minimum (a drop of 20 N m), drives
        // 2-3 centre on 0.
        for r in &report.table1 {
            if r.drive == 1 {
                assert!(r.summary.min < -15.0, "{r:?}");
            } else {
                assert!(r.summary.median.abs() < 0.2 && r.summary.iqr < 0.5, "{r:?}");
            }
        }
        let temporal = |d: usize| {
            &report
                .detection
                .iter()
                .find(|r| r.method == AdhesionMethod::Temporal && r.drive == d)
                .unwrap()
                .score
        };
        assert!(temporal(1).f1.unwrap() >= 0.98);
        for name in [
            "estimates.csv",
            "table1.csv",
            "detection.csv",
            "drives.csv",
            "events.csv",
        ] {
            assert!(out.join(name).is_file(), "{name}");
        }
        // The alarm's episodes in detection.csv are its slip_started events in events.csv
        // (the configured method, temporal), drive by drive.
        let rows = |name: &str| -> Vec<csv::StringRecord> {
            let mut r = csv::Reader::from_path(out.join(name)).unwrap();
            let header = r.headers().unwrap().clone();
            std::iter::once(header)
                .chain(r.records().map(Result::unwrap))
                .collect()
        };
        let (detection, events) = (rows("detection.csv"), rows("events.csv"));
        let column = |name: &str| detection[0].iter().position(|h| h == name).unwrap();
        let (episodes, false_episodes) = (column("alarm_episodes"), column("alarm_false_episodes"));
        for row in detection.iter().filter(|r| &r[0] == "temporal") {
            let started = events
                .iter()
                .filter(|e| &e[1] == "slip_started" && e[3] == row[1])
                .count();
            assert_eq!(row[episodes], started.to_string(), "{row:?}");
            assert!(row[false_episodes].parse::<usize>().unwrap() <= started);
        }
        assert!(events.iter().any(|e| &e[1] == "slip_started"));
        let table1 = std::fs::read_to_string(out.join("table1.csv")).unwrap();
        assert!(
            table1.starts_with("method,drive,min,q1,median,q3,max,mean,std,iqr\nvb,1,"),
            "{table1}"
        );

        // Replay the record without any settings: the scenario has no [monitor], so both
        // paths run SlipMonitorConfig::default() and give the same numbers (issue 8).
        let replay_out = tmp.0.join("replay");
        let replay = run(&args(
            Some(out.join("drives.csv")),
            None,
            None,
            replay_out.clone(),
            true,
        ))
        .unwrap();
        assert_eq!(replay.table1, report.table1);
        assert_eq!(replay.detection, report.detection);
        assert_eq!(
            std::fs::read_to_string(replay_out.join("events.csv")).unwrap(),
            std::fs::read_to_string(out.join("events.csv")).unwrap()
        );
        assert_eq!(
            std::fs::read_to_string(replay_out.join("table1.csv")).unwrap(),
            table1
        );
    }

    #[test]
    fn plots_are_written() {
        let tmp = TempDir::new("plots");
        let scenario_path = tmp.0.join("short.toml");
        std::fs::write(
            &scenario_path,
            SEED.replace("n_steps = 20000", "n_steps = 1500"),
        )
        .unwrap();
        run(&args(None, Some(scenario_path), None, tmp.0.clone(), false)).unwrap();
        for name in [
            "torque_drive1.png",
            "temporal_differences.png",
            "vb_histogram_drive3.png",
            "median_slip_probability.png",
        ] {
            let bytes = std::fs::read(tmp.0.join(name)).unwrap();
            assert_eq!(&bytes[1..4], b"PNG", "{name}");
        }
    }

    /// Runs `--input` (`--strict`) on `text` and returns the error message.
    fn input_error_of(tag: &str, text: &str) -> String {
        let tmp = TempDir::new(tag);
        let path = tmp.0.join("drives.csv");
        std::fs::write(&path, text).unwrap();
        let mut a = args(Some(path.clone()), None, None, tmp.0.join("out"), true);
        a.run.strict = true;
        let err = run(&a).unwrap_err().to_string();
        assert!(!err.contains('\n'), "one line: {err}");
        assert!(
            err.contains(&path.display().to_string()),
            "names the file: {err}"
        );
        err
    }

    const GOOD: &str = "step,drive,u_alpha_v,u_beta_v,i_alpha_a,i_beta_a\n\
                        0,1,10,20,1,2\n0,2,10,20,1,2\n1,1,10,20,1,2\n1,2,10,20,1,2\n";

    #[test]
    fn bad_recordings_give_one_line_errors_naming_file_line_and_field() {
        let err = input_error_of("nan", &GOOD.replace("1,1,10,20,1,2", "1,1,10,NaN,1,2"));
        assert!(err.contains(":4: field \"u_beta_v\" = \"NaN\""), "{err}");
        let err = input_error_of("missing", &GOOD.replace(",i_alpha_a", ",i_alpha"));
        assert!(
            err.contains(":1: field \"i_alpha_a\": missing column"),
            "{err}"
        );
        let err = input_error_of("truncated", &format!("{GOOD}2,1,10"));
        assert!(err.contains(":6:") && err.contains("truncated"), "{err}");
        let err = input_error_of("range", &format!("{GOOD}2,1,10,20,1,2\n2,3,10,20,1,2\n"));
        assert!(
            err.contains(":7: field \"drive\" = \"3\": drive number out of range 1..=2"),
            "{err}"
        );
    }

    #[test]
    fn a_good_recording_without_truth_gives_table1_only() {
        let tmp = TempDir::new("notruth");
        let path = tmp.0.join("drives.csv");
        std::fs::write(&path, GOOD).unwrap();
        let out = tmp.0.join("out");
        let report = run(&args(Some(path), None, None, out.clone(), true)).unwrap();
        assert_eq!(report.n_steps, 2);
        assert!(report.detection.is_empty());
        assert!(out.join("table1.csv").is_file() && !out.join("detection.csv").exists());
    }

    #[test]
    fn a_non_finite_sample_is_counted_and_skipped_and_strict_names_it() {
        let tmp = TempDir::new("nan-skip");
        let path = tmp.0.join("drives.csv");
        let text = format!("{GOOD}2,1,10,20,1,2\n2,2,10,20,1,2\n")
            .replace("1,2,10,20,1,2", "1,2,10,20,NaN,2");
        std::fs::write(&path, text).unwrap();
        let out = tmp.0.join("out");
        let report = run(&args(Some(path), None, None, out.clone(), true)).unwrap();
        assert_eq!(report.refused.count("not_finite"), 1);
        assert_eq!(report.refused.total(), 1);
        assert_eq!(report.n_steps, 2);
        let refused = std::fs::read_to_string(out.join("refused.csv")).unwrap();
        assert!(refused.contains("not_finite,1\n"), "{refused}");
        // `--strict`: the second drive's row of step 1 (line 5) is the error.
        let err = input_error_of(
            "nan-strict",
            &GOOD.replace("1,2,10,20,1,2", "1,2,10,20,NaN,2"),
        );
        assert!(err.contains(":5: field \"i_alpha_a\" = \"NaN\""), "{err}");
    }

    #[test]
    fn currents_in_milliamperes_are_refused_as_the_service_refuses_them() {
        // Issue 26 item 4: the service refuses such a frame (`out_of_range`); analyze read
        // 8,570 N m and raised 251 slip events from a file in mA.
        let tmp = TempDir::new("ma-skip");
        let path = tmp.0.join("drives.csv");
        let text = format!("{GOOD}2,1,10,20,1,2\n2,2,10,20,1,2\n")
            .replace("1,2,10,20,1,2", "1,2,10,20,1500,2");
        std::fs::write(&path, text).unwrap();
        let out = tmp.0.join("out");
        let report = run(&args(Some(path), None, None, out.clone(), true)).unwrap();
        assert_eq!(report.refused.count("out_of_range"), 1);
        assert_eq!((report.refused.total(), report.n_steps), (1, 2));
        let err = input_error_of(
            "ma-strict",
            &GOOD.replace("1,2,10,20,1,2", "1,2,10,20,1500,2"),
        );
        assert!(
            err.contains(":5: field \"i_alpha_a\" = \"1500\"") && err.contains("out_of_range"),
            "{err}"
        );
    }

    #[test]
    fn a_lost_sample_in_a_recording_with_times_is_bridged() {
        let tmp = TempDir::new("bridge");
        let scenario_path = tmp.0.join("short.toml");
        std::fs::write(
            &scenario_path,
            SEED.replace("n_steps = 20000", "n_steps = 3000"),
        )
        .unwrap();
        let full_out = tmp.0.join("full");
        let full = run(&args(
            None,
            Some(scenario_path),
            None,
            full_out.clone(),
            true,
        ))
        .unwrap();
        assert_eq!(
            (full.timeline.skipped_periods, full.refused.total()),
            (0, 0)
        );
        // The record has the times; leave step 2000 out (a sample lost at the source).
        let record = std::fs::read_to_string(full_out.join("drives.csv")).unwrap();
        assert!(
            record.starts_with("step,time_s,drive,"),
            "{}",
            &record[..60]
        );
        let lost: String = record
            .lines()
            .filter(|l| !l.starts_with("2000,"))
            .map(|l| format!("{l}\n"))
            .collect();
        assert_eq!(lost.lines().count(), record.lines().count() - 3);
        let path = tmp.0.join("lost.csv");
        std::fs::write(&path, lost).unwrap();
        let out = tmp.0.join("lost");
        let report = run(&args(Some(path), None, None, out.clone(), true)).unwrap();
        assert_eq!(report.timeline.skipped_periods, 1);
        assert_eq!(report.refused.total(), 0);
        assert_eq!(report.n_steps, 2999);
        // Bridged, the EKFs end where the full run's do.
        let last_torques = |dir: &Path| -> Vec<f64> {
            let text = std::fs::read_to_string(dir.join("estimates.csv")).unwrap();
            let lines: Vec<&str> = text.lines().collect();
            lines[lines.len() - 3..]
                .iter()
                .map(|l| l.split(',').nth(3).unwrap().parse().unwrap())
                .collect()
        };
        let (a, b) = (last_torques(&full_out), last_torques(&out));
        for (x, y) in a.iter().zip(&b) {
            assert!((x - y).abs() < 0.05 * x.abs().max(1.0), "{a:?} {b:?}");
        }
    }
}
