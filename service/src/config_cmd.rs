//! `railmon config`: the settings reference, and a check of a configuration without starting
//! anything (as `promtool check config` and `vector validate` do).

use std::path::PathBuf;

use anyhow::Context;
use railmon_service::{config, ServiceConfig};

#[derive(clap::Subcommand)]
pub enum ConfigCommand {
    /// Print every setting (key, default, type, unit, meaning) as Markdown; docs/configuration.md
    /// is this output.
    Reference,
    /// Validate a config file and the RAILMON_<SECTION>__<KEY> environment overrides as
    /// `railmon serve --config FILE` would read them, without starting anything; exit 1 naming
    /// the key on the first invalid value.
    Check {
        /// Config file (TOML); without it, the defaults and the environment are checked.
        #[arg(env = "RAILMON_CONFIG")]
        file: Option<PathBuf>,
    },
}

pub fn run(command: ConfigCommand) -> anyhow::Result<()> {
    match command {
        ConfigCommand::Reference => crate::print_out(&config::reference_markdown()),
        ConfigCommand::Check { file } => {
            let name = file
                .as_deref()
                .map_or("the defaults".to_string(), |f| f.display().to_string());
            let (config, overrides) =
                ServiceConfig::load_reporting(file.as_deref(), std::env::vars())
                    .with_context(|| format!("{name}: invalid configuration"))?;
            crate::print_out(&format!("{}\n", summary(&name, &config, &overrides)))
        }
    }
}

/// What a valid configuration runs: the streams on, where it listens and stores, and each
/// environment override applied.
fn summary(name: &str, config: &ServiceConfig, overrides: &[(String, String)]) -> String {
    let on = |enabled: bool| if enabled { "on" } else { "off" };
    let mut lines = vec![
        format!("{name}: valid"),
        format!(
            "  streams: drive {}, bogie {} ({} bogies), vehicle {}",
            on(config.drive.enabled),
            on(config.bogie.enabled),
            config.bogie.bogies.len(),
            on(config.vehicle.enabled)
        ),
        format!("  http.listen: {}", config.http.listen),
        format!(
            "  storage.data_dir: {}",
            match config.storage.data_dir.is_empty() {
                true => "(the default)",
                false => config.storage.data_dir.as_str(),
            }
        ),
    ];
    for (key, variable) in overrides {
        lines.push(format!("  {key}: from {variable}"));
    }
    lines.join("\n")
}
