//! The states after a pause estimated from the first measurements, then given to every
//! particle and sentinel (issue 24 item 4).
//!
//! After a stop the states restart at rest ([`super::Rbpf::reset_states`]), but the plant is
//! not at rest when the speed passes the minimum again: it has run below it for seconds. The
//! particles' filters are steady-state (Riccati) filters: their gain is the one for an error
//! covariance `P_ss` of a filter that has run for ever, far smaller than the error of a state
//! guessed at rest, so they forget the wrong start only as fast as their closed-loop modes
//! decay (the slowest mode's ~2 s). Until then each hypothesis's innovations carry that
//! transient, which moves the likelihood ratios of the jump search (docs/notes/damper-log.md,
//! 29 Nov: every traced healthy dip after a stop is a jump adopted within 0.3 s of the
//! settling).
//!
//! Here one exact time-varying Kalman filter (the paper's section 4.3: full covariance,
//! Joseph update) at the published posterior mean runs from a diffuse start, the plant's
//! stationary covariance `P_inf = sum_k Phi^k Q Phi'^k` at the speed it resumes at (the
//! spread of a state the track has driven for long; an upper bound of the state's spread after
//! a stop, so the data, not the guess, fix the state). Its gain is the optimal one for that
//! start, so its state is the best estimate of the first samples, and after a window it is
//! handed to every particle and sentinel: from there the steady-state filters start near the
//! truth instead of at rest.

use crate::expm::discretize;
use crate::filter_model::FilterModel;
use crate::kalman::{self, NoiseCovariances, StateEstimate};
use crate::model::{BogieModel, Matrix17, Vector17, Vector5};
use crate::params::Dampers;
use crate::DamperError;
use railmon_filter::kalman::symmetrize;

/// Doublings of the stationary covariance: `2^40` steps, far beyond the drift leak's 10 s
/// (`drift_leak_per_s`); the sum converges long before (stops when a doubling adds nothing).
const MAX_DOUBLINGS: usize = 40;

/// [`ResumeInit`] for a snapshot: the dampers it runs at (`ln C_sy, ln C_say`), its state
/// and covariance (column-major, as plain numbers) and the samples it has filtered. The model is
/// set to the schedule of the next sample before each step.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ResumeInitState {
    ln_dampers: [f64; 2],
    x: Vec<f64>,
    p: Vec<f64>,
    steps: u64,
}

/// One exact Kalman filter at the posterior mean, started diffuse.
#[derive(Debug, Clone)]
pub(super) struct ResumeInit {
    model: BogieModel,
    noise: NoiseCovariances,
    dampers: Dampers,
    dt_s: f64,
    est: StateEstimate,
    steps: u64,
}

impl ResumeInit {
    /// At the posterior mean `dampers`, the schedule `(speed_m_s, half_body_mass_kg)`, from
    /// the state at rest with the stationary covariance there.
    pub(super) fn new(
        filter_model: &FilterModel,
        dampers: Dampers,
        speed_m_s: f64,
        half_body_mass_kg: f64,
    ) -> Result<Self, DamperError> {
        let mut model = filter_model.bogie_model()?;
        model.set_speed(speed_m_s)?;
        model.set_half_body_mass_kg(half_body_mass_kg)?;
        let noise = filter_model.noise();
        let disc = discretize(&model.a_matrix(&dampers), &model.g_matrix(), filter_model.dt_s)?;
        // Smith's doubling: P_{2m} = P_m + Phi^m P_m Phi^m', P_1 = Q.
        let mut p = noise.process(&disc.gamma);
        let mut phi = disc.phi;
        for _ in 0..MAX_DOUBLINGS {
            let add = phi * p * phi.transpose();
            let done = add.amax() <= 1e-12 * p.amax();
            p += add;
            symmetrize(&mut p);
            phi = phi * phi;
            if done {
                break;
            }
        }
        if !p.iter().all(|v| v.is_finite()) {
            return Err(DamperError::NonFinite {
                what: "stationary covariance",
            });
        }
        Ok(ResumeInit {
            model,
            noise,
            dampers,
            dt_s: filter_model.dt_s,
            est: StateEstimate {
                x: Vector17::zeros(),
                p,
            },
            steps: 0,
        })
    }

    /// One predict and update on `y`, the model at the schedule of this sample, the sensor
    /// noise scaled by the estimate the particles use (`variance_scale`, held during the
    /// settling).
    pub(super) fn step(
        &mut self,
        y: &Vector5,
        variance_scale: &[f64; 5],
        speed_m_s: f64,
        half_body_mass_kg: f64,
    ) -> Result<(), DamperError> {
        if self.model.params().speed_m_s != speed_m_s {
            self.model.set_speed(speed_m_s)?;
        }
        if self.model.params().half_body_mass_kg != half_body_mass_kg {
            self.model.set_half_body_mass_kg(half_body_mass_kg)?;
        }
        let disc = discretize(
            &self.model.a_matrix(&self.dampers),
            &self.model.g_matrix(),
            self.dt_s,
        )?;
        let pred = kalman::predict(&self.est, &disc, &self.noise);
        let mut q_v = self.noise.q_v;
        for (i, d) in variance_scale.iter().enumerate() {
            for j in 0..5 {
                q_v[(i, j)] *= d.sqrt() * variance_scale[j].sqrt();
            }
        }
        let (post, _) = kalman::update(&pred, y, &self.model.h_matrix(), &q_v)?;
        self.est = post;
        self.steps += 1;
        Ok(())
    }

    pub(super) fn save(&self) -> ResumeInitState {
        ResumeInitState {
            ln_dampers: self.dampers.ln(),
            x: self.est.x.iter().copied().collect(),
            p: self.est.p.iter().copied().collect(),
            steps: self.steps,
        }
    }

    /// The filter `state` saved (checked: sizes and finite numbers).
    pub(super) fn restore(
        filter_model: &FilterModel,
        state: ResumeInitState,
    ) -> Result<Self, DamperError> {
        let n = crate::model::N_STATES;
        if state.x.len() != n || state.p.len() != n * n {
            return Err(DamperError::Config(
                "snapshot: resume_init of the wrong size".into(),
            ));
        }
        if state.x.iter().chain(&state.p).chain(&state.ln_dampers).any(|v| !v.is_finite()) {
            return Err(DamperError::NonFinite {
                what: "snapshot resume_init",
            });
        }
        let model = filter_model.bogie_model()?;
        Ok(ResumeInit {
            model,
            noise: filter_model.noise(),
            dampers: Dampers::from_ln(state.ln_dampers),
            dt_s: filter_model.dt_s,
            est: StateEstimate {
                x: Vector17::from_column_slice(&state.x),
                p: Matrix17::from_column_slice(&state.p),
            },
            steps: state.steps,
        })
    }

    /// Samples filtered so far.
    pub(super) fn steps(&self) -> u64 {
        self.steps
    }

    /// The state estimate and its covariance.
    pub(super) fn estimate(&self) -> (&Vector17, &Matrix17) {
        (&self.est.x, &self.est.p)
    }
}
