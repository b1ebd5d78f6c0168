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
use crate::model::{idx, wrap_angle, DriveModel, DriveState, MotorParams};
use crate::sample::{is_slipping, DriveSample, DriveTruth, SLIP_RULE_FLOOR_NM};
use crate::scenario::{AdhesionScenario, ControllerConfig, NoiseConfig, TrainSpeedConfig};

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

/// The vehicle of a scenario with a train speed ([`TrainSpeedConfig`]).
#[derive(Debug, Clone, Copy)]
struct Train {
    config: TrainSpeedConfig,
    /// Electrical rotor speed per m/s of train speed, `G p_p / r`.
    rad_s_per_m_s: f64,
    /// The motor's corner speed (constant power above) and the electric brake's fade speed,
    /// electrical rad/s.
    base_speed_rad_s: f64,
    fade_speed_rad_s: f64,
    /// True train speed.
    speed_m_s: f64,
    /// The measurement of the last step.
    measured_m_s: f64,
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
    train: Option<Train>,
}

impl DriveSimulator {
    pub fn new(scenario: &AdhesionScenario) -> Result<Self, SlipError> {
        scenario.validate()?;
        let plant = &scenario.plant;
        let sub_model = DriveModel::new(plant.motor, scenario.dt_s / plant.substeps as f64)?;
        let mut rng = ChaCha8Rng::seed_from_u64(scenario.seed);
        let k_t = plant.motor.torque_constant_nm_per_a();
        let speed = plant.controller.reference_speed_rad_s;
        let train = scenario.train_speed.map(|config| {
            let rad_s_per_m_s = config.gear_ratio * plant.motor.pole_pairs / config.wheel_radius_m;
            let speed_m_s = speed.abs() / rad_s_per_m_s;
            Train {
                config,
                rad_s_per_m_s,
                base_speed_rad_s: 2.0 * speed.abs(),
                fade_speed_rad_s: 0.1 * speed.abs(),
                speed_m_s,
                measured_m_s: speed_m_s,
            }
        });
        let drives = (0..scenario.n_drives)
            .map(|k| {
                // Start in steady state at the reference speed carrying the initial load, at a
                // random rotor angle (the wheels are not aligned). With a train, the rotor runs
                // at the train's speed plus the creep that carries the load.
                let load = scenario.true_load_nm(k, 0.0).0;
                let i_q = load / k_t;
                let theta = wrap_angle(rand::Rng::random::<f64>(&mut rng) * std::f64::consts::TAU);
                let (s, c) = theta.sin_cos();
                let speed = match &train {
                    Some(t) => speed + load / t.config.creep_stiffness_nm_s_per_rad,
                    None => speed,
                };
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
            train,
        })
    }

    /// The measured train speed (m/s) of the step the last call returned, when the scenario
    /// has a train speed (`[train_speed]`): what the monitor's
    /// [`crate::SlipMonitor::step_with_train_speed`] takes.
    pub fn train_speed_m_s(&self) -> Option<f64> {
        self.train.as_ref().map(|t| t.measured_m_s)
    }

    /// The true train speed (m/s) at that step.
    pub fn true_train_speed_m_s(&self) -> Option<f64> {
        self.train.as_ref().map(|t| t.speed_m_s)
    }

    pub fn scenario(&self) -> &AdhesionScenario {
        &self.scenario
    }

    /// Index of the step the next call returns.
    pub fn step_index(&self) -> usize {
        self.step
    }

    /// [`DriveSimulator::step`] with the measured train speed of the step (m/s; `None` when
    /// the scenario has none), what [`crate::SlipMonitor::step_with_train_speed`] takes.
    #[allow(clippy::type_complexity)]
    pub fn step_with_train_speed(
        &mut self,
    ) -> Option<(&[DriveSample], &[DriveTruth], Option<f64>)> {
        self.step()?;
        let train = self.train_speed_m_s();
        Some((&self.samples, &self.truth, train))
    }

    /// Next time step, or `None` after `n_steps`.
    pub fn step(&mut self) -> Option<(&[DriveSample], &[DriveTruth])> {
        if self.step >= self.scenario.n_steps {
            return None;
        }
        if self.train.is_some() {
            self.advance_with_train();
            self.step += 1;
            return Some((&self.samples, &self.truth));
        }
        let t = self.step as f64;
        let noise = self.scenario.noise;
        for (k, drive) in self.drives.iter_mut().enumerate() {
            let (load, slipping) = self.scenario.true_load_nm(k, t);
            drive.x[idx::TORQUE] = load + gaussian(&mut self.rng, noise.load_std_nm);
            self.truth[k] = DriveTruth {
                speed_rad_s: drive.x[idx::OMEGA],
                angle_rad: drive.x[idx::THETA],
                torque_nm: load,
                slipping,
            };
            self.samples[k] = Plant::of(&self.scenario, &self.sub_model).measure_and_step(
                drive,
                &mut self.rng,
                &noise,
                None,
            );
        }
        self.step += 1;
        Some((&self.samples, &self.truth))
    }

    /// One step of a scenario with a train speed ([`TrainSpeedConfig`] has the physics).
    fn advance_with_train(&mut self) {
        let Some(train) = &mut self.train else {
            return;
        };
        let t = self.step as f64;
        let noise = self.scenario.noise;
        let dt = self.scenario.dt_s;
        let c = train.config;
        let omega_v = train.speed_m_s * train.rad_s_per_m_s;
        let mut deficit_nm = 0.0;
        for (k, drive) in self.drives.iter_mut().enumerate() {
            let healthy = self.scenario.healthy_load_nm(k, t);
            let (load, breaks_rule) = self.scenario.true_load_nm(k, t);
            let limit = if breaks_rule {
                load.abs()
            } else {
                load.abs() + (c.adhesion_reserve * healthy.abs()).max(SLIP_RULE_FLOOR_NM)
            };
            let omega = drive.x[idx::OMEGA];
            let rail = (c.creep_stiffness_nm_s_per_rad * (omega - omega_v)).clamp(-limit, limit);
            deficit_nm += rail - healthy;
            drive.x[idx::TORQUE] = rail + gaussian(&mut self.rng, noise.load_std_nm);
            // The notch asks for the healthy load; the motor gives it up to constant power
            // above its corner speed, and its electric brake fades near standstill.
            let demand = if healthy * omega >= 0.0 {
                healthy * (train.base_speed_rad_s / omega.abs().max(1e-9)).min(1.0)
            } else {
                healthy * (omega.abs() / train.fade_speed_rad_s).min(1.0)
            };
            self.truth[k] = DriveTruth {
                speed_rad_s: omega,
                angle_rad: drive.x[idx::THETA],
                torque_nm: rail,
                slipping: is_slipping(rail, healthy),
            };
            self.samples[k] = Plant::of(&self.scenario, &self.sub_model).measure_and_step(
                drive,
                &mut self.rng,
                &noise,
                Some(demand),
            );
        }
        // A speed sensor reads a magnitude: near standstill its noise must not make it
        // negative (the service refuses a negative train speed as implausible).
        train.measured_m_s = (train.speed_m_s + gaussian(&mut self.rng, c.noise_std_m_s)).max(0.0);
        let mass_kg = c.mass_per_drive_kg * self.drives.len() as f64;
        let force_n = deficit_nm * c.gear_ratio / c.wheel_radius_m;
        train.speed_m_s = (train.speed_m_s + dt * force_n / mass_kg).max(0.0);
    }
}

/// What one drive's step needs of the scenario's plant.
struct Plant<'a> {
    controller: &'a ControllerConfig,
    params: &'a MotorParams,
    dt_s: f64,
    sub_model: &'a DriveModel,
    substeps: usize,
}

impl<'a> Plant<'a> {
    fn of(scenario: &'a AdhesionScenario, sub_model: &'a DriveModel) -> Self {
        Plant {
            controller: &scenario.plant.controller,
            params: &scenario.plant.motor,
            dt_s: scenario.dt_s,
            sub_model,
            substeps: scenario.plant.substeps,
        }
    }

    /// Measures `drive`'s currents, runs its controller (`demand`: a torque demand, else
    /// speed control), steps it through the substeps and gives the sample the inverter's
    /// sensors see (noise drawn in the order currents, then voltages).
    fn measure_and_step(
        &self,
        drive: &mut Drive,
        rng: &mut ChaCha8Rng,
        noise: &NoiseConfig,
        demand: Option<f64>,
    ) -> DriveSample {
        let i_meas = Vector2::new(
            drive.x[idx::I_ALPHA] + gaussian(rng, noise.current_std_a),
            drive.x[idx::I_BETA] + gaussian(rng, noise.current_std_a),
        );
        let u = foc_voltage(
            self.controller,
            self.params,
            self.dt_s,
            &mut drive.controller,
            &drive.x,
            &i_meas,
            demand,
        );
        let sample = DriveSample {
            u_alpha_v: u[0] + gaussian(rng, noise.voltage_std_v),
            u_beta_v: u[1] + gaussian(rng, noise.voltage_std_v),
            i_alpha_a: i_meas[0],
            i_beta_a: i_meas[1],
        };
        for _ in 0..self.substeps {
            drive.x = self.sub_model.transition(&drive.x, &u);
        }
        drive.x[idx::THETA] = wrap_angle(drive.x[idx::THETA]);
        sample
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
    m: &MotorParams,
    dt: f64,
    state: &mut Controller,
    x: &DriveState,
    i_meas: &Vector2<f64>,
    torque_demand_nm: Option<f64>,
) -> Vector2<f64> {
    let omega = x[idx::OMEGA];
    let theta = x[idx::THETA];
    let (s, co) = theta.sin_cos();
    let i_d = i_meas[0] * co + i_meas[1] * s;
    let i_q = -i_meas[0] * s + i_meas[1] * co;

    let i_q_ref = match torque_demand_nm {
        // Torque control (a vehicle with a train speed): the notch's torque.
        Some(torque) => {
            (torque / m.torque_constant_nm_per_a()).clamp(-c.max_current_a, c.max_current_a)
        }
        None => {
            let speed_error = c.reference_speed_rad_s - omega;
            let i_q_ref_raw = c.speed_kp_a_per_rad_s * speed_error + state.speed_integral_a;
            let i_q_ref = i_q_ref_raw.clamp(-c.max_current_a, c.max_current_a);
            // Anti-windup: integrate only while the reference is not saturated.
            if i_q_ref == i_q_ref_raw {
                state.speed_integral_a += c.speed_ki_a_per_rad * speed_error * dt;
            }
            i_q_ref
        }
    };

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
