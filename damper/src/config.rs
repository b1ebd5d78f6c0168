//! Configuration of the damper monitor (RBPF + EKF), as validated values. Defaults are the
//! paper's where it gives them (N = 1000, delta = 0.99, T = 1 ms).

use serde::{Deserialize, Serialize};

use crate::alarm::DamperAlarmConfig;
use crate::consistency::ConsistencyConfig;
use crate::noise_scale::NoiseScaleConfig;
use crate::params::{non_negative, positive, BogieParams, Dampers};
use crate::rbpf::JumpSearchConfig;
use crate::sample::SensorNoise;
use crate::DamperError;

/// How each particle's Kalman filter propagates (section 4.3 and the speed/accuracy study in
/// `docs/damper.md`).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum Propagation {
    /// Per particle and step: `Phi, Gamma` by the matrix exponential of its own `A(theta)`,
    /// full covariance predict and Joseph update. The reference; ~100x too slow for 1 kHz.
    Exact,
    /// Per particle: `Phi(theta) x` by a Taylor series of the sparse `A(theta)` (exact to
    /// `taylor_order`), and the steady-state gain and innovation covariance of its `theta`,
    /// interpolated bilinearly on a log-parameter grid of Riccati solutions.
    #[default]
    SteadyState,
}

/// When the Liu-West kernel moves the particles.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum KernelSchedule {
    /// Every step, as in the paper (section 4.3: draw `theta_k(i)` from eq. 24 each step).
    EveryStep,
    /// Only right after a resampling (resample-move): between resamplings the parameters are
    /// fixed and each particle's Kalman filter is that of one static `theta`.
    #[default]
    AtResampling,
}

/// Grid of steady-state Riccati solutions over `(ln C_sy, ln C_say)`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct GainGridConfig {
    /// Nodes per axis.
    pub points_per_axis: usize,
    /// Lower end of the grid as a ratio of the nominal coefficients (both axes); particles
    /// outside use the edge gain (their own `Phi` stays exact).
    pub min_ratio: f64,
    /// Upper end of the grid as a ratio of the nominal coefficients (both axes).
    pub max_ratio: f64,
}

impl Default for GainGridConfig {
    fn default() -> Self {
        GainGridConfig {
            points_per_axis: 33,
            min_ratio: 0.1,
            max_ratio: 3.0,
        }
    }
}

/// The speeds the filter's model is valid at, and its speed schedule (`gain_table` docs).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct SpeedConfig {
    /// Below this speed (standstill, shunting) the filter holds its parameter posterior and
    /// reports `paused: low_speed`: the creep model `~ 1 / v` is not valid there (m/s).
    pub min_m_s: f64,
    /// Above it the filter holds likewise (`paused: high_speed`): the range the gain table
    /// covers (m/s). The default stays below the linear model's critical speed: with the
    /// paper's parameters an eigenvalue of `A` crosses into the right half-plane (hunting)
    /// between 58 and 60 m/s with nominal dampers, and between 50 and 55 m/s with `C_say` at
    /// 40 % (`tests::the_default_top_speed_is_below_the_critical_speed`). Beyond it the linear
    /// plant grows without bound, which no real bogie does (it hunts in a limit cycle the
    /// linear model cannot represent), so a filter built on it would learn nonsense.
    pub max_m_s: f64,
    /// Ratio of neighbouring speed nodes of the gain table (geometric grid about the
    /// vehicle's configured speed).
    pub grid_ratio: f64,
    /// After a pause the per-particle state estimates are those of the last valid sample:
    /// for this long they are run (predict and update) without weighting the particles, so
    /// that the transient of stale states does not move the posterior (s).
    pub resume_settle_s: f64,
}

impl Default for SpeedConfig {
    fn default() -> Self {
        SpeedConfig {
            min_m_s: 5.0,
            max_m_s: 55.0,
            grid_ratio: 1.05,
            resume_settle_s: 1.0,
        }
    }
}

impl SpeedConfig {
    pub fn validate(&self) -> Result<(), DamperError> {
        positive("speed.min_m_s", self.min_m_s)?;
        positive("speed.max_m_s", self.max_m_s)?;
        if self.max_m_s <= self.min_m_s {
            return Err(DamperError::InvalidParameter {
                field: "speed.max_m_s",
                value: self.max_m_s,
                reason: "must exceed speed.min_m_s",
            });
        }
        // At most 2 (a node every factor of 2 would be no schedule); at least 1.001 (a
        // thousand nodes between 5 and 70 m/s would be a gigabyte of grids).
        if !(self.grid_ratio >= 1.001 && self.grid_ratio <= 2.0) {
            return Err(DamperError::InvalidParameter {
                field: "speed.grid_ratio",
                value: self.grid_ratio,
                reason: "must be in [1.001, 2]",
            });
        }
        non_negative("speed.resume_settle_s", self.resume_settle_s)
    }

    /// Why the filter pauses at `speed_m_s`, if it does.
    pub fn pause_reason(&self, speed_m_s: f64) -> Option<PauseReason> {
        if speed_m_s < self.min_m_s {
            Some(PauseReason::LowSpeed)
        } else if speed_m_s > self.max_m_s {
            Some(PauseReason::HighSpeed)
        } else {
            None
        }
    }
}

/// Why a damper monitor holds its posterior.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PauseReason {
    /// Below `speed.min_m_s`.
    LowSpeed,
    /// Above `speed.max_m_s`.
    HighSpeed,
}

impl PauseReason {
    pub const ALL: [PauseReason; 2] = [PauseReason::LowSpeed, PauseReason::HighSpeed];

    pub fn as_str(self) -> &'static str {
        match self {
            PauseReason::LowSpeed => "low_speed",
            PauseReason::HighSpeed => "high_speed",
        }
    }
}

/// The Rao-Blackwellised particle filter (section 4).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct RbpfConfig {
    /// `N`.
    pub particles: usize,
    /// Liu-West discount factor `delta` (eq. 24): `a = (3 delta - 1) / (2 delta)`,
    /// `h^2 = 1 - a^2`.
    pub delta: f64,
    /// Resample when the effective sample size falls below this fraction of `N`.
    pub resample_ess_fraction: f64,
    /// Prior mean: `ln C ~ N(ln(prior_ratio * nominal), prior_ln_std^2)` for each damper.
    pub prior_ratio: f64,
    /// Prior standard deviation of `ln C` (0: the parameters are known).
    pub prior_ln_std: f64,
    /// Extra random walk of `ln C` (1/sqrt(s)) added to the Liu-West move, so that the filter
    /// can follow a damper that fails after the posterior has narrowed. `0` is the paper's
    /// static-parameter filter.
    pub ln_diffusion_per_sqrt_s: f64,
    /// Probability, per particle and coefficient, of being redrawn (log-uniform over the gain
    /// grid's range) at each kernel move, so that a damper that fails suddenly (a step far
    /// outside the narrowed posterior) is found again. `0` is the paper's filter.
    pub regeneration_fraction: f64,
    /// Weight of a regenerated particle relative to the others, in (0, 1].
    pub regeneration_weight: f64,
    /// Evidence-triggered search for a failed damper (`crate::rbpf::jump`): sentinels beside
    /// the particles whose posterior odds of a jump, once high enough, become particles.
    pub jump_search: JumpSearchConfig,
    pub propagation: Propagation,
    pub kernel: KernelSchedule,
    /// Order of the Taylor series for `Phi(theta) x` (steady-state propagation). 6, 8 and 10
    /// give the exact filter's likelihood mode to 0.01% (`benches/accuracy.rs`); 1 (the
    /// paper's `I + A T`) moves it by 20%.
    pub taylor_order: usize,
    pub gain_grid: GainGridConfig,
    /// The online estimate of the sensors' noise (issue 9 item 2).
    pub noise_scale: NoiseScaleConfig,
    /// Seed of the filter's own random numbers (kernel moves, resampling).
    pub seed: u64,
}

impl Default for RbpfConfig {
    fn default() -> Self {
        RbpfConfig {
            particles: 1000,
            delta: 0.99,
            resample_ess_fraction: 0.5,
            prior_ratio: 1.0,
            prior_ln_std: 0.5,
            ln_diffusion_per_sqrt_s: 0.002,
            regeneration_fraction: 0.01,
            regeneration_weight: 0.1,
            jump_search: JumpSearchConfig::default(),
            propagation: Propagation::SteadyState,
            kernel: KernelSchedule::AtResampling,
            taylor_order: 8,
            gain_grid: GainGridConfig::default(),
            noise_scale: NoiseScaleConfig::default(),
            seed: 0,
        }
    }
}

impl RbpfConfig {
    pub fn validate(&self) -> Result<(), DamperError> {
        // At most a million: each particle holds a 17-state covariance (~2.5 kB), and 1e9
        // particles aborted the service on a 136 GB allocation at its first frame.
        if !(2..=1_000_000).contains(&self.particles) {
            return Err(DamperError::InvalidParameter {
                field: "rbpf.particles",
                value: self.particles as f64,
                reason: "must be in 2..=1000000",
            });
        }
        if !(self.delta > 1.0 / 3.0 && self.delta < 1.0) {
            // a = (3 delta - 1) / (2 delta) must lie in (0, 1).
            return Err(DamperError::InvalidParameter {
                field: "rbpf.delta",
                value: self.delta,
                reason: "must be in (1/3, 1)",
            });
        }
        if !(self.resample_ess_fraction > 0.0 && self.resample_ess_fraction <= 1.0) {
            return Err(DamperError::InvalidParameter {
                field: "rbpf.resample_ess_fraction",
                value: self.resample_ess_fraction,
                reason: "must be in (0, 1]",
            });
        }
        positive("rbpf.prior_ratio", self.prior_ratio)?;
        non_negative("rbpf.prior_ln_std", self.prior_ln_std)?;
        if !(0.0..0.5).contains(&self.regeneration_fraction) {
            return Err(DamperError::InvalidParameter {
                field: "rbpf.regeneration_fraction",
                value: self.regeneration_fraction,
                reason: "must be in [0, 0.5)",
            });
        }
        non_negative("rbpf.ln_diffusion_per_sqrt_s", self.ln_diffusion_per_sqrt_s)?;
        if !(self.regeneration_weight > 0.0 && self.regeneration_weight <= 1.0) {
            return Err(DamperError::InvalidParameter {
                field: "rbpf.regeneration_weight",
                value: self.regeneration_weight,
                reason: "must be in (0, 1]",
            });
        }
        if !(1..=30).contains(&self.taylor_order) {
            return Err(DamperError::InvalidParameter {
                field: "rbpf.taylor_order",
                value: self.taylor_order as f64,
                reason: "must be in 1..=30",
            });
        }
        let g = &self.gain_grid;
        if g.points_per_axis < 2 {
            return Err(DamperError::InvalidParameter {
                field: "rbpf.gain_grid.points_per_axis",
                value: g.points_per_axis as f64,
                reason: "must be at least 2",
            });
        }
        positive("rbpf.gain_grid.min_ratio", g.min_ratio)?;
        positive("rbpf.gain_grid.max_ratio", g.max_ratio)?;
        if g.max_ratio <= g.min_ratio {
            return Err(DamperError::InvalidParameter {
                field: "rbpf.gain_grid.max_ratio",
                value: g.max_ratio,
                reason: "must exceed min_ratio",
            });
        }
        if self.jump_search.enabled && self.kernel != KernelSchedule::AtResampling {
            return Err(DamperError::Config(
                "rbpf.jump_search needs kernel = \"at_resampling\"".into(),
            ));
        }
        self.jump_search.validate()?;
        self.noise_scale.validate()
    }

    /// Liu-West shrinkage `a` and kernel variance factor `h^2` (eq. 24).
    pub fn liu_west(&self) -> (f64, f64) {
        let a = (3.0 * self.delta - 1.0) / (2.0 * self.delta);
        (a, 1.0 - a * a)
    }
}

/// The augmented-state EKF of section 3 (baseline).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct EkfConfig {
    /// Run the augmented EKF beside the RBPF (its estimate is published for comparison).
    pub enabled: bool,
    /// Initial parameter estimate as a ratio of nominal.
    pub initial_ratio: f64,
    /// Standard deviation of the initial estimate (ratio of nominal).
    pub initial_ratio_std: f64,
    /// Random walk of the parameters (`Q_n`, eq. 17), standard deviation per sqrt(s) in
    /// ratio units.
    pub ratio_random_walk_per_sqrt_s: f64,
}

impl Default for EkfConfig {
    fn default() -> Self {
        EkfConfig {
            enabled: true,
            initial_ratio: 1.0,
            initial_ratio_std: 0.5,
            ratio_random_walk_per_sqrt_s: 0.01,
        }
    }
}

impl EkfConfig {
    pub fn validate(&self) -> Result<(), DamperError> {
        positive("ekf.initial_ratio", self.initial_ratio)?;
        positive("ekf.initial_ratio_std", self.initial_ratio_std)?;
        non_negative(
            "ekf.ratio_random_walk_per_sqrt_s",
            self.ratio_random_walk_per_sqrt_s,
        )
    }
}

/// Everything one bogie's monitor needs.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct DamperMonitorConfig {
    /// The vehicle's design parameters (appendix).
    pub vehicle: BogieParams,
    /// The healthy dampers; health ratio = estimate / nominal.
    pub nominal: Dampers,
    /// Sample period `T` (s).
    pub dt_s: f64,
    /// The filters' white track-velocity model: `Q_w = sigma^2 I` per step ((m/s)).
    pub track_velocity_std_m_s: f64,
    /// The filters' sensor noise `Q_v`.
    pub sensors: SensorNoise,
    /// Standard deviation added to every state each step in the filters' model (units of
    /// each state: m, rad, m/s, rad/s). The track input reaches the fast modes (the series
    /// node at -145/s, the creep modes at -326/s) so weakly that their variance falls below
    /// roundoff and a covariance loses definiteness within 0.3 s; the unmodelled forces of a
    /// real vehicle (wind, traction, creep non-linearity) are the physical floor. 1e-8 per
    /// step moves a position by 0.3 um per second: nothing the sensors could see.
    pub process_noise_floor_std_per_step: f64,
    /// Rate at which the filter model lets the unobservable track position relax (1/s), see
    /// `model` docs; changes nothing observable, keeps covariances bounded.
    pub drift_leak_per_s: f64,
    pub rbpf: RbpfConfig,
    pub ekf: EkfConfig,
    /// The degraded / recovered rule judging the RBPF's posterior.
    pub alarm: DamperAlarmConfig,
    /// The filter's check of its own model (`model_mismatch`).
    pub consistency: ConsistencyConfig,
    /// Valid speed range and speed schedule.
    pub speed: SpeedConfig,
}

impl Default for DamperMonitorConfig {
    fn default() -> Self {
        DamperMonitorConfig {
            vehicle: BogieParams::default(),
            nominal: Dampers::NOMINAL,
            dt_s: 1e-3,
            // The four damper scenarios' (white track of 0.1 m/s per step, and the ERRI
            // tracks the white model is run on): the setting every figure in docs/damper.md
            // was measured with.
            track_velocity_std_m_s: 0.1,
            sensors: SensorNoise::default(),
            process_noise_floor_std_per_step: 1e-8,
            drift_leak_per_s: 0.1,
            rbpf: RbpfConfig::default(),
            ekf: EkfConfig::default(),
            alarm: DamperAlarmConfig::default(),
            consistency: ConsistencyConfig::default(),
            speed: SpeedConfig::default(),
        }
    }
}

impl railmon_settings::Presets for DamperMonitorConfig {
    const PRESETS: &'static [&'static str] = &["paper"];

    fn preset(name: &str) -> Option<Self> {
        (name == "paper").then(DamperMonitorConfig::paper)
    }
}

impl DamperMonitorConfig {
    /// The paper's filter (section 4.3): the exact per-particle Kalman filters, the Liu-West
    /// kernel every step, static parameters (no diffusion, no regeneration). Slow (about 100x
    /// real time at N = 1000) and unable to follow a damper that fails after its posterior
    /// narrowed; kept to reproduce the paper. A scenario asks for it with `preset = "paper"`.
    pub fn paper() -> Self {
        let d = DamperMonitorConfig::default();
        DamperMonitorConfig {
            rbpf: RbpfConfig {
                propagation: Propagation::Exact,
                kernel: KernelSchedule::EveryStep,
                ln_diffusion_per_sqrt_s: 0.0,
                regeneration_fraction: 0.0,
                jump_search: JumpSearchConfig {
                    enabled: false,
                    ..d.rbpf.jump_search
                },
                ..d.rbpf
            },
            ..d
        }
    }

    /// Parses a TOML table with the fields of this struct (all optional) and validates it.
    pub fn from_toml_str(text: &str) -> Result<Self, DamperError> {
        let c: DamperMonitorConfig =
            toml::from_str(text).map_err(|e| DamperError::Config(e.to_string()))?;
        c.validate()?;
        Ok(c)
    }

    pub fn validate(&self) -> Result<(), DamperError> {
        self.vehicle.validate()?;
        self.nominal.validate()?;
        positive("dt_s", self.dt_s)?;
        positive("track_velocity_std_m_s", self.track_velocity_std_m_s)?;
        self.sensors.validate()?;
        positive("drift_leak_per_s", self.drift_leak_per_s)?;
        non_negative(
            "process_noise_floor_std_per_step",
            self.process_noise_floor_std_per_step,
        )?;
        self.rbpf.validate()?;
        self.ekf.validate()?;
        self.alarm.validate()?;
        self.consistency.validate()?;
        self.speed.validate()
    }

    /// `Q_w` and `Q_v` of the filter model.
    pub fn noise(&self) -> crate::kalman::NoiseCovariances {
        crate::kalman::NoiseCovariances {
            q_w: nalgebra::Matrix2::identity() * self.track_velocity_std_m_s.powi(2),
            q_v: self.sensors.covariance(),
            q_floor: self.process_noise_floor_std_per_step.powi(2),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The largest real part of the eigenvalues of `A` at `speed_m_s`, leaving out the two
    /// drift modes (eigenvalue 0 up to rounding).
    fn growth_rate_per_s(dampers: &crate::Dampers, speed_m_s: f64) -> f64 {
        let params = crate::BogieParams::default();
        let mut model = crate::model::BogieModel::new(&params, 0.0).unwrap();
        model.set_speed(speed_m_s).unwrap();
        let a = model.a_matrix(dampers);
        a.complex_eigenvalues()
            .iter()
            .map(|e| e.re)
            .fold(f64::MIN, f64::max)
    }

    /// Hunting: above the critical speed the linear model is unstable (an eigenvalue of `A`
    /// in the right half-plane), so the filter's valid range must end below it.
    #[test]
    fn the_default_top_speed_is_below_the_critical_speed() {
        let top = SpeedConfig::default().max_m_s;
        let nominal = crate::Dampers::NOMINAL;
        assert!(
            growth_rate_per_s(&nominal, top) < 1e-6,
            "unstable at {top} m/s"
        );
        assert!(growth_rate_per_s(&nominal, 58.0) < 1e-6);
        // The critical speed exists and lies just above: the check above can fail.
        assert!(growth_rate_per_s(&nominal, 60.0) > 0.1);
        // A failed anti-yaw damper lowers it (why such a bogie is dangerous at speed).
        let failed = crate::Dampers {
            csay_ns_per_m: 0.4 * nominal.csay_ns_per_m,
            ..nominal
        };
        assert!(growth_rate_per_s(&failed, 50.0) < 1e-6);
        assert!(growth_rate_per_s(&failed, 55.0) > 0.1);
    }

    fn rejects(cfg: DamperMonitorConfig, name: &str) {
        match cfg.validate() {
            Err(DamperError::InvalidParameter { field, .. }) => assert_eq!(field, name),
            other => panic!("{name}: {other:?}"),
        }
    }

    #[test]
    fn default_is_valid_and_liu_west_matches_the_paper() {
        let c = DamperMonitorConfig::default();
        c.validate().unwrap();
        let (a, h2) = c.rbpf.liu_west();
        // delta = 0.99: a = 1.97 / 1.98.
        assert!((a - 1.97 / 1.98).abs() < 1e-15);
        assert!((h2 - (1.0 - a * a)).abs() < 1e-15);
    }

    /// One test per invalid monitor parameter, each error naming its field.
    #[test]
    fn each_invalid_monitor_parameter_is_rejected_by_name() {
        let d = DamperMonitorConfig::default;
        let with_rbpf = |f: fn(&mut RbpfConfig)| {
            let mut c = d();
            f(&mut c.rbpf);
            c
        };
        rejects(DamperMonitorConfig { dt_s: 0.0, ..d() }, "dt_s");
        rejects(
            DamperMonitorConfig {
                track_velocity_std_m_s: f64::NAN,
                ..d()
            },
            "track_velocity_std_m_s",
        );
        rejects(
            DamperMonitorConfig {
                drift_leak_per_s: 0.0,
                ..d()
            },
            "drift_leak_per_s",
        );
        rejects(
            DamperMonitorConfig {
                process_noise_floor_std_per_step: -1.0,
                ..d()
            },
            "process_noise_floor_std_per_step",
        );
        let mut c = d();
        c.sensors.accel_std_m_s2 = -1.0;
        rejects(c, "accel_std_m_s2");
        let mut c = d();
        c.sensors.gyro_std_rad_s = 0.0;
        rejects(c, "gyro_std_rad_s");
        let mut c = d();
        c.nominal.csay_ns_per_m = 0.0;
        rejects(c, "csay_ns_per_m");
        rejects(with_rbpf(|r| r.particles = 1), "rbpf.particles");
        rejects(with_rbpf(|r| r.particles = 1_000_000_000), "rbpf.particles");
        rejects(with_rbpf(|r| r.delta = 1.0), "rbpf.delta");
        rejects(with_rbpf(|r| r.delta = 0.2), "rbpf.delta");
        rejects(
            with_rbpf(|r| r.resample_ess_fraction = 0.0),
            "rbpf.resample_ess_fraction",
        );
        rejects(with_rbpf(|r| r.prior_ratio = -1.0), "rbpf.prior_ratio");
        rejects(with_rbpf(|r| r.prior_ln_std = -0.1), "rbpf.prior_ln_std");
        rejects(
            with_rbpf(|r| r.regeneration_fraction = 0.5),
            "rbpf.regeneration_fraction",
        );
        rejects(
            with_rbpf(|r| r.ln_diffusion_per_sqrt_s = -0.1),
            "rbpf.ln_diffusion_per_sqrt_s",
        );
        rejects(
            with_rbpf(|r| r.regeneration_weight = 0.0),
            "rbpf.regeneration_weight",
        );
        rejects(with_rbpf(|r| r.taylor_order = 0), "rbpf.taylor_order");
        rejects(
            with_rbpf(|r| r.gain_grid.points_per_axis = 1),
            "rbpf.gain_grid.points_per_axis",
        );
        rejects(
            with_rbpf(|r| r.gain_grid.min_ratio = 0.0),
            "rbpf.gain_grid.min_ratio",
        );
        rejects(
            with_rbpf(|r| r.gain_grid.max_ratio = 0.05),
            "rbpf.gain_grid.max_ratio",
        );
        let mut c = d();
        c.ekf.initial_ratio = 0.0;
        rejects(c, "ekf.initial_ratio");
        let mut c = d();
        c.ekf.initial_ratio_std = f64::INFINITY;
        rejects(c, "ekf.initial_ratio_std");
        let mut c = d();
        c.ekf.ratio_random_walk_per_sqrt_s = -1.0;
        rejects(c, "ekf.ratio_random_walk_per_sqrt_s");
        let mut c = d();
        c.vehicle.conicity = 0.0;
        rejects(c, "conicity");
        let mut c = d();
        c.speed.min_m_s = f64::NAN;
        rejects(c, "speed.min_m_s");
        let mut c = d();
        c.speed.max_m_s = 4.0;
        rejects(c, "speed.max_m_s");
        let mut c = d();
        c.speed.grid_ratio = 1.0;
        rejects(c, "speed.grid_ratio");
        let mut c = d();
        c.speed.resume_settle_s = -1.0;
        rejects(c, "speed.resume_settle_s");
    }
}
