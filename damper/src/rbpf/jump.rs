//! Evidence-triggered search for a failed damper (`[monitor.rbpf.jump_search]`).
//!
//! The Liu-West filter finds a damper that failed after its posterior narrowed only through
//! particles redrawn at kernel moves (regeneration), and moves come at resamplings: where the
//! data say little per second (10 m/s: 80 times less about `C_say` than at 45.3 m/s) the
//! weights degenerate slowly, moves come seconds apart and the newcomers near the new value
//! come late. Moving on a clock instead changes the filter of every healthy bogie.
//!
//! Here the data decide when to search, and where. A few *sentinels*, Kalman filters of the
//! particles' kind at fixed offsets from the posterior mean (one damper at a time, the other
//! at its mean: [`SENTINEL_LN_OFFSETS`]), run beside the particles. Each carries the
//! posterior odds that its damper jumped to the sentinel's value at some time in the past,
//! against the particle mixture: the Shiryaev-Roberts recursion of a change-point with hazard
//! `lambda` per second,
//!
//! `Q_k = (Q_{k-1} + lambda dt) p_j(y_k | y_1..k-1) / p_mix(y_k | y_1..k-1)`,
//!
//! `p_j` the sentinel's predictive density, `p_mix` the mixture's (the weights' normaliser,
//! eq. 22). It is the change-point posterior of a model in which each damper may jump, with
//! that hazard, to one of the sentinels' values. While healthy, `Q` crosses a level `A` about
//! once in `A / lambda` seconds whatever the speed (the Shiryaev-Roberts property; a CUSUM on
//! the same log-likelihood ratios would fire `exp(h) / KL` apart, so on a fixed threshold
//! far more often where the data are informative). When the total odds `Q = sum_j Q_j` cross
//! `materialise_odds`, the hypotheses become particles: a share `Q / (1 + Q)` of the
//! particles (at least `min_newcomer_fraction`), chosen at random, are replaced by newcomers,
//! allotted to the sentinels in proportion to `Q_j` (systematic resampling of the
//! sentinels), each with its sentinel's coefficient (jittered by `newcomer_ln_std` in `ln C`),
//! the other coefficient its own, and the sentinel's Kalman state; together, in equal
//! weights, they get the jump's posterior mass `Q / (1 + Q)`, the other particles the rest in
//! their old proportions. No resampling and no kernel move: the cloud of a healthy bogie
//! loses a few random particles (a random subsample of a weighted sample is still one) and
//! moves no more often than before (more moves would regenerate more, which at low speed
//! costs the healthy estimate: "Low speed" in docs/damper.md). From then on the data weigh
//! the newcomers like any particle, and every `Q_j` starts again.
//!
//! **Publishing a jump.** The particles a hypothesis became are *on probation*: the filter
//! weighs, resamples and moves them like any particle, but the published posterior
//! (`Rbpf::estimate`, `Rbpf::mean`: the health ratio, the interval, hence the alarm) leaves
//! them out until they have held a decisive posterior mass, [`ADOPT_POSTERIOR_MASS`], for
//! [`ADOPT_TIME_CONSTANTS`] time constants of the model's slowest mode in a row; then they
//! are adopted and published with the rest. Meanwhile the published particles are kept
//! apart: while the hypotheses hold more than `1 -` [`MIN_PUBLISHED_SHARE`] of the posterior a
//! resampling keeps that share of the particles for the published side (stratified, the
//! weights exact), and the published particles' kernel, the wear drift and the sentinels
//! follow the published side's own mean. Before (until 30 Nov) a resampling that kept only
//! hypotheses published them at once, and in the transient after a step or a stop's resume
//! they could be the other damper's (the log, "The published side kept apart"). Why: the
//! likelihood ratio above is exact only when the filter's model is the plant's. With the
//! plant's conicity, noise or mass off the model's, the ratio of a failed-damper hypothesis
//! to a healthy cloud swings by tens of nats within tenths of a second, both ways: on the
//! condition sampler's held-out draws (27 Nov, mass given) 400 hypotheses became particles on
//! healthy dampers in 0.29 h, 145 moved a published ratio down by more than 0.05, and a
//! healthy damper's published ratio fell below the alarm's 0.7 in 54 stretches (8.1 s, to
//! 0.11 x nominal), 45 of them within 2 s of a hypothesis becoming particles. Evidence of a
//! failure persists; a transient of the plant's dynamics decays within its slowest time
//! constant. The window costs a real failure that much more before it is published (the
//! alarm's interval test needs 95 % of the mass below its threshold anyway).
//!
//! What is approximate (each a choice of the proposal, not of the weights' bookkeeping,
//! except the last two): the jump targets are the sentinels' values, not a continuum; the
//! sentinel's Kalman state and likelihood stand for those of a filter whose parameter jumped
//! at the change time (the filter forgets its state in a fraction of a second, so the two
//! differ only in the first instants); the newcomers' jitter shares the sentinel's weight
//! (the data then sort them); sentinels follow the posterior mean at each kernel move and
//! keep their odds (a shift of a few percent of a hypothesis 0.4-1.4 in `ln C` away).

use serde::{Deserialize, Serialize};

use crate::filter_model::FilterModel;
use crate::gain_table::GainGridConfig;
use crate::model::{BogieModel, Vector5, N_OUTPUTS};
use crate::params::positive;
use crate::speed::SpeedConfig;
use crate::DamperError;
use railmon_filter::logspace::log_sum_exp;

use super::bank::{Bank, BankState, StepOutput, Whitening};

/// Offsets of the sentinels from the posterior mean, in `ln C`, for each damper: 0.22, 0.33,
/// 0.45 and 0.61 times the mean. Spaced 0.3-0.4 apart, so that a failure anywhere in
/// 0.2-0.65 x is within 0.2 of one (at 10 m/s, `I(ln C_say)` = 5/s, a sentinel 0.2 off
/// loses 0.1 nats a second against the truth: little beside the 2-3 nats a second a failure
/// to 40 % gains), and newcomers jittered about them cover the rest. Only failures (less
/// damping), none near the mean: the alarm is for failures, and on a healthy bogie a false
/// hypothesis `d` away in `ln C` moves the mean by its mass times `d` for a time `~ 1 / KL`,
/// `KL ~ I d^2 / 2`: the near ones cost the healthy estimate the most. The gain grid's range
/// (0.1-3 x nominal) clamps them.
pub const SENTINEL_LN_OFFSETS: [f64; 4] = [-1.5, -1.1, -0.8, -0.5];

/// The posterior mass jump hypotheses on probation must hold to be published (the alarm's
/// interval test, `q95` below its threshold, needs this much of the mass below it).
pub const ADOPT_POSTERIOR_MASS: f64 = 0.95;

/// How long they must hold it, in time constants of the model's slowest mode at the body
/// mass's node ([`slowest_time_constant_s`], 2.07 s at the design mass): about as long as a
/// transient of the plant's own dynamics moves the odds. Half a time constant since the
/// published side is kept apart (30 Nov): a failure is no longer published at once by a
/// resampling that keeps only its hypotheses, and a whole one cost detections 1-4 s (v8 in
/// the log), half 0.3-0.9 s at the median.
pub const ADOPT_TIME_CONSTANTS: f64 = 0.5;

/// The share of the particles kept for the published posterior (those not on probation) at
/// a resampling while jump hypotheses hold more than `1 -` this share of the posterior
/// (`Rbpf::ancestors`): 50 of 500 particles, enough for its 5 % and 95 % quantiles.
pub const MIN_PUBLISHED_SHARE: f64 = 0.1;

/// The sentinels: each offset for each damper.
pub const N_SENTINELS: usize = 2 * SENTINEL_LN_OFFSETS.len();

/// The jump search (`[monitor.rbpf.jump_search]`), module docs of `railmon_damper::rbpf::jump`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct JumpSearchConfig {
    /// `false`: no sentinels (the filter before this search: newcomers only by regeneration
    /// at moves). Only with `kernel = "at_resampling"` (`DamperMonitorConfig::paper()` has it
    /// off).
    pub enabled: bool,
    /// `lambda`: the prior rate (per second) of a jump of one damper to one sentinel's value.
    /// The odds of a healthy bogie's hypothesis reach `A` about once in `A / lambda` s per
    /// sentinel; a failure needs about `ln(19 r / lambda)` nats of evidence for 95 % of the
    /// posterior (`r` the nats per second it gains).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub hazard_per_s: f64,
    /// Posterior odds `A` at which a sentinel's hypothesis becomes particles.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub materialise_odds: f64,
    /// Newcomers replace a share of the particles equal to the hypotheses' posterior mass
    /// (equal weights), but at least this share (so that the jitter covers a sentinel's
    /// neighbourhood), in (0, 0.5].
    #[schemars(extend("exclusiveMinimum" = 0.0), range(max = 0.5))]
    pub min_newcomer_fraction: f64,
    /// Spread of the newcomers' coefficient about the sentinel's (standard deviation in
    /// `ln C`; about half the sentinels' spacing).
    #[schemars(range(min = 0.0))]
    pub newcomer_ln_std: f64,
    /// After a pause (low or high speed) the filter settles (its states run, its weights and
    /// the sentinels' odds do not move) for at most this many time constants of the slowest
    /// mode of the vehicle model ([`slowest_time_constant_s`]: 2.07 s for the paper's vehicle
    /// over 5-55 m/s), or `speed.resume_settle_s` if longer; sooner when some hypothesis
    /// explains the data again (`railmon_damper::monitor`: after a stop the states restart at
    /// rest and it takes the 1 s minimum). The odds then start again from nothing. Stale
    /// states favour whichever hypothesis forgets them fastest, not the true dampers (after
    /// the 1 s settling alone on the held states, a cascade of newcomers at 25-35 % of
    /// nominal within a second, then a false `damper_degraded`, on the speed profile with
    /// stops; docs/damper.md "Low speed: the jump search"). The filter without the search
    /// keeps `speed.resume_settle_s` alone.
    #[schemars(range(min = 0.0))]
    pub resume_hold_time_constants: f64,
}

impl Default for JumpSearchConfig {
    fn default() -> Self {
        JumpSearchConfig {
            // On by default since the longer settling after a pause
            // (`resume_hold_time_constants`): 0 false `damper_degraded` in every cell of the
            // 600 s x 3 seed matrix with it, and the C_say step to 40 % found within 10 s at
            // every speed (10 m/s: 7.30 / 9.38 / 7.15 s; without it 14.94 / 12.76 / 10.02 s).
            // Before that fix it raised false alarms when accelerating from standstill
            // (docs/damper.md, "Low speed: the jump search").
            enabled: true,
            hazard_per_s: 1e-3,
            materialise_odds: 0.01,
            min_newcomer_fraction: 0.01,
            newcomer_ln_std: 0.15,
            // e^-3: 5 % of the stale states' error is left when the search judges again at
            // the latest.
            resume_hold_time_constants: 3.0,
        }
    }
}

impl JumpSearchConfig {
    pub fn validate(&self) -> Result<(), DamperError> {
        positive("rbpf.jump_search.hazard_per_s", self.hazard_per_s)?;
        positive("rbpf.jump_search.materialise_odds", self.materialise_odds)?;
        if !(self.min_newcomer_fraction > 0.0 && self.min_newcomer_fraction <= 0.5) {
            return Err(DamperError::InvalidParameter {
                field: "rbpf.jump_search.min_newcomer_fraction",
                value: self.min_newcomer_fraction,
                reason: "must be in (0, 0.5]",
            });
        }
        if !(self.newcomer_ln_std >= 0.0 && self.newcomer_ln_std.is_finite()) {
            return Err(DamperError::InvalidParameter {
                field: "rbpf.jump_search.newcomer_ln_std",
                value: self.newcomer_ln_std,
                reason: "must be finite and non-negative",
            });
        }
        crate::params::non_negative(
            "rbpf.jump_search.resume_hold_time_constants",
            self.resume_hold_time_constants,
        )?;
        Ok(())
    }
}

/// What a snapshot keeps of the sentinels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SentinelState {
    bank: BankState,
    ln_theta: Vec<[f64; 2]>,
    ln_odds: Vec<f64>,
    fires: u64,
}

/// The sentinel filters and their odds.
#[derive(Debug, Clone)]
pub(super) struct Sentinels {
    bank: Bank,
    /// Each sentinel's `ln C_sy, ln C_say`.
    ln_theta: Vec<[f64; 2]>,
    /// `ln Q_j` (`-inf`: none yet, after a start or a materialisation).
    ln_odds: Vec<f64>,
    /// `ln(lambda dt)`: the prior odds of a jump in one step.
    ln_hazard_step: f64,
    ln_materialise: f64,
    /// `ln C` range of the gain grid (absolute).
    ln_range: [[f64; 2]; 2],
    ll: Vec<f64>,
    nis: Vec<f64>,
    z: Vec<f64>,
    fires: u64,
}

impl Sentinels {
    /// Sentinels of the search `js` about `centre` (`ln C`), within the gain grid `g` of
    /// `filter_model`; `bank` holds their [`N_SENTINELS`] Kalman filters, of the particles'
    /// kind and at rest like theirs.
    pub(super) fn new(
        filter_model: &FilterModel,
        js: &JumpSearchConfig,
        g: &GainGridConfig,
        bank: Bank,
        centre: [f64; 2],
    ) -> Self {
        let nominal = filter_model.nominal.ln();
        let ln_range =
            [0, 1].map(|k| [nominal[k] + g.min_ratio.ln(), nominal[k] + g.max_ratio.ln()]);
        let mut s = Sentinels {
            bank,
            ln_theta: vec![centre; N_SENTINELS],
            ln_odds: vec![f64::NEG_INFINITY; N_SENTINELS],
            ln_hazard_step: (js.hazard_per_s * filter_model.dt_s).ln(),
            ln_materialise: js.materialise_odds.ln(),
            ln_range,
            ll: vec![0.0; N_SENTINELS],
            nis: vec![0.0; N_SENTINELS],
            z: vec![0.0; N_OUTPUTS * N_SENTINELS],
            fires: 0,
        };
        s.recentre(centre);
        s
    }

    /// Puts the sentinels at their offsets from `centre` (the posterior mean of `ln C`).
    pub(super) fn recentre(&mut self, centre: [f64; 2]) {
        let range = self.ln_range;
        for (j, th) in self.ln_theta.iter_mut().enumerate() {
            let k = j / SENTINEL_LN_OFFSETS.len();
            let offset = SENTINEL_LN_OFFSETS[j % SENTINEL_LN_OFFSETS.len()];
            *th = centre;
            th[k] = (centre[k] + offset).clamp(range[k][0], range[k][1]);
        }
    }

    /// `ln C` of damper `k` kept within the gain grid.
    pub(super) fn clamp(&self, k: usize, ln_c: f64) -> f64 {
        ln_c.clamp(self.ln_range[k][0], self.ln_range[k][1])
    }

    /// Runs the sentinels' filters on `y`; nothing is committed (see `commit`).
    pub(super) fn step(&mut self, y: &Vector5, whiten: &Whitening) -> Result<(), DamperError> {
        self.bank.step(
            &self.ln_theta,
            &[],
            y,
            whiten,
            StepOutput {
                ll: &mut self.ll,
                nis: &mut self.nis,
                z: &mut self.z,
            },
        )
    }

    /// Commits the step and updates the odds against the mixture's predictive log-density
    /// `mixture_ll` of the same step.
    pub(super) fn commit(&mut self, mixture_ll: f64) {
        self.bank.commit();
        for (q, l) in self.ln_odds.iter_mut().zip(&self.ll) {
            *q = updated_ln_odds(*q, self.ln_hazard_step, l - mixture_ll);
        }
    }

    /// Runs the sentinels' filters during a pause's settling: the odds start again (what they
    /// held came before the pause, and the settling's innovations are the stale states').
    pub(super) fn step_states(
        &mut self,
        y: &Vector5,
        whiten: &Whitening,
    ) -> Result<(), DamperError> {
        self.step(y, whiten)?;
        self.bank.commit();
        self.ln_odds.fill(f64::NEG_INFINITY);
        Ok(())
    }

    pub(super) fn set_schedule(
        &mut self,
        speed_m_s: f64,
        half_body_mass_kg: f64,
    ) -> Result<(), DamperError> {
        self.bank.set_schedule(speed_m_s, half_body_mass_kg)
    }

    pub(super) fn reset_states(&mut self) {
        self.bank.reset_states();
    }

    /// Every sentinel's state set to the common state after a pause (`super::resume_init`).
    pub(super) fn set_all_states(
        &mut self,
        x: &crate::model::Vector17,
        p: &crate::model::Matrix17,
    ) {
        self.bank.set_all_states(x, p);
    }

    /// Each sentinel's normalised innovation squared of the last step.
    pub(super) fn nis(&self) -> &[f64] {
        &self.nis
    }

    /// `ln` of the total posterior odds of a jump (any sentinel's), if it crossed
    /// `materialise_odds`.
    pub(super) fn due(&self) -> Option<f64> {
        let total = log_sum_exp(&self.ln_odds);
        (total >= self.ln_materialise).then_some(total)
    }

    /// Sentinel `j`'s parameters and Kalman filter, for the newcomers.
    pub(super) fn sentinel(&self, j: usize) -> ([f64; 2], &Bank) {
        (self.ln_theta[j], &self.bank)
    }

    /// After a materialisation: the mixture now holds the hypothesis; every odds starts again.
    pub(super) fn materialised(&mut self) {
        self.ln_odds.fill(f64::NEG_INFINITY);
        self.fires += 1;
    }

    pub(super) fn ln_odds(&self) -> &[f64] {
        &self.ln_odds
    }

    #[cfg(test)]
    pub(super) fn ln_odds_mut(&mut self) -> &mut [f64] {
        &mut self.ln_odds
    }

    pub(super) fn ln_theta(&self) -> &[[f64; 2]] {
        &self.ln_theta
    }

    /// How many hypotheses became particles so far.
    pub(super) fn fires(&self) -> u64 {
        self.fires
    }

    /// The largest `ln Q` (diagnostics).
    pub(super) fn max_ln_odds(&self) -> f64 {
        self.ln_odds
            .iter()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max)
    }

    pub(super) fn save(&self) -> SentinelState {
        SentinelState {
            bank: self.bank.save(),
            ln_theta: self.ln_theta.clone(),
            ln_odds: self.ln_odds.clone(),
            fires: self.fires,
        }
    }

    pub(super) fn restore(&mut self, state: SentinelState) -> Result<(), DamperError> {
        if state.ln_theta.len() != N_SENTINELS || state.ln_odds.len() != N_SENTINELS {
            return Err(DamperError::Config(
                "snapshot: another sentinel count".into(),
            ));
        }
        if state.ln_theta.iter().flatten().any(|v| !v.is_finite())
            || state.ln_odds.iter().any(|v| v.is_nan())
        {
            return Err(DamperError::NonFinite {
                what: "snapshot sentinels",
            });
        }
        self.bank.restore(state.bank)?;
        self.ln_theta = state.ln_theta;
        self.ln_odds = state.ln_odds;
        self.fires = state.fires;
        Ok(())
    }
}

/// The time constant of the slowest mode of the vehicle model over the speeds the filter runs
/// at, with nominal dampers (s): `1 / min |Re lambda|` over the eigenvalues `lambda` of
/// `A(nominal, v)` (but the two zero ones, the unobservable drift: `model` docs), `v` on a
/// geometric grid of ratio `speed.grid_ratio` over `[speed.min_m_s, speed.max_m_s]`. The
/// slowest part of a stale state's error decays at this rate in the plant's own dynamics
/// (open loop: the filter's gain corrects it on top). For the paper's vehicle it is the body's lateral mode on the secondary
/// suspension (0.67 Hz, decay 0.58 /s) at most speeds, and another mode at the lowest
/// speeds of the grid (decay 0.48 /s: 2.07 s over 5-55 m/s);
/// `tests::the_slowest_mode_is_the_body_at_speed`.
pub fn slowest_time_constant_s(
    filter_model: &FilterModel,
    speed: &SpeedConfig,
) -> Result<f64, DamperError> {
    // The plant's own modes: without the filter model's drift leak.
    let mut model = BogieModel::new(&filter_model.vehicle, 0.0)?;
    let sp = speed;
    let mut slowest_rate = f64::INFINITY;
    let mut v = sp.min_m_s;
    loop {
        model.set_speed(v.min(sp.max_m_s))?;
        let a = model.a_matrix(&filter_model.nominal);
        for z in a.complex_eigenvalues().iter() {
            if z.norm() > 1e-9 {
                slowest_rate = slowest_rate.min(-z.re);
            }
        }
        if v >= sp.max_m_s {
            break;
        }
        v *= sp.grid_ratio;
    }
    if slowest_rate.is_nan() || slowest_rate <= 0.0 {
        return Err(DamperError::Config(
            "jump_search: the vehicle model has an unstable mode within the speed range".into(),
        ));
    }
    Ok(1.0 / slowest_rate)
}

/// The odds can exceed any float only on a plant that diverged (per-step log-likelihoods of
/// 1e200 and more: conicity 0.25 in the robustness matrix, flagged `model_mismatch`): there
/// `ln Q` is held at this bound instead of becoming infinite, so that a materialisation's
/// weights stay finite.
const MAX_LN_ODDS: f64 = 700.0;

/// `ln Q_k` from `ln Q_{k-1}`, `ln(lambda dt)` and the step's `ln p_j - ln p_mix` (possibly
/// infinite when the two differ by more than a float holds), at most [`MAX_LN_ODDS`].
fn updated_ln_odds(ln_odds: f64, ln_hazard_step: f64, ln_ratio: f64) -> f64 {
    // `log_add_exp` with a finite `ln_hazard_step` is finite, so the sum is never NaN.
    (log_add_exp(ln_odds, ln_hazard_step) + ln_ratio).min(MAX_LN_ODDS)
}

/// `ln(e^a + e^b)`, exact for `a = -inf`.
fn log_add_exp(a: f64, b: f64) -> f64 {
    let (hi, lo) = if a > b { (a, b) } else { (b, a) };
    if lo == f64::NEG_INFINITY {
        return hi;
    }
    hi + (lo - hi).exp().ln_1p()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_odds_follow_shiryaev_roberts_and_stay_finite_on_a_diverged_plant() {
        let h = (1e-3_f64 * 1e-3).ln();
        let q1 = updated_ln_odds(f64::NEG_INFINITY, h, 0.5);
        assert!((q1 - (h + 0.5)).abs() < 1e-12);
        let q2 = updated_ln_odds(q1, h, -0.25);
        assert!((q2 - ((q1.exp() + h.exp()).ln() - 0.25)).abs() < 1e-12);
        // 1e308 - (-1e308) overflows to +inf; -1e308 - 1e308 to -inf.
        assert_eq!(updated_ln_odds(q2, h, 1e308 - -1e308), MAX_LN_ODDS);
        assert_eq!(updated_ln_odds(MAX_LN_ODDS, h, f64::INFINITY), MAX_LN_ODDS);
        assert_eq!(
            updated_ln_odds(MAX_LN_ODDS, h, -1e308 - 1e308),
            f64::NEG_INFINITY
        );
        assert_eq!(
            updated_ln_odds(f64::NEG_INFINITY, h, f64::NEG_INFINITY),
            f64::NEG_INFINITY
        );
    }

    /// The hold's time constant is the slowest decay of the model (checked against a
    /// simulation of the free response: a stale state's error shrinks by `e` in about it).
    #[test]
    fn the_slowest_mode_is_the_body_at_speed() {
        let c = crate::DamperMonitorConfig::default();
        let tau = slowest_time_constant_s(&c.filter_model(), &c.speed).unwrap();
        // The body's lateral mode alone, `2 m_bd / C_sy` = 1.625 s: coupled to the bogie it
        // decays a little slower (0.58 /s), and at 5 m/s another mode slower still.
        let body = 2.0 * c.vehicle.half_body_mass_kg / c.nominal.csy_ns_per_m;
        assert!(tau > body && tau < 1.3 * body, "{tau} against {body}");
        // Free response from a body displacement at 5 m/s: after 3 tau what is left is at
        // most e^-3 of it, give or take the oscillation's phase (envelope).
        // A crowded car's body sways slower: the hold scales with the body mass (scheduled
        // on it, `Rbpf::set_half_body_mass_kg`).
        let mut heavy = c.filter_model();
        heavy.vehicle.half_body_mass_kg *= 1.4;
        let tau_heavy = slowest_time_constant_s(&heavy, &c.speed).unwrap();
        assert!(tau_heavy > 1.25 * tau, "{tau_heavy} against {tau}");
        let mut f = crate::Rbpf::new(
            &c.filter_model(),
            &crate::RbpfConfig {
                particles: 4,
                propagation: crate::Propagation::Exact,
                ..c.rbpf
            },
            &c.speed,
        )
        .unwrap();
        let hold = f.max_resume_settle_s();
        let heavy_kg = 1.4 * c.vehicle.half_body_mass_kg;
        f.set_half_body_mass_kg(Some(heavy_kg)).unwrap();
        assert!(
            f.max_resume_settle_s() > 1.25 * hold,
            "{}",
            f.max_resume_settle_s()
        );
        f.set_half_body_mass_kg(None).unwrap();
        assert_eq!(f.max_resume_settle_s(), hold);
        let mut m = BogieModel::new(&c.vehicle, 0.0).unwrap();
        m.set_speed(c.speed.min_m_s).unwrap();
        let phi = crate::expm::expm(&(m.a_matrix(&c.nominal) * 0.01)).unwrap();
        let mut x = crate::model::Vector17::zeros();
        x[13] = 1.0;
        let mut peak_late: f64 = 0.0;
        for k in 1..=(6.0 * tau / 0.01) as usize {
            x = phi * x;
            if k as f64 * 0.01 >= 3.0 * tau {
                peak_late = peak_late.max(x[13].abs());
            }
        }
        assert!(peak_late < 3.0 * (-3.0f64).exp(), "{peak_late}");
    }

    #[test]
    fn log_add_exp_is_the_log_of_the_sum() {
        assert_eq!(log_add_exp(f64::NEG_INFINITY, -3.0), -3.0);
        assert_eq!(log_add_exp(-3.0, f64::NEG_INFINITY), -3.0);
        let v = log_add_exp(2.0_f64.ln(), 3.0_f64.ln());
        assert!((v - 5.0_f64.ln()).abs() < 1e-15);
        let v = log_add_exp(-800.0, -801.0);
        assert!((v - (-800.0 + (-1.0f64).exp().ln_1p())).abs() < 1e-12);
    }
}
