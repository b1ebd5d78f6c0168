//! Degraded compute (issue 28 item 3, "never late, never silent"): when the bogies' filters
//! cannot keep up with real time, every bogie's RBPF runs fewer particles (resampled down,
//! `railmon_damper::Rbpf::set_particles`) instead of lagging, down to
//! [`railmon_damper::MIN_DEGRADED_PARTICLES`]; the configured count comes back when the CPU
//! does. Pure logic: the pipeline feeds it one window (one second of sample time) at a time.
//!
//! The rule, per window, from the stream's own measures (`crate::ingest`'s `RealTimeTracker`:
//! the load is compute time over sample time, the lag the growth of wall minus sample time):
//! - **cut** when the load is above [`CUT_LOAD`] or the lag above the budget
//!   (`bogie.realtime.lag_budget_ms`): to the count that puts the load at [`TARGET_LOAD`]
//!   (the cost of a step is proportional to the particles), at least by [`MIN_CUT`], not
//!   below the floor;
//! - **restore** (towards the configured count) once the lag stayed under half the budget and
//!   the load under [`CALM_LOAD`] for a calm stretch ([`CALM_WINDOWS`]): to the count the
//!   stretch's highest load projects at [`TARGET_LOAD`], when that is at least [`MIN_RAISE`]
//!   more (or the configured count);
//! - after a change the next [`SETTLE_WINDOWS`] windows are not judged (they mix both counts);
//! - a cut soon after a raise (within twice the calm stretch) doubles the calm stretch needed
//!   for the next raise, up to [`MAX_CALM_WINDOWS`]: a CPU that comes and goes does not make the
//!   count oscillate. A cut long after the last raise resets it.

/// Above this load a window cuts the particles. Below 1 (where the filters fall behind): a
/// second's load varies by about 10 % with the scheduler and the frames' batching.
pub const CUT_LOAD: f64 = 0.9;
/// The load a cut or a raise aims at: 0.2 below [`CUT_LOAD`], the hysteresis band between
/// raising and cutting again.
pub const TARGET_LOAD: f64 = 0.7;
/// A cut takes at least this share off (a window just above [`CUT_LOAD`] would otherwise cut a
/// few particles at a time, one window after the other).
pub const MIN_CUT: f64 = 0.2;
/// A raise below the configured count adds at least this share (else it waits).
pub const MIN_RAISE: f64 = 0.25;
/// A window is calm (counts towards a raise) at most at this load: room for [`MIN_RAISE`]
/// more particles at [`TARGET_LOAD`]. Right after a cut (at [`TARGET_LOAD`]) none is.
pub const CALM_LOAD: f64 = TARGET_LOAD / (1.0 + MIN_RAISE);
/// Windows (s of samples) of calm before a raise: long beside a window's noise, short beside
/// the minutes a competing job or a thermal throttle lasts.
pub const CALM_WINDOWS: u32 = 30;
/// The longest calm stretch a count that keeps coming back asks for (s).
pub const MAX_CALM_WINDOWS: u32 = 480;
/// Windows not judged after a change.
pub const SETTLE_WINDOWS: u32 = 2;

/// What a window changed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ComputeChange {
    /// Fewer particles than before (`particles`).
    Cut { particles: usize },
    /// More particles than before, `particles` (the configured count: compute restored).
    Raise { particles: usize },
}

/// One window's measures.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ComputeWindow {
    /// Compute time over sample time (1: all of real time).
    pub load: f64,
    pub lag_s: f64,
}

#[derive(Clone, Debug)]
pub struct ComputeController {
    configured: usize,
    floor: usize,
    lag_budget_s: f64,
    particles: usize,
    settle: u32,
    /// Calm windows in a row, and the highest load among them.
    calm: u32,
    calm_max_load: f64,
    calm_needed: u32,
    /// Windows since the last raise (`None` before one).
    since_raise: Option<u32>,
}

impl ComputeController {
    /// `configured` particles per filter, cut down to `floor` at most (the configured count
    /// when it is smaller), lag budget `lag_budget_s`.
    pub fn new(configured: usize, floor: usize, lag_budget_s: f64) -> Self {
        Self {
            configured,
            floor: floor.min(configured).max(1),
            lag_budget_s,
            particles: configured,
            settle: 0,
            calm: 0,
            calm_max_load: 0.0,
            calm_needed: CALM_WINDOWS,
            since_raise: None,
        }
    }

    /// The particles each filter runs now.
    pub fn particles(&self) -> usize {
        self.particles
    }

    pub fn configured(&self) -> usize {
        self.configured
    }

    pub fn degraded(&self) -> bool {
        self.particles < self.configured
    }

    /// The calm windows the next raise needs.
    #[cfg(test)]
    pub fn calm_needed(&self) -> u32 {
        self.calm_needed
    }

    /// One closed window; the change it makes, if any.
    pub fn observe(&mut self, w: ComputeWindow) -> Option<ComputeChange> {
        if let Some(s) = &mut self.since_raise {
            *s = s.saturating_add(1);
        }
        if self.settle > 0 {
            self.settle -= 1;
            return None;
        }
        // A NaN load (no compute measured) is neither calm nor over.
        let over = w.load > CUT_LOAD || w.lag_s > self.lag_budget_s;
        if over {
            self.calm = 0;
            self.calm_max_load = 0.0;
            if self.particles <= self.floor {
                return None;
            }
            // Lagging at a load below the cut: the backlog needs the headroom of a cut at
            // `CUT_LOAD` to drain.
            let load = w.load.max(CUT_LOAD);
            let aimed = (self.particles as f64 * TARGET_LOAD / load).floor() as usize;
            let most = (self.particles as f64 * (1.0 - MIN_CUT)).floor() as usize;
            let particles = aimed.min(most).max(self.floor);
            match self.since_raise {
                Some(s) if s <= 2 * self.calm_needed => {
                    self.calm_needed = (2 * self.calm_needed).min(MAX_CALM_WINDOWS)
                }
                Some(_) => self.calm_needed = CALM_WINDOWS,
                None => {}
            }
            return Some(self.change(particles));
        }
        let calm = w.load <= CALM_LOAD && w.lag_s <= 0.5 * self.lag_budget_s;
        if !calm || !self.degraded() {
            self.calm = 0;
            self.calm_max_load = 0.0;
            return None;
        }
        self.calm += 1;
        self.calm_max_load = self.calm_max_load.max(w.load);
        if self.calm < self.calm_needed {
            return None;
        }
        let projected = if self.calm_max_load > 0.0 {
            self.particles as f64 * TARGET_LOAD / self.calm_max_load
        } else {
            f64::INFINITY
        };
        let particles = (projected.floor() as usize).min(self.configured);
        let enough = (self.particles as f64 * (1.0 + MIN_RAISE)).ceil() as usize;
        if particles < self.configured && particles < enough {
            return None;
        }
        self.since_raise = Some(0);
        Some(self.change(particles))
    }

    fn change(&mut self, particles: usize) -> ComputeChange {
        let cut = particles < self.particles;
        self.particles = particles;
        self.settle = SETTLE_WINDOWS;
        self.calm = 0;
        self.calm_max_load = 0.0;
        if cut {
            ComputeChange::Cut { particles }
        } else {
            ComputeChange::Raise { particles }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn w(load: f64, lag_s: f64) -> ComputeWindow {
        ComputeWindow { load, lag_s }
    }

    /// The machine of the issue: 16 bogies at N = 1000 need ~1.8 cores of 2, a competing job
    /// takes one. Load proportional to the particles: `load_per_particle` x N.
    fn run(c: &mut ComputeController, load_per_particle: f64, windows: u32) -> Vec<ComputeChange> {
        (0..windows)
            .filter_map(|_| c.observe(w(load_per_particle * c.particles() as f64, 0.0)))
            .collect()
    }

    #[test]
    fn a_quiet_host_keeps_the_configured_count() {
        let mut c = ComputeController::new(1000, 200, 0.05);
        assert!(run(&mut c, 0.6 / 1000.0, 600).is_empty());
        assert_eq!(c.particles(), 1000);
        assert!(!c.degraded());
    }

    #[test]
    fn an_overload_cuts_to_the_target_load_and_stays_there() {
        let mut c = ComputeController::new(1000, 200, 0.05);
        // 1.6 at N = 1000: to 1000 x 0.7 / 1.6 = 437, in one change, and no more.
        let changes = run(&mut c, 1.6 / 1000.0, 600);
        assert_eq!(changes, vec![ComputeChange::Cut { particles: 437 }]);
        assert!(c.degraded());
    }

    #[test]
    fn a_lag_over_the_budget_cuts_even_at_a_moderate_load() {
        let mut c = ComputeController::new(1000, 200, 0.05);
        assert_eq!(c.observe(w(0.5, 0.04)), None);
        assert_eq!(
            c.observe(w(0.5, 0.06)),
            Some(ComputeChange::Cut { particles: 777 })
        );
        // Settling: the next two windows are not judged, however late.
        assert_eq!(c.observe(w(0.5, 1.0)), None);
        assert_eq!(c.observe(w(0.5, 1.0)), None);
        assert_eq!(
            c.observe(w(0.5, 1.0)),
            Some(ComputeChange::Cut { particles: 604 })
        );
    }

    #[test]
    fn the_floor_is_never_crossed() {
        let mut c = ComputeController::new(1000, 200, 0.05);
        let changes = run(&mut c, 50.0 / 1000.0, 100);
        assert_eq!(c.particles(), 200);
        assert!(changes
            .iter()
            .all(|ch| matches!(ch, ComputeChange::Cut { particles } if *particles >= 200)));
        // A configured count under the floor is never cut.
        let mut small = ComputeController::new(50, 200, 0.05);
        assert_eq!(small.observe(w(3.0, 1.0)), None);
        assert_eq!(small.particles(), 50);
    }

    #[test]
    fn the_count_comes_back_after_a_calm_stretch_and_not_before() {
        let mut c = ComputeController::new(1000, 200, 0.05);
        run(&mut c, 1.6 / 1000.0, 10);
        assert_eq!(c.particles(), 437);
        // The competing job ends: 0.8 at N = 1000 (0.35 at 437).
        let quiet = 0.8 / 1000.0;
        let changes = run(&mut c, quiet, CALM_WINDOWS - 1);
        assert!(changes.is_empty(), "{changes:?}");
        // The raise aims at 0.7: 437 x 0.7 / 0.35 = 875, not yet all.
        assert_eq!(
            run(&mut c, quiet, 1),
            vec![ComputeChange::Raise { particles: 874 }]
        );
        // A load of 0.7 at 874 is not calm (no room for 25 % more): it waits.
        assert!(run(&mut c, quiet, 600).is_empty());
        assert_eq!(c.particles(), 874);
        // The host gets quieter still: all of it.
        let changes = run(&mut c, 0.5 / 1000.0, 600);
        assert_eq!(changes, vec![ComputeChange::Raise { particles: 1000 }]);
        assert!(!c.degraded());
    }

    #[test]
    fn a_load_that_comes_and_goes_does_not_make_the_count_oscillate() {
        let mut c = ComputeController::new(1000, 200, 0.05);
        // A competing job for 20 s of every 60 (1.6 with it, 0.6 without), for an hour.
        let mut changes = 0;
        for t in 0..3600u32 {
            let per_particle = if t % 60 < 20 { 1.6 } else { 0.6 } / 1000.0;
            changes += usize::from(
                c.observe(w(per_particle * c.particles() as f64, 0.0))
                    .is_some(),
            );
        }
        // Without the back-off: a cut and a raise every minute, 120.
        assert!(changes <= 20, "{changes} changes in an hour");
        assert!(c.calm_needed() > CALM_WINDOWS);
    }

    #[test]
    fn a_window_without_a_load_changes_nothing() {
        let mut c = ComputeController::new(1000, 200, 0.05);
        assert_eq!(c.observe(w(f64::NAN, 0.0)), None);
        assert_eq!(c.particles(), 1000);
    }
}
