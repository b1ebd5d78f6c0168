//! Solving the gain table's nodes ahead of the filters (issue 9 item 4, issue 24 item 1).
//!
//! A filter reaching a speed node nobody has solved yet solves it itself, in its step: about
//! half a second (`cargo bench -p railmon-damper --bench rbpf_variants`) in which its bogie,
//! and the others of that sample time, stall. One thread here follows the vehicle's speed and
//! solves every unsolved node, the nearest to that speed first, so that the filters find them
//! ready; a filter that gets there first waits for the solution under way instead of solving
//! it again (`GainTable::grid_at`). Once, per service start: about 26 s of one core and 50 MB
//! for the 50 nodes of 5-55 m/s (1 MB each). Solving only the two nodes either side of the
//! speed was measured first: accelerating from rest the vehicle passes about two low-speed
//! nodes a second (they are 5 % apart), faster than they are solved, and the bogies of
//! `damper-speed-profile.toml` ended 7.9 s behind real time (docs/damper.md).
//!
//! The body mass is a second axis of nodes (`GainTable::node_at`): the thread also follows
//! the masses the filters run at (a measured mass, or the span of the particles' own while
//! none is measured: up to 11 mass nodes at the start, one or two once the mass is learnt),
//! every mass in that span at a speed before the next speed, each taken from the cache when
//! stored there (about 5 ms) and solved otherwise. Only those nodes: the whole table is 18
//! mass nodes x 50 speeds, 900 MB.

use std::ops::RangeInclusive;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use std::time::Instant;

use railmon_damper::gain_table::GainTable;
use railmon_records::gain_cache::GainCache;

/// How often the thread looks again when every node is solved or being solved.
const POLL: Duration = Duration::from_millis(100);

pub(super) struct NodeWarmer {
    speed_bits: Arc<AtomicU64>,
    /// The span of masses the filters run at (kg, `f64` bits: lightest, heaviest).
    mass_bits: Arc<[AtomicU64; 2]>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl NodeWarmer {
    /// Starts the thread, first around `speed_m_s` at the design mass: it loads the
    /// design-mass nodes stored in `cache`, then solves the others (and stores them there).
    pub(super) fn new(table: Arc<GainTable>, speed_m_s: f64, cache: Option<GainCache>) -> Self {
        let speed_bits = Arc::new(AtomicU64::new(speed_m_s.to_bits()));
        let design_kg = table.node_half_body_mass_kg(0);
        let mass_bits = Arc::new([
            AtomicU64::new(design_kg.to_bits()),
            AtomicU64::new(design_kg.to_bits()),
        ]);
        let stop = Arc::new(AtomicBool::new(false));
        let (speed, masses, halt) = (speed_bits.clone(), mass_bits.clone(), stop.clone());
        let thread = std::thread::Builder::new()
            .name("bogie-gain-nodes".into())
            .spawn(move || {
                let started = Instant::now();
                let mut loaded = 0;
                if let Some(cache) = &cache {
                    // Nearest the speed first (the slower side first on a tie), as the
                    // solving below: about 5 ms a node against 0.3-0.5 s to solve it.
                    let centre = table.node_of(f64::from_bits(speed.load(Ordering::Relaxed)));
                    let mut order: Vec<usize> = (0..table.n_nodes()).collect();
                    order.sort_by_key(|&node| node.abs_diff(centre));
                    for node in order {
                        if halt.load(Ordering::Relaxed) {
                            return;
                        }
                        match cache.load(&table, node) {
                            Ok(true) => loaded += 1,
                            Ok(false) => {}
                            Err(e) => tracing::warn!("bogie gain table: {e}"),
                        }
                    }
                }
                let mut solved = 0;
                let mut reported = false;
                // Nodes taken or solved here since the last `store_all`.
                let mut unstored = false;
                while !halt.load(Ordering::Relaxed) {
                    let v = f64::from_bits(speed.load(Ordering::Relaxed));
                    let span = f64::from_bits(masses[0].load(Ordering::Relaxed))
                        ..=f64::from_bits(masses[1].load(Ordering::Relaxed));
                    let Some(node) = table.missing_near(v, span, table.n_nodes()) else {
                        if unstored {
                            unstored = false;
                            // With the nodes a filter solved itself, before this thread got
                            // to them.
                            if let Some(Err(e)) = cache.as_ref().map(|c| c.store_all(&table)) {
                                tracing::warn!("bogie gain table: not stored: {e}");
                            }
                        }
                        if !reported && (0..table.n_nodes()).all(|n| table.is_solved(n)) {
                            reported = true;
                            tracing::info!(
                                "bogie gain table: all {} speed nodes ready {:.2} s after start \
                                 ({loaded} from the cache, {solved} solved here)",
                                table.n_nodes(),
                                started.elapsed().as_secs_f64()
                            );
                        }
                        std::thread::park_timeout(POLL);
                        continue;
                    };
                    unstored = true;
                    match cache.as_ref().map(|c| c.load(&table, node)) {
                        Some(Ok(true)) => {
                            loaded += 1;
                            continue;
                        }
                        Some(Err(e)) => tracing::warn!("bogie gain table: {e}"),
                        Some(Ok(false)) | None => {}
                    }
                    if let Err(e) = table.grid_at(node) {
                        // The filter reaching it will fail the same way and say so per frame.
                        tracing::error!(
                            "bogie gain table: the node of {:.1} m/s, {:.0} kg cannot be solved \
                             ({e}); no more nodes are solved ahead",
                            table.node_speed_m_s(node),
                            table.node_half_body_mass_kg(node)
                        );
                        return;
                    }
                    solved += 1;
                    tracing::debug!(
                        "bogie gain table: node {node} ({:.1} m/s, {:.0} kg) solved ahead",
                        table.node_speed_m_s(node),
                        table.node_half_body_mass_kg(node)
                    );
                    if let Some(cache) = &cache {
                        if let Err(e) = cache.store(&table, node) {
                            tracing::warn!("bogie gain table: node {node} not stored: {e}");
                        }
                    }
                }
                if let Some(Err(e)) = cache.as_ref().map(|c| c.store_all(&table)) {
                    tracing::warn!("bogie gain table: not stored: {e}");
                }
            })
            .expect("spawn the gain-node thread");
        Self {
            speed_bits,
            mass_bits,
            stop,
            thread: Some(thread),
        }
    }

    /// The vehicle's latest speed (m/s); non-finite or non-positive values are ignored.
    pub(super) fn follow(&self, speed_m_s: f64) {
        if speed_m_s.is_finite() && speed_m_s > 0.0 {
            self.speed_bits
                .store(speed_m_s.to_bits(), Ordering::Relaxed);
        }
    }

    /// The masses the filters run at now (kg, lightest to heaviest, over every bogie);
    /// non-finite, non-positive or reversed spans are ignored.
    pub(super) fn follow_masses(&self, half_body_masses_kg: RangeInclusive<f64>) {
        let (lo, hi) = half_body_masses_kg.into_inner();
        if lo.is_finite() && hi.is_finite() && 0.0 < lo && lo <= hi {
            self.mass_bits[0].store(lo.to_bits(), Ordering::Relaxed);
            self.mass_bits[1].store(hi.to_bits(), Ordering::Relaxed);
        }
    }
}

impl Drop for NodeWarmer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            t.thread().unpark();
            // A node being solved finishes first (under a second).
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use railmon_damper::{DamperMonitorConfig, Rbpf};

    /// With a cache the thread loads the stored nodes (to the bit), solves the missing and
    /// the damaged ones and stores them: a second start finds every node stored.
    #[test]
    fn loads_the_stored_nodes_and_stores_the_ones_it_solves() {
        let dir = std::env::temp_dir().join(format!("railmon-warm-cache-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let cache = GainCache::new(&dir);
        let mut c = DamperMonitorConfig::default();
        c.rbpf.gain_grid.points_per_axis = 4;
        let table = || Rbpf::unsolved_gain_table(&c.filter_model(), &c.rbpf, &c.speed).unwrap();
        let reference = table();
        for node in 0..reference.n_nodes() {
            reference.grid_at(node).unwrap();
        }
        // Half the nodes stored, one of them damaged.
        for node in (0..reference.n_nodes()).step_by(2) {
            cache.store(&reference, node).unwrap();
        }
        let damaged = cache.path_of(reference.fingerprint(0).unwrap());
        let mut bytes = std::fs::read(&damaged).unwrap();
        *bytes.last_mut().unwrap() ^= 1;
        std::fs::write(&damaged, bytes).unwrap();
        let all_ready = |t: &Arc<GainTable>| {
            let start = Instant::now();
            while !(0..t.n_nodes()).all(|n| t.is_solved(n)) {
                assert!(start.elapsed() < Duration::from_secs(60));
                std::thread::sleep(Duration::from_millis(20));
            }
        };
        let first = table();
        let warmer = NodeWarmer::new(first.clone(), c.vehicle.speed_m_s, Some(cache.clone()));
        all_ready(&first);
        drop(warmer);
        for node in 0..first.n_nodes() {
            assert_eq!(
                first.solved_grid(node).unwrap(),
                reference.solved_grid(node).unwrap()
            );
        }
        // Every node stored now: the second start solves none.
        let second = table();
        assert_eq!(cache.load_all(&second).loaded.len(), second.n_nodes());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Without a load signal the filters run at their particles' masses: the thread solves
    /// those mass nodes at the speed before a filter asks, takes them from the cache when
    /// stored there, and stores the ones it solved.
    #[test]
    fn solves_and_stores_the_nodes_of_the_masses_the_filters_run_at() {
        let dir = std::env::temp_dir().join(format!("railmon-warm-mass-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let cache = GainCache::new(&dir);
        let mut c = DamperMonitorConfig::default();
        c.rbpf.gain_grid.points_per_axis = 4;
        let table = || Rbpf::unsolved_gain_table(&c.filter_model(), &c.rbpf, &c.speed).unwrap();
        let (v0, m0) = (c.vehicle.speed_m_s, c.vehicle.half_body_mass_kg);
        let (light, heavy) = (m0 * 0.9, m0 * 1.3);
        let wait_for = |t: &GainTable, node: usize| {
            let start = Instant::now();
            while !t.is_solved(node) {
                assert!(start.elapsed() < Duration::from_secs(60), "node {node}");
                std::thread::sleep(Duration::from_millis(20));
            }
        };
        let first = table();
        let warmer = NodeWarmer::new(first.clone(), v0, Some(cache.clone()));
        warmer.follow_masses(light..=heavy);
        let at_speed: Vec<usize> = first
            .nodes_of_masses(light..=heavy)
            .into_iter()
            .filter(|&n| first.node_speed_m_s(n) == first.node_speed_m_s(first.node_of(v0)))
            .collect();
        assert_eq!(
            at_speed.len(),
            8,
            "0.9-1.3 x design: 8 mass nodes 5 % apart"
        );
        for &node in &at_speed {
            wait_for(&first, node);
        }
        // A mass outside the span is not solved ahead.
        assert!(!first.is_solved(first.node_at(v0, m0 * 1.5)));
        drop(warmer);
        // Stored: a second start takes them from the cache, to the bit.
        let second = table();
        let loaded = cache.load_all(&second).loaded;
        for &node in &at_speed {
            assert!(loaded.contains(&node), "node {node}");
            assert_eq!(second.solved_grid(node), first.solved_grid(node));
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// The thread solves the node next to the vehicle's speed on its own, and a new speed
    /// moves it there (nearest first); dropping it stops it before it has solved them all.
    #[test]
    fn solves_the_nodes_near_the_speed_before_a_filter_asks() {
        let c = DamperMonitorConfig::default();
        let table = Rbpf::gain_table(&c.filter_model(), &c.rbpf, &c.speed).unwrap();
        let v0 = c.vehicle.speed_m_s;
        let k = table.node_of(v0);
        let far = k - 6;
        let warmer = NodeWarmer::new(table.clone(), v0, None);
        let wait_for = |node: usize| {
            let start = Instant::now();
            while !table.is_solved(node) {
                assert!(start.elapsed() < Duration::from_secs(60), "node {node}");
                std::thread::sleep(Duration::from_millis(20));
            }
        };
        wait_for(k - 1);
        warmer.follow(table.node_speed_m_s(far));
        wait_for(far);
        drop(warmer);
        let solved = |t: &GainTable| (0..t.n_nodes()).filter(|&n| t.is_solved(n)).count();
        let at_drop = solved(&table);
        assert!(at_drop < table.n_nodes(), "{at_drop}");
        // Stopped: nothing more is solved.
        std::thread::sleep(POLL * 5);
        assert_eq!(solved(&table), at_drop);
    }
}
