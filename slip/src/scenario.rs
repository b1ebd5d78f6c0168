//! Adhesion scenarios (`config/scenarios/adhesion-*.toml`): the plant, its controller, the
//! load profiles and slip events of every drive, sensor noise, and the monitor settings.
//!
//! Drives are numbered from 1 in the file, as in the paper.

use serde::{Deserialize, Serialize};

use crate::adhesion::temporal::normal_cdf;
use crate::error::{check_finite, check_in, check_non_negative, check_positive, SlipError};
use crate::model::MotorParams;
use crate::monitor::SlipMonitorConfig;
use crate::sample::is_slipping;
use crate::speed_reference::SpeedReferenceConfig;

/// The field-oriented speed controller of the simulated drives (PI speed loop giving the
/// quadrature current reference, PI current loops in the d-q frame with decoupling).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ControllerConfig {
    /// Electrical speed the controller holds.
    pub reference_speed_rad_s: f64,
    pub speed_kp_a_per_rad_s: f64,
    pub speed_ki_a_per_rad: f64,
    pub current_kp_v_per_a: f64,
    pub current_ki_v_per_a_s: f64,
    /// Limit of the quadrature current reference.
    pub max_current_a: f64,
}

impl Default for ControllerConfig {
    fn default() -> Self {
        // Current loop at ~200 Hz (kp = L w_c, ki = R w_c), speed loop at ~20 Hz for the
        // default motor (i_q -> omega gain p_p k_t / J = 119 rad/s^2/A).
        ControllerConfig {
            reference_speed_rad_s: 200.0,
            speed_kp_a_per_rad_s: 1.0,
            speed_ki_a_per_rad: 30.0,
            current_kp_v_per_a: 4.35,
            current_ki_v_per_a_s: 350.0,
            max_current_a: 80.0,
        }
    }
}

impl ControllerConfig {
    fn validate(&self) -> Result<(), SlipError> {
        check_finite(
            "plant.controller.reference_speed_rad_s",
            self.reference_speed_rad_s,
        )?;
        check_non_negative(
            "plant.controller.speed_kp_a_per_rad_s",
            self.speed_kp_a_per_rad_s,
        )?;
        check_non_negative(
            "plant.controller.speed_ki_a_per_rad",
            self.speed_ki_a_per_rad,
        )?;
        check_non_negative(
            "plant.controller.current_kp_v_per_a",
            self.current_kp_v_per_a,
        )?;
        check_non_negative(
            "plant.controller.current_ki_v_per_a_s",
            self.current_ki_v_per_a_s,
        )?;
        check_positive("plant.controller.max_current_a", self.max_current_a)
    }
}

/// The simulated drives (all identical).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PlantConfig {
    /// True motor parameters of the plant (the monitor has its own copy in `monitor.motor`).
    pub motor: MotorParams,
    /// Euler sub-steps per sample period: 1 is exactly the model (11) the EKF uses; more
    /// integrates the continuous motor more finely (a small model mismatch for the EKF).
    pub substeps: usize,
    pub controller: ControllerConfig,
}

impl Default for PlantConfig {
    fn default() -> Self {
        PlantConfig {
            motor: MotorParams::default(),
            substeps: 1,
            controller: ControllerConfig::default(),
        }
    }
}

/// Sensor noise of the simulated measurements.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NoiseConfig {
    /// Standard deviation of each measured current (the EKF's `R = 0.01` is 0.1 A).
    pub current_std_a: f64,
    /// Standard deviation of the error of each reported voltage (reconstructed from the PWM).
    pub voltage_std_v: f64,
    /// Standard deviation of a white load-torque disturbance per step (road roughness).
    pub load_std_nm: f64,
}

impl Default for NoiseConfig {
    fn default() -> Self {
        NoiseConfig {
            current_std_a: 0.1,
            voltage_std_v: 0.0,
            load_std_nm: 0.0,
        }
    }
}

/// The train's own speed (issue 23 item 2): present, the simulated vehicle moves at a speed of
/// its own, measured with noise (radar, GNSS), and the drives are coupled to it through the
/// wheel-rail contact instead of holding a speed of their own.
///
/// **The plant then** (`DriveSimulator`): each drive is torque-controlled (`i_q` reference =
/// its healthy load, the driver's notch, over `k_t`; the motor's torque fades above twice the
/// starting speed, constant power, and an electric brake fades below a tenth of it). The rail
/// takes from the wheel the creep force `K (omega - omega_v)` (`omega_v` the rotor speed the
/// train speed implies, `K` the creep stiffness: the linear part of the creep curve, Kalker;
/// Polach, Wear 258, 2005) up to the adhesion limit: the healthy load plus a reserve
/// (`adhesion_reserve` of it, at least 0.5 N m) while the drive adheres, the scenario's load
/// where its events break the slip rule. Past the limit the rail takes only the limit and the
/// rotor runs away from the train, ahead in traction, behind in braking, until the limit
/// returns and the creep force pulls it back. The truth torque is what the rail takes, the
/// truth flag the slip rule on it (a wheel being pulled back is still slipping). The train
/// speed `v` follows `M dv/dt = sum_k (T_rail,k - T_healthy,k) G / r` (the healthy efforts
/// balance the running resistance and gradient; `M` = `mass_per_drive_kg` x drives).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainSpeedConfig {
    /// Standard deviation of the measured train speed (radar/GNSS: 0.05-0.2 m/s), white.
    pub noise_std_m_s: f64,
    /// Gear ratio and wheel radius of the plant (the monitor's own copy is its
    /// [`SpeedReferenceConfig`]).
    pub gear_ratio: f64,
    pub wheel_radius_m: f64,
    /// Vehicle mass per drive (scaled to the small motors of the scenarios).
    pub mass_per_drive_kg: f64,
    /// Creep stiffness `K`, N m per electrical rad/s of the rotor's departure from the train.
    pub creep_stiffness_nm_s_per_rad: f64,
    /// The adhesion limit of an adhering wheel above its healthy load, as a fraction of it.
    pub adhesion_reserve: f64,
}

impl Default for TrainSpeedConfig {
    fn default() -> Self {
        let geometry = SpeedReferenceConfig::default();
        TrainSpeedConfig {
            noise_std_m_s: 0.1,
            gear_ratio: geometry.gear_ratio,
            wheel_radius_m: geometry.wheel_radius_m,
            mass_per_drive_kg: 2000.0,
            creep_stiffness_nm_s_per_rad: 40.0,
            adhesion_reserve: 0.3,
        }
    }
}

impl TrainSpeedConfig {
    fn validate(&self) -> Result<(), SlipError> {
        check_non_negative("train_speed.noise_std_m_s", self.noise_std_m_s)?;
        check_positive("train_speed.gear_ratio", self.gear_ratio)?;
        check_positive("train_speed.wheel_radius_m", self.wheel_radius_m)?;
        check_positive("train_speed.mass_per_drive_kg", self.mass_per_drive_kg)?;
        check_positive(
            "train_speed.creep_stiffness_nm_s_per_rad",
            self.creep_stiffness_nm_s_per_rad,
        )?;
        check_non_negative("train_speed.adhesion_reserve", self.adhesion_reserve)
    }

    /// The monitor's train-speed settings for this plant: its geometry, the rest default.
    pub fn speed_reference(&self) -> SpeedReferenceConfig {
        SpeedReferenceConfig {
            gear_ratio: self.gear_ratio,
            wheel_radius_m: self.wheel_radius_m,
            ..SpeedReferenceConfig::default()
        }
    }
}

/// The healthy load profile shared by the drives: piecewise constant `levels_nm`, switching at
/// `switch_steps`, each switch smoothed by a normal CDF with scale `smoothing_steps`
/// (section 5: 10 / 20 / 30 N m, switches at 8000 and 16000, scale 30).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoadProfile {
    pub levels_nm: Vec<f64>,
    pub switch_steps: Vec<f64>,
    pub smoothing_steps: f64,
    /// Healthy load of drive i is `drive_scale[i] * profile` (default: all 1, the paper's).
    #[serde(default)]
    pub drive_scale: Vec<f64>,
}

impl LoadProfile {
    /// Shared profile at step `t`.
    pub fn at(&self, t: f64) -> f64 {
        let mut v = self.levels_nm[0];
        for (w, s) in self.levels_nm.windows(2).zip(&self.switch_steps) {
            v += (w[1] - w[0]) * smooth_step(t - s, self.smoothing_steps);
        }
        v
    }
}

/// `Phi(dt / scale)`, a hard step when `scale == 0`.
fn smooth_step(dt_steps: f64, scale_steps: f64) -> f64 {
    if scale_steps > 0.0 {
        normal_cdf(dt_steps / scale_steps)
    } else if dt_steps >= 0.0 {
        1.0
    } else {
        0.0
    }
}

/// A loss of adhesion on one drive.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, tag = "kind", rename_all = "snake_case")]
pub enum SlipEvent {
    /// The load falls to `remaining_fraction` of the healthy load on `[start_step, end_step]`
    /// (the paper's drops to 0), both edges smoothed with a normal CDF of scale
    /// `smoothing_steps` (absent: the profile's; 0: sharp).
    Drop {
        drive: usize,
        start_step: f64,
        end_step: f64,
        #[serde(default)]
        remaining_fraction: f64,
        smoothing_steps: Option<f64>,
    },
    /// The negative half of a sine of `amplitude_nm` is added on `[start_step, end_step]`.
    HalfSine {
        drive: usize,
        start_step: f64,
        end_step: f64,
        amplitude_nm: f64,
    },
    /// Slow loss: the load falls linearly from the healthy load at `start_step` to
    /// `remaining_fraction` of it at `full_step`, stays there until `end_step`, and recovers
    /// with a normal CDF of scale `smoothing_steps` (absent: the profile's).
    Ramp {
        drive: usize,
        start_step: f64,
        full_step: f64,
        end_step: f64,
        remaining_fraction: f64,
        smoothing_steps: Option<f64>,
    },
}

impl SlipEvent {
    fn drive(&self) -> usize {
        match self {
            SlipEvent::Drop { drive, .. }
            | SlipEvent::HalfSine { drive, .. }
            | SlipEvent::Ramp { drive, .. } => *drive,
        }
    }

    fn validate(&self, k: usize, n_drives: usize) -> Result<(), SlipError> {
        let f = |n: &str| format!("events[{k}].{n}");
        let drive = self.drive();
        if drive == 0 || drive > n_drives {
            return Err(SlipError::invalid(
                f("drive"),
                drive,
                "must be a drive number in 1..=n_drives",
            ));
        }
        match self {
            SlipEvent::Drop {
                start_step,
                end_step,
                remaining_fraction,
                smoothing_steps,
                ..
            } => {
                check_smoothing(&f, *smoothing_steps)?;
                check_window(&f, "start_step", *start_step, "end_step", *end_step, 0.0)?;
                check_in(
                    &f("remaining_fraction"),
                    *remaining_fraction,
                    0.0,
                    1.0,
                    "must be in [0, 1]",
                )
            }
            SlipEvent::HalfSine {
                start_step,
                end_step,
                amplitude_nm,
                ..
            } => {
                check_window(&f, "start_step", *start_step, "end_step", *end_step, 1.0)?;
                check_finite(&f("amplitude_nm"), *amplitude_nm)
            }
            SlipEvent::Ramp {
                start_step,
                full_step,
                end_step,
                remaining_fraction,
                smoothing_steps,
                ..
            } => {
                check_smoothing(&f, *smoothing_steps)?;
                check_window(&f, "start_step", *start_step, "full_step", *full_step, 1.0)?;
                check_window(&f, "full_step", *full_step, "end_step", *end_step, 0.0)?;
                check_in(
                    &f("remaining_fraction"),
                    *remaining_fraction,
                    0.0,
                    1.0,
                    "must be in [0, 1]",
                )
            }
        }
    }

    /// Applies the event to `load` (the load so far) of its drive at step `t`.
    fn apply(&self, t: f64, healthy: f64, load: f64, smoothing: f64) -> f64 {
        match *self {
            SlipEvent::Drop {
                start_step,
                end_step,
                remaining_fraction,
                smoothing_steps,
                ..
            } => {
                let smoothing = smoothing_steps.unwrap_or(smoothing);
                let inside =
                    smooth_step(t - start_step, smoothing) - smooth_step(t - end_step, smoothing);
                load - (1.0 - remaining_fraction) * healthy * inside
            }
            SlipEvent::HalfSine {
                start_step,
                end_step,
                amplitude_nm,
                ..
            } => {
                if t >= start_step && t <= end_step {
                    let phase = std::f64::consts::PI * (t - start_step) / (end_step - start_step);
                    load - amplitude_nm * phase.sin()
                } else {
                    load
                }
            }
            SlipEvent::Ramp {
                start_step,
                full_step,
                end_step,
                remaining_fraction,
                smoothing_steps,
                ..
            } => {
                let smoothing = smoothing_steps.unwrap_or(smoothing);
                let depth = if t < start_step {
                    0.0
                } else if t < full_step {
                    (t - start_step) / (full_step - start_step)
                } else {
                    1.0 - smooth_step(t - end_step, smoothing)
                };
                load - (1.0 - remaining_fraction) * healthy * depth
            }
        }
    }
}

/// `start >= 0` and `end >= start + min_len`, errors naming the field through `f`.
fn check_window(
    f: &impl Fn(&str) -> String,
    start_name: &str,
    start: f64,
    end_name: &str,
    end: f64,
    min_len: f64,
) -> Result<(), SlipError> {
    check_non_negative(&f(start_name), start)?;
    check_in(
        &f(end_name),
        end,
        start + min_len,
        f64::MAX,
        "must come after the start of the event",
    )
}

fn check_smoothing(
    f: &impl Fn(&str) -> String,
    smoothing_steps: Option<f64>,
) -> Result<(), SlipError> {
    smoothing_steps.map_or(Ok(()), |s| check_non_negative(&f("smoothing_steps"), s))
}

/// A parsed and validated scenario.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AdhesionScenario {
    pub name: String,
    #[serde(default)]
    pub description: String,
    pub n_drives: usize,
    pub n_steps: usize,
    pub dt_s: f64,
    /// Seed of every random draw of the simulation.
    pub seed: u64,
    #[serde(default)]
    pub plant: PlantConfig,
    #[serde(default)]
    pub noise: NoiseConfig,
    pub load: LoadProfile,
    #[serde(default)]
    pub events: Vec<SlipEvent>,
    /// The train's own speed; absent (the default), the drives hold the controller's
    /// reference speed and no train speed is measured, as before issue 23 item 2.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub train_speed: Option<TrainSpeedConfig>,
    /// The monitor's settings: absent, [`SlipMonitorConfig::default`]; a table may start
    /// from a preset (`preset = "paper"`) and override single keys.
    #[serde(
        default,
        deserialize_with = "railmon_settings::deserialize_with_preset"
    )]
    pub monitor: SlipMonitorConfig,
}

impl AdhesionScenario {
    pub fn from_toml_str(text: &str) -> Result<Self, SlipError> {
        let s: AdhesionScenario =
            toml::from_str(text).map_err(|e| SlipError::Toml(e.to_string()))?;
        s.validate()?;
        Ok(s)
    }

    pub fn validate(&self) -> Result<(), SlipError> {
        if self.n_drives == 0 || self.n_drives > 4096 {
            return Err(SlipError::invalid(
                "n_drives",
                self.n_drives,
                "must be in 1..=4096",
            ));
        }
        // Bounded so a typo (1e14 steps) is an error, not an allocation that aborts `analyze`:
        // 1e8 steps are 3.5 h at 8 kHz.
        if !(1..=100_000_000).contains(&self.n_steps) {
            return Err(SlipError::invalid(
                "n_steps",
                self.n_steps,
                "must be in 1..=100000000",
            ));
        }
        check_positive("dt_s", self.dt_s)?;
        self.plant.motor.validate("plant.motor")?;
        if self.plant.substeps == 0 || self.plant.substeps > 1000 {
            return Err(SlipError::invalid(
                "plant.substeps",
                self.plant.substeps,
                "must be in 1..=1000",
            ));
        }
        self.plant.controller.validate()?;
        check_non_negative("noise.current_std_a", self.noise.current_std_a)?;
        check_non_negative("noise.voltage_std_v", self.noise.voltage_std_v)?;
        check_non_negative("noise.load_std_nm", self.noise.load_std_nm)?;
        let l = &self.load;
        if l.levels_nm.is_empty() || l.levels_nm.iter().any(|v| !v.is_finite()) {
            return Err(SlipError::invalid(
                "load.levels_nm",
                format!("{:?}", l.levels_nm),
                "must be one or more finite values",
            ));
        }
        if l.switch_steps.len() + 1 != l.levels_nm.len()
            || l.switch_steps.iter().any(|v| !v.is_finite())
        {
            return Err(SlipError::invalid(
                "load.switch_steps",
                format!("{:?}", l.switch_steps),
                "must be finite, one fewer than load.levels_nm",
            ));
        }
        check_non_negative("load.smoothing_steps", l.smoothing_steps)?;
        if !l.drive_scale.is_empty()
            && (l.drive_scale.len() != self.n_drives
                || l.drive_scale.iter().any(|v| !v.is_finite() || *v <= 0.0))
        {
            return Err(SlipError::invalid(
                "load.drive_scale",
                format!("{:?}", l.drive_scale),
                "must be empty or n_drives positive values",
            ));
        }
        for (k, e) in self.events.iter().enumerate() {
            e.validate(k, self.n_drives)?;
        }
        if let Some(t) = &self.train_speed {
            t.validate()?;
            let speed = self.plant.controller.reference_speed_rad_s.abs()
                / self.plant.motor.pole_pairs
                * t.wheel_radius_m
                / t.gear_ratio;
            if !(speed > 0.0 && speed <= crate::speed_reference::TRAIN_SPEED_RANGE_M_S.1) {
                return Err(SlipError::invalid(
                    "plant.controller.reference_speed_rad_s",
                    self.plant.controller.reference_speed_rad_s,
                    "with a train speed, must give a starting speed in (0, 100] m/s",
                ));
            }
        }
        if (self.monitor.dt_s - self.dt_s).abs() > 1e-12 * self.dt_s {
            return Err(SlipError::invalid(
                "monitor.dt_s",
                self.monitor.dt_s,
                "must equal dt_s",
            ));
        }
        self.monitor.validate()
    }

    pub fn n_drives(&self) -> usize {
        self.n_drives
    }
    pub fn n_steps(&self) -> usize {
        self.n_steps
    }
    pub fn dt_s(&self) -> f64 {
        self.dt_s
    }

    /// The estimator settings the scenario asks for.
    pub fn monitor_config(&self) -> SlipMonitorConfig {
        self.monitor.clone()
    }

    /// Healthy load of `drive` (0-based) at step `t`.
    pub fn healthy_load_nm(&self, drive: usize, t: f64) -> f64 {
        let scale = self.load.drive_scale.get(drive).copied().unwrap_or(1.0);
        scale * self.load.at(t)
    }

    /// True load of `drive` (0-based) at step `t` without the random disturbance, and whether
    /// it breaks the slip rule.
    pub fn true_load_nm(&self, drive: usize, t: f64) -> (f64, bool) {
        let healthy = self.healthy_load_nm(drive, t);
        let load = self
            .events
            .iter()
            .filter(|e| e.drive() == drive + 1)
            .fold(healthy, |load, e| {
                e.apply(t, healthy, load, self.load.smoothing_steps)
            });
        (load, is_slipping(load, healthy))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) const SEED: &str = include_str!("../../config/scenarios/adhesion-seed.toml");

    #[test]
    fn seed_scenario_matches_the_paper() {
        let s = AdhesionScenario::from_toml_str(SEED).unwrap();
        assert_eq!((s.n_drives(), s.n_steps(), s.dt_s()), (3, 20_000, 125e-6));
        // Levels 10 / 20 / 30, half-way at the switches (to the 1.2e-7 accuracy of the
        // normal CDF we use).
        assert!((s.healthy_load_nm(1, 4000.0) - 10.0).abs() < 1e-9);
        assert!((s.healthy_load_nm(1, 8000.0) - 15.0).abs() < 1e-5);
        assert!((s.healthy_load_nm(2, 19_000.0) - 30.0).abs() < 1e-9);
        // Drive 1 drops to 0 inside [500, 1500] and [10000, 12000].
        assert!(s.true_load_nm(0, 1000.0).0.abs() < 1e-9 && s.true_load_nm(0, 1000.0).1);
        assert!(s.true_load_nm(0, 11_000.0).0.abs() < 1e-9);
        // Negative half sine of 10 on [17000, 18000]: 20 at the middle.
        assert!((s.true_load_nm(0, 17_500.0).0 - 20.0).abs() < 1e-9);
        // Drives 2 and 3 never slip.
        for t in (0..20_000).step_by(7) {
            assert!(!s.true_load_nm(1, t as f64).1 && !s.true_load_nm(2, t as f64).1);
        }
        // The slip rule flags the half sine only where it exceeds 3 N m (10 % of 30).
        assert!(!s.true_load_nm(0, 17_050.0).1 && s.true_load_nm(0, 17_200.0).1);
    }

    fn rejects(edit: (&str, &str), field: &str) {
        let text = SEED.replacen(edit.0, edit.1, 1);
        assert_ne!(text, SEED, "edit {edit:?} did not apply");
        let err = AdhesionScenario::from_toml_str(&text)
            .unwrap_err()
            .to_string();
        assert!(err.contains(field), "{err}");
    }

    #[test]
    fn each_invalid_scenario_field_is_rejected() {
        rejects(("n_drives = 3", "n_drives = 0"), "n_drives");
        rejects(("n_steps = 20000", "n_steps = 0"), "n_steps");
        rejects(("n_steps = 20000", "n_steps = 100000000000000"), "n_steps");
        rejects(("dt_s = 125e-6", "dt_s = -1.0"), "dt_s");
        rejects(
            ("levels_nm = [10.0, 20.0, 30.0]", "levels_nm = [10.0, 20.0]"),
            "load.switch_steps",
        );
        rejects(
            ("smoothing_steps = 30.0", "smoothing_steps = -30.0"),
            "load.smoothing_steps",
        );
        rejects(("drive = 1", "drive = 4"), "events[0].drive");
        rejects(("drive = 1", "drive = 0"), "events[0].drive");
        rejects(
            ("current_std_a = 0.01", "current_std_a = -0.1"),
            "noise.current_std_a",
        );
        rejects(("n_drives = 3", "n_drives = 3\nbogus = 1"), "unknown field");
        rejects(
            ("[noise]", "[noise]\nvoltage_std_v = nan"),
            "noise.voltage_std_v",
        );
        rejects(("substeps = 1", "substeps = 0"), "plant.substeps");
        rejects(
            (
                "reference_speed_rad_s = 200.0",
                "reference_speed_rad_s = 200.0\nmax_current_a = 0.0",
            ),
            "plant.controller.max_current_a",
        );
        rejects(
            (
                "reference_speed_rad_s = 200.0",
                "reference_speed_rad_s = inf",
            ),
            "plant.controller.reference_speed_rad_s",
        );
        rejects(
            (
                "smoothing_steps = 30.0",
                "smoothing_steps = 30.0\ndrive_scale = [1.0, -1.0, 1.0]",
            ),
            "load.drive_scale",
        );
        let with_monitor = |table: &str| format!("{SEED}\n[monitor]\n{table}\n");
        let err = AdhesionScenario::from_toml_str(&with_monitor("dt_s = 1e-4"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("monitor.dt_s"), "{err}");
        let err = AdhesionScenario::from_toml_str(&with_monitor("preset = \"magic\""))
            .unwrap_err()
            .to_string();
        assert!(err.contains("magic") && err.contains("paper"), "{err}");
        rejects(
            ("end_step = 1500.0", "end_step = 400.0"),
            "events[0].end_step",
        );
        rejects(
            ("amplitude_nm = 10.0", "amplitude_nm = nan"),
            "events[2].amplitude_nm",
        );
        rejects(
            ("[noise]", "[plant.motor]\nl_s_h = 0.0\n\n[noise]"),
            "plant.motor.l_s_h",
        );
    }
}
