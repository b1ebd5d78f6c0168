//! The drive stream: an adhesion scenario through `railmon_slip::DriveSimulator`, or a recorded
//! drive CSV (`railmon_records::drive`), published as `DriveFrame`s.

use std::fs::File;
use std::path::PathBuf;

use anyhow::{bail, Context};
use railmon_bus::{DriveChannels, DriveFrame, MAX_DRIVES};
use railmon_records::drive::{DriveCsvReader, DriveCsvWriter, DriveSample, DriveTruth};
use railmon_records::AtomicFile;
use railmon_slip::{AdhesionScenario, DriveSimulator, SlipMonitorConfig};

use crate::replay::{publish, Outcome, Source};
use crate::{input_label, ReplayArgs};

#[derive(clap::Args, Debug)]
pub struct DriveArgs {
    /// Adhesion scenario (e.g. config/scenarios/adhesion-seed.toml): simulated drives.
    #[arg(long, conflicts_with = "csv", required_unless_present = "csv")]
    scenario: Option<PathBuf>,
    /// Recorded drive CSV (`step[,time_s],drive,u_alpha_v,u_beta_v,i_alpha_a,i_beta_a
    /// [,truth...][,train_speed_m_s]`); the train speed, when the file has it, goes out with
    /// each frame; with `time_s` each frame carries the file's time (a lost sample stays lost),
    /// without it frame k of a run is stamped k control steps after the run's start.
    #[arg(long)]
    csv: Option<PathBuf>,
    /// Control step of the CSV recording, s, in [1e-6, 1] (scenarios carry their own); by
    /// default the monitor's (`railmon_slip::SlipMonitorConfig::default().dt_s`).
    #[arg(long, default_value_t = SlipMonitorConfig::default().dt_s, value_parser = crate::bounded_f64(1e-6, 1.0))]
    dt_s: f64,
    #[command(flatten)]
    replay: ReplayArgs,
}

/// One step of every drive, with ground truth and the train's measured speed when the source
/// has them.
#[derive(Default)]
struct Step {
    /// The recording's sample time (s), when it has a `time_s` column.
    time_s: Option<f64>,
    drives: Vec<DriveSample>,
    truth: Option<Vec<DriveTruth>>,
    train_speed_m_s: Option<f64>,
}

enum DriveData {
    Scenario {
        scenario: Box<AdhesionScenario>,
        simulator: Box<DriveSimulator>,
    },
    Csv {
        path: PathBuf,
        reader: Box<DriveCsvReader<File>>,
        dt_s: f64,
    },
}

impl DriveData {
    fn open(args: &DriveArgs) -> anyhow::Result<Self> {
        if let Some(path) = &args.scenario {
            let text =
                railmon_records::read_text_file(path, railmon_records::MAX_SETTINGS_FILE_BYTES)
                    .with_context(|| format!("cannot read scenario {}", path.display()))?;
            let scenario = AdhesionScenario::from_toml_str(&text)
                .with_context(|| format!("invalid scenario {}", path.display()))?;
            if scenario.n_drives() > MAX_DRIVES {
                bail!(
                    "scenario {} has {} drives; a drive frame holds at most {MAX_DRIVES}",
                    path.display(),
                    scenario.n_drives()
                );
            }
            let simulator = DriveSimulator::new(&scenario)
                .with_context(|| format!("cannot simulate {}", path.display()))?;
            return Ok(DriveData::Scenario {
                scenario: Box::new(scenario),
                simulator: Box::new(simulator),
            });
        }
        let path = args
            .csv
            .clone()
            .context("give --scenario FILE or --csv FILE")?;
        let reader = DriveCsvReader::open(&path, None)?;
        Ok(DriveData::Csv {
            path,
            reader: Box::new(reader),
            dt_s: args.dt_s,
        })
    }

    fn dt_s(&self) -> f64 {
        match self {
            DriveData::Scenario { scenario, .. } => scenario.dt_s(),
            DriveData::Csv { dt_s, .. } => *dt_s,
        }
    }

    fn has_truth(&self) -> bool {
        match self {
            DriveData::Scenario { .. } => true,
            DriveData::Csv { reader, .. } => reader.has_truth(),
        }
    }

    /// Whether the source has a train speed (a scenario's `[train_speed]`, a recording's
    /// `train_speed_m_s` column): a recording of it gets the column.
    fn has_train_speed(&self) -> bool {
        match self {
            DriveData::Scenario { scenario, .. } => scenario.train_speed.is_some(),
            DriveData::Csv { reader, .. } => reader.has_train_speed(),
        }
    }

    /// Fills `step` with the next step; false at the end.
    fn next(&mut self, step: &mut Step) -> anyhow::Result<bool> {
        match self {
            DriveData::Scenario { simulator, .. } => {
                let Some((samples, truth, train_speed_m_s)) = simulator.step_with_train_speed()
                else {
                    return Ok(false);
                };
                step.time_s = None;
                step.drives.clear();
                step.drives.extend_from_slice(samples);
                step.truth = Some(truth.to_vec());
                step.train_speed_m_s = train_speed_m_s;
                Ok(true)
            }
            DriveData::Csv { reader, .. } => match reader.next_frame()? {
                Some(frame) => {
                    if frame.drives.len() > MAX_DRIVES {
                        bail!(
                            "step {} has {} drives; a drive frame holds at most {MAX_DRIVES}",
                            frame.step,
                            frame.drives.len()
                        );
                    }
                    if frame.time_s.is_some_and(|t| t * 1e9 >= u64::MAX as f64) {
                        bail!("step {}: time_s beyond what a frame can carry", frame.step);
                    }
                    step.time_s = frame.time_s;
                    step.drives = frame.drives;
                    step.truth = frame.truth;
                    step.train_speed_m_s = frame.train_speed_m_s;
                    Ok(true)
                }
                None => Ok(false),
            },
        }
    }

    /// Back to the first step (for `--loop`).
    fn rewind(&mut self) -> anyhow::Result<()> {
        match self {
            DriveData::Scenario {
                scenario,
                simulator,
            } => **simulator = DriveSimulator::new(scenario)?,
            DriveData::Csv { path, reader, .. } => **reader = DriveCsvReader::open(path, None)?,
        }
        Ok(())
    }
}

/// The drive stream's [`Source`]: steps of a simulator or a recording, with its recorder.
struct DriveSource {
    source: DriveData,
    dt_ns: u64,
    step: Step,
    run_step: u64,
    /// The sample time of the frame `next` returned last (ns from the run's start).
    sample_time_ns: u64,
    drives: Vec<DriveChannels>,
    recorder: Option<DriveCsvWriter<AtomicFile>>,
}

impl Source for DriveSource {
    type Frame = DriveFrame;

    fn period_s(&self) -> f64 {
        self.source.dt_s()
    }

    fn next(&mut self) -> anyhow::Result<Option<(DriveFrame, u64)>> {
        if !self.source.next(&mut self.step)? {
            return Ok(None);
        }
        self.drives.clear();
        self.drives
            .extend(self.step.drives.iter().map(DriveChannels::from));
        let frame =
            DriveFrame::new(self.dt_ns, &self.drives)?.with_train_speed(self.step.train_speed_m_s);
        let sample_time_ns = match self.step.time_s {
            Some(t) => (t * 1e9).round() as u64,
            None => self.run_step * self.dt_ns,
        };
        self.sample_time_ns = sample_time_ns;
        self.run_step += 1;
        Ok(Some((frame, sample_time_ns)))
    }

    fn rewind(&mut self) -> anyhow::Result<()> {
        self.run_step = 0;
        self.source.rewind()
    }

    /// Steps are numbered by `sent`, which continues across runs; `time_s` is the time the
    /// frame carried, from the first run's start (as the bogie and vehicle streams record).
    fn record(&mut self, sent: u64, run_offset_s: f64) -> anyhow::Result<()> {
        if let Some(recorder) = self.recorder.as_mut() {
            recorder.write_frame(
                sent,
                ((run_offset_s * 1e9).round() as u64 + self.sample_time_ns) as f64 / 1e9,
                &self.step.drives,
                self.step.truth.as_deref(),
                self.step.train_speed_m_s,
            )?;
        }
        Ok(())
    }

    fn finish_recording(&mut self) -> anyhow::Result<()> {
        if let Some(recorder) = self.recorder.take() {
            recorder.finish()?;
        }
        Ok(())
    }

    fn describe(&self) -> String {
        format!("{} drives", self.drives.len())
    }
}

pub fn run(args: DriveArgs) -> anyhow::Result<Outcome> {
    args.replay
        .refuse_recording_over_an_input(&[args.scenario.as_deref(), args.csv.as_deref()])?;
    let source = DriveData::open(&args)?;
    let recorder = match &args.replay.record {
        Some(path) => Some(DriveCsvWriter::create(
            path,
            source.has_truth(),
            source.has_train_speed(),
        )?),
        None => None,
    };
    let mut drive = DriveSource {
        dt_ns: (source.dt_s() * 1e9).round() as u64,
        source,
        step: Step::default(),
        run_step: 0,
        sample_time_ns: 0,
        drives: Vec::new(),
        recorder,
    };
    publish(
        &mut drive,
        &args.replay,
        &input_label(&args.csv, &args.scenario),
    )
}
