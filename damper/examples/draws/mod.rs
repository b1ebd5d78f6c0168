//! What the sampler matrices (`condition_matrix`, `ramp_matrix`) share (`mod draws;`): which
//! seeds a `--split` takes, and running the draws of a seed list on the machine's cores.
#![allow(dead_code)]

use std::str::FromStr;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use railmon_damper::sampler;

/// `--split`: even seeds tune, odd seeds are held out (`sampler::is_held_out`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Split {
    All,
    Tune,
    HeldOut,
}

impl Split {
    pub fn name(self) -> &'static str {
        match self {
            Split::All => "all",
            Split::Tune => "tune",
            Split::HeldOut => "held-out",
        }
    }

    /// Whether `seed` belongs to the split.
    pub fn admits(self, seed: u64) -> bool {
        match self {
            Split::All => true,
            Split::Tune => !sampler::is_held_out(seed),
            Split::HeldOut => sampler::is_held_out(seed),
        }
    }
}

impl FromStr for Split {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "all" => Ok(Split::All),
            "tune" => Ok(Split::Tune),
            "held-out" => Ok(Split::HeldOut),
            other => Err(format!("--split {other}: all, tune or held-out")),
        }
    }
}

/// `run(seed)` for every seed, on at most two threads (the machine's two shared cores; a run
/// is single-threaded), a progress line on stderr as each ends (`seconds` of its outcome: its
/// own run time); the outcomes in the order of `seeds`, whatever the order they ended in.
pub fn run_each<T: Send>(
    seeds: &[u64],
    run: impl Fn(u64) -> T + Sync,
    seconds: impl Fn(&T) -> f64 + Sync,
) -> Vec<T> {
    let threads = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(2);
    let started = Instant::now();
    let next = AtomicUsize::new(0);
    let outcomes = Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for _ in 0..threads {
            scope.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some(&seed) = seeds.get(i) else { break };
                let o = run(seed);
                eprintln!(
                    "[{:.0} s] seed {seed} done ({:.0} s)",
                    started.elapsed().as_secs_f64(),
                    seconds(&o)
                );
                outcomes.lock().unwrap().push((i, o));
            });
        }
    });
    let mut outcomes = outcomes.into_inner().unwrap();
    outcomes.sort_by_key(|(i, _)| *i);
    outcomes.into_iter().map(|(_, o)| o).collect()
}
