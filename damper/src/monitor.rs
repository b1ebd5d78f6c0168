//! One bogie's damper monitor: the RBPF (the estimate) and the EKF baseline side by side, fed
//! one validated sample at a time. This is what the service runs per bogie.

use std::sync::Arc;

use crate::burst::BurstHold;
use crate::config::DamperMonitorConfig;
use crate::consistency::ConsistencyCheck;
use crate::ekf::{AugmentedEkf, EkfState};
use crate::estimate::{BodyMass, DamperEstimate, MassSource};
use crate::gain_table::GainTable;
use crate::rbpf::{Propagation, Rbpf, RbpfConfig, RbpfState};
use crate::sample::BogieSample;
use crate::speed::{PauseReason, SpeedConfig};
use crate::trend::{DegradationTrend, TrendEstimate};
use crate::{DamperError, DamperId};

/// A monitor's state for a snapshot ([`DamperMonitor::state`], [`DamperMonitor::resume`]):
/// the RBPF's particles, weights and Kalman states, the EKF's state and covariance, the
/// consistency check. The health flags are [`crate::DamperAlarm`]'s, saved beside it.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DamperMonitorState {
    rbpf: RbpfState,
    ekf: Option<EkfState>,
    ekf_diverged_at_s: Option<f64>,
    steps: u64,
    consistency: ConsistencyCheck,
    pause: PauseState,
    /// Each damper's degradation trend (`C_sy`, `C_say`).
    trends: [DegradationTrend; 2],
    /// The publication held through a burst of innovations (`crate::burst`).
    burst: BurstHold,
}

impl DamperMonitorState {
    /// The version of this type's serialised layout (everything in it), which the service
    /// writes into each bogie snapshot. Raise it with every change of the layout;
    /// `tests/state_layout.rs` pins the layout under it
    /// (`tests/data/golden/state-layout-damper.txt`), so a change cannot ship without it.
    /// 3: the RBPF's jump-search sentinels (`RbpfState`).
    /// 4: the settling after a pause judged on the innovations (`PauseState`).
    /// 5: jump hypotheses on probation, not yet published (`RbpfState`).
    /// 6: each damper's degradation trend (`trends`).
    /// 7: the particles' body masses while none is measured (`RbpfState`).
    /// 8: the common state estimated after a pause (`RbpfState`).
    /// 9: the publication held through a burst of innovations (`burst`).
    /// 10: a wear rate per particle in place of the drift read off the mean (`RbpfState`).
    pub const STATE_FORMAT_VERSION: u32 = 10;
}

/// Where a monitor is with respect to its valid speed range.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
struct PauseState {
    /// Why it is paused (and still settling after the pause), if it is.
    reason: Option<PauseReason>,
    /// Samples in a row outside the range (the current or the last pause).
    paused_steps: u64,
    /// Samples run without weighting since the speed came back into range.
    settle_steps: u64,
    /// Per hypothesis ([`Rbpf::hypothesis_nis`]), the sum of its normalised innovations
    /// squared over the settling's current window (empty before its first sample).
    settle_nis_sums: Vec<f64>,
    /// The settling is over: the next sample in range weighs the particles.
    settled: bool,
    speed_m_s: f64,
}

impl PauseState {
    fn running(speed_m_s: f64) -> Self {
        PauseState {
            reason: None,
            paused_steps: 0,
            settle_steps: 0,
            settle_nis_sums: Vec::new(),
            settled: true,
            speed_m_s,
        }
    }
}

/// The settling after a pause, in samples (`DamperMonitor::step`).
#[derive(Debug, Clone, Copy)]
struct Settling {
    /// At least this long (`speed.resume_settle_s`).
    min_steps: u64,
    /// At most this long (`max(speed.resume_settle_s, Rbpf::max_resume_settle_s)`).
    max_steps: u64,
    /// The innovations are judged over windows this long ([`SETTLE_WINDOW_S`]).
    window_steps: u64,
    /// A pause at least this long (the model's slowest time constant) restarts the states at
    /// rest; `u64::MAX` without the jump search (the states kept, as before it).
    reset_after_steps: u64,
}

/// The window over which the settling judges the innovations (s): 500 samples at 1 kHz, so
/// that the mean of a chi-square with 5 degrees of freedom (standard deviation
/// `sqrt(10 / 500)` = 0.14) stays well inside [`SETTLED_NIS_RATIO`] when the states are
/// right.
pub const SETTLE_WINDOW_S: f64 = 0.5;

/// The settling ends (after `speed.resume_settle_s`) at the first window whose mean
/// normalised innovation squared is at most this ratio of its expectation (5): 6 against the
/// 5.0-5.4 of a settled filter on the shipped speed profile, 8.5-12 while the stale states of
/// a stop still dominate (docs/notes/damper-log.md, 27 Nov).
pub const SETTLED_NIS_RATIO: f64 = 1.2;

/// The longest gap of missing samples [`DamperMonitor::bridge`] steps over: one or two lost
/// 1 kHz samples shift the states by 1-2 ms of a model whose fastest lateral modes take tens of
/// ms; settling for at least `speed.resume_settle_s` after each would stop the learning of a
/// source that loses a sample now and then.
pub const MAX_STEPPED_OVER_SAMPLES: u64 = 2;

#[derive(Debug, Clone)]
pub struct DamperMonitor {
    rbpf: Rbpf,
    ekf: Option<AugmentedEkf>,
    ekf_diverged_at_s: Option<f64>,
    dt_s: f64,
    steps: u64,
    consistency: ConsistencyCheck,
    speed: SpeedConfig,
    pause: PauseState,
    estimate: DamperEstimate,
    /// Each damper's degradation trend (`C_sy`, `C_say`), fed while the filter learns.
    trends: [DegradationTrend; 2],
    /// The nominal dampers (`C_sy`, `C_say`; N s/m) the trends' ratios are of.
    nominal_ns_per_m: [f64; 2],
    /// What is published through a burst of innovations (`crate::burst`).
    burst: BurstHold,
}

impl Settling {
    /// From the filter's current model (its slowest mode follows the body mass).
    fn of(dt_s: f64, speed: &SpeedConfig, rbpf: &Rbpf) -> Self {
        let steps = |s: f64| (s / dt_s).round() as u64;
        let min_steps = steps(speed.resume_settle_s);
        Settling {
            min_steps,
            max_steps: min_steps.max(steps(rbpf.max_resume_settle_s())),
            window_steps: steps(SETTLE_WINDOW_S).max(1),
            reset_after_steps: rbpf.slowest_time_constant_s().map_or(u64::MAX, steps),
        }
    }
}

impl DamperMonitor {
    /// `seed` seeds the RBPF (one monitor per bogie: give each its own).
    pub fn new(config: &DamperMonitorConfig, seed: u64) -> Result<Self, DamperError> {
        config.validate()?;
        let table = match config.rbpf.propagation {
            Propagation::SteadyState => Some(Rbpf::gain_table(
                &config.filter_model(),
                &config.rbpf,
                &config.speed,
            )?),
            Propagation::Exact => None,
        };
        Self::with_gain_table(config, seed, table)
    }

    /// The monitor of bogie `bogie_id` of a vehicle: its RBPF seeded with
    /// [`DamperMonitor::bogie_seed`], so that the service and `railmon analyze damper --bogie`
    /// give the same answer on the same data.
    pub fn for_bogie(
        config: &DamperMonitorConfig,
        bogie_id: u32,
        table: Option<Arc<GainTable>>,
    ) -> Result<Self, DamperError> {
        Self::with_gain_table(config, Self::bogie_seed(config, bogie_id), table)
    }

    /// `rbpf.seed + bogie_id - 1`: bogie 1 runs on the configured seed (the one every figure
    /// in `docs/damper.md` was measured with), each other bogie on its own.
    pub fn bogie_seed(config: &DamperMonitorConfig, bogie_id: u32) -> u64 {
        config
            .rbpf
            .seed
            .wrapping_add(u64::from(bogie_id))
            .wrapping_sub(1)
    }

    /// As [`DamperMonitor::new`] with a gain table shared by the bogies of one vehicle type
    /// (`Rbpf::gain_table(&config.filter_model(), &config.rbpf, &config.speed)`).
    pub fn with_gain_table(
        config: &DamperMonitorConfig,
        seed: u64,
        table: Option<Arc<GainTable>>,
    ) -> Result<Self, DamperError> {
        // The whole configuration, as the filters each check only their own part.
        config.validate()?;
        let model = config.filter_model();
        let rbpf_config = RbpfConfig {
            seed,
            ..config.rbpf
        };
        let mut rbpf = Rbpf::with_gain_table(&model, &rbpf_config, &config.speed, table)?;
        let ekf = if config.ekf.enabled {
            Some(AugmentedEkf::new(&model, &config.ekf)?)
        } else {
            None
        };
        let r = rbpf.estimate();
        Ok(DamperMonitor {
            estimate: DamperEstimate {
                time_s: 0.0,
                csy: r.csy,
                csay: r.csay,
                effective_sample_size: r.effective_sample_size,
                ekf: ekf.as_ref().map(|e| e.estimate()),
                nis_window_mean: None,
                model_mismatch: false,
                noise_std_ratio: rbpf.noise_std_ratio(),
                paused: None,
                held_through_burst: false,
                speed_m_s: config.vehicle.speed_m_s,
                measured_half_body_mass_kg: None,
            },
            consistency: ConsistencyCheck::new(&config.consistency, config.dt_s),
            rbpf,
            ekf,
            ekf_diverged_at_s: None,
            dt_s: config.dt_s,
            steps: 0,
            speed: config.speed,
            pause: PauseState::running(config.vehicle.speed_m_s),
            trends: [(); 2].map(|_| DegradationTrend::new(config.alarm.degraded_below_ratio)),
            nominal_ns_per_m: [model.nominal.csy_ns_per_m, model.nominal.csay_ns_per_m],
            burst: BurstHold::new(config.dt_s),
        })
    }

    /// Validates the sample (every field finite: else an error naming the field, and nothing
    /// changes), then steps both filters.
    /// Outside the valid speed range (`speed`) the filters are not stepped: the posterior,
    /// the particles and their states stay bit for bit as they were, and the estimate says
    /// `paused`. Back inside, the per-particle states run without weighting (still `paused`)
    /// before the posterior learns again. With the jump search, after a pause of at least the
    /// model's slowest time constant the states first restart at rest, as at the filter's
    /// start: the plant has forgotten the state the pause began with, and after a stop it is
    /// at rest itself; then the first samples fix a common state for all of them
    /// (`rbpf::RESUME_INIT_S`: one exact Kalman filter from the plant's stationary spread,
    /// `rbpf/resume_init.rs`); unless the pause was above the speed range, the particles that
    /// carry the body mass (no mass measured) draw it again from the prior, the load having
    /// possibly changed at a stop ([`Rbpf::forget_unmeasured_mass`]). The settling lasts
    /// `speed.resume_settle_s` at least, then ends at the
    /// first [`SETTLE_WINDOW_S`] window whose mean normalised innovation squared is at most
    /// [`SETTLED_NIS_RATIO`] times 5 (the states explain the data again), or after
    /// [`Rbpf::max_resume_settle_s`] (3 time constants of that mode) at the latest.
    pub fn step(&mut self, sample: &BogieSample) -> Result<&DamperEstimate, DamperError> {
        let y = sample.validate()?;
        // The measured body mass (or the design one): checked before anything changes.
        let mass_kg = self
            .rbpf
            .checked_half_body_mass_kg(sample.half_body_mass_kg)?;
        let speed_m_s = sample.speed_m_s;
        if let Some(reason) = self.speed.pause_reason(speed_m_s) {
            self.steps += 1;
            // A pause that interrupts a settling continues the pause before it.
            let p = &mut self.pause;
            if p.settle_steps > 0 {
                p.paused_steps = 0;
            }
            p.reason = Some(reason);
            p.paused_steps += 1;
            p.settle_steps = 0;
            p.settle_nis_sums.clear();
            // No settling at all when none is asked for.
            p.settled = Settling::of(self.dt_s, &self.speed, &self.rbpf).max_steps == 0;
            p.speed_m_s = speed_m_s;
            self.estimate.time_s = self.steps as f64 * self.dt_s;
            self.estimate.paused = Some(reason);
            self.estimate.speed_m_s = speed_m_s;
            self.estimate.measured_half_body_mass_kg = sample.half_body_mass_kg;
            return Ok(&self.estimate);
        }
        self.rbpf.set_speed(speed_m_s)?;
        self.rbpf.set_half_body_mass_kg(sample.half_body_mass_kg)?;
        if self.pause.settled {
            self.rbpf.step(&y)?;
            self.pause.reason = None;
        } else {
            self.settle(&y)?;
        }
        self.pause.speed_m_s = speed_m_s;
        self.steps += 1;
        let time_s = self.steps as f64 * self.dt_s;
        let ekf_step = |e: &mut AugmentedEkf| {
            e.set_speed(speed_m_s)
                .and_then(|_| e.set_half_body_mass_kg(mass_kg))
                .and_then(|_| e.step(&y))
        };
        let ekf = match self.ekf.as_mut().map(ekf_step) {
            Some(Ok(e)) => Some(e),
            Some(Err(_)) => {
                // The baseline diverged (the paper's figures 4-5 show it doing so): stop it,
                // remember when, keep the RBPF running.
                self.ekf = None;
                self.ekf_diverged_at_s = Some(time_s);
                None
            }
            None => None,
        };
        let r = self.rbpf.estimate();
        let [csy, csay] = if self.pause.reason.is_none() {
            let nis = self.rbpf.normalised_innovation_squared();
            self.consistency.update(nis);
            let settled_nis = SETTLED_NIS_RATIO * crate::model::N_OUTPUTS as f64;
            let max_hold_steps = self.max_hold_steps();
            self.burst
                .update(nis, [r.csy, r.csay], max_hold_steps, settled_nis)
        } else {
            // Settling after a pause: the posterior does not learn; what was published stays.
            self.burst.published().unwrap_or([r.csy, r.csay])
        };
        let held_through_burst = self.burst.holding();
        self.estimate = DamperEstimate {
            time_s,
            csy,
            csay,
            effective_sample_size: r.effective_sample_size,
            ekf,
            nis_window_mean: self.consistency.window_mean(),
            model_mismatch: self.consistency.mismatch(),
            noise_std_ratio: self.rbpf.noise_std_ratio(),
            paused: self.pause.reason,
            held_through_burst,
            speed_m_s,
            measured_half_body_mass_kg: sample.half_body_mass_kg,
        };
        // Operating time: the filter learnt from this sample and its model explains the data.
        if self.pause.reason.is_none() && !self.estimate.model_mismatch && !held_through_burst {
            for ((trend, p), nominal) in self
                .trends
                .iter_mut()
                .zip([csy, csay])
                .zip(self.nominal_ns_per_m)
            {
                trend.update(
                    self.dt_s,
                    p.health_ratio,
                    p.q05_ns_per_m / nominal,
                    p.q95_ns_per_m / nominal,
                );
            }
        }
        Ok(&self.estimate)
    }

    /// Carries the monitor over `missing_steps` samples that no frame covered (lost at the
    /// source, or the time across a restart of the service), before the next sample is
    /// stepped. Up to [`MAX_STEPPED_OVER_SAMPLES`] the next sample is stepped as if it followed
    /// the last. A longer gap leaves the states stale, so they settle on the data again as
    /// after a pause (`paused` = `gap` meanwhile; after a gap of at least the slowest mode's
    /// time constant they restart at rest); the posterior is kept.
    pub fn bridge(&mut self, missing_steps: u64) {
        if missing_steps <= MAX_STEPPED_OVER_SAMPLES {
            return;
        }
        let settling = Settling::of(self.dt_s, &self.speed, &self.rbpf);
        let p = &mut self.pause;
        // A gap within a pause or its settling lengthens that pause.
        if p.reason.is_none() || p.settle_steps > 0 {
            p.paused_steps = 0;
        }
        if p.reason.is_none() {
            p.reason = Some(PauseReason::Gap);
        }
        p.paused_steps = p.paused_steps.saturating_add(missing_steps);
        p.settle_steps = 0;
        p.settle_nis_sums.clear();
        p.settled = settling.max_steps == 0;
        self.steps += missing_steps;
        self.estimate.paused = p.reason;
    }

    /// One sample of the settling after a pause (`step`).
    fn settle(&mut self, y: &crate::model::Vector5) -> Result<(), DamperError> {
        let st = Settling::of(self.dt_s, &self.speed, &self.rbpf);
        let p = &mut self.pause;
        if p.settle_steps == 0 && p.paused_steps >= st.reset_after_steps {
            // Below the speed range, or samples missing, the train may have stood and its
            // load changed; above it, not.
            if p.reason != Some(PauseReason::HighSpeed) {
                self.rbpf.forget_unmeasured_mass()?;
            }
            self.rbpf.reset_states();
        }
        self.rbpf.step_states(y)?;
        p.settle_steps += 1;
        let sums = &mut p.settle_nis_sums;
        if sums.is_empty() {
            sums.extend(self.rbpf.hypothesis_nis());
        } else {
            for (sum, q) in sums.iter_mut().zip(self.rbpf.hypothesis_nis()) {
                *sum += q;
            }
        }
        let window_end = p.settle_steps.is_multiple_of(st.window_steps);
        // Some hypothesis (a particle, or a sentinel: a damper that failed during the pause)
        // explains the data again; the weighted mean would not, after such a failure.
        let in_band = window_end
            && sums.iter().copied().fold(f64::INFINITY, f64::min) / st.window_steps as f64
                <= SETTLED_NIS_RATIO * crate::model::N_OUTPUTS as f64;
        if window_end {
            sums.fill(0.0);
        }
        p.settled = p.settle_steps >= st.max_steps || (p.settle_steps >= st.min_steps && in_band);
        Ok(())
    }

    pub fn state(&self) -> DamperMonitorState {
        DamperMonitorState {
            rbpf: self.rbpf.state(),
            ekf: self.ekf.as_ref().map(AugmentedEkf::state),
            ekf_diverged_at_s: self.ekf_diverged_at_s,
            steps: self.steps,
            consistency: self.consistency,
            pause: self.pause.clone(),
            trends: self.trends.clone(),
            burst: self.burst.clone(),
        }
    }

    /// The monitor of `config` where `state` left it (its gain table `table`, as
    /// [`DamperMonitor::with_gain_table`]): the same samples then give exactly the estimates
    /// the monitor that saved it would have given. A state of more particles than configured
    /// or of another propagation is refused, and nothing is built; one of fewer (saved while
    /// degraded, [`DamperMonitor::set_particles`]) resumes at its own count.
    pub fn resume(
        config: &DamperMonitorConfig,
        table: Option<Arc<GainTable>>,
        state: DamperMonitorState,
    ) -> Result<Self, DamperError> {
        config.validate()?;
        let model = config.filter_model();
        let mut rbpf = Rbpf::resume(&model, &config.rbpf, &config.speed, table, state.rbpf)?;
        let pause = state.pause;
        if config.speed.pause_reason(pause.speed_m_s).is_none() {
            rbpf.set_speed(pause.speed_m_s)?;
        }
        let ekf = match (config.ekf.enabled, state.ekf) {
            (true, Some(s)) => Some(AugmentedEkf::resume(&model, &config.ekf, s)?),
            _ => None,
        };
        let r = rbpf.estimate();
        let consistency = state.consistency;
        let burst = state.burst;
        let [csy, csay] = burst.published().unwrap_or([r.csy, r.csay]);
        Ok(DamperMonitor {
            estimate: DamperEstimate {
                time_s: state.steps as f64 * config.dt_s,
                csy,
                csay,
                effective_sample_size: r.effective_sample_size,
                ekf: ekf.as_ref().map(|e| e.estimate()),
                nis_window_mean: consistency.window_mean(),
                model_mismatch: consistency.mismatch(),
                noise_std_ratio: rbpf.noise_std_ratio(),
                paused: pause.reason,
                held_through_burst: burst.holding(),
                speed_m_s: pause.speed_m_s,
                // Not in the state: the next sample says (the filters take it before they step).
                measured_half_body_mass_kg: None,
            },
            rbpf,
            ekf,
            ekf_diverged_at_s: state.ekf_diverged_at_s,
            dt_s: config.dt_s,
            steps: state.steps,
            consistency,
            speed: config.speed,
            pause,
            trends: state.trends,
            nominal_ns_per_m: [model.nominal.csy_ns_per_m, model.nominal.csay_ns_per_m],
            burst,
        })
    }

    /// The longest hold of the publication through a burst ([`crate::burst`]):
    /// [`Rbpf::max_resume_settle_s`] (3 time constants of the model's slowest mode, the
    /// settling's longest after a pause). None without the jump search, whose adoptions are
    /// what a burst moves.
    fn max_hold_steps(&self) -> u64 {
        match self.rbpf.slowest_time_constant_s() {
            Some(_) => (self.rbpf.max_resume_settle_s() / self.dt_s).round() as u64,
            None => 0,
        }
    }

    pub fn estimate(&self) -> &DamperEstimate {
        &self.estimate
    }

    /// `damper`'s degradation trend (`crate::trend`) at its last closed bin: `None` before two
    /// operating minutes.
    pub fn trend(&self, damper: DamperId) -> Option<TrendEstimate> {
        self.trends[damper.index()].estimate()
    }

    pub fn rbpf(&self) -> &Rbpf {
        &self.rbpf
    }

    /// The body mass above the bogie the filter runs at after the last sample: measured,
    /// the particles' posterior mean while none is measured (`rbpf.unmeasured_mass`; a pass
    /// over the particles), or the design mass. What the service's view and `analyze`'s
    /// `estimates.csv` publish.
    pub fn body_mass(&self) -> BodyMass {
        if let Some(m) = self.estimate.measured_half_body_mass_kg {
            return BodyMass {
                source: MassSource::Measured,
                half_body_mass_kg: m,
            };
        }
        match self.rbpf.estimated_half_body_mass_kg() {
            Some(m) => BodyMass {
                source: MassSource::Estimated,
                half_body_mass_kg: m,
            },
            None => BodyMass {
                source: MassSource::Design,
                half_body_mass_kg: self.rbpf.design_half_body_mass_kg(),
            },
        }
    }

    /// Resamples the RBPF's cloud to `n` particles ([`Rbpf::set_particles`]): what a host that
    /// cannot keep up at the configured count runs meanwhile. The estimate is the next step's.
    pub fn set_particles(&mut self, n: usize) -> Result<(), DamperError> {
        self.rbpf.set_particles(n)
    }

    /// The particles the RBPF runs now (the configured count unless
    /// [`DamperMonitor::set_particles`] said otherwise).
    pub fn particles(&self) -> usize {
        self.rbpf.n_particles()
    }

    pub fn ekf(&self) -> Option<&AugmentedEkf> {
        self.ekf.as_ref()
    }

    /// When the EKF baseline stopped (non-finite estimate), if it did.
    pub fn ekf_diverged_at_s(&self) -> Option<f64> {
        self.ekf_diverged_at_s
    }

    pub fn steps(&self) -> u64 {
        self.steps
    }
}
