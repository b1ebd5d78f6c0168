//! The bogie stream: a damper scenario through `railmon_damper::BogieSimulator` (one
//! simulator per bogie, seeded `scenario seed + k`), or a recorded bogie CSV
//! (`records/src/bogie.rs`: with a `bogie` column, every bogie in it; without, one bogie),
//! published as `BogieFrame`s at 1 kHz by the samples' own time stamps. All bogies go through
//! this one publisher, interleaved per step; `--record` writes every frame with its bogie id.

use std::collections::VecDeque;
use std::path::PathBuf;

use anyhow::{bail, Context};
use railmon_bus::BogieFrame;
use railmon_damper::{BogieSample, BogieSimulator, DamperScenario, DEFAULT_SPEED_M_S};
use railmon_records::bogie::{BogieCsvReader, BogieCsvWriter, BogieRecord, DEFAULT_BOGIE_ID};

use crate::replay::{publish, Outcome, Source};
use crate::{input_label, ReplayArgs};

#[derive(clap::Args, Debug)]
pub struct BogieArgs {
    /// Damper scenario (e.g. config/scenarios/damper-fault.toml): simulated bogies with truth.
    #[arg(long, conflicts_with = "csv", required_unless_present = "csv")]
    scenario: Option<PathBuf>,
    /// Bogie CSV: `time_s[,bogie],wheelset1_accel_m_s2,...,body_accel_m_s2[,speed_m_s][,half_body_mass_kg][,true_csy_ns_per_m,true_csay_ns_per_m]`
    /// (every bogie of its `bogie` column; without one, one bogie).
    #[arg(long)]
    csv: Option<PathBuf>,
    /// Bogies to simulate (ids `--bogie-id`, `--bogie-id + 1`, ...; scenario only).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=16))]
    bogies: u32,
    /// Id of the first (or only) bogie [default: 1]; a CSV with a `bogie` column names its own.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    bogie_id: Option<u32>,
    /// Simulate only this much of the scenario, s (scenario only; the scenario's bounds apply).
    #[arg(long)]
    duration_s: Option<f64>,
    /// Vehicle speed to send with a CSV that has no `speed_m_s` column, m/s (with a warning)
    /// [default: the damper model's, 45.3].
    #[arg(long)]
    assume_speed_m_s: Option<f64>,
    #[command(flatten)]
    replay: ReplayArgs,
}

/// Where the samples come from.
enum Samples {
    /// One simulator per bogie (and the scenario, to rewind).
    Simulated {
        // Both variants' bulk is boxed (the scenario carries the monitor's whole
        // configuration, the reader its buffers), so neither outweighs the other.
        scenario: Box<DamperScenario>,
        simulators: Vec<BogieSimulator>,
    },
    Recorded {
        path: PathBuf,
        reader: Box<BogieCsvReader<std::fs::File>>,
    },
}

struct BogieSource {
    samples: Samples,
    /// Id of the first simulated bogie, or of a CSV without a `bogie` column.
    first_id: u32,
    n_bogies: u32,
    dt_s: f64,
    /// The current step's records not sent yet (simulated bogies, in id order).
    pending: VecDeque<(u32, BogieRecord)>,
    /// The record `next` returned last, with its bogie id.
    last: Option<(u32, BogieRecord)>,
    /// Every bogie id sent, for the summary.
    ids_sent: Vec<u32>,
    writer: Option<BogieCsvWriter>,
    /// The speed of a recording without a `speed_m_s` column.
    assumed_speed_m_s: f64,
}

/// The id of the last of `n` simulated bogies numbered from `first`: an error, not a wrap to
/// 0, when it would be past `u32::MAX` (`--bogie-id 4294967295 --bogies 2`).
fn last_bogie_id(first: u32, n: u32) -> anyhow::Result<u32> {
    first.checked_add(n - 1).with_context(|| {
        format!(
            "--bogie-id {first} with --bogies {n}: the ids would run past {}",
            u32::MAX
        )
    })
}

fn assumed_speed_m_s(args: &BogieArgs) -> f64 {
    args.assume_speed_m_s.unwrap_or(DEFAULT_SPEED_M_S)
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
        args.replay
            .refuse_recording_over_an_input(&[args.scenario.as_deref(), args.csv.as_deref()])?;
        let (samples, n_bogies, dt_s, with_truth) = match (&args.scenario, &args.csv) {
            (Some(path), _) => {
                let text =
                    railmon_records::read_text_file(path, railmon_records::MAX_SETTINGS_FILE_BYTES)
                        .with_context(|| format!("cannot read scenario {}", path.display()))?;
                let mut scenario = DamperScenario::from_toml_str(&text)
                    .with_context(|| format!("scenario {}", path.display()))?;
                if let Some(d) = args.duration_s {
                    scenario.duration_s = d;
                    scenario
                        .validate()
                        .with_context(|| format!("--duration-s {d}"))?;
                }
                last_bogie_id(args.bogie_id.unwrap_or(DEFAULT_BOGIE_ID), args.bogies)?;
                let simulators = simulators(&scenario, args.bogies)
                    .with_context(|| format!("scenario {}", path.display()))?;
                let dt_s = scenario.dt_s;
                let samples = Samples::Simulated {
                    scenario: Box::new(scenario),
                    simulators,
                };
                (samples, args.bogies, dt_s, true)
            }
            (None, Some(path)) => {
                if args.bogies != 1 {
                    bail!("--bogies applies to --scenario only (a CSV names its bogies)");
                }
                let reader = BogieCsvReader::open(path)?;
                if reader.has_bogie_column() && args.bogie_id.is_some() {
                    bail!(
                        "--bogie-id: {} names the bogie of every row (column `bogie`)",
                        path.display()
                    );
                }
                let with_truth = reader.has_truth();
                if !reader.has_speed() {
                    eprintln!(
                        "sensors-replay: warning: {} has no speed_m_s column: sending {} m/s \
                         (--assume-speed-m-s)",
                        path.display(),
                        assumed_speed_m_s(args)
                    );
                }
                let samples = Samples::Recorded {
                    path: path.clone(),
                    reader: Box::new(reader),
                };
                (samples, 1, 1e-3, with_truth)
            }
            (None, None) => bail!("give --scenario FILE or --csv FILE"),
        };
        let writer = match &args.replay.record {
            Some(path) => Some(BogieCsvWriter::create_with_bogie_ids(path, with_truth)?),
            None => None,
        };
        Ok(Self {
            samples,
            first_id: args.bogie_id.unwrap_or(DEFAULT_BOGIE_ID),
            n_bogies,
            dt_s,
            pending: VecDeque::new(),
            last: None,
            ids_sent: Vec::new(),
            writer,
            assumed_speed_m_s: assumed_speed_m_s(args),
        })
    }

    /// The next record and its bogie id; `None` at the end of the run.
    fn next_record(&mut self) -> anyhow::Result<Option<(u32, BogieRecord)>> {
        match &mut self.samples {
            Samples::Simulated { simulators, .. } => {
                if self.pending.is_empty() {
                    // Ids checked at open: `first_id + k` stays within u32 (no RangeFrom,
                    // whose step past the last id would overflow at u32::MAX).
                    for (k, s) in (0..).zip(simulators.iter_mut()) {
                        let k = self.first_id + k;
                        // The simulators share the scenario's duration: they end together.
                        let Some((y, truth)) = s.step() else {
                            self.pending.clear();
                            return Ok(None);
                        };
                        let record = BogieRecord {
                            time_s: truth.time_s,
                            sensors: y.to_vector().into(),
                            speed_m_s: Some(y.speed_m_s),
                            // The scenario's `[load] measured`: the plant's mass, or none.
                            half_body_mass_kg: y.half_body_mass_kg,
                            truth_ns_per_m: Some([
                                truth.dampers.csy_ns_per_m,
                                truth.dampers.csay_ns_per_m,
                            ]),
                        };
                        self.pending.push_back((k, record));
                    }
                }
                Ok(self.pending.pop_front())
            }
            Samples::Recorded { path, reader } => {
                let file_ids = reader.has_bogie_column();
                let Some((id, record)) = reader.next_bogie_record()? else {
                    return Ok(None);
                };
                if record.time_s < 0.0 {
                    bail!(
                        "{}:{}: field \"time_s\" = \"{}\": negative (the bus carries times >= 0)",
                        path.display(),
                        reader.line(),
                        record.time_s
                    );
                }
                Ok(Some((if file_ids { id } else { self.first_id }, record)))
            }
        }
    }
}

impl Source for BogieSource {
    type Frame = BogieFrame;

    fn period_s(&self) -> f64 {
        self.dt_s
    }

    fn next(&mut self) -> anyhow::Result<Option<(BogieFrame, u64)>> {
        let Some((id, record)) = self.next_record()? else {
            return Ok(None);
        };
        if !self.ids_sent.contains(&id) {
            self.ids_sent.push(id);
        }
        let speed_m_s = record.speed_m_s.unwrap_or(self.assumed_speed_m_s);
        let sample = BogieSample {
            half_body_mass_kg: record.half_body_mass_kg,
            ..BogieSample::from_vector(&record.sensors.into(), speed_m_s)
        };
        // Recorded as sent: with the speed the frame carried.
        let record = BogieRecord {
            speed_m_s: Some(speed_m_s),
            ..record
        };
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
                reader: Box::new(BogieCsvReader::open(path)?),
                path: path.clone(),
            },
        };
        self.pending.clear();
        Ok(())
    }

    fn record(&mut self, _sent: u64, run_offset_s: f64) -> anyhow::Result<()> {
        if let (Some(writer), Some((id, record))) = (self.writer.as_mut(), &self.last) {
            let time_s = record.time_s + run_offset_s;
            writer.write_bogie(*id, &BogieRecord { time_s, ..*record })?;
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
        format!("1 of {} bogie(s)", self.ids_sent.len())
    }
}

pub fn run(args: BogieArgs) -> anyhow::Result<Outcome> {
    let mut source = BogieSource::open(&args)?;
    publish(
        &mut source,
        &args.replay,
        &input_label(&args.csv, &args.scenario),
    )
}

#[cfg(test)]
mod tests {
    use clap::Parser;

    use super::*;
    use crate::replay::replay_offline;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        bogie: BogieArgs,
    }

    fn source(args: &[&str]) -> anyhow::Result<BogieSource> {
        let cli = Cli::try_parse_from(std::iter::once("bogie").chain(args.iter().copied()))?;
        BogieSource::open(&cli.bogie)
    }

    fn temp_dir(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("sensors-replay-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    const SCENARIO: &str = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../config/scenarios/damper-fault.toml"
    );

    #[test]
    fn every_bogie_and_every_run_is_recorded_and_replays_as_sent() {
        let dir = temp_dir("bogies");
        let record = dir.join("bogies.csv");
        let record_arg = record.to_str().unwrap();
        let args = [
            "--scenario",
            SCENARIO,
            "--bogies",
            "2",
            "--bogie-id",
            "3",
            "--duration-s",
            "0.005",
            "--record",
            record_arg,
        ];
        let sent = replay_offline(&mut source(&args).unwrap(), 2).unwrap();
        // 2 runs of 5 steps of bogies 3 and 4, interleaved; the second run repeats the first
        // (same seeds); its time 0 is one period (1 ms) after the first run's last sample.
        assert_eq!(sent.len(), 2 * 5 * 2);
        let ids: Vec<u32> = sent.iter().map(|(f, _)| f.bogie_id).collect();
        assert_eq!(ids, [3, 4].repeat(10));
        assert_ne!(sent[0].0, sent[1].0, "two bogies, two simulators");
        assert_eq!((sent[10].0, sent[11].0), (sent[0].0, sent[1].0));
        assert_eq!(sent[10].1, sent[9].1 + 1_000_000 + sent[0].1);
        assert_eq!(sent[0].1, sent[1].1);

        // The recording holds every frame sent, with its bogie id, on the replay's clock.
        let mut reader = BogieCsvReader::open(&record).unwrap();
        assert!(reader.has_bogie_column() && reader.has_truth());
        for (frame, time_ns) in &sent {
            let (id, r) = reader.next_bogie_record().unwrap().unwrap();
            let sample = BogieSample {
                half_body_mass_kg: r.half_body_mass_kg,
                ..BogieSample::from_vector(&r.sensors.into(), r.speed_m_s.unwrap())
            };
            assert_eq!(BogieFrame::from_sample(id, &sample), *frame);
            assert_eq!((r.time_s * 1e9).round() as u64, *time_ns);
        }
        assert_eq!(reader.next_bogie_record().unwrap(), None);

        // Replaying the recording sends the same frames at the same times.
        let mut replayed = source(&["--csv", record_arg]).unwrap();
        assert_eq!(replay_offline(&mut replayed, 1).unwrap(), sent);
        let err = source(&["--csv", record_arg, "--bogie-id", "2"])
            .err()
            .unwrap();
        assert!(err.to_string().contains("column `bogie`"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_csv_without_bogie_column_is_one_bogie_of_the_given_id() {
        let dir = temp_dir("one-bogie");
        // The layout before bogie ids and speed.
        let old = dir.join("old.csv");
        let mut text = railmon_records::bogie::BOGIE_COLUMNS.join(",");
        for k in 1..=3 {
            text += &format!("\n{},0.1,0.2,0.3,0.004,{k}", 1e-3 * f64::from(k));
        }
        std::fs::write(&old, text + "\n").unwrap();
        let args = |id: &'static str| ["--csv", old.to_str().unwrap(), "--bogie-id", id];
        let sent = replay_offline(&mut source(&args("2")).unwrap(), 1).unwrap();
        let got: Vec<(u32, f64, u64, f64)> = sent
            .iter()
            .map(|(f, t)| (f.bogie_id, f.body_accel_m_s2, *t, f.speed_m_s))
            .collect();
        // Without a speed column: the assumed speed, the damper model's default.
        let v = DEFAULT_SPEED_M_S;
        assert_eq!(
            got,
            [
                (2, 1.0, 1_000_000, v),
                (2, 2.0, 2_000_000, v),
                (2, 3.0, 3_000_000, v)
            ]
        );
        let path = old.to_str().unwrap();
        let assumed = ["--csv", path, "--assume-speed-m-s", "30"];
        let sent = replay_offline(&mut source(&assumed).unwrap(), 1).unwrap();
        assert!(sent.iter().all(|(f, _)| f.speed_m_s == 30.0));
        assert!(source(&args("0")).is_err());
        let err = source(&[
            "--scenario",
            SCENARIO,
            "--bogie-id",
            "4294967295",
            "--bogies",
            "2",
        ])
        .err()
        .unwrap();
        assert!(err.to_string().contains("run past 4294967295"), "{err}");
        let err = source(&["--scenario", SCENARIO, "--duration-s=-1"])
            .err()
            .unwrap();
        assert!(format!("{err:#}").contains("duration_s"), "{err:#}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
