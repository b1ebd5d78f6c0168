//! Simulated traction drives: the PMSM plant (eq. 11 integrated with `substeps` Euler steps
//! per sample), a field-oriented speed controller per drive, sensor noise, and the ground
//! truth next to every sample.
//!
//! Timing within a step `t`: the currents are measured, the controller computes the voltage
//! from them, the sample `(u_t, i_t)` is emitted, and the plant advances with `u_t` to `t+1`
//! (the EKF predicts `x_{t+1}` from `u_t`, eq. 11).

use nalgebra::Vector2;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use crate::error::SlipError;
use crate::model::{idx, wrap_angle, DriveModel, DriveState};
use crate::sample::{DriveSample, DriveTruth};
use crate::scenario::{AdhesionScenario, ControllerConfig};

/// PI controller state of one drive.
#[derive(Debug, Clone, Copy)]
struct Controller {
    speed_integral_a: f64,
    d_integral_v: f64,
    q_integral_v: f64,
}

/// One simulated drive: plant state (the torque slot holds the current true load).
#[derive(Debug, Clone, Copy)]
struct Drive {
    x: DriveState,
    controller: Controller,
}

/// The simulator of a scenario.
pub struct DriveSimulator {
    scenario: AdhesionScenario,
    /// Model at the sub-step `dt / substeps`.
    sub_model: DriveModel,
    drives: Vec<Drive>,
    samples: Vec<DriveSample>,
    truth: Vec<DriveTruth>,
    rng: ChaCha8Rng,
    step: usize,
}

impl DriveSimulator {
    pub fn new(scenario: &AdhesionScenario) -> Result<Self, SlipError> {
        scenario.validate()?;
        let plant = &scenario.plant;
        let sub_model = DriveModel::new(plant.motor, scenario.dt_s / plant.substeps as f64)?;
        let mut rng = ChaCha8Rng::seed_from_u64(scenario.seed);
        let k_t = plant.motor.torque_constant_nm_per_a();
        let speed = plant.controller.reference_speed_rad_s;
        let drives = (0..scenario.n_drives)
            .map(|k| {
                // Start in steady state at the reference speed carrying the initial load, at a
                // random rotor angle (the wheels are not aligned).
                let load = scenario.true_load_nm(k, 0.0).0;
                let i_q = load / k_t;
                let theta = wrap_angle(rand::Rng::random::<f64>(&mut rng) * std::f64::consts::TAU);
                let (s, c) = theta.sin_cos();
                Drive {
                    x: DriveState::new(-i_q * s, i_q * c, speed, theta, load),
                    controller: Controller {
                        speed_integral_a: i_q,
                        d_integral_v: 0.0,
                        q_integral_v: plant.motor.r_s_ohm * i_q,
                    },
                }
            })
            .collect();
        Ok(DriveSimulator {
            scenario: scenario.clone(),
            sub_model,
            drives,
            samples: vec![DriveSample::default(); scenario.n_drives],
            truth: vec![
                DriveTruth {
                    speed_rad_s: 0.0,
                    angle_rad: 0.0,
                    torque_nm: 0.0,
                    slipping: false
                };
                scenario.n_drives
            ],
            rng,
            step: 0,
        })
    }

    pub fn scenario(&self) -> &AdhesionScenario {
        &self.scenario
    }

    /// Index of the step the next call returns.
    pub fn step_index(&self) -> usize {
        self.step
    }

    /// Next time step, or `None` after `n_steps`.
    pub fn step(&mut self) -> Option<(&[DriveSample], &[DriveTruth])> {
        if self.step >= self.scenario.n_steps {
            return None;
        }
        let t = self.step as f64;
        let noise = self.scenario.noise;
        let controller = self.scenario.plant.controller;
        let dt = self.scenario.dt_s;
        let params = self.scenario.plant.motor;
        for (k, drive) in self.drives.iter_mut().enumerate() {
            let (load, slipping) = self.scenario.true_load_nm(k, t);
            drive.x[idx::TORQUE] = load + gaussian(&mut self.rng, noise.load_std_nm);
            let i_meas = Vector2::new(
                drive.x[idx::I_ALPHA] + gaussian(&mut self.rng, noise.current_std_a),
                drive.x[idx::I_BETA] + gaussian(&mut self.rng, noise.current_std_a),
            );
            let u = foc_voltage(
                &controller,
                &params,
                dt,
                &mut drive.controller,
                &drive.x,
                &i_meas,
            );
            self.samples[k] = DriveSample {
                u_alpha_v: u[0] + gaussian(&mut self.rng, noise.voltage_std_v),
                u_beta_v: u[1] + gaussian(&mut self.rng, noise.voltage_std_v),
                i_alpha_a: i_meas[0],
                i_beta_a: i_meas[1],
            };
            self.truth[k] = DriveTruth {
                speed_rad_s: drive.x[idx::OMEGA],
                angle_rad: drive.x[idx::THETA],
                torque_nm: load,
                slipping,
            };
            for _ in 0..self.scenario.plant.substeps {
                drive.x = self.sub_model.transition(&drive.x, &u);
            }
            drive.x[idx::THETA] = wrap_angle(drive.x[idx::THETA]);
        }
        self.step += 1;
        Some((&self.samples, &self.truth))
    }
}

fn gaussian(rng: &mut ChaCha8Rng, std: f64) -> f64 {
    if std > 0.0 {
        Normal::new(0.0, std).map_or(0.0, |n| n.sample(rng))
    } else {
        0.0
    }
}

/// Field-oriented speed control: the speed PI gives the quadrature current reference
/// (d-axis reference 0), the current PIs give `u_d, u_q` with the usual decoupling and
/// back-EMF feed-forward, and the inverse Park transform at the mid-step angle gives
/// `u_alpha, u_beta`. Uses the encoder speed and angle: the *controller* is not sensorless,
/// the *monitor* is (it sees only voltages and currents).
fn foc_voltage(
    c: &ControllerConfig,
    m: &crate::model::MotorParams,
    dt: f64,
    state: &mut Controller,
    x: &DriveState,
    i_meas: &Vector2<f64>,
) -> Vector2<f64> {
    let omega = x[idx::OMEGA];
    let theta = x[idx::THETA];
    let (s, co) = theta.sin_cos();
    let i_d = i_meas[0] * co + i_meas[1] * s;
    let i_q = -i_meas[0] * s + i_meas[1] * co;

    let speed_error = c.reference_speed_rad_s - omega;
    let i_q_ref_raw = c.speed_kp_a_per_rad_s * speed_error + state.speed_integral_a;
    let i_q_ref = i_q_ref_raw.clamp(-c.max_current_a, c.max_current_a);
    // Anti-windup: integrate only while the reference is not saturated.
    if i_q_ref == i_q_ref_raw {
        state.speed_integral_a += c.speed_ki_a_per_rad * speed_error * dt;
    }

    let e_d = -i_d;
    let e_q = i_q_ref - i_q;
    state.d_integral_v += c.current_ki_v_per_a_s * e_d * dt;
    state.q_integral_v += c.current_ki_v_per_a_s * e_q * dt;
    let u_d = c.current_kp_v_per_a * e_d + state.d_integral_v - omega * m.l_s_h * i_q;
    let u_q =
        c.current_kp_v_per_a * e_q + state.q_integral_v + omega * (m.l_s_h * i_d + m.psi_pm_wb);

    let (s_mid, c_mid) = (theta + 0.5 * omega * dt).sin_cos();
    Vector2::new(u_d * c_mid - u_q * s_mid, u_d * s_mid + u_q * c_mid)
}
