//! `sensors-replay`: publishes a sensor stream on the bus, from a simulated scenario or a
//! recorded CSV file, paced at `--speed 1` (real time), `--speed 10`, ... or `--speed max`.
//!
//! It waits until a subscriber (the service) has connected before the first frame (iceoryx2
//! drops frames sent before), and again whenever nobody takes a frame (service restarted).

mod bogie;
mod drive;
mod pacing;
mod replay;
mod vehicle;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::Context;
use clap::{Parser, Subcommand};
use railmon_bus::{BusConfig, BusError};
use railmon_settings as settings;

#[derive(Parser)]
#[command(
    name = "sensors-replay",
    version,
    about = "Publish simulated or recorded sensor streams on the railmon bus"
)]
struct Cli {
    #[command(subcommand)]
    stream: StreamCommand,
}

/// One subcommand per stream.
#[derive(Subcommand)]
enum StreamCommand {
    /// Traction drives: voltages and currents of all drives per control step.
    Drive(drive::DriveArgs),
    /// Bogies at 1 kHz: wheelset, bogie and body accelerations and the bogie's yaw rate.
    Bogie(bogie::BogieArgs),
    /// Road vehicle at 1 Hz: fuel flow, speed, pedal, engine torque and speed, gear.
    Vehicle(vehicle::VehicleArgs),
}

/// Options every stream shares.
#[derive(clap::Args, Debug)]
pub struct ReplayArgs {
    /// Pace: 1 = real time, 10 = ten times faster, `max` = as fast as the subscriber takes them.
    #[arg(long, default_value = "1")]
    pub speed: pacing::Speed,
    /// Start again from the beginning at the end (the service restarts its estimator).
    #[arg(long = "loop")]
    pub repeat: bool,
    /// Also write every frame sent to this CSV file (the stream's recording format, every
    /// bogie, every `--loop` run with times continuing). Written under a temporary name and
    /// put in place at the end: an existing file is replaced only once frames were sent, and
    /// never when it is an input.
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// Config file whose `[bus]` section names prefix, root path and services (default: the
    /// embedded defaults); RAILMON_BUS__* environment variables override it.
    #[arg(long, env = "RAILMON_CONFIG")]
    pub config: Option<PathBuf>,
    /// Give up when no subscriber connects within this many seconds (0: wait forever; at
    /// most 86400).
    #[arg(long, default_value_t = 30.0, value_parser = bounded_f64(0.0, MAX_WAIT_SUBSCRIBER_S))]
    pub wait_subscriber_s: f64,
    /// At `--speed max`, wake the subscriber once per this many frames (paced: every frame).
    #[arg(long, default_value_t = 32, value_parser = clap::value_parser!(u64).range(1..=65_536))]
    pub notify_every: u64,
    /// A gap between samples longer than this (s of stream time) is shortened to it when
    /// paced: the replay starts at the first sample whatever its time, and a recording with a
    /// day-long pause does not wait a day. In (0, 86400].
    #[arg(long, default_value_t = 5.0, value_parser = bounded_f64(1e-3, MAX_WAIT_SUBSCRIBER_S))]
    pub max_gap_s: f64,
    /// Stop after this many frames (all runs together).
    #[arg(long)]
    pub max_frames: Option<u64>,
    /// UTC time of the first sample (RFC 3339, e.g. 2026-11-22T08:00:00Z): frames carry
    /// it plus their time on the replay's clock as their acquisition time. Default: when the
    /// replay starts.
    #[arg(long, value_parser = railmon_bus::utc::parse_rfc3339)]
    pub start_utc: Option<i64>,
}

impl ReplayArgs {
    pub fn wait_timeout(&self) -> Option<Duration> {
        (self.wait_subscriber_s > 0.0).then(|| Duration::from_secs_f64(self.wait_subscriber_s))
    }

    /// Refuses a `--record` file that is one of the stream's `inputs` (or the `--config`
    /// file): `--csv X --record X` would replace the recording being replayed.
    pub fn refuse_recording_over_an_input(&self, inputs: &[Option<&Path>]) -> anyhow::Result<()> {
        let Some(record) = &self.record else {
            return Ok(());
        };
        let inputs: Vec<&Path> = inputs
            .iter()
            .copied()
            .chain([self.config.as_deref()])
            .flatten()
            .collect();
        railmon_records::refuse_output_that_is_an_input(record, &inputs, "--record")?;
        Ok(())
    }
}

/// The `[bus]` section of `file` (if any) with the environment's overrides.
pub fn load_bus_config(file: Option<&Path>) -> anyhow::Result<BusConfig> {
    let mut table = match file {
        Some(path) => {
            let text =
                railmon_records::read_text_file(path, railmon_records::MAX_SETTINGS_FILE_BYTES)
                    .with_context(|| format!("cannot read config file {}", path.display()))?;
            settings::parse_table(&text, &path.display().to_string())?
        }
        None => toml::Table::new(),
    };
    let overrides = settings::apply_env_overrides(&mut table, settings::process_env())?;
    let bus = table
        .remove("bus")
        .unwrap_or_else(|| toml::Value::Table(toml::Table::new()));
    let config: BusConfig = settings::deserialize(bus, "bus", &overrides)?;
    config.validate()?;
    Ok(config)
}

/// The longest `--wait-subscriber-s` (a day): a larger number is a mistake, and `inf` or
/// `1e20` overflowed the wait's duration (a panic).
const MAX_WAIT_SUBSCRIBER_S: f64 = 86_400.0;

/// A clap parser for a finite number in `[min, max]`, whose error names the range.
pub fn bounded_f64(min: f64, max: f64) -> impl Fn(&str) -> Result<f64, String> + Clone {
    move |text: &str| match text.parse::<f64>() {
        Ok(x) if x.is_finite() && (min..=max).contains(&x) => Ok(x),
        Ok(_) => Err(format!("`{text}` is not in [{min}, {max}]")),
        Err(_) => Err(format!("`{text}` is not a number")),
    }
}

/// The input named in messages: the CSV file or the scenario.
pub fn input_label(csv: &Option<PathBuf>, scenario: &Option<PathBuf>) -> String {
    csv.as_ref()
        .or(scenario.as_ref())
        .map_or_else(|| "<no input>".to_string(), |p| p.display().to_string())
}

pub static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn request_stop(_signal: libc::c_int) {
    STOP.store(true, Ordering::Relaxed);
}

/// SIGINT / SIGTERM end the replay after the current frame, so the publisher is dropped cleanly.
fn install_stop_handlers() {
    let handler = request_stop as extern "C" fn(libc::c_int) as libc::sighandler_t;
    // SAFETY: the handler only stores to an atomic, which is async-signal-safe.
    unsafe {
        libc::signal(libc::SIGINT, handler);
        libc::signal(libc::SIGTERM, handler);
    }
}

pub fn stop_requested() -> bool {
    STOP.load(Ordering::Relaxed)
}

/// Exit codes (docs/reliability.md). 0: the source ended, `--max-frames` was reached, or
/// SIGINT / SIGTERM stopped it (also while waiting for a subscriber), and every frame sent was
/// taken or is unconfirmed at a stop; 1: an error (bad input, bus, file), named on stderr;
/// 2: bad arguments (clap); the rest below.
mod exit {
    /// No subscriber answered within `--wait-subscriber-s`.
    pub const NO_SUBSCRIBER: u8 = 3;
    /// The input holds no samples (a header-only file): nothing was sent.
    pub const NO_SAMPLES: u8 = 4;
    /// Frames were lost: sent, never taken by any subscriber (a service died holding them).
    pub const FRAMES_LOST: u8 = 5;
}

fn main() -> std::process::ExitCode {
    install_stop_handlers();
    let result = match Cli::parse().stream {
        StreamCommand::Drive(args) => drive::run(args),
        StreamCommand::Bogie(args) => bogie::run(args),
        StreamCommand::Vehicle(args) => vehicle::run(args),
    };
    let code = match result {
        Ok(outcome) if outcome.report.lost > 0 => exit::FRAMES_LOST,
        Ok(_) => 0,
        Err(e) => {
            eprintln!("sensors-replay: error: {e:#}");
            match e.downcast_ref::<BusError>() {
                Some(BusError::NoSubscriber { .. }) => exit::NO_SUBSCRIBER,
                _ if e.is::<replay::NoSamples>() => exit::NO_SAMPLES,
                _ => 1,
            }
        }
    };
    std::process::ExitCode::from(code)
}
