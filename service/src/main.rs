//! `railmon`: the onboard condition-monitoring service (`serve`) and offline analysis (`analyze`).

#[cfg(feature = "analyze")]
mod analyze_cmd;
mod config_cmd;
mod damper_cmd;
mod fleet_cmd;
mod serve;
#[cfg(feature = "analyze")]
mod summary;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "railmon",
    version,
    about = "Onboard condition monitoring for rail vehicles: wheel slip, damper health, fuel use",
    after_help = "Logs go to stderr; RAILMON_LOG (or RUST_LOG) sets the filter, e.g. RAILMON_LOG=warn."
)]
struct Cli {
    /// Log as JSON lines instead of human-readable text.
    #[arg(long, global = true)]
    log_json: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Ingest the sensor streams from the bus and serve estimates over HTTP.
    Serve(serve::ServeArgs),
    /// The fleet view: a stateless HTTP service answering fleet queries (a vehicle's events,
    /// its latest health summary, the vehicles with an active alarm) from the vehicles'
    /// NATS JetStream stream.
    Fleet(fleet_cmd::FleetArgs),
    /// The settings: their reference, and a check of a configuration.
    #[command(subcommand)]
    Config(config_cmd::ConfigCommand),
    /// The damper estimator's gain cache.
    #[command(subcommand)]
    Damper(damper_cmd::DamperCommand),
    /// Run an estimator offline over a scenario or a recorded CSV: CSV reports and PNG plots.
    #[cfg(feature = "analyze")]
    #[command(subcommand)]
    Analyze(Analyze),
}

#[cfg(feature = "analyze")]
use railmon_analyze::many::Many;

/// One line per domain: `Name(Many<railmon_analyze::name::Args>)` here and its arm in `run`.
#[cfg(feature = "analyze")]
#[derive(Subcommand)]
enum Analyze {
    /// Wheel slip of traction drives: EKF per drive, then VB, VMP, k-means, median and temporal.
    #[command(long_about = None)]
    Adhesion(Many<railmon_analyze::adhesion::Args>),
    /// Damper health of a bogie: Rao-Blackwellised particle filter against an augmented EKF.
    #[command(long_about = None)]
    Damper(Many<railmon_analyze::damper::Args>),
    /// Fuel use and driving regime: recursive mixture with data-dependent switching.
    #[command(long_about = None)]
    Fuel(Many<railmon_analyze::fuel::Args>),
}

/// An error and its causes on one line, each cause once: an error whose message already
/// includes its source's (the usual `"{file}: {source}"`) is not followed by it again.
/// Runs of white space (line breaks) become one space.
pub(crate) fn one_line(error: &anyhow::Error) -> String {
    let mut line = error.to_string();
    for cause in error.chain().skip(1) {
        let cause = cause.to_string();
        if !line.contains(&cause) {
            line.push_str(": ");
            line.push_str(&cause);
        }
    }
    // Messages that span lines (a settings error names key and variable on lines of their
    // own) become one line.
    line.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// Writes `text` to stdout; a reader that went away (`railmon analyze ... | head`) ends the
/// output quietly instead of a panic (Rust ignores SIGPIPE, so the write fails with EPIPE).
pub(crate) fn print_out(text: &str) -> anyhow::Result<()> {
    use std::io::Write;
    let mut stdout = std::io::stdout().lock();
    match stdout
        .write_all(text.as_bytes())
        .and_then(|()| stdout.flush())
    {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        other => Ok(other?),
    }
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Serve(args) => serve::run(args),
        Command::Fleet(args) => fleet_cmd::run(args),
        Command::Config(command) => config_cmd::run(command),
        Command::Damper(command) => damper_cmd::run(command),
        #[cfg(feature = "analyze")]
        Command::Analyze(analyze) => match analyze {
            Analyze::Adhesion(many) => analyze_cmd::run(
                many,
                analyze_cmd::Shown {
                    tables: |r| Some(&r.tables_text),
                    headline: summary::adhesion,
                },
            ),
            Analyze::Damper(many) => analyze_cmd::run(
                many,
                analyze_cmd::Shown {
                    tables: |_| None,
                    headline: summary::damper,
                },
            ),
            Analyze::Fuel(many) => analyze_cmd::run(
                many,
                analyze_cmd::Shown {
                    tables: |_| None,
                    headline: summary::fuel,
                },
            ),
        },
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    serve::init_tracing(cli.log_json);
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("railmon: {}", one_line(&e));
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::one_line;

    #[derive(Debug, thiserror::Error)]
    #[error("config/x.toml: {0}")]
    struct Outer(#[source] std::io::Error);

    #[test]
    fn an_error_is_one_line_with_each_cause_once() {
        let inner = std::io::Error::other("no such key `foo`\n (from RAILMON_FOO)");
        let e = anyhow::Error::from(Outer(inner)).context("invalid configuration");
        assert_eq!(
            one_line(&e),
            "invalid configuration: config/x.toml: no such key `foo` (from RAILMON_FOO)"
        );
    }
}
