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
//! Joseph update) at the published posterior mean runs from a wide start, the plant's
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

/// How long the common filter runs before its state is handed over (s): one window of the
/// settling's innovation test (`monitor::SETTLE_WINDOW_S`, 0.5 s), so that with the least
/// settling (`speed.resume_settle_s`, 1 s) the window that ends it judges the handed-over
/// states, the ones the posterior then learns with. A settling that ends sooner takes the
/// state as it is by then. Measured on the condition sampler's healthy draws that dipped after
/// a stop (docs/notes/damper-log.md, 29 Nov): 8 of 8 below 0.7 with the states at rest, 1 of
/// 8 (for 3 ms, 22 s after moving off) with this.
pub const RESUME_INIT_S: f64 = 0.5;

/// Doublings of the stationary covariance: `2^40` steps, far beyond the drift leak's 10 s
/// (`drift_leak_per_s`); the sum converges long before (stops when a doubling adds nothing).
const MAX_DOUBLINGS: usize = 40;

/// [`ResumeInit`] for a snapshot: the dampers it runs at (`C_sy, C_say`, N s/m), its state
/// and covariance (column-major, as plain numbers) and the samples it has filtered. The model is
/// set to the schedule of the next sample before each step.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ResumeInitState {
    dampers_ns_per_m: [f64; 2],
    /// The speed (m/s) and body mass (kg) of its last step.
    schedule: [f64; 2],
    x: Vec<f64>,
    p: Vec<f64>,
    steps: u64,
}

/// One exact Kalman filter at the posterior mean, started from the plant's stationary spread.
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
        let disc = discretize(
            &model.a_matrix(&dampers),
            &model.g_matrix(),
            filter_model.dt_s,
        )?;
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
        let p = self.model.params();
        ResumeInitState {
            dampers_ns_per_m: [self.dampers.csy_ns_per_m, self.dampers.csay_ns_per_m],
            schedule: [p.speed_m_s, p.half_body_mass_kg],
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
        if state
            .x
            .iter()
            .chain(&state.p)
            .chain(&state.dampers_ns_per_m)
            .chain(&state.schedule)
            .any(|v| !v.is_finite())
        {
            return Err(DamperError::NonFinite {
                what: "snapshot resume_init",
            });
        }
        // The model as `new` and `step` left it: the same calls, the same entries.
        let mut model = filter_model.bogie_model()?;
        model.set_speed(state.schedule[0])?;
        model.set_half_body_mass_kg(state.schedule[1])?;
        Ok(ResumeInit {
            model,
            noise: filter_model.noise(),
            dampers: Dampers {
                csy_ns_per_m: state.dampers_ns_per_m[0],
                csay_ns_per_m: state.dampers_ns_per_m[1],
            },
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::DamperMonitorConfig;

    fn filter_at_10_m_s() -> (FilterModel, ResumeInit) {
        let fm = DamperMonitorConfig::default().filter_model();
        let init = ResumeInit::new(&fm, fm.nominal, 10.0, fm.vehicle.half_body_mass_kg).unwrap();
        (fm, init)
    }

    /// The start's covariance is the plant's stationary one: `P = Phi P Phi' + Q` (the
    /// discrete Lyapunov equation), to the doubling's stopping tolerance.
    #[test]
    fn the_start_is_the_stationary_covariance() {
        let (fm, init) = filter_at_10_m_s();
        let mut model = fm.bogie_model().unwrap();
        model.set_speed(10.0).unwrap();
        let disc = discretize(&model.a_matrix(&fm.nominal), &model.g_matrix(), fm.dt_s).unwrap();
        let (_, p) = init.estimate();
        let residual = p - (disc.phi * p * disc.phi.transpose() + fm.noise().process(&disc.gamma));
        assert!(
            residual.amax() <= 1e-9 * p.amax(),
            "{} of {}",
            residual.amax(),
            p.amax()
        );
        // Wider than the error the steady-state particles assume (their Riccati `P-`): what
        // lets the data, not the start, fix the state.
        let ss = kalman::steady_state(&disc, &model.h_matrix(), &fm.noise()).unwrap();
        assert!(
            p.trace() > ss.p_pred.trace(),
            "{} {}",
            p.trace(),
            ss.p_pred.trace()
        );
    }

    /// A snapshot resumes bit for bit, and a damaged one is refused.
    #[test]
    fn a_saved_filter_resumes_where_it_was() {
        let (fm, mut init) = filter_at_10_m_s();
        let y = Vector5::new(0.1, -0.2, 0.05, 0.001, 0.02);
        for _ in 0..20 {
            init.step(&y, &[1.0; 5], 10.0, fm.vehicle.half_body_mass_kg)
                .unwrap();
        }
        let mut resumed = ResumeInit::restore(&fm, init.save()).unwrap();
        for f in [&mut init, &mut resumed] {
            f.step(&y, &[1.2; 5], 10.5, fm.vehicle.half_body_mass_kg)
                .unwrap();
        }
        assert_eq!(init.estimate(), resumed.estimate());
        assert_eq!(resumed.steps(), 21);
        let mut bad = init.save();
        bad.p.pop();
        assert!(ResumeInit::restore(&fm, bad).is_err());
        let mut bad = init.save();
        bad.x[3] = f64::NAN;
        assert!(ResumeInit::restore(&fm, bad).is_err());
    }
}
