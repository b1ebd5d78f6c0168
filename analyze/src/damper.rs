//! `railmon analyze damper`: the RBPF and the EKF baseline (issue 4) over a simulated
//! scenario or a recorded bogie CSV.
//!
//! Writes into `--out`:
//! - `estimates.csv`: every `--csv-every` steps: time, per damper the RBPF mean and 90%
//!   interval, its health ratio, the EKF estimate and standard deviation, the truth when
//!   known; and the effective sample size;
//! - `summary.csv` (when the truth is known):
//!   `method,damper,truth,error_10s,error_30s,error_end,settle_s,covered_end`: relative
//!   errors `estimate / truth - 1` at 10 s, 30 s and the end; `settle_s` the time after which
//!   the estimate stays within 5% of the truth (empty if it never does); `covered_end` whether
//!   the 90% interval holds the truth at the end (RBPF: its 5%/95% quantiles; EKF: its mean
//!   +- 1.645 standard deviations);
//! - `faults.csv` (scenarios with faults): per fault, method and damper, the relative error
//!   10 s after the fault is complete and the time from then until the estimate settles
//!   within 5% for good;
//! - `events.csv`: `id,kind,stream_time_s,subject,detail`, the damper health events
//!   (`damper_degraded` / `damper_recovered`) of `railmon_damper::DamperAlarm` (`subject` =
//!   `<bogie>/<damper>`) and the bogie status events (`damper_paused` / `damper_resumed`,
//!   `damper_model_mismatch` / `damper_model_ok`) of `railmon_damper::BogieStatusWatch`
//!   (`subject` = `<bogie>`): the rules the service applies, its kinds and JSON fields;
//! - `timing.csv`: steps, particles, propagation, mean wall time of one monitor step (RBPF,
//!   EKF and the posterior summary) and the real-time factor at the sample rate, and when
//!   the EKF diverged if it did;
//! - `bogie.csv` (scenarios only): the simulated record in the layout `--input` reads
//!   (`railmon_records::bogie`), so a scenario run can be replayed from its file;
//! - PNG plots after the paper's figures 2-5 (RBPF and EKF estimates of both dampers
//!   against the truth) and of the effective sample size.
//!
//! Errors and settling times are evaluated on the `--csv-every` grid (10 ms by default).

use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use railmon_damper::gain_table::{GainTable, NodeSource};
use railmon_damper::params::checked_half_body_mass_kg;
use railmon_records::gain_cache::GainCache;

use railmon_damper::{
    BodyMass, BogieSample, BogieSimulator, BogieStatusEvent, BogieStatusWatch, DamperAlarm,
    DamperError, DamperEstimate, DamperEvent, DamperFault, DamperId, DamperMonitor,
    DamperMonitorConfig, DamperScenario, FaultKind, Propagation, Rbpf, SampleRanges,
};
use railmon_records::bogie::{BogieCsvReader, BogieCsvWriter, BogieRecord};
use railmon_records::{write_csv_table, RecordError};

use crate::report::{create_out_dir, line_plot, progress_bar, Axes, RunArgs, Series};
use crate::report::{AnalysisError, Refusals, RunSize, Timeline};
use railmon_records::sample_clock::{Rejection, TimeJudge, BOGIE_STALE_AFTER_MS};

/// Arguments of `railmon analyze damper`.
#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    #[command(flatten)]
    pub run: RunArgs,
    /// Number of particles (overrides the configuration).
    #[arg(long)]
    pub particles: Option<usize>,
    /// Per-particle filter: `steady-state` (fast, default) or `exact` (reference, slow).
    #[arg(long, value_parser = parse_propagation)]
    pub propagation: Option<Propagation>,
    /// Run only the first seconds of the scenario or recording.
    #[arg(long)]
    pub duration_s: Option<f64>,
    /// The bogie analysed: with `--input`, whose rows (a recording of several bogies holds
    /// them interleaved; a file without a `bogie` column is bogie 1); always, whose RBPF seed
    /// (`rbpf.seed + bogie - 1`, as the service seeds it) and event subject.
    #[arg(long, default_value_t = 1)]
    pub bogie: u32,
    /// Analyse every bogie of each recording, each as `--bogie` would, into its own folder
    /// `bogie-<id>` (under the input's), all of them in parallel with `--jobs`.
    #[arg(long, conflicts_with_all = ["bogie", "scenario"])]
    pub every_bogie: bool,
    /// Write a row of `estimates.csv` (and a plot point) every this many steps.
    #[arg(long, default_value_t = 10)]
    pub csv_every: usize,
    /// Keep the solved gain grids in this directory (created if needed): nodes stored there
    /// are loaded instead of solved, nodes solved are stored (`railmon damper warm-cache`
    /// fills one; the service's is `<storage.data_dir>/gain-cache`). Without it every run
    /// solves the nodes it reaches (0.3-0.5 s each).
    #[arg(long, value_name = "DIR")]
    pub gain_cache: Option<std::path::PathBuf>,
}

crate::many::analysis!(DamperReport, DamperAnalysisError;
    fn parts(&self, input: &Path) -> Result<Option<Vec<crate::many::Part>>, DamperAnalysisError> {
        if !self.every_bogie {
            return Ok(None);
        }
        let ids = BogieCsvReader::bogies_in(input)?;
        Ok(Some(
            ids.into_iter()
                .map(|id| crate::many::Part {
                    id,
                    folder: format!("bogie-{id}"),
                })
                .collect(),
        ))
    }
    fn select_part(&mut self, id: u32) {
        self.bogie = id;
    }
);

/// The gain cache as the table's [`NodeSource`]: a file refused is removed, a warning says
/// why, and the node is solved (and stored at the end of the run).
#[derive(Debug)]
struct CacheSource(GainCache);

impl NodeSource for CacheSource {
    fn fill(&self, table: &GainTable, node: usize) {
        if let Err(e) = self.0.load(table, node) {
            eprintln!("railmon analyze damper: warning: {e}");
        }
    }
}

fn parse_propagation(s: &str) -> Result<Propagation, String> {
    match s {
        "exact" => Ok(Propagation::Exact),
        "steady-state" | "steady_state" => Ok(Propagation::SteadyState),
        _ => Err(format!("unknown propagation {s:?} (exact, steady-state)")),
    }
}

/// Why `railmon analyze damper` failed.
pub type DamperAnalysisError = AnalysisError<DamperError>;

fn input_error(path: &Path, reason: impl ToString) -> DamperAnalysisError {
    DamperAnalysisError::Input {
        file: path.display().to_string(),
        reason: reason.to_string(),
    }
}

fn estimator_error(file: &str) -> impl Fn(DamperError) -> DamperAnalysisError + '_ {
    move |source| DamperAnalysisError::Estimator {
        file: file.to_owned(),
        source,
    }
}

fn read_text(path: &Path) -> Result<String, DamperAnalysisError> {
    railmon_records::read_text_file(path, railmon_records::MAX_SETTINGS_FILE_BYTES)
        .map_err(|e| input_error(path, format!("cannot read: {e}")))
}

/// One row of `summary.csv`.
#[derive(Debug, Clone, PartialEq)]
pub struct SummaryRow {
    pub method: &'static str,
    pub damper: &'static str,
    /// Truth at the end (N s/m).
    pub truth: f64,
    pub error_10s: Option<f64>,
    pub error_30s: Option<f64>,
    pub error_end: Option<f64>,
    pub settle_s: Option<f64>,
    pub covered_end: bool,
}

/// One row of `faults.csv`.
#[derive(Debug, Clone, PartialEq)]
pub struct FaultRow {
    pub method: &'static str,
    pub damper: &'static str,
    pub kind: &'static str,
    pub at_s: f64,
    /// When the fault is complete (`at_s` for a step).
    pub done_s: f64,
    pub ratio: f64,
    pub error_10s_after: Option<f64>,
    /// Time from `done_s` until the estimate stays within 5% of the truth.
    pub settle_after_s: Option<f64>,
}

/// What a run produced (also written to the output directory).
#[derive(Debug, Clone)]
pub struct DamperReport {
    pub summary: Vec<SummaryRow>,
    /// The health and status events, as the service would raise them, in its order.
    pub events: Vec<BogieEvent>,
    pub faults: Vec<FaultRow>,
    pub steps: u64,
    /// Mean wall time of one monitor step (RBPF + EKF + posterior summary).
    pub mean_step_us: f64,
    pub ekf_diverged_at_s: Option<f64>,
    /// The samples refused by the service's checks (the sample clock's, `SampleRanges`) and
    /// skipped.
    pub refused: Refusals,
    /// Periods bridged and new timelines, as the service's sample clock judges the times.
    pub timeline: Timeline,
}

/// The reasons a bogie sample is refused for, the labels of the service's bogie stream: its
/// sample clock's (`railmon_records::sample_clock`) and the estimator's
/// (`railmon_damper::DamperError::reason`; `unknown_bogie` is the service's configuration).
pub const REFUSAL_REASONS: [&str; 9] = [
    "time_backwards",
    "time_repeated",
    "time_jump",
    "period_mismatch",
    "rate_mismatch",
    "not_finite",
    "speed_out_of_range",
    "out_of_range",
    "mass_out_of_range",
];

/// One point of the estimate trace.
#[derive(Debug, Clone, Copy)]
struct TracePoint {
    time_s: f64,
    estimate: DamperEstimate,
    /// The body mass the filter ran at (`DamperMonitor::body_mass`).
    body_mass: BodyMass,
    truth: Option<[f64; 2]>,
}

enum Source {
    Simulator(Box<BogieSimulator>),
    /// A recording, and the speed assumed for a file without a `speed_m_s` column (the
    /// monitor configuration's vehicle speed).
    Recording(Box<BogieCsvReader<std::fs::File>>, f64),
}

/// A sample, its time (s) and, for simulated or recorded-with-truth data, the true
/// `[C_sy, C_say]`.
type TruthSample = (BogieSample, f64, Option<[f64; 2]>);

impl Source {
    /// The line of the recording's row read last (`None` for the simulator).
    fn line(&self) -> Option<u64> {
        match self {
            Source::Simulator(_) => None,
            Source::Recording(r, _) => Some(r.line()),
        }
    }

    /// Next sample and truth; `Ok(None)` at the end.
    fn next(&mut self) -> Result<Option<TruthSample>, DamperAnalysisError> {
        match self {
            Source::Simulator(sim) => Ok(sim.step().map(|(y, t)| {
                (
                    *y,
                    t.time_s,
                    Some([t.dampers.csy_ns_per_m, t.dampers.csay_ns_per_m]),
                )
            })),
            Source::Recording(r, assumed_speed_m_s) => Ok(r.next_record()?.map(|rec| {
                (
                    BogieSample {
                        half_body_mass_kg: rec.half_body_mass_kg,
                        ..BogieSample::from_vector(
                            &rec.sensors.into(),
                            rec.speed_m_s.unwrap_or(*assumed_speed_m_s),
                        )
                    },
                    rec.time_s,
                    rec.truth_ns_per_m,
                )
            })),
        }
    }
}

/// Runs the analysis the arguments ask for and writes every report file.
pub fn run(args: &Args) -> Result<DamperReport, DamperAnalysisError> {
    create_out_dir(&args.run.out)?;
    let (name, mut config, mut source, n_steps, faults, record) =
        match (&args.run.input, &args.run.scenario) {
            (Some(path), _) => {
                let reader = BogieCsvReader::open(path)?
                    .only_bogie(args.bogie)
                    .as_recorded();
                let name = path.display().to_string();
                (
                    name,
                    DamperMonitorConfig::default(),
                    Source::Recording(Box::new(reader), f64::NAN),
                    None,
                    vec![],
                    None,
                )
            }
            (None, Some(path)) => {
                let name = path.display().to_string();
                let mut scenario = DamperScenario::from_toml_str(&read_text(path)?)
                    .map_err(estimator_error(&name))?;
                if let Some(d) = args.duration_s {
                    scenario.duration_s = d;
                }
                let sim = BogieSimulator::new(&scenario).map_err(estimator_error(&name))?;
                let writer = BogieCsvWriter::create(&args.run.out.join("bogie.csv"), true)?;
                (
                    name,
                    scenario.monitor_config(),
                    Source::Simulator(Box::new(sim)),
                    Some(scenario.n_steps()),
                    scenario.faults.clone(),
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
        let file = path.display().to_string();
        config = DamperMonitorConfig::from_toml_str(&read_text(path)?)
            .map_err(estimator_error(&file))?;
    }
    if let Source::Recording(reader, assumed_speed_m_s) = &mut source {
        *assumed_speed_m_s = config.vehicle.speed_m_s;
        if !reader.has_speed() {
            eprintln!(
                "railmon analyze damper: warning: {name} has no speed_m_s column: assuming the \
                 configured constant speed, vehicle.speed_m_s = {} m/s",
                config.vehicle.speed_m_s
            );
        }
    }
    if let Some(n) = args.particles {
        config.rbpf.particles = n;
    }
    if let Some(p) = args.propagation {
        config.rbpf.propagation = p;
    }
    let max_steps = args
        .duration_s
        .map(|d| (d / config.dt_s).round() as u64)
        .or(n_steps.map(|n| n as u64));
    if n_steps.is_some() {
        // Per step, measured (`analyze damper --no-plots`, damper-seed at 10 and 40 s): the
        // traces stream to disk (RSS flat), 147 B of CSV.
        RunSize::of(max_steps.unwrap_or(0), 0, 150).check_fits(&args.run.out, "this run")?;
    }
    let cache = match (&args.gain_cache, config.rbpf.propagation) {
        (Some(dir), Propagation::SteadyState) => Some(GainCache::new(dir)),
        _ => None,
    };
    let table = match &cache {
        Some(cache) => {
            let table =
                Rbpf::unsolved_gain_table(&config.filter_model(), &config.rbpf, &config.speed)
                    .map_err(estimator_error(&name))?;
            // The nodes the run reaches, read when it reaches them (not all ~550 ahead:
            // that was 11 % of a 60 s run's CPU, issue 28).
            table.set_source(Box::new(CacheSource(cache.clone())));
            Some(table)
        }
        None => None,
    };
    let run = run_monitor(
        &name,
        &config,
        args.bogie,
        source,
        record,
        table.clone(),
        (max_steps, args.csv_every.max(1), args.run.strict),
    )?;
    if let (Some(cache), Some(table)) = (&cache, &table) {
        cache.store_all(table)?;
    }
    let MonitorRun {
        trace,
        events,
        steps,
        elapsed,
        ekf_diverged_at_s,
        refused,
        timeline,
    } = run;
    refused.write_csv(&args.run.out.join("refused.csv"))?;
    write_estimates(&args.run.out.join("estimates.csv"), &trace)?;
    write_events(&args.run.out.join("events.csv"), args.bogie, &events)?;
    let has_truth = trace.iter().all(|p| p.truth.is_some()) && !trace.is_empty();
    // The EKF baseline is compared only where it ran (`[monitor.ekf] enabled`, off by default).
    let methods = if config.ekf.enabled {
        &METHODS[..]
    } else {
        &METHODS[..1]
    };
    let summary = if has_truth {
        summarise(&trace, methods)
    } else {
        vec![]
    };
    if has_truth {
        write_summary(&args.run.out.join("summary.csv"), &summary)?;
    }
    let fault_rows = if has_truth && !faults.is_empty() {
        let rows = fault_table(&trace, &faults, methods);
        write_faults(&args.run.out.join("faults.csv"), &rows)?;
        rows
    } else {
        vec![]
    };
    if !args.run.no_plots {
        plots(&args.run.out, &trace, methods)?;
    }
    let mean_step_us = elapsed.as_secs_f64() * 1e6 / steps.max(1) as f64;
    write_csv_table(
        &args.run.out.join("timing.csv"),
        &[
            "steps",
            "particles",
            "propagation",
            "mean_step_us",
            "real_time_factor",
            "ekf_diverged_at_s",
        ],
        [vec![
            steps.to_string(),
            config.rbpf.particles.to_string(),
            match config.rbpf.propagation {
                Propagation::Exact => "exact",
                Propagation::SteadyState => "steady_state",
            }
            .to_owned(),
            format!("{mean_step_us:.1}"),
            format!("{:.2}", config.dt_s * 1e6 / mean_step_us),
            opt(ekf_diverged_at_s),
        ]],
    )?;
    Ok(DamperReport {
        summary,
        events,
        faults: fault_rows,
        steps,
        mean_step_us,
        ekf_diverged_at_s,
        refused,
        timeline,
    })
}

/// One event of `events.csv`: a damper's health flag (`railmon_damper::DamperAlarm`) or the
/// bogie's status (`railmon_damper::BogieStatusWatch`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BogieEvent {
    Health(DamperEvent),
    Status(BogieStatusEvent),
}

impl BogieEvent {
    pub fn kind(&self) -> &'static str {
        match self {
            BogieEvent::Health(e) => e.kind.as_str(),
            BogieEvent::Status(e) => e.kind.as_str(),
        }
    }

    pub fn time_s(&self) -> f64 {
        match self {
            BogieEvent::Health(e) => e.time_s,
            BogieEvent::Status(e) => e.time_s,
        }
    }

    /// The service's subject (`<bogie>/<damper>` for health, `<bogie>` for status) and detail.
    fn subject_and_detail(&self, bogie: u32) -> (String, serde_json::Value) {
        match self {
            BogieEvent::Health(e) => (
                format!("{bogie}/{}", e.damper.name()),
                serde_json::json!({
                    "bogie": bogie,
                    "damper": e.damper.name(),
                    "health_ratio": e.health_ratio,
                }),
            ),
            BogieEvent::Status(e) => (
                bogie.to_string(),
                serde_json::to_value(e.detail(bogie)).unwrap_or_default(),
            ),
        }
    }
}

struct MonitorRun {
    trace: Vec<TracePoint>,
    events: Vec<BogieEvent>,
    steps: u64,
    elapsed: Duration,
    ekf_diverged_at_s: Option<f64>,
    refused: Refusals,
    timeline: Timeline,
}

/// A sample refused for its time as an error: `file:line: field "time_s" = "value": reason`
/// for a recording, the clock's words (with the time) for the simulator.
fn time_error(name: &str, line: Option<u64>, time_s: f64, r: &Rejection) -> DamperAnalysisError {
    match line {
        Some(line) => DamperAnalysisError::Record(RecordError {
            file: name.to_owned(),
            line: Some(line),
            field: Some(railmon_records::bogie::BOGIE_COLUMNS[0].to_owned()),
            value: Some(time_s.to_string()),
            reason: format!("{} ({})", r.message, r.reason),
        }),
        None => input_error(
            Path::new(name),
            format!("sample at {time_s} s: {} ({})", r.message, r.reason),
        ),
    }
}

/// A refused sample as an error: `file:line: field "column" = "value": reason` for a
/// recording, the estimator's words for the simulator.
fn refusal_error(name: &str, line: Option<u64>, e: DamperError) -> DamperAnalysisError {
    let field = match &e {
        DamperError::InvalidSample { field, value }
        | DamperError::SampleOutOfRange { field, value, .. } => Some((*field, *value)),
        _ => None,
    };
    match (line, field) {
        (Some(line), Some((field, value))) => DamperAnalysisError::Record(RecordError {
            file: name.to_owned(),
            line: Some(line),
            field: Some(field.to_owned()),
            value: Some(value.to_string()),
            reason: e.to_string(),
        }),
        _ => estimator_error(name)(e),
    }
}

fn run_monitor(
    name: &str,
    config: &DamperMonitorConfig,
    bogie: u32,
    mut source: Source,
    mut record: Option<BogieCsvWriter>,
    table: Option<Arc<GainTable>>,
    (max_steps, every, strict): (Option<u64>, usize, bool),
) -> Result<MonitorRun, DamperAnalysisError> {
    let ranges = SampleRanges::default();
    let mut refused = Refusals::new(&REFUSAL_REASONS);
    let mut first_refusal: Option<DamperAnalysisError> = None;
    let mut read = 0u64;
    let new_monitor =
        || DamperMonitor::for_bogie(config, bogie, table.clone()).map_err(estimator_error(name));
    let mut monitor = new_monitor()?;
    let mut alarms = DamperAlarm::pair(&config.alarm, &config.filter_model(), [false; 2]);
    let mut status = BogieStatusWatch::new();
    // The service's bogie stream clock: the estimator's period, the bogies of one step share
    // a time, at most the stream's default `stale_after_ms` between samples.
    let mut clock = TimeJudge::new(
        (config.dt_s * 1e9).round() as u64,
        true,
        BOGIE_STALE_AFTER_MS,
    );
    let mut timeline = Timeline::default();
    let mut events = vec![];
    let bar = progress_bar(max_steps.unwrap_or(0), "damper");
    let mut trace = vec![];
    let mut steps = 0u64;
    let mut elapsed = Duration::ZERO;
    while max_steps.is_none_or(|m| read < m) {
        let Some((sample, time_s, truth)) = source.next()? else {
            break;
        };
        read += 1;
        let time_ns = TimeJudge::ns_of(time_s).ok_or_else(|| {
            let r = Rejection::new(
                "time_backwards",
                "a negative time, which no frame can carry",
            );
            time_error(name, source.line(), time_s, &r)
        })?;
        // The service's order: the sample's time first (refused, or a confirmed jump that
        // restarts the estimator), then its content. A refused sample is counted and skipped
        // (no estimate, no record), or with `--strict` the error.
        let refusal = match clock.time(time_ns) {
            Ok(new_timeline) => {
                if new_timeline {
                    // As the service restarts its bogie pipeline: a new filter; the health
                    // flags carry over until the new filter's estimates clear them.
                    monitor = new_monitor()?;
                    alarms.iter_mut().for_each(DamperAlarm::restart);
                    timeline.new_timelines_s.push(time_s);
                    eprintln!(
                        "railmon analyze damper: {name}: the sample clock jumped to {time_s} s \
                         (line {}): estimator restarted",
                        source.line().map_or("-".to_owned(), |l| l.to_string())
                    );
                }
                // The service's checks: the magnitudes, then a measured mass within its ratio
                // of the design mass.
                let design_kg = config.vehicle.half_body_mass_kg;
                let checked = ranges.check(&sample).and_then(|_| {
                    checked_half_body_mass_kg(design_kg, sample.half_body_mass_kg).map(|_| ())
                });
                checked.err().map(|e| {
                    let reason = e.reason().unwrap_or("estimator");
                    (reason, refusal_error(name, source.line(), e))
                })
            }
            Err(r) => Some((r.reason, time_error(name, source.line(), time_s, &r))),
        };
        if let Some((reason, error)) = refusal {
            if strict {
                return Err(error);
            }
            refused.add(reason);
            first_refusal.get_or_insert(error);
            continue;
        }
        // Lost samples are bridged as the service bridges them (`DamperMonitor::bridge`).
        let skipped = clock.skipped_periods(time_ns);
        if skipped > 0 {
            monitor.bridge(skipped);
            timeline.skipped_periods += skipped;
        }
        let started = Instant::now();
        let estimate = *monitor.step(&sample).map_err(estimator_error(name))?;
        elapsed += started.elapsed();
        clock.used(time_ns);
        steps += 1;
        // Stamped with the sample's own time, as the service stamps its events; health
        // before status, as the service stores them.
        events.extend(alarms.iter_mut().filter_map(|a| {
            a.update(&estimate)
                .map(|e| BogieEvent::Health(DamperEvent { time_s, ..e }))
        }));
        events.extend(
            status
                .update(&estimate)
                .into_iter()
                .map(|e| BogieEvent::Status(BogieStatusEvent { time_s, ..e })),
        );
        if let Some(w) = record.as_mut() {
            w.write(&BogieRecord {
                time_s: estimate.time_s,
                sensors: sample_array(&sample),
                speed_m_s: Some(sample.speed_m_s),
                half_body_mass_kg: sample.half_body_mass_kg,
                truth_ns_per_m: truth,
            })?;
        }
        if (steps as usize).is_multiple_of(every) {
            trace.push(TracePoint {
                time_s: estimate.time_s,
                estimate,
                body_mass: monitor.body_mass(),
                truth,
            });
        }
        if steps.is_multiple_of(1000) {
            bar.inc(1000);
        }
    }
    bar.finish_and_clear();
    if let Some(mut error) = first_refusal.filter(|_| refused.total() > steps) {
        // Mostly refused: not glitches but another rate, other units or a broken file.
        let counts = format!(
            "{} of {read} samples refused, {}; the first",
            refused.total(),
            refused.line()
        );
        match &mut error {
            DamperAnalysisError::Record(r) => r.reason = format!("{counts}: {}", r.reason),
            DamperAnalysisError::Input { reason, .. } => *reason = format!("{counts}: {reason}"),
            _ => {}
        }
        return Err(error);
    }
    if let Some(w) = record {
        w.finish()?;
    }
    Ok(MonitorRun {
        trace,
        events,
        steps,
        elapsed,
        ekf_diverged_at_s: monitor.ekf_diverged_at_s(),
        refused,
        timeline,
    })
}

/// `events.csv`: the columns every `railmon analyze` domain writes, the service's kinds,
/// subjects and detail fields.
fn write_events(path: &Path, bogie: u32, events: &[BogieEvent]) -> Result<(), RecordError> {
    write_csv_table(
        path,
        &["id", "kind", "stream_time_s", "subject", "detail"],
        events.iter().enumerate().map(|(i, e)| {
            let (subject, detail) = e.subject_and_detail(bogie);
            vec![
                (i + 1).to_string(),
                e.kind().to_owned(),
                format!("{:.6}", e.time_s()),
                subject,
                detail.to_string(),
            ]
        }),
    )
}

fn sample_array(s: &BogieSample) -> [f64; 5] {
    [
        s.wheelset1_accel_m_s2,
        s.wheelset2_accel_m_s2,
        s.bogie_accel_m_s2,
        s.bogie_yaw_rate_rad_s,
        s.body_accel_m_s2,
    ]
}

/// What one method says about one damper at a trace point: estimate and 90% interval.
fn method_view(p: &TracePoint, method: &str, damper: DamperId) -> Option<(f64, f64, f64)> {
    let e = &p.estimate;
    match method {
        "rbpf" => {
            let post = match damper {
                DamperId::Csy => e.csy,
                DamperId::Csay => e.csay,
            };
            Some((post.mean_ns_per_m, post.q05_ns_per_m, post.q95_ns_per_m))
        }
        _ => e.ekf.map(|k| {
            let i = damper.index();
            let mean = [k.dampers.csy_ns_per_m, k.dampers.csay_ns_per_m][i];
            let half = 1.645 * k.std_ns_per_m[i];
            (mean, mean - half, mean + half)
        }),
    }
}

const METHODS: [&str; 2] = ["rbpf", "ekf"];
const SETTLE_TOLERANCE: f64 = 0.05;

fn relative_error(p: &TracePoint, method: &str, damper: DamperId) -> Option<f64> {
    let truth = p.truth?[damper.index()];
    method_view(p, method, damper).map(|(m, _, _)| m / truth - 1.0)
}

/// The trace point nearest to `t_s`, if the run reached it.
fn at_time(trace: &[TracePoint], t_s: f64) -> Option<&TracePoint> {
    let last = trace.last()?;
    if t_s > last.time_s + 1e-9 {
        return None;
    }
    trace
        .iter()
        .min_by(|a, b| (a.time_s - t_s).abs().total_cmp(&(b.time_s - t_s).abs()))
}

/// First time from which every later point is within tolerance (`None` if the last is not).
fn settle_time(points: &[TracePoint], method: &str, damper: DamperId) -> Option<f64> {
    let mut settled = None;
    for p in points.iter().rev() {
        match relative_error(p, method, damper) {
            Some(e) if e.abs() <= SETTLE_TOLERANCE => settled = Some(p.time_s),
            _ => break,
        }
    }
    settled
}

fn summarise(trace: &[TracePoint], methods: &[&'static str]) -> Vec<SummaryRow> {
    let mut rows = vec![];
    let Some(end) = trace.last() else {
        return rows;
    };
    for &method in methods {
        for damper in DamperId::ALL {
            let truth = end.truth.map_or(f64::NAN, |t| t[damper.index()]);
            let err_at = |t: f64| at_time(trace, t).and_then(|p| relative_error(p, method, damper));
            rows.push(SummaryRow {
                method,
                damper: damper.name(),
                truth,
                error_10s: err_at(10.0),
                error_30s: err_at(30.0),
                error_end: relative_error(end, method, damper),
                settle_s: settle_time(trace, method, damper),
                covered_end: method_view(end, method, damper)
                    .is_some_and(|(_, lo, hi)| lo <= truth && truth <= hi),
            });
        }
    }
    rows
}

fn fault_table(
    trace: &[TracePoint],
    faults: &[DamperFault],
    methods: &[&'static str],
) -> Vec<FaultRow> {
    let mut rows = vec![];
    for f in faults {
        let done_s = match f.kind {
            FaultKind::Step => f.at_s,
            FaultKind::Ramp => f.end_s.unwrap_or(f.at_s),
        };
        let after: Vec<TracePoint> = trace
            .iter()
            .filter(|p| p.time_s >= done_s)
            .copied()
            .collect();
        for &method in methods {
            rows.push(FaultRow {
                method,
                damper: f.damper.name(),
                kind: match f.kind {
                    FaultKind::Step => "step",
                    FaultKind::Ramp => "ramp",
                },
                at_s: f.at_s,
                done_s,
                ratio: f.ratio,
                error_10s_after: at_time(trace, done_s + 10.0)
                    .and_then(|p| relative_error(p, method, f.damper)),
                settle_after_s: settle_time(&after, method, f.damper).map(|t| t - done_s),
            });
        }
    }
    rows
}

fn opt(v: Option<f64>) -> String {
    v.map_or_else(String::new, |x| format!("{x:.6}"))
}

fn write_estimates(path: &Path, trace: &[TracePoint]) -> Result<(), RecordError> {
    let mut header = vec!["time_s".to_owned()];
    for d in DamperId::ALL {
        let n = d.name();
        for col in [
            "rbpf_mean_ns_per_m",
            "rbpf_q05_ns_per_m",
            "rbpf_q95_ns_per_m",
            "rbpf_health_ratio",
            "ekf_ns_per_m",
            "ekf_std_ns_per_m",
            "true_ns_per_m",
        ] {
            header.push(format!("{n}_{col}"));
        }
    }
    header.extend(
        [
            "effective_sample_size",
            "nis_window_mean",
            "model_mismatch",
            "speed_m_s",
            "paused",
            "half_body_mass_kg",
            "mass_source",
            "held_through_burst",
        ]
        .map(str::to_owned),
    );
    let rows = trace.iter().map(|p| {
        let mut row = vec![format!("{:.3}", p.time_s)];
        for d in DamperId::ALL {
            let post = match d {
                DamperId::Csy => p.estimate.csy,
                DamperId::Csay => p.estimate.csay,
            };
            let ekf = p.estimate.ekf.map(|k| {
                (
                    [k.dampers.csy_ns_per_m, k.dampers.csay_ns_per_m][d.index()],
                    k.std_ns_per_m[d.index()],
                )
            });
            row.extend([
                format!("{:.3}", post.mean_ns_per_m),
                format!("{:.3}", post.q05_ns_per_m),
                format!("{:.3}", post.q95_ns_per_m),
                format!("{:.6}", post.health_ratio),
                opt(ekf.map(|e| e.0)),
                opt(ekf.map(|e| e.1)),
                opt(p.truth.map(|t| t[d.index()])),
            ]);
        }
        row.push(format!("{:.1}", p.estimate.effective_sample_size));
        row.push(
            p.estimate
                .nis_window_mean
                .map_or_else(String::new, |v| format!("{v:.4}")),
        );
        row.push(p.estimate.model_mismatch.to_string());
        row.push(format!("{:.3}", p.estimate.speed_m_s));
        row.push(p.estimate.paused.map_or("", |r| r.as_str()).to_owned());
        row.push(format!("{:.1}", p.body_mass.half_body_mass_kg));
        row.push(p.body_mass.source.as_str().to_owned());
        row.push(p.estimate.held_through_burst.to_string());
        row
    });
    write_csv_table(path, &header, rows)
}

fn write_summary(path: &Path, rows: &[SummaryRow]) -> Result<(), RecordError> {
    let header = [
        "method",
        "damper",
        "truth",
        "error_10s",
        "error_30s",
        "error_end",
        "settle_s",
        "covered_end",
    ];
    write_csv_table(
        path,
        &header,
        rows.iter().map(|r| {
            vec![
                r.method.to_owned(),
                r.damper.to_owned(),
                format!("{:.1}", r.truth),
                opt(r.error_10s),
                opt(r.error_30s),
                opt(r.error_end),
                opt_s(r.settle_s),
                r.covered_end.to_string(),
            ]
        }),
    )
}

fn write_faults(path: &Path, rows: &[FaultRow]) -> Result<(), RecordError> {
    let header = [
        "method",
        "damper",
        "kind",
        "at_s",
        "done_s",
        "ratio",
        "error_10s_after",
        "settle_after_s",
    ];
    write_csv_table(
        path,
        &header,
        rows.iter().map(|r| {
            vec![
                r.method.to_owned(),
                r.damper.to_owned(),
                r.kind.to_owned(),
                format!("{:.3}", r.at_s),
                format!("{:.3}", r.done_s),
                format!("{:.3}", r.ratio),
                opt(r.error_10s_after),
                opt_s(r.settle_after_s),
            ]
        }),
    )
}

fn opt_s(v: Option<f64>) -> String {
    v.map_or_else(String::new, |s| format!("{s:.2}"))
}

/// Figures 2-5 of the paper (RBPF and, when it ran, the EKF, each damper, estimate against
/// truth, in kN s/m), with the RBPF's 90% interval, plus the effective sample size.
fn plots(
    dir: &Path,
    trace: &[TracePoint],
    methods: &[&'static str],
) -> Result<(), DamperAnalysisError> {
    let kn = |v: f64| v / 1e3;
    for &method in methods {
        let label = if method == "ekf" { "EKF" } else { "RBPF" };
        for d in DamperId::ALL {
            let view: Vec<(f64, (f64, f64, f64))> = trace
                .iter()
                .filter_map(|p| method_view(p, method, d).map(|v| (p.time_s, v)))
                .collect();
            let mut series = vec![Series {
                label: "estimate",
                points: view.iter().map(|(t, v)| (*t, kn(v.0))).collect(),
            }];
            series.push(Series {
                label: "90% interval",
                points: view.iter().map(|(t, v)| (*t, kn(v.1))).collect(),
            });
            series.push(Series {
                label: "",
                points: view.iter().map(|(t, v)| (*t, kn(v.2))).collect(),
            });
            if trace.iter().all(|p| p.truth.is_some()) {
                series.push(Series {
                    label: "truth",
                    points: trace
                        .iter()
                        .filter_map(|p| p.truth.map(|t| (p.time_s, kn(t[d.index()]))))
                        .collect(),
                });
            }
            let title = format!(
                "{label}: {} ({})",
                match d {
                    DamperId::Csy => "secondary lateral damping C_sy",
                    DamperId::Csay => "anti-yaw damping C_say",
                },
                if method == "ekf" {
                    "+-1.645 sd"
                } else {
                    "90% interval"
                }
            );
            line_plot(
                &dir.join(format!("{method}_{}.png", d.name())),
                &Axes {
                    title: &title,
                    x_label: "time (s)",
                    y_label: "damping (kN s/m)",
                },
                &series,
            )?;
        }
    }
    line_plot(
        &dir.join("ess.png"),
        &Axes {
            title: "RBPF effective sample size",
            x_label: "time (s)",
            y_label: "ESS",
        },
        &[Series {
            label: "ESS",
            points: trace
                .iter()
                .map(|p| (p.time_s, p.estimate.effective_sample_size))
                .collect(),
        }],
    )?;
    Ok(())
}
