//! `railmon damper warm-cache`: solves the damper filters' gain grids of a configuration and
//! stores them where `railmon serve` with that configuration loads them
//! (`<storage.data_dir>/gain-cache`), e.g. while building an image, so that the service
//! estimates every bogie at any speed within a few seconds of its start (issue 28 item 1).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context};
use railmon_damper::{Propagation, Rbpf};
use railmon_records::gain_cache::GainCache;
use railmon_service::ServiceConfig;

#[derive(clap::Subcommand)]
pub enum DamperCommand {
    /// Solve every speed node of the bogie estimator's gain table at the design mass and at
    /// the masses `estimator.rbpf.unmeasured_mass` spans (what a service runs at when the
    /// frames carry no `half_body_mass_kg`), and store them in the gain cache (nodes already
    /// stored and valid are kept); prints what it did.
    WarmCache {
        /// Every mass node of the table too (0.7-1.6 x the design mass: 18 x the speed
        /// nodes, about 1 MB each): for vehicles whose frames carry a measured mass.
        #[arg(long)]
        all_masses: bool,
        /// Config file (TOML) as `railmon serve --config FILE` reads it, with the
        /// RAILMON_<SECTION>__<KEY> environment overrides; without it, the defaults.
        #[arg(long, env = "RAILMON_CONFIG")]
        config: Option<PathBuf>,
        /// The cache directory; without it, `<storage.data_dir>/gain-cache` of the
        /// configuration (where `serve` looks).
        #[arg(long)]
        dir: Option<PathBuf>,
    },
}

pub fn run(command: DamperCommand) -> anyhow::Result<()> {
    match command {
        DamperCommand::WarmCache {
            config,
            dir,
            all_masses,
        } => {
            let name = config
                .as_deref()
                .map_or("the defaults".to_string(), |f| f.display().to_string());
            let (service, _) = ServiceConfig::load_reporting(config.as_deref(), std::env::vars())
                .with_context(|| format!("{name}: invalid configuration"))?;
            let cache = match (dir, service.storage.gain_cache()) {
                (Some(dir), _) => GainCache::new(dir),
                (None, Some(cache)) => cache,
                (None, None) => bail!(
                    "storage.data_dir is :memory:, which keeps no gain cache; name one with --dir"
                ),
            };
            let estimator = &service.bogie.estimator;
            if estimator.rbpf.propagation != Propagation::SteadyState {
                return crate::print_out(
                    "bogie.estimator.rbpf.propagation is exact: no gain table to cache\n",
                );
            }
            let started = Instant::now();
            let table = Rbpf::unsolved_gain_table(
                &estimator.filter_model(),
                &estimator.rbpf,
                &estimator.speed,
            )
            .context("bogie.estimator")?;
            let report = cache.load_all(&table);
            for e in &report.refused {
                eprintln!("railmon: {e}");
            }
            let design_kg = estimator.vehicle.half_body_mass_kg;
            let masses_kg = if all_masses {
                0.0..=f64::INFINITY
            } else {
                estimator
                    .rbpf
                    .unmeasured_mass
                    .prior_masses_kg(design_kg)
                    .unwrap_or(design_kg..=design_kg)
            };
            let mut nodes: Vec<usize> = (0..table.n_nodes()).collect();
            nodes.extend(
                table
                    .nodes_of_masses(masses_kg)
                    .into_iter()
                    .filter(|&n| n >= table.n_nodes()),
            );
            let mut solved = 0;
            for &node in &nodes {
                if table.is_solved(node) {
                    continue;
                }
                table.grid_at(node).with_context(|| {
                    format!(
                        "the gain grid at {:.2} m/s, {:.0} kg cannot be solved",
                        table.node_speed_m_s(node),
                        table.node_half_body_mass_kg(node)
                    )
                })?;
                cache.store(&table, node)?;
                solved += 1;
            }
            let masses: Vec<f64> = nodes
                .iter()
                .step_by(table.n_nodes())
                .map(|&n| table.node_half_body_mass_kg(n))
                .collect();
            let (lightest, heaviest) = masses
                .iter()
                .fold((f64::INFINITY, 0.0_f64), |(lo, hi), &m| {
                    (lo.min(m), hi.max(m))
                });
            crate::print_out(&format!(
                "{}: {} nodes: {} speeds ({:.2}-{:.2} m/s) x {} masses ({lightest:.0}-{heaviest:.0} \
                 kg), {} were stored, {solved} solved and stored, in {:.1} s\n",
                cache.dir().display(),
                nodes.len(),
                table.n_nodes(),
                table.node_speed_m_s(0),
                table.node_speed_m_s(table.n_nodes() - 1),
                masses.len(),
                report.loaded.len(),
                started.elapsed().as_secs_f64()
            ))
        }
    }
}
