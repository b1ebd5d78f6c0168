//! The drive stream: an adhesion scenario through `railmon_slip::DriveSimulator`, or a recorded
//! drive CSV (`railmon_records::drive`), published as `DriveFrame`s.

use std::fs::File;
use std::io::BufWriter;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context};
use railmon_bus::{BusNode, DriveChannels, DriveFrame, FramePublisher, MAX_DRIVES};
use railmon_records::drive::{DriveCsvReader, DriveCsvWriter, DriveMeasurement, DriveTruthRecord};
use railmon_slip::{AdhesionScenario, DriveSimulator};

use crate::pacing::{Pacer, Speed};
use crate::{load_bus_config, stop_requested, ReplayArgs};

#[derive(clap::Args, Debug)]
pub struct DriveArgs {
    /// Adhesion scenario (e.g. config/scenarios/adhesion-seed.toml): simulated drives.
    #[arg(long, conflicts_with = "csv", required_unless_present = "csv")]
    scenario: Option<PathBuf>,
    /// Recorded drive CSV (`step,drive,u_alpha_v,u_beta_v,i_alpha_a,i_beta_a[,truth...]`).
    #[arg(long)]
    csv: Option<PathBuf>,
    /// Control step of the CSV recording, s (scenarios carry their own).
    #[arg(long, default_value_t = 125e-6)]
    dt_s: f64,
    #[command(flatten)]
    replay: ReplayArgs,
}

/// One step of every drive, with ground truth when the source has it.
#[derive(Default)]
struct Step {
    drives: Vec<DriveMeasurement>,
    truth: Option<Vec<DriveTruthRecord>>,
}

enum Source {
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

impl Source {
    fn open(args: &DriveArgs) -> anyhow::Result<Self> {
        if let Some(path) = &args.scenario {
            let text = std::fs::read_to_string(path)
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
            return Ok(Source::Scenario {
                scenario: Box::new(scenario),
                simulator: Box::new(simulator),
            });
        }
        let path = args
            .csv
            .clone()
            .context("give --scenario FILE or --csv FILE")?;
        if !(args.dt_s.is_finite() && args.dt_s > 0.0) {
            bail!(
                "--dt-s {}: expected a positive number of seconds",
                args.dt_s
            );
        }
        let reader = DriveCsvReader::open(&path, None)?;
        Ok(Source::Csv {
            path,
            reader: Box::new(reader),
            dt_s: args.dt_s,
        })
    }

    fn dt_s(&self) -> f64 {
        match self {
            Source::Scenario { scenario, .. } => scenario.dt_s(),
            Source::Csv { dt_s, .. } => *dt_s,
        }
    }

    fn has_truth(&self) -> bool {
        match self {
            Source::Scenario { .. } => true,
            Source::Csv { reader, .. } => reader.has_truth(),
        }
    }

    /// Fills `step` with the next step; false at the end.
    fn next(&mut self, step: &mut Step) -> anyhow::Result<bool> {
        match self {
            Source::Scenario { simulator, .. } => {
                let Some((samples, truth)) = simulator.step() else {
                    return Ok(false);
                };
                step.drives.clear();
                step.drives.extend(samples.iter().map(|s| DriveMeasurement {
                    u_alpha_v: s.u_alpha_v,
                    u_beta_v: s.u_beta_v,
                    i_alpha_a: s.i_alpha_a,
                    i_beta_a: s.i_beta_a,
                }));
                step.truth = Some(
                    truth
                        .iter()
                        .map(|t| DriveTruthRecord {
                            speed_rad_s: t.speed_rad_s,
                            angle_rad: t.angle_rad,
                            torque_nm: t.torque_nm,
                            slipping: t.slipping,
                        })
                        .collect(),
                );
                Ok(true)
            }
            Source::Csv { reader, .. } => match reader.next_frame()? {
                Some(frame) => {
                    if frame.drives.len() > MAX_DRIVES {
                        bail!(
                            "step {} has {} drives; a drive frame holds at most {MAX_DRIVES}",
                            frame.step,
                            frame.drives.len()
                        );
                    }
                    step.drives = frame.drives;
                    step.truth = frame.truth;
                    Ok(true)
                }
                None => Ok(false),
            },
        }
    }

    /// Back to the first step (for `--loop`).
    fn rewind(&mut self) -> anyhow::Result<()> {
        match self {
            Source::Scenario {
                scenario,
                simulator,
            } => **simulator = DriveSimulator::new(scenario)?,
            Source::Csv { path, reader, .. } => **reader = DriveCsvReader::open(path, None)?,
        }
        Ok(())
    }
}

fn channels(step: &Step, out: &mut Vec<DriveChannels>) {
    out.clear();
    out.extend(step.drives.iter().map(|d| DriveChannels {
        u_alpha_v: d.u_alpha_v,
        u_beta_v: d.u_beta_v,
        i_alpha_a: d.i_alpha_a,
        i_beta_a: d.i_beta_a,
    }));
}

fn wait_for_subscriber(
    publisher: &FramePublisher<DriveFrame>,
    args: &ReplayArgs,
) -> anyhow::Result<()> {
    eprintln!(
        "sensors-replay: waiting for a subscriber on `{}`",
        publisher.service_name()
    );
    publisher.wait_for_subscriber(args.wait_timeout(), &stop_requested)?;
    eprintln!("sensors-replay: subscriber connected");
    Ok(())
}

pub fn run(args: DriveArgs) -> anyhow::Result<()> {
    let bus = load_bus_config(args.replay.config.as_deref())?;
    let mut source = Source::open(&args)?;
    let dt_ns = (source.dt_s() * 1e9).round() as u64;
    let mut recorder: Option<DriveCsvWriter<BufWriter<File>>> = match &args.replay.record {
        Some(path) => Some(DriveCsvWriter::create(path, source.has_truth())?),
        None => None,
    };
    let node = BusNode::create(&bus, "sensors-replay-drive")?;
    let mut publisher = node.publisher::<DriveFrame>()?;
    let replay = &args.replay;
    wait_for_subscriber(&publisher, replay)?;
    let mut pacer = Pacer::new(replay.speed, source.dt_s());
    let notify_every = if pacer.is_paced() {
        1
    } else {
        replay.notify_every.max(1)
    };
    let (mut step, mut drives) = (Step::default(), Vec::new());
    let (mut run_step, mut sent, mut undelivered, mut runs) = (0u64, 0u64, 0u64, 1u64);
    let start = Instant::now();
    while !stop_requested() && replay.max_frames.is_none_or(|max| sent < max) {
        if !source.next(&mut step)? {
            if !replay.repeat {
                break;
            }
            source.rewind()?;
            publisher.start_new_run();
            (run_step, runs) = (0, runs + 1);
            continue;
        }
        channels(&step, &mut drives);
        let frame = DriveFrame::new(dt_ns, &drives)?;
        pacer.wait_next();
        let recipients = publisher.send(&frame, run_step * dt_ns)?;
        if recipients == 0 || sent.is_multiple_of(notify_every) {
            publisher.notify()?;
        }
        if recipients == 0 {
            undelivered += 1;
            eprintln!("sensors-replay: frame {sent} reached no subscriber");
            wait_for_subscriber(&publisher, replay)?;
            pacer.reset();
        }
        if let Some(recorder) = recorder.as_mut() {
            recorder.write_frame(sent, &step.drives, step.truth.as_deref())?;
        }
        (run_step, sent) = (run_step + 1, sent + 1);
    }
    publisher.notify()?;
    if let Some(recorder) = recorder {
        recorder.finish()?;
    }
    let elapsed_s = start.elapsed().as_secs_f64();
    let speed = match replay.speed {
        Speed::Max => "max".to_string(),
        Speed::Times(x) => format!("{x}x"),
    };
    eprintln!(
        "sensors-replay: sent {sent} frames ({} drives, {runs} run(s)) in {elapsed_s:.3} s = {:.0} frames/s at speed {speed}; undelivered {undelivered}",
        drives.len(),
        sent as f64 / elapsed_s.max(1e-9),
    );
    Ok(())
}
