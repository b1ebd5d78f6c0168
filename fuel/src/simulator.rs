//! A vehicle that follows standard drive-cycle speed traces (UDDS, HWFET, US06, WLTC), with a
//! driver model (eco or sporty), road load, a 6-speed gearbox with a shift schedule, an engine
//! torque limit and fuel map with fuel cut-off on overrun. It produces, at 1 Hz, what the
//! paper's car gives (fuel, speed, pedal, engine torque, engine speed, gear) and the regime
//! label of the segment being driven, so that regime recognition can be scored.
//!
//! The speed traces are data passed in by the caller ([`DriveCycle`]); this module reads no
//! file. Physics is integrated at 10 Hz, samples are taken every second.

use std::collections::BTreeMap;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use crate::{FuelError, FuelMonitorConfig, VehicleSample};

const G_M_S2: f64 = 9.81;
const AIR_DENSITY_KG_M3: f64 = 1.2;
/// Lower heating value of petrol (kJ/g) and its density (g/cm^3): fuel power -> cm^3/s.
const PETROL_LHV_KJ_G: f64 = 43.0;
const PETROL_DENSITY_G_CM3: f64 = 0.745;
const SUBSTEPS: usize = 10;

/// A speed trace at 1 Hz (the `cycMps` and `cycGrade` columns of the drive-cycle files).
#[derive(Clone, Debug, PartialEq)]
pub struct DriveCycle {
    pub speed_m_s: Vec<f64>,
    pub grade_rad: Vec<f64>,
}

/// How the driver follows the trace and shifts.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DriverStyle {
    Eco,
    Sporty,
}

impl DriverStyle {
    /// (speed-error time constant s, max acceleration m/s^2, up-shift rpm, down-shift rpm,
    /// pedal noise %, max pedal %). Eco drivers anticipate, accelerate gently, short-shift and
    /// never floor the pedal (they fall behind a trace that asks for more); sporty drivers close
    /// the speed error fast and rev the engine out.
    fn parameters(self) -> (f64, f64, f64, f64, f64, f64) {
        match self {
            DriverStyle::Eco => (2.5, 1.2, 2000.0, 1100.0, 1.0, 60.0),
            DriverStyle::Sporty => (0.8, 3.5, 3800.0, 1900.0, 3.0, 100.0),
        }
    }
}

/// Vehicle and powertrain parameters; the defaults are a mid-size petrol saloon like the 2018
/// Camry of the real data (1.6 t, 2.5 l).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VehicleParameters {
    pub mass_kg: f64,
    pub rolling_resistance: f64,
    pub drag_area_m2: f64,
    pub wheel_radius_m: f64,
    pub gear_ratios: Vec<f64>,
    pub final_drive: f64,
    pub driveline_efficiency: f64,
    pub idle_rpm: f64,
    pub max_rpm: f64,
    /// Peak engine torque; the full-load curve falls off below 1500 and above 5000 rpm.
    pub max_torque_nm: f64,
    /// Indicated efficiency of the engine (fuel power -> indicated power).
    pub indicated_efficiency: f64,
    /// Friction power at 1000 rpm (kW), growing with rpm^1.5.
    pub friction_kw_at_1000_rpm: f64,
    /// Fuel cut-off on overrun above this engine speed (pedal released, vehicle moving).
    pub cut_off_min_rpm: f64,
    /// Standard deviation of the fuel-flow meter noise, cm^3/s (not applied to exact cut-off).
    pub fuel_noise_cm3_s: f64,
}

impl Default for VehicleParameters {
    fn default() -> Self {
        VehicleParameters {
            mass_kg: 1600.0,
            rolling_resistance: 0.009,
            drag_area_m2: 0.72,
            wheel_radius_m: 0.33,
            gear_ratios: vec![3.30, 2.05, 1.40, 1.00, 0.78, 0.64],
            final_drive: 3.9,
            driveline_efficiency: 0.92,
            idle_rpm: 700.0,
            max_rpm: 6500.0,
            max_torque_nm: 240.0,
            indicated_efficiency: 0.34,
            friction_kw_at_1000_rpm: 1.6,
            cut_off_min_rpm: 1000.0,
            fuel_noise_cm3_s: 0.03,
        }
    }
}

impl VehicleParameters {
    pub fn validate(&self) -> Result<(), FuelError> {
        let positive = [
            ("vehicle.mass_kg", self.mass_kg),
            ("vehicle.drag_area_m2", self.drag_area_m2),
            ("vehicle.wheel_radius_m", self.wheel_radius_m),
            ("vehicle.final_drive", self.final_drive),
            ("vehicle.idle_rpm", self.idle_rpm),
            ("vehicle.max_torque_nm", self.max_torque_nm),
            (
                "vehicle.friction_kw_at_1000_rpm",
                self.friction_kw_at_1000_rpm,
            ),
        ];
        for (field, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(FuelError::invalid(field, v, "must be finite and > 0"));
            }
        }
        let fractions = [
            ("vehicle.rolling_resistance", self.rolling_resistance),
            ("vehicle.driveline_efficiency", self.driveline_efficiency),
            ("vehicle.indicated_efficiency", self.indicated_efficiency),
        ];
        for (field, v) in fractions {
            if !(v > 0.0 && v <= 1.0) {
                return Err(FuelError::invalid(field, v, "must be in (0, 1]"));
            }
        }
        if self.gear_ratios.len() != 6
            || self
                .gear_ratios
                .windows(2)
                .any(|w| !(w[0] > w[1] && w[1] > 0.0))
        {
            return Err(FuelError::invalid(
                "vehicle.gear_ratios",
                format!("{:?}", self.gear_ratios),
                "must be 6 positive, decreasing ratios",
            ));
        }
        if !self.max_rpm.is_finite() || self.max_rpm <= self.idle_rpm * 2.0 {
            return Err(FuelError::invalid(
                "vehicle.max_rpm",
                self.max_rpm,
                "must be finite and > 2 idle_rpm",
            ));
        }
        if !(self.cut_off_min_rpm >= self.idle_rpm && self.cut_off_min_rpm < self.max_rpm) {
            return Err(FuelError::invalid(
                "vehicle.cut_off_min_rpm",
                self.cut_off_min_rpm,
                "must be in [idle_rpm, max_rpm)",
            ));
        }
        if !(self.fuel_noise_cm3_s >= 0.0 && self.fuel_noise_cm3_s.is_finite()) {
            return Err(FuelError::invalid(
                "vehicle.fuel_noise_cm3_s",
                self.fuel_noise_cm3_s,
                "must be finite and >= 0",
            ));
        }
        Ok(())
    }

    /// Full-load torque at an engine speed.
    fn full_load_torque_nm(&self, rpm: f64) -> f64 {
        let shape = if rpm < 1500.0 {
            0.65 + 0.35 * (rpm / 1500.0)
        } else if rpm > 5000.0 {
            1.0 - 0.25 * (rpm - 5000.0) / (self.max_rpm - 5000.0)
        } else {
            1.0
        };
        self.max_torque_nm * shape.max(0.3)
    }

    /// Engine speed for a road speed in a gear (1-based), not below idle.
    fn engine_rpm(&self, speed_m_s: f64, gear: usize) -> f64 {
        let wheel_rpm = speed_m_s / self.wheel_radius_m * 60.0 / std::f64::consts::TAU;
        (wheel_rpm * self.gear_ratios[gear - 1] * self.final_drive).max(self.idle_rpm)
    }

    fn friction_kw(&self, rpm: f64) -> f64 {
        self.friction_kw_at_1000_rpm * (rpm / 1000.0).powf(1.5)
    }

    /// Road load (rolling, aerodynamic, grade), N.
    fn road_load_n(&self, speed_m_s: f64, grade_rad: f64) -> f64 {
        let rolling = if speed_m_s > 0.01 {
            self.rolling_resistance * self.mass_kg * G_M_S2 * grade_rad.cos()
        } else {
            0.0
        };
        rolling
            + 0.5 * AIR_DENSITY_KG_M3 * self.drag_area_m2 * speed_m_s * speed_m_s
            + self.mass_kg * G_M_S2 * grade_rad.sin()
    }
}

/// One part of a scenario: a drive cycle driven by one driver, labelled with a regime.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Segment {
    /// Name of the drive cycle (the caller supplies its trace, e.g. from `<name>.csv`).
    pub cycle: String,
    pub driver: DriverStyle,
    /// The regime label written beside the samples (e.g. `city`, `highway`, `aggressive`).
    pub regime: String,
    /// Only the first `max_s` seconds of the cycle (all of it when absent).
    #[serde(default)]
    pub max_s: Option<usize>,
}

/// A `config/scenarios/fuel-*.toml` file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VehicleScenario {
    /// Seed of the simulator's noise (driver, meter).
    pub seed: u64,
    /// Directory of the drive-cycle CSV files, relative to the scenario file (resolved by the
    /// caller, which reads them).
    pub drive_cycle_dir: String,
    #[serde(default)]
    pub vehicle: VehicleParameters,
    #[serde(rename = "segment")]
    pub segments: Vec<Segment>,
    /// The estimator settings this scenario is analysed with: `FuelMonitorConfig::default()`
    /// when the table is absent, the preset its `preset` key names, single keys on top.
    #[serde(
        default,
        deserialize_with = "railmon_settings::deserialize_with_preset"
    )]
    pub monitor: FuelMonitorConfig,
}

impl VehicleScenario {
    pub fn from_toml_str(text: &str) -> Result<Self, FuelError> {
        let s: VehicleScenario =
            toml::from_str(text).map_err(|e| FuelError::Scenario(e.to_string()))?;
        s.validate()?;
        Ok(s)
    }

    pub fn validate(&self) -> Result<(), FuelError> {
        if self.segments.is_empty() {
            return Err(FuelError::invalid(
                "segment",
                0,
                "a scenario needs at least one segment",
            ));
        }
        if let Some(s) = self.segments.iter().find(|s| s.max_s == Some(0)) {
            return Err(FuelError::invalid(
                "segment.max_s",
                0,
                if s.cycle.is_empty() {
                    "empty"
                } else {
                    "must be > 0"
                },
            ));
        }
        self.vehicle.validate()?;
        self.monitor.validate()
    }

    /// Names of the drive cycles the scenario needs, each once.
    pub fn cycle_names(&self) -> Vec<String> {
        let mut names: Vec<String> = self.segments.iter().map(|s| s.cycle.clone()).collect();
        names.sort();
        names.dedup();
        names
    }

    /// Regime labels in order of first appearance; a sample's `regime` indexes this list.
    pub fn regimes(&self) -> Vec<String> {
        let mut out: Vec<String> = Vec::new();
        for s in &self.segments {
            if !out.contains(&s.regime) {
                out.push(s.regime.clone());
            }
        }
        out
    }
}

/// What the simulator knows that a real vehicle does not tell.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VehicleTruth {
    /// Index into [`VehicleScenario::regimes`].
    pub regime: usize,
    pub driver: DriverStyle,
    /// The speed the trace asked for, m/s.
    pub target_speed_m_s: f64,
    /// Fuel before the meter noise, cm^3/s.
    pub fuel_true_cm3_s: f64,
}

/// The vehicle simulator: [`VehicleSimulator::step`] gives one 1 Hz sample and its truth.
#[derive(Clone, Debug)]
pub struct VehicleSimulator {
    vehicle: VehicleParameters,
    /// Per second: (target speed, grade, driver, regime).
    plan: Vec<(f64, f64, DriverStyle, usize)>,
    t: usize,
    speed_m_s: f64,
    gear: usize,
    /// Smoothed pedal (the driver's foot has inertia).
    pedal_pct: f64,
    rng: ChaCha8Rng,
}

impl VehicleSimulator {
    /// `cycles` maps each name of [`VehicleScenario::cycle_names`] to its trace.
    pub fn new(
        scenario: &VehicleScenario,
        cycles: &BTreeMap<String, DriveCycle>,
    ) -> Result<Self, FuelError> {
        scenario.validate()?;
        let regimes = scenario.regimes();
        let mut plan = Vec::new();
        for seg in &scenario.segments {
            let cycle = cycles.get(&seg.cycle).ok_or_else(|| {
                FuelError::Scenario(format!("drive cycle `{}` was not supplied", seg.cycle))
            })?;
            if cycle.speed_m_s.len() != cycle.grade_rad.len() || cycle.speed_m_s.is_empty() {
                return Err(FuelError::Scenario(format!(
                    "drive cycle `{}`: speed and grade lengths differ or are empty",
                    seg.cycle
                )));
            }
            if let Some(v) = cycle
                .speed_m_s
                .iter()
                .chain(&cycle.grade_rad)
                .find(|v| !v.is_finite() || v.abs() > 100.0)
            {
                return Err(FuelError::Scenario(format!(
                    "drive cycle `{}`: implausible value {v}",
                    seg.cycle
                )));
            }
            let regime = regimes
                .iter()
                .position(|r| *r == seg.regime)
                .expect("regimes come from the segments");
            let n = seg
                .max_s
                .map_or(cycle.speed_m_s.len(), |m| m.min(cycle.speed_m_s.len()));
            for k in 0..n {
                plan.push((
                    cycle.speed_m_s[k].max(0.0),
                    cycle.grade_rad[k],
                    seg.driver,
                    regime,
                ));
            }
        }
        Ok(VehicleSimulator {
            vehicle: scenario.vehicle.clone(),
            plan,
            t: 0,
            speed_m_s: 0.0,
            gear: 1,
            pedal_pct: 0.0,
            rng: ChaCha8Rng::seed_from_u64(scenario.seed),
        })
    }

    /// Number of samples the scenario produces.
    pub fn len(&self) -> usize {
        self.plan.len()
    }

    pub fn is_empty(&self) -> bool {
        self.plan.is_empty()
    }

    /// The next 1 Hz sample, or `None` at the end of the scenario.
    pub fn step(&mut self) -> Option<(VehicleSample, VehicleTruth)> {
        let (target, grade, driver, regime) = *self.plan.get(self.t)?;
        let next_target = self.plan.get(self.t + 1).map_or(target, |p| p.0);
        let p = &self.vehicle;
        let (tau_s, max_accel, up_rpm, down_rpm, pedal_noise, max_pedal) = driver.parameters();
        let noise = Normal::new(0.0, 1.0).expect("unit normal");
        let dt = 1.0 / SUBSTEPS as f64;
        let mut out = (0.0, 0.0);
        let mut fuel_sum = 0.0;
        for sub in 0..SUBSTEPS {
            let frac = (sub + 1) as f64 / SUBSTEPS as f64;
            let reference = target + (next_target - target) * frac;
            // Driver: close the speed error with time constant tau, within the comfort limit.
            let wanted_accel = ((reference - self.speed_m_s) / tau_s + (next_target - target))
                .clamp(-4.0, max_accel);
            let road = p.road_load_n(self.speed_m_s, grade);
            let force_needed = p.mass_kg * wanted_accel + road;
            // Shift schedule (section 4.1's 6-speed box): up above up_rpm, down below down_rpm.
            let moving = self.speed_m_s > 0.5 || reference > 0.5;
            if !moving {
                self.gear = 1;
            } else if self.gear < 6 && p.engine_rpm(self.speed_m_s, self.gear) > up_rpm {
                self.gear += 1;
            } else if self.gear > 1 && p.engine_rpm(self.speed_m_s, self.gear) < down_rpm {
                self.gear -= 1;
            }
            let ratio = p.gear_ratios[self.gear - 1] * p.final_drive;
            let rpm = p.engine_rpm(self.speed_m_s, self.gear).min(p.max_rpm);
            let full_load = p.full_load_torque_nm(rpm);
            let wanted_pedal = if force_needed > 0.0 && moving {
                let torque = force_needed * p.wheel_radius_m / (ratio * p.driveline_efficiency);
                (100.0 * torque / full_load).clamp(0.0, max_pedal)
            } else {
                0.0
            };
            // The foot follows with a 0.3 s lag, plus tremor.
            self.pedal_pct += (wanted_pedal - self.pedal_pct) * (dt / 0.3).min(1.0);
            if wanted_pedal == 0.0 && self.pedal_pct < 0.5 {
                self.pedal_pct = 0.0;
            }
            let pedal = if self.pedal_pct > 0.0 {
                (self.pedal_pct + pedal_noise * noise.sample(&mut self.rng) * dt.sqrt())
                    .clamp(0.0, 100.0)
            } else {
                0.0
            };
            let omega = rpm * std::f64::consts::TAU / 60.0;
            let friction_nm = p.friction_kw(rpm) * 1000.0 / omega;
            let overrun = pedal == 0.0 && self.speed_m_s > 3.0 && rpm >= p.cut_off_min_rpm;
            let (torque_nm, fuel_cm3_s) = if overrun {
                // Fuel cut-off: the engine is dragged, its friction brakes the car.
                (-friction_nm, 0.0)
            } else {
                let torque = if moving {
                    full_load * pedal / 100.0
                } else {
                    0.0
                };
                let indicated_kw = (torque + friction_nm) * omega / 1000.0;
                // Enrichment near full load.
                let enrich = if pedal > 90.0 { 1.15 } else { 1.0 };
                let fuel = enrich * indicated_kw
                    / p.indicated_efficiency
                    / PETROL_LHV_KJ_G
                    / PETROL_DENSITY_G_CM3;
                (torque, fuel)
            };
            let wheel_force = if self.speed_m_s > 0.0 || torque_nm > 0.0 {
                torque_nm * ratio * p.driveline_efficiency / p.wheel_radius_m
            } else {
                0.0
            };
            // Brakes make up what the engine does not: the driver follows the trace.
            let brake = (wheel_force - force_needed).max(0.0);
            let accel = (wheel_force - brake - road) / p.mass_kg;
            self.speed_m_s = (self.speed_m_s + accel * dt).max(0.0);
            out = (torque_nm, pedal);
            fuel_sum += fuel_cm3_s;
        }
        let (torque_nm, pedal) = out;
        // The flow meter integrates over the second.
        let fuel_true = fuel_sum / SUBSTEPS as f64;
        let rpm = if self.speed_m_s < 0.5 && target < 0.5 {
            p.idle_rpm
        } else {
            p.engine_rpm(self.speed_m_s, self.gear).min(p.max_rpm)
        };
        let fuel_measured = if fuel_true > 0.0 {
            (fuel_true + p.fuel_noise_cm3_s * noise.sample(&mut self.rng)).max(0.0)
        } else {
            0.0
        };
        let stopped = self.speed_m_s < 0.1 && target < 0.1;
        let sample = VehicleSample {
            time_s: self.t as f64,
            fuel_cm3_s: Some(fuel_measured),
            speed_m_s: Some(self.speed_m_s),
            pedal_pct: Some(pedal),
            engine_torque_nm: Some(torque_nm),
            engine_speed_rpm: Some(rpm),
            // The road car's estimator settings do not use the grade (the paper's channels).
            gradient_permille: None,
            // Neutral while standing (the paper's gear 0).
            gear: Some(if stopped { 0 } else { self.gear as i32 }),
        };
        let truth = VehicleTruth {
            regime,
            driver,
            target_speed_m_s: target,
            fuel_true_cm3_s: fuel_true,
        };
        self.t += 1;
        Some((sample, truth))
    }
}
