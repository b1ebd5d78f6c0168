//! The vehicle stream: a fuel scenario through `railmon_fuel::VehicleSimulator` (via
//! `railmon_records::vehicle_scenario`, which reads its drive cycles), or a recorded
//! vehicle CSV (the railmon layout or an ANL Camry file as it ships), published as
//! `VehicleFrame`s at the samples' own 1 Hz time stamps.

use std::path::PathBuf;

use anyhow::{bail, Context};
use railmon_bus::VehicleFrame;
use railmon_fuel::VehicleSample;
use railmon_records::vehicle::{read_vehicle_csv, write_vehicle_csv, VehicleRow};
use railmon_records::vehicle_scenario::simulate_vehicle_scenario;

use crate::replay::{publish, Outcome, Source};
use crate::{input_label, ReplayArgs};

#[derive(clap::Args, Debug)]
pub struct VehicleArgs {
    /// Fuel scenario (e.g. config/scenarios/fuel-cycles.toml): simulated vehicle, regime labels.
    #[arg(long, conflicts_with = "csv", required_unless_present = "csv")]
    scenario: Option<PathBuf>,
    /// Vehicle CSV: `time_s,fuel_cm3_s,speed_m_s[,pedal_pct,...,gear,regime]` or an ANL Camry
    /// dynamometer file (`Time[s],Eng_FuelFlow_Direct_DI[ccps],Dyno_Spd[mph]`).
    #[arg(long)]
    csv: Option<PathBuf>,
    #[command(flatten)]
    replay: ReplayArgs,
}

/// All rows of the run (1 Hz data: a day is 86,400 rows), replayed in order.
struct VehicleSource {
    rows: Vec<VehicleRow>,
    samples: Vec<VehicleSample>,
    /// Sample time of each row within the run, ns.
    times_ns: Vec<u64>,
    period_s: f64,
    next: usize,
    recorded: Option<(PathBuf, Vec<VehicleRow>)>,
}

impl VehicleSource {
    fn open(args: &VehicleArgs) -> anyhow::Result<Self> {
        args.replay
            .refuse_recording_over_an_input(&[args.scenario.as_deref(), args.csv.as_deref()])?;
        let (label, rows) = match (&args.scenario, &args.csv) {
            (Some(path), _) => {
                let run = simulate_vehicle_scenario(path)
                    .with_context(|| format!("cannot simulate scenario {}", path.display()))?;
                (path.display().to_string(), run.rows)
            }
            (None, Some(path)) => (path.display().to_string(), read_vehicle_csv(path)?.1),
            (None, None) => bail!("give --scenario FILE or --csv FILE"),
        };
        // The bus carries times since the run's start as unsigned ns.
        let times_ns = rows
            .iter()
            .enumerate()
            .map(|(k, r)| match r.sample.time_s >= 0.0 {
                true => Ok((r.sample.time_s * 1e9).round() as u64),
                false => bail!(
                    "{label}: row {}: time_s {} is negative (the bus carries times >= 0)",
                    k + 1,
                    r.sample.time_s
                ),
            })
            .collect::<anyhow::Result<Vec<u64>>>()?;
        let period_s = match rows.as_slice() {
            [first, second, ..] => second.sample.time_s - first.sample.time_s,
            _ => 1.0,
        };
        Ok(Self {
            samples: rows.iter().map(|r| r.sample).collect(),
            rows,
            times_ns,
            period_s,
            next: 0,
            recorded: args.replay.record.clone().map(|path| (path, Vec::new())),
        })
    }
}

impl Source for VehicleSource {
    type Frame = VehicleFrame;

    fn period_s(&self) -> f64 {
        self.period_s
    }

    fn next(&mut self) -> anyhow::Result<Option<(VehicleFrame, u64)>> {
        let Some(sample) = self.samples.get(self.next) else {
            return Ok(None);
        };
        let frame = VehicleFrame::from_sample(sample);
        let time_ns = self.times_ns[self.next];
        self.next += 1;
        Ok(Some((frame, time_ns)))
    }

    fn rewind(&mut self) -> anyhow::Result<()> {
        self.next = 0;
        Ok(())
    }

    fn record(&mut self, _sent: u64, run_offset_s: f64) -> anyhow::Result<()> {
        if let Some((_, rows)) = self.recorded.as_mut() {
            let mut row = self.rows[self.next - 1].clone();
            row.sample.time_s += run_offset_s;
            rows.push(row);
        }
        Ok(())
    }

    fn finish_recording(&mut self) -> anyhow::Result<()> {
        // Written at the end (`write_vehicle_csv` takes the columns from the first row), so
        // a `--loop` recording holds every row sent in memory until then (1 Hz: ~100 bytes a
        // sample, ~9 MB a day at real time).
        if let Some((path, rows)) = self.recorded.take() {
            write_vehicle_csv(&path, &rows)?;
        }
        Ok(())
    }

    fn describe(&self) -> String {
        let channels = self
            .samples
            .first()
            .map_or(0, |s| VehicleFrame::from_sample(s).present.count_ones());
        format!("{channels} vehicle channels")
    }
}

pub fn run(args: VehicleArgs) -> anyhow::Result<Outcome> {
    let mut source = VehicleSource::open(&args)?;
    publish(
        &mut source,
        &args.replay,
        &input_label(&args.csv, &args.scenario),
    )
}

#[cfg(test)]
mod tests {
    use clap::Parser;
    use railmon_records::vehicle::read_vehicle_csv;

    use super::*;
    use crate::replay::replay_offline;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        vehicle: VehicleArgs,
    }

    #[test]
    fn every_run_is_recorded_on_a_continuing_clock_and_replays_as_sent() {
        let dir =
            std::env::temp_dir().join(format!("sensors-replay-vehicle-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (input, record) = (dir.join("in.csv"), dir.join("record.csv"));
        std::fs::write(&input, "time_s,fuel_cm3_s,speed_m_s,gear,regime\n10,0.5,3,1,eco\n11,0.75,4,2,eco\n12,1.5,6,2,sporty\n").unwrap();
        let open = |args: &[&str]| {
            let cli = Cli::try_parse_from(std::iter::once("vehicle").chain(args.iter().copied()));
            VehicleSource::open(&cli.unwrap().vehicle).unwrap()
        };
        let (input_arg, record_arg) = (input.to_str().unwrap(), record.to_str().unwrap());
        let sent =
            replay_offline(&mut open(&["--csv", input_arg, "--record", record_arg]), 2).unwrap();
        let times: Vec<u64> = sent.iter().map(|(_, t)| t / 1_000_000_000).collect();
        // The second run's time 0 is one period (1 s) after the first run's last sample.
        assert_eq!(times, [10, 11, 12, 23, 24, 25]);

        let (_, input_rows) = read_vehicle_csv(&input).unwrap();
        let (_, recorded) = read_vehicle_csv(&record).unwrap();
        assert_eq!(recorded.len(), 6);
        for (k, row) in recorded.iter().enumerate() {
            let mut want = input_rows[k % 3].clone();
            want.sample.time_s = times[k] as f64;
            // The recording's own line: after its header, one row per sample.
            want.line = k as u64 + 2;
            assert_eq!(*row, want);
        }
        let replayed = replay_offline(&mut open(&["--csv", record_arg]), 1).unwrap();
        assert_eq!(replayed, sent);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
