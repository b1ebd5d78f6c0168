//! One gain table per filter model for all the runs of a test binary.
//!
//! A monitor built with no table (`DamperMonitor::new`, `for_bogie(.., None)`) builds its own
//! and solves every speed and mass node it reaches again (0.3-0.5 s a node in release, more in
//! the tests' dev profile): a run through a stop, with the particles carrying their own body
//! mass, reaches dozens, and the same ones in every run and on every seed. The service shares
//! one table among the bogies of a vehicle type the same way (`DamperMonitor::with_gain_table`).
//! A node's grid is solved from the table's inputs alone, blocking any other user of the node
//! until it is done (`GainTable::grid_at`): a filter on a shared table computes bit for bit what
//! it would on its own, whichever run solved the node first.
//!
//! Included with `#[path]` by the test binaries that use it (not from `common/mod.rs`: the
//! binaries that do not would warn of dead code).

use std::ops::RangeInclusive;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::Duration;

use railmon_damper::gain_table::GainTable;
use railmon_damper::{DamperMonitorConfig, FilterModel, GainGridConfig, Rbpf, SpeedConfig};

/// Everything a table is built from (`GainTable::for_model`'s arguments): a table is shared
/// only by configurations equal in all of it, never used for another model's fingerprint.
type Key = (FilterModel, GainGridConfig, SpeedConfig);

static TABLES: Mutex<Vec<(Key, Arc<GainTable>)>> = Mutex::new(Vec::new());

/// The table `DamperMonitor::new(config, ..)` would build for itself, built once per test
/// binary for each filter model, speed range and grid.
pub fn for_config(config: &DamperMonitorConfig) -> Arc<GainTable> {
    let key = (config.filter_model(), config.rbpf.gain_grid, config.speed);
    // Held while building: a second test asking for the same table waits for it (the first
    // node's solution) instead of solving it too.
    let mut tables = TABLES.lock().unwrap_or_else(PoisonError::into_inner);
    if let Some((_, table)) = tables.iter().find(|(k, _)| *k == key) {
        return table.clone();
    }
    let table = Rbpf::gain_table(&key.0, &config.rbpf, &config.speed).unwrap();
    tables.push((key, table.clone()));
    table
}

/// Solves, on one thread a core, the nodes next to the speed and masses a run's filter is at,
/// as the service's thread does (`service/src/bogie/warm.rs`): a filter through a stop with
/// its mass withheld needs up to 11 new mass nodes at each speed node it accelerates through,
/// and would otherwise solve them one after the other in its step while the other core idles.
/// The filter waits for a node being solved here rather than solving it too
/// (`GainTable::grid_at`), so what it computes does not change, only when the nodes are solved.
/// Stopped (after the nodes under way) when dropped.
pub struct SolvingAhead {
    /// Speed (m/s), lightest and heaviest mass (kg), as `f64` bits (read one by one: a thread
    /// may solve one node off the filter's way, no more).
    at: Arc<[AtomicU64; 3]>,
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
}

impl SolvingAhead {
    /// Speed nodes either side of the filter's own that are solved ahead: the filter passes
    /// one at a time, and a wider reach would solve speeds it never runs at.
    const REACH: usize = 1;

    pub fn new(table: Arc<GainTable>) -> Self {
        let at = Arc::new([0.0; 3].map(|x: f64| AtomicU64::new(x.to_bits())));
        let stop = Arc::new(AtomicBool::new(false));
        // One thread a core: the filter itself mostly waits for the nodes under way here.
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
        let threads = (0..threads)
            .map(|_| {
                let (table, at, stop) = (table.clone(), at.clone(), stop.clone());
                std::thread::spawn(move || {
                    while !stop.load(Ordering::Relaxed) {
                        let [v, lo, hi] =
                            [0, 1, 2].map(|k| f64::from_bits(at[k].load(Ordering::Relaxed)));
                        let missing = if v > 0.0 && lo > 0.0 {
                            table.missing_near(v, lo..=hi, Self::REACH)
                        } else {
                            // Nothing followed yet.
                            None
                        };
                        match missing {
                            // An error is the filter's to report, when it reaches the node.
                            Some(node) => drop(table.grid_at(node)),
                            None => std::thread::sleep(Duration::from_millis(1)),
                        }
                    }
                })
            })
            .collect();
        SolvingAhead { at, stop, threads }
    }

    /// The filter runs at `speed_m_s` and the masses `half_body_masses_kg` now: the
    /// measured one, or the span of its particles' own (`Rbpf::particle_mass_span_kg`), or the
    /// design mass.
    pub fn follow(&self, speed_m_s: f64, half_body_masses_kg: RangeInclusive<f64>) {
        let (lo, hi) = half_body_masses_kg.into_inner();
        for (k, x) in [speed_m_s, lo, hi].into_iter().enumerate() {
            self.at[k].store(x.to_bits(), Ordering::Relaxed);
        }
    }
}

impl Drop for SolvingAhead {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for thread in self.threads.drain(..) {
            let _ = thread.join();
        }
    }
}
