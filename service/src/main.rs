//! `railmon`: the onboard condition-monitoring service (`serve`) and offline analysis (`analyze`).

mod serve;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "railmon",
    version,
    about = "Onboard condition monitoring for rail vehicles"
)]
struct Cli {
    /// Logs as JSON lines instead of human-readable text.
    #[arg(long, global = true)]
    log_json: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Ingest the sensor streams from the bus and serve estimates over HTTP.
    Serve(serve::ServeArgs),
    /// Offline analysis of a scenario or a recorded CSV.
    #[command(subcommand)]
    Analyze(Analyze),
}

/// One line per domain: `Name(railmon_analyze::name::Args)` here and its arm in `main`.
#[derive(Subcommand)]
enum Analyze {
    Adhesion(railmon_analyze::adhesion::Args),
    Damper(railmon_analyze::damper::Args),
    Fuel(railmon_analyze::fuel::Args),
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    serve::init_tracing(cli.log_json);
    match cli.command {
        Command::Serve(args) => serve::run(args),
        Command::Analyze(analyze) => match analyze {
            Analyze::Adhesion(args) => railmon_analyze::adhesion::run(&args)
                .map(|_| ())
                .map_err(anyhow::Error::from),
            Analyze::Damper(args) => railmon_analyze::damper::run(&args)
                .map(|_| ())
                .map_err(anyhow::Error::from),
            Analyze::Fuel(args) => railmon_analyze::fuel::run(&args)
                .map(|_| ())
                .map_err(anyhow::Error::from),
        },
    }
}
