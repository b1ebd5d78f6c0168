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
use railmon_bus::BusConfig;
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
    /// bogie, every `--loop` run with times continuing; vehicle: written at the end).
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// Config file whose `[bus]` section names prefix, root path and services (default: the
    /// embedded defaults); RAILMON_BUS__* environment variables override it.
    #[arg(long, env = "RAILMON_CONFIG")]
    pub config: Option<PathBuf>,
    /// Give up when no subscriber connects within this many seconds (0: wait forever).
    #[arg(long, default_value_t = 30.0)]
    pub wait_subscriber_s: f64,
    /// At `--speed max`, wake the subscriber once per this many frames (paced: every frame).
    #[arg(long, default_value_t = 32)]
    pub notify_every: u64,
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
}

/// The `[bus]` section of `file` (if any) with the environment's overrides.
pub fn load_bus_config(file: Option<&Path>) -> anyhow::Result<BusConfig> {
    let mut table = match file {
        Some(path) => {
            let text = std::fs::read_to_string(path)
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

static STOP: AtomicBool = AtomicBool::new(false);

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

fn main() -> anyhow::Result<()> {
    install_stop_handlers();
    match Cli::parse().stream {
        StreamCommand::Drive(args) => drive::run(args),
        StreamCommand::Bogie(args) => bogie::run(args),
        StreamCommand::Vehicle(args) => vehicle::run(args),
    }
}
