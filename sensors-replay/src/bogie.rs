//! The bogie stream: a damper scenario through `railmon_damper::BogieSimulator` (one
//! simulator per bogie, seeded `scenario seed + k`), or a recorded bogie CSV
//! (`records/src/bogie.rs`, one bogie), published as `BogieFrame`s at 1 kHz by the samples'
//! own time stamps. All bogies go through this one publisher, interleaved per step.

use std::path::PathBuf;

use anyhow::{bail, Context};
use railmon_bus::BogieFrame;
use railmon_damper::{BogieSample, BogieSimulator, DamperScenario};
use railmon_records::bogie::{BogieCsvReader, BogieCsvWriter, BogieRecord};

use crate::replay::{publish, Source};
use crate::ReplayArgs;

#[derive(clap::Args, Debug)]
pub struct BogieArgs {
    /// Damper scenario (e.g. config/scenarios/damper-fault.toml): simulated bogies with truth.
    #[arg(long, conflicts_with = "csv", required_unless_present = "csv")]
    scenario: Option<PathBuf>,
    /// Bogie CSV: `time_s,wheelset1_accel_m_s2,...,body_accel_m_s2[,true_csy_ns_per_m,true_csay_ns_per_m]`.
    #[arg(long)]
    csv: Option<PathBuf>,
    /// Bogies to simulate (ids `--bogie-id`, `--bogie-id + 1`, ...; scenario only).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=16))]
    bogies: u32,
    /// Id of the first (or only) bogie.
    #[arg(long, default_value_t = 1)]
    bogie_id: u32,
    /// Simulate only this much of the scenario, s (scenario only).
    #[arg(long)]
    duration_s: Option<f64>,
    #[command(flatten)]
    replay: ReplayArgs,
}

/// Where the samples come from.
enum Samples {
    /// One simulator per bogie (and the scenario, to rewind).
    Simulated {
        scenario: DamperScenario,
        simulators: Vec<BogieSimulator>,
    },
    Recorded {
        path: PathBuf,
        reader: BogieCsvReader<std::fs::File>,
    },
}

struct BogieSource {
    samples: Samples,
    first_id: u32,
    n_bogies: u32,
    dt_s: f64,
    /// Bogie of the next frame within the step (0-based) and the step's records.
    next_bogie: usize,
    step: Vec<BogieRecord>,
    /// The record `next` returned last.
    last: Option<(u32, BogieRecord)>,
    writer: Option<BogieCsvWriter>,
}

fn simulators(scenario: &DamperScenario, n: u32) -> anyhow::Result<Vec<BogieSimulator>> {
    (0..n)
        .map(|k| {
            let mut s = scenario.clone();
            s.seed = scenario.seed.wrapping_add(u64::from(k));
            BogieSimulator::new(&s).with_context(|| format!("bogie {k}: cannot simulate"))
        })
        .collect()
}

impl BogieSource {
    fn open(args: &BogieArgs) -> anyhow::Result<Self> {
        let (samples, n_bogies, dt_s, with_truth) = match (&args.scenario, &args.csv) {
            (Some(path), _) => {
                let text = std::fs::read_to_string(path)
                    .with_context(|| format!("cannot read scenario {}", path.display()))?;
                let mut scenario = DamperScenario::from_toml_str(&text)
                    .with_context(|| format!("scenario {}", path.display()))?;
                if let Some(d) = args.duration_s {
                    scenario.duration_s = d;
                }
                let simulators = simulators(&scenario, args.bogies)
                    .with_context(|| format!("scenario {}", path.display()))?;
                let dt_s = scenario.dt_s;
                let samples = Samples::Simulated {
                    scenario,
                    simulators,
                };
                (samples, args.bogies, dt_s, true)
            }
            (None, Some(path)) => {
                if args.bogies != 1 {
                    bail!("--bogies applies to --scenario only (a CSV holds one bogie)");
                }
                let reader = BogieCsvReader::open(path)?;
                let with_truth = reader.has_truth();
                let samples = Samples::Recorded {
                    path: path.clone(),
                    reader,
                };
                (samples, 1, 1e-3, with_truth)
            }
            (None, None) => bail!("give --scenario FILE or --csv FILE"),
        };
        let writer = match &args.replay.record {
            Some(path) => Some(BogieCsvWriter::create(path, with_truth)?),
            None => None,
        };
        Ok(Self {
            samples,
            first_id: args.bogie_id,
            n_bogies,
            dt_s,
            next_bogie: 0,
            step: Vec::new(),
            last: None,
            writer,
        })
    }

    /// The next step's record of every bogie; empty at the end of the run.
    fn next_step(&mut self) -> anyhow::Result<Vec<BogieRecord>> {
        match &mut self.samples {
            Samples::Simulated { simulators, .. } => Ok(simulators
                .iter_mut()
                .map_while(|s| {
                    s.step().map(|(y, truth)| BogieRecord {
                        time_s: truth.time_s,
                        sensors: y.to_vector().into(),
                        truth_ns_per_m: Some([
                            truth.dampers.csy_ns_per_m,
                            truth.dampers.csay_ns_per_m,
                        ]),
                    })
                })
                .collect()),
            Samples::Recorded { reader, .. } => Ok(reader.next_record()?.into_iter().collect()),
        }
    }
}

impl Source for BogieSource {
    type Frame = BogieFrame;

    fn period_s(&self) -> f64 {
        self.dt_s
    }

    fn next(&mut self) -> anyhow::Result<Option<(BogieFrame, u64)>> {
        if self.next_bogie >= self.step.len() {
            self.step = self.next_step()?;
            self.next_bogie = 0;
            if self.step.len() < self.n_bogies as usize {
                return Ok(None);
            }
        }
        let record = self.step[self.next_bogie];
        let id = self.first_id + self.next_bogie as u32;
        self.next_bogie += 1;
        if record.time_s < 0.0 {
            bail!(
                "bogie {id}: time_s {} is negative (the bus carries times >= 0)",
                record.time_s
            );
        }
        let sample = BogieSample::from_vector(&record.sensors.into());
        self.last = Some((id, record));
        Ok(Some((
            BogieFrame::from_sample(id, &sample),
            (record.time_s * 1e9).round() as u64,
        )))
    }

    fn rewind(&mut self) -> anyhow::Result<()> {
        self.samples = match &self.samples {
            Samples::Simulated { scenario, .. } => Samples::Simulated {
                simulators: simulators(scenario, self.n_bogies)?,
                scenario: scenario.clone(),
            },
            Samples::Recorded { path, .. } => Samples::Recorded {
                reader: BogieCsvReader::open(path)?,
                path: path.clone(),
            },
        };
        self.step.clear();
        self.next_bogie = 0;
        // A recording holds one run of the first bogie.
        if let Some(writer) = self.writer.take() {
            writer.finish()?;
        }
        Ok(())
    }

    fn record(&mut self, _sent: u64) -> anyhow::Result<()> {
        if let (Some(writer), Some((id, record))) = (self.writer.as_mut(), &self.last) {
            if *id == self.first_id {
                writer.write(record)?;
            }
        }
        Ok(())
    }

    fn finish_recording(&mut self) -> anyhow::Result<()> {
        if let Some(writer) = self.writer.take() {
            writer.finish()?;
        }
        Ok(())
    }

    fn describe(&self) -> String {
        format!("1 of {} bogies", self.n_bogies)
    }
}

pub fn run(args: BogieArgs) -> anyhow::Result<()> {
    let mut source = BogieSource::open(&args)?;
    publish(&mut source, &args.replay)
}
