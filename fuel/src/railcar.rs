//! A diesel multiple unit (DMU) driven along a route (issue 14 item 2): gradient and
//! speed-limit profile, station stops, a driver who notches up, holds the line speed, coasts
//! and brakes into the next station, notch-based traction and an engine fuel map. It produces,
//! at 1 Hz, what a railcar's logger gives (fuel flow, speed, gradient, throttle notch) and the
//! driving regime as a label: `idle` (standing at a station), `accelerating` (notching up
//! towards the line speed), `cruising` (holding it under power), `coasting` (notch 0, no
//! brake), `braking`.
//!
//! Figures it is based on (defaults of [`RailcarParameters`]):
//! - Engine: Cummins QSK19-R railcar engine, 567 kW (760 hp) rated, one underfloor per car; a
//!   three-car set "totaling 2280 hp (1700 kW)" (Cummins press release, 25 April 2014, "Cummins
//!   QSK19-R to power Nippon Sharyo DMU").
//! - Specific fuel consumption at rated power: **assumed** 205 g/kWh (typical of a modern
//!   high-speed diesel at full load; the release gives none). Below rated power the map is a
//!   Willans line (fuel = idle fuel + marginal consumption x power), which makes the specific
//!   consumption rise at part load as measured engines do; the idle fuel (1.5 cm^3/s per
//!   engine, ~5.4 l/h) is **assumed**. Diesel 0.835 g/cm^3.
//! - **Assumed**: 190 t (three cars with passengers, 6 % rotating-mass allowance), Davis
//!   resistance `m (A + B v) + C v^2`, hydrodynamic transmission efficiency 0.82, 30 kW of
//!   auxiliaries per engine (always on), 150 kN starting tractive effort, service braking
//!   0.7 m/s^2, engine power following the notch with a 2 s lag, one notch per 2 s.
//!
//! Physics is integrated at 10 Hz, samples are taken every second. The route is data of the
//! scenario; this module reads no file.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use crate::{FuelError, FuelMonitorConfig, VehicleSample};

const G_M_S2: f64 = 9.81;
const DIESEL_DENSITY_G_CM3: f64 = 0.835;
const SUBSTEPS: usize = 10;
/// The driver stops this far short of the platform's end, m (a train stopping within 25 m of
/// it is at the platform).
const STOP_MARGIN_M: f64 = 5.0;
/// The simulator stops after this many seconds whatever happens (a week).
const MAX_STEPS: u64 = 604_800;
/// The highest throttle notch (0 idle .. 8 full power).
pub const MAX_NOTCH: i32 = 8;

/// The labelled driving regimes, in this order (the label index of [`RailcarTruth::regime`]).
pub const RAILCAR_REGIMES: [&str; 5] = ["idle", "accelerating", "cruising", "coasting", "braking"];

/// Vehicle, engine and driver parameters. See the module documentation for their sources.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RailcarParameters {
    pub mass_t: f64,
    pub rotating_mass_allowance: f64,
    /// Davis `A`, N per tonne.
    pub davis_a_n_per_t: f64,
    /// Davis `B`, N per tonne per m/s.
    pub davis_b_n_per_t_m_s: f64,
    /// Davis `C`, N per (m/s)^2 (the whole train).
    pub davis_c_n_per_m2_s2: f64,
    pub engines: usize,
    pub rated_power_kw: f64,
    pub sfc_rated_g_per_kwh: f64,
    pub idle_fuel_cm3_s: f64,
    pub auxiliary_kw: f64,
    pub transmission_efficiency: f64,
    pub max_tractive_effort_kn: f64,
    pub service_brake_m_s2: f64,
    /// Time constant of the engine power following the notch, s.
    pub engine_lag_s: f64,
    /// The driver moves the controller by one notch per this many seconds.
    pub notch_interval_s: f64,
    /// Distance before a station at which the driver shuts off and coasts, m.
    pub coast_before_stop_m: f64,
    /// Standard deviation of the fuel-flow meter noise, cm^3/s.
    pub fuel_noise_cm3_s: f64,
    /// Standard deviation of the speed sensor's noise while the train moves, m/s (a tachometer
    /// reads 0 at standstill; the reading is never negative). 0 by default: the shipped routes
    /// measure the speed exactly; a noisier sensor is a condition to test the estimator on.
    pub speed_noise_m_s: f64,
}

impl Default for RailcarParameters {
    fn default() -> Self {
        RailcarParameters {
            mass_t: 190.0,
            rotating_mass_allowance: 0.06,
            davis_a_n_per_t: 12.0,
            davis_b_n_per_t_m_s: 0.1,
            davis_c_n_per_m2_s2: 6.0,
            engines: 3,
            rated_power_kw: 567.0,
            sfc_rated_g_per_kwh: 205.0,
            idle_fuel_cm3_s: 1.5,
            auxiliary_kw: 30.0,
            transmission_efficiency: 0.82,
            max_tractive_effort_kn: 150.0,
            service_brake_m_s2: 0.7,
            engine_lag_s: 2.0,
            notch_interval_s: 2.0,
            coast_before_stop_m: 1200.0,
            fuel_noise_cm3_s: 0.5,
            speed_noise_m_s: 0.0,
        }
    }
}

impl RailcarParameters {
    /// Fuel flow (cm^3/s) of one engine delivering `power_kw` (Willans line through the idle
    /// fuel at 0 kW and `sfc_rated` at rated power).
    pub fn fuel_cm3_s(&self, power_kw: f64) -> f64 {
        let idle_g_s = self.idle_fuel_cm3_s * DIESEL_DENSITY_G_CM3;
        let rated_g_s = self.sfc_rated_g_per_kwh * self.rated_power_kw / 3600.0;
        let marginal_g_per_kj = (rated_g_s - idle_g_s) / self.rated_power_kw;
        (idle_g_s + marginal_g_per_kj * power_kw.max(0.0)) / DIESEL_DENSITY_G_CM3
    }

    fn validate(&self) -> Result<(), FuelError> {
        let positive = [
            ("railcar.mass_t", self.mass_t),
            ("railcar.rated_power_kw", self.rated_power_kw),
            ("railcar.sfc_rated_g_per_kwh", self.sfc_rated_g_per_kwh),
            ("railcar.idle_fuel_cm3_s", self.idle_fuel_cm3_s),
            (
                "railcar.transmission_efficiency",
                self.transmission_efficiency,
            ),
            (
                "railcar.max_tractive_effort_kn",
                self.max_tractive_effort_kn,
            ),
            ("railcar.service_brake_m_s2", self.service_brake_m_s2),
            ("railcar.engine_lag_s", self.engine_lag_s),
            ("railcar.notch_interval_s", self.notch_interval_s),
        ];
        for (field, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(FuelError::invalid(field, v, "must be finite and > 0"));
            }
        }
        let non_negative = [
            (
                "railcar.rotating_mass_allowance",
                self.rotating_mass_allowance,
            ),
            ("railcar.davis_a_n_per_t", self.davis_a_n_per_t),
            ("railcar.davis_b_n_per_t_m_s", self.davis_b_n_per_t_m_s),
            ("railcar.davis_c_n_per_m2_s2", self.davis_c_n_per_m2_s2),
            ("railcar.auxiliary_kw", self.auxiliary_kw),
            ("railcar.coast_before_stop_m", self.coast_before_stop_m),
            ("railcar.fuel_noise_cm3_s", self.fuel_noise_cm3_s),
            ("railcar.speed_noise_m_s", self.speed_noise_m_s),
        ];
        for (field, v) in non_negative {
            if !(v.is_finite() && v >= 0.0) {
                return Err(FuelError::invalid(field, v, "must be finite and >= 0"));
            }
        }
        if !(1..=8).contains(&self.engines) || self.auxiliary_kw >= self.rated_power_kw {
            return Err(FuelError::invalid(
                "railcar.engines",
                self.engines,
                "1..=8 engines, each rated above its auxiliary load",
            ));
        }
        if self.transmission_efficiency > 1.0 {
            return Err(FuelError::invalid(
                "railcar.transmission_efficiency",
                self.transmission_efficiency,
                "must be in (0, 1]",
            ));
        }
        Ok(())
    }
}

/// A stretch of line with one gradient and one speed limit; a station stop at its end when
/// `stop_s > 0`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RouteSection {
    pub length_m: f64,
    /// Per mille, positive uphill in the direction of the outward run.
    pub gradient_permille: f64,
    pub speed_limit_km_h: f64,
    /// Dwell at a station at the end of the section, s (0: no station).
    #[serde(default)]
    pub stop_s: f64,
}

/// A `config/scenarios/fuel-railcar.toml` file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RailcarScenario {
    /// Seed of the simulator's noise (dwell times, load, meter).
    pub seed: u64,
    /// Round trips: out along the sections, back along them reversed (gradients negated).
    pub round_trips: usize,
    /// Dwell at the first station before the first departure, s.
    #[serde(default = "RailcarScenario::default_initial_dwell_s")]
    pub initial_dwell_s: f64,
    #[serde(default)]
    pub railcar: RailcarParameters,
    #[serde(rename = "section")]
    pub sections: Vec<RouteSection>,
    /// The estimator settings this scenario is analysed with (as a fuel scenario's).
    #[serde(
        default,
        deserialize_with = "railmon_settings::deserialize_with_preset"
    )]
    pub monitor: FuelMonitorConfig,
}

impl RailcarScenario {
    fn default_initial_dwell_s() -> f64 {
        60.0
    }

    /// Whether a scenario file describes a route (`[[section]]` tables) rather than drive
    /// cycles; a file that does not parse is left to the reader that reports it.
    pub fn is_one(text: &str) -> bool {
        toml::from_str::<toml::Table>(text).is_ok_and(|t| t.contains_key("section"))
    }

    pub fn from_toml_str(text: &str) -> Result<Self, FuelError> {
        let s: RailcarScenario =
            toml::from_str(text).map_err(|e| FuelError::Scenario(e.to_string()))?;
        s.validate()?;
        Ok(s)
    }

    pub fn validate(&self) -> Result<(), FuelError> {
        self.railcar.validate()?;
        self.monitor.validate()?;
        if self.sections.is_empty() || self.sections.last().is_some_and(|s| s.stop_s <= 0.0) {
            return Err(FuelError::invalid(
                "section",
                self.sections.len(),
                "a route needs sections and must end at a station (`stop_s` > 0)",
            ));
        }
        if !(1..=1000).contains(&self.round_trips) {
            return Err(FuelError::invalid(
                "round_trips",
                self.round_trips,
                "must be in 1..=1000",
            ));
        }
        if !(self.initial_dwell_s.is_finite() && self.initial_dwell_s >= 0.0) {
            return Err(FuelError::invalid(
                "initial_dwell_s",
                self.initial_dwell_s,
                "must be finite and >= 0",
            ));
        }
        for s in &self.sections {
            let plausible = (1e-3..=1e6).contains(&s.length_m)
                && (-60.0..=60.0).contains(&s.gradient_permille)
                && s.speed_limit_km_h > 5.0
                && s.speed_limit_km_h <= 200.0
                && (0.0..=3600.0).contains(&s.stop_s);
            if !plausible {
                return Err(FuelError::invalid(
                    "section",
                    format!("{s:?}"),
                    "length in (0, 10^6] m, |gradient| <= 60 per mille, limit in (5, 200] km/h, \
                     stop in [0, 3600] s",
                ));
            }
        }
        Ok(())
    }

    /// The label names, index = [`RailcarTruth::regime`].
    pub fn regimes(&self) -> Vec<String> {
        RAILCAR_REGIMES.iter().map(|s| (*s).to_owned()).collect()
    }
}

/// What the simulator knows and the estimator does not.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RailcarTruth {
    /// Index into [`RAILCAR_REGIMES`].
    pub regime: usize,
    pub fuel_true_cm3_s: f64,
    pub position_m: f64,
    pub engine_power_kw: f64,
    /// The true speed (the sample's is the sensor's), m/s.
    pub speed_m_s: f64,
}

/// One leg: from a station to the next, as sections with absolute end positions.
#[derive(Clone, Debug)]
struct Leg {
    /// (end position m, gradient per mille, limit m/s) per section.
    sections: Vec<(f64, f64, f64)>,
    length_m: f64,
    dwell_s: f64,
}

/// The simulator. See the module documentation.
pub struct RailcarSimulator {
    p: RailcarParameters,
    legs: Vec<Leg>,
    leg: usize,
    /// Position within the current leg, m.
    x_m: f64,
    v_m_s: f64,
    notch: i32,
    /// Seconds since the last notch change.
    since_notch_s: f64,
    engine_kw: f64,
    dwell_left_s: f64,
    mass_factor: f64,
    t: u64,
    rng: ChaCha8Rng,
    done: bool,
    /// The driver has started braking for the station and keeps braking until the train
    /// stands (releasing when the brake had taken a little too much made the train coast,
    /// then brake again harder, and reach the platform at several m/s).
    stopping: bool,
}

impl RailcarSimulator {
    pub fn new(scenario: &RailcarScenario) -> Result<Self, FuelError> {
        scenario.validate()?;
        let mut legs = Vec::new();
        let mut current: Vec<(f64, f64, f64)> = Vec::new();
        let mut x = 0.0;
        let mut push = |s: &RouteSection, gradient: f64, stop_s: f64, legs: &mut Vec<Leg>| {
            x += s.length_m;
            current.push((x, gradient, s.speed_limit_km_h / 3.6));
            if stop_s > 0.0 {
                legs.push(Leg {
                    sections: std::mem::take(&mut current),
                    length_m: x,
                    dwell_s: stop_s,
                });
                x = 0.0;
            }
        };
        for _ in 0..scenario.round_trips {
            for s in &scenario.sections {
                push(s, s.gradient_permille, s.stop_s, &mut legs);
            }
            // Back: sections reversed, gradients negated; each station's dwell is that of the
            // section that ended at it on the way out, the terminus that of the last section.
            let n = scenario.sections.len();
            for i in (0..n).rev() {
                let s = &scenario.sections[i];
                let stop_s = if i == 0 {
                    scenario.sections[n - 1].stop_s
                } else {
                    scenario.sections[i - 1].stop_s
                };
                push(s, -s.gradient_permille, stop_s, &mut legs);
            }
        }
        Ok(RailcarSimulator {
            p: scenario.railcar.clone(),
            legs,
            leg: 0,
            x_m: 0.0,
            v_m_s: 0.0,
            notch: 0,
            since_notch_s: 0.0,
            engine_kw: scenario.railcar.auxiliary_kw,
            dwell_left_s: scenario.initial_dwell_s.max(1.0),
            mass_factor: 1.0,
            t: 0,
            rng: ChaCha8Rng::seed_from_u64(scenario.seed),
            done: false,
            stopping: false,
        })
    }

    /// (gradient per mille, limit m/s, distance to the section end m, next section's limit
    /// m/s or 0 at the station) where the train is.
    fn track(&self) -> (f64, f64, f64, f64) {
        let leg = &self.legs[self.leg];
        let i = leg
            .sections
            .iter()
            .position(|s| self.x_m < s.0)
            .unwrap_or(leg.sections.len() - 1);
        let (end, gradient, limit) = leg.sections[i];
        let next = leg.sections.get(i + 1).map_or(0.0, |s| s.2);
        (gradient, limit, end - self.x_m, next)
    }

    /// Davis resistance plus grade, N.
    fn resistance_n(&self, v: f64, gradient_permille: f64) -> f64 {
        let p = &self.p;
        let m_t = p.mass_t * self.mass_factor;
        m_t * (p.davis_a_n_per_t + p.davis_b_n_per_t_m_s * v)
            + p.davis_c_n_per_m2_s2 * v * v
            + m_t * 1000.0 * G_M_S2 * gradient_permille / 1000.0
    }

    /// Tractive force at the wheel, N, for an engine delivering `engine_kw` in total.
    fn tractive_n(&self, engine_kw: f64, v: f64) -> f64 {
        let p = &self.p;
        let wheel_w =
            p.transmission_efficiency * (engine_kw - p.engines as f64 * p.auxiliary_kw) * 1e3;
        (wheel_w.max(0.0) / v.max(1.0)).min(p.max_tractive_effort_kn * 1e3)
    }

    /// Total engine power (all engines, auxiliaries included) at `notch`.
    fn notch_kw(&self, notch: i32) -> f64 {
        let p = &self.p;
        let aux = p.engines as f64 * p.auxiliary_kw;
        aux + f64::from(notch) / f64::from(MAX_NOTCH) * (p.engines as f64 * p.rated_power_kw - aux)
    }

    /// How far the track falls from the train to `until_m` (a position in the current leg),
    /// m: negative where it climbs.
    fn fall_m(&self, until_m: f64) -> f64 {
        let leg = &self.legs[self.leg];
        let mut start: f64 = 0.0;
        let mut fall = 0.0;
        for &(end, gradient, _) in &leg.sections {
            let overlap = end.min(until_m) - start.max(self.x_m);
            if overlap > 0.0 {
                fall -= gradient / 1000.0 * overlap;
            }
            start = end;
        }
        fall
    }

    /// The driver's decision for the next second: (target notch, brake deceleration, regime).
    fn drive(&mut self) -> (i32, f64, usize) {
        let v = self.v_m_s;
        let leg = &self.legs[self.leg];
        let to_stop = leg.length_m - self.x_m;
        let (gradient, limit, to_boundary, next_limit) = self.track();
        let b = self.p.service_brake_m_s2;
        // Brake for the station: the deceleration that stops exactly at the platform, once it
        // reaches 90 % of the service brake. Grade-corrected by energy: a constant brake `B`
        // over the distance `d` to the stop takes the kinetic energy and what the track falls
        // by (`h`) on the way, `B d = v^2 / 2 + g h` (resistance neglected: it helps). Without
        // the `g h` a train at the foot of a 4 km descent at 20 per mille (issue 25) braked too
        // late and reached the platform at 6 m/s.
        // The driver aims at a stop mark `STOP_MARGIN_M` short of the platform's end: aiming at
        // the end itself, the last second's brake (decided once a second) often arrived with
        // 1-2 m/s left, which `step` then zeroed in one sample.
        let stop_at = (to_stop - STOP_MARGIN_M).max(0.5);
        let for_stop = (v * v / 2.0 + G_M_S2 * self.fall_m(self.x_m + stop_at)) / stop_at;
        // Brake for a lower limit ahead.
        let for_limit = if next_limit > 0.0 && v > next_limit {
            let d = to_boundary.max(0.5);
            ((v * v - next_limit * next_limit) / 2.0 + G_M_S2 * self.fall_m(self.x_m + d)) / d
        } else {
            0.0
        };
        let needed = for_stop.max(for_limit);
        // Braked to a stand short of the platform (beyond where `step` accepts it): release.
        if self.stopping && v < 0.05 {
            self.stopping = false;
        }
        self.stopping |= for_stop >= 0.9 * b;
        if self.stopping {
            // A kinematic 0.1 m/s^2 at least (well below the 0.9 b that started it, so that a
            // brake that took a little too much does not stop the train short), never less
            // than a light 0.05 m/s^2 up a climb.
            let floor = (0.1 - G_M_S2 * gradient / 1000.0).max(0.05);
            return (0, needed.max(floor).min(1.3 * b), 4);
        }
        if needed >= 0.9 * b || v > limit + 1.0 {
            return (0, needed.max(0.3).min(1.3 * b), 4);
        }
        // Coast only where the train's momentum carries it to the platform (uphill it would
        // stall short of it): the distance to a stop at today's resistance.
        let mass_kg = self.p.mass_t * self.mass_factor * 1000.0;
        let drag_m_s2 = self.resistance_n(v, gradient) / mass_kg;
        // A standing train does not coast off: its brakes hold it (`step` keeps a train at rest
        // at notch 0), so on a down grade "gravity carries it" chose coasting for ever at the
        // first station; it takes power instead.
        let carries =
            v > 0.0 && (drag_m_s2 <= 0.0 || v * v / (2.0 * drag_m_s2) > to_stop.min(2000.0));
        if carries && (to_stop < self.p.coast_before_stop_m || v > limit - 0.3) {
            return (0, 0.0, 3);
        }
        if v < limit - 2.0 {
            return (MAX_NOTCH, 0.0, 1);
        }
        // Hold the line speed: the notch whose power covers the resistance at this speed.
        let need_n = self.resistance_n(v, gradient);
        let notch = (0..=MAX_NOTCH)
            .find(|&n| self.tractive_n(self.notch_kw(n), v) >= need_n)
            .unwrap_or(MAX_NOTCH);
        match notch {
            0 => (0, 0.0, 3),
            n => (n, 0.0, 2),
        }
    }

    /// The next 1 Hz sample and its truth; `None` after the last station of the last trip.
    pub fn step(&mut self) -> Option<(VehicleSample, RailcarTruth)> {
        // A train that stalls (parameters too weak for a gradient) would otherwise run forever.
        if self.done || self.t >= MAX_STEPS {
            return None;
        }
        let p = self.p.clone();
        let (target_notch, brake, mut regime) = if self.dwell_left_s > 0.0 {
            self.dwell_left_s -= 1.0;
            (0, 0.0, 0)
        } else {
            self.drive()
        };
        // The controller moves one notch at a time; shutting off (notch 0) is immediate.
        self.since_notch_s += 1.0;
        if target_notch == 0 {
            self.notch = 0;
        } else if target_notch != self.notch && self.since_notch_s >= p.notch_interval_s {
            self.notch += (target_notch - self.notch).signum();
            self.since_notch_s = 0.0;
        }
        if regime == 2 && self.notch < target_notch && target_notch == MAX_NOTCH {
            regime = 1;
        }
        let demand_kw = self.notch_kw(self.notch);
        let (gradient, _, _, _) = self.track();
        let mass_kg = p.mass_t * self.mass_factor * 1000.0 * (1.0 + p.rotating_mass_allowance);
        let dt = 1.0 / SUBSTEPS as f64;
        let mut fuel_sum = 0.0;
        for _ in 0..SUBSTEPS {
            self.engine_kw += (demand_kw - self.engine_kw) * dt / p.engine_lag_s;
            fuel_sum += p.engines as f64 * p.fuel_cm3_s(self.engine_kw / p.engines as f64);
            if self.dwell_left_s > 0.0 || (self.v_m_s <= 0.0 && self.notch == 0) {
                self.v_m_s = 0.0;
                continue;
            }
            let force = self.tractive_n(self.engine_kw, self.v_m_s)
                - self.resistance_n(self.v_m_s, gradient)
                - brake * mass_kg;
            self.v_m_s = (self.v_m_s + force / mass_kg * dt).max(0.0);
            self.x_m += self.v_m_s * dt;
        }
        let fuel_true = fuel_sum / SUBSTEPS as f64;
        let leg = &self.legs[self.leg];
        // At the platform (or stopped by the brake within a few metres of it): dwell.
        if self.dwell_left_s <= 0.0
            && (self.x_m >= leg.length_m - 0.5 || (brake > 0.0 && self.v_m_s < 0.05))
            && leg.length_m - self.x_m < 25.0
        {
            self.v_m_s = 0.0;
            self.notch = 0;
            // Dwell times vary +-20 %, and the load with the passengers (+-5 % of the mass).
            self.dwell_left_s = (leg.dwell_s * self.rng.random_range(0.8..1.2)).round();
            self.mass_factor = self.rng.random_range(0.95..1.05);
            self.stopping = false;
            self.leg += 1;
            self.x_m = 0.0;
            if self.leg == self.legs.len() {
                self.done = true;
                self.leg -= 1;
            }
        }
        let noise = Normal::new(0.0, p.fuel_noise_cm3_s.max(1e-12)).expect("finite sd");
        let fuel_cm3_s = (fuel_true + noise.sample(&mut self.rng)).max(0.0);
        // Drawn only when asked for, so that the routes without it keep their samples.
        let speed_m_s = if p.speed_noise_m_s > 0.0 && self.v_m_s > 0.0 {
            let noise = Normal::new(0.0, p.speed_noise_m_s).expect("finite sd");
            (self.v_m_s + noise.sample(&mut self.rng)).max(0.0)
        } else {
            self.v_m_s
        };
        let sample = VehicleSample {
            time_s: self.t as f64,
            fuel_cm3_s: Some(fuel_cm3_s),
            speed_m_s: Some(speed_m_s),
            gradient_permille: Some(gradient),
            gear: Some(self.notch),
            ..Default::default()
        };
        self.t += 1;
        let truth = RailcarTruth {
            regime,
            fuel_true_cm3_s: fuel_true,
            position_m: self.x_m,
            engine_power_kw: self.engine_kw,
            speed_m_s: self.v_m_s,
        };
        Some((sample, truth))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_fuel_map_passes_through_idle_and_the_rated_consumption() {
        let p = RailcarParameters::default();
        assert!((p.fuel_cm3_s(0.0) - 1.5).abs() < 1e-12);
        // 567 kW x 205 g/kWh = 32.29 g/s = 38.67 cm^3/s.
        let rated = 567.0 * 205.0 / 3600.0 / DIESEL_DENSITY_G_CM3;
        assert!((p.fuel_cm3_s(567.0) - rated).abs() < 1e-9);
        // Part load costs more per kWh (Willans line with idle fuel).
        let sfc = |kw: f64| p.fuel_cm3_s(kw) * DIESEL_DENSITY_G_CM3 * 3600.0 / kw;
        assert!(sfc(100.0) > sfc(300.0) && sfc(300.0) > sfc(567.0));
    }

    fn flat_line() -> RailcarScenario {
        RailcarScenario {
            seed: 1,
            round_trips: 1,
            initial_dwell_s: 30.0,
            railcar: RailcarParameters {
                fuel_noise_cm3_s: 0.0,
                ..Default::default()
            },
            sections: vec![RouteSection {
                length_m: 8000.0,
                gradient_permille: 0.0,
                speed_limit_km_h: 100.0,
                stop_s: 40.0,
            }],
            monitor: FuelMonitorConfig::railcar(),
        }
    }

    #[test]
    fn a_run_between_two_stations_goes_through_every_regime_and_stops_at_the_platform() {
        let mut sim = RailcarSimulator::new(&flat_line()).unwrap();
        let mut seen = [0usize; 5];
        let mut max_v: f64 = 0.0;
        let mut max_fuel: f64 = 0.0;
        let mut distance = 0.0;
        let mut n = 0;
        while let Some((s, truth)) = sim.step() {
            seen[truth.regime] += 1;
            let v = s.speed_m_s.unwrap();
            max_v = max_v.max(v);
            max_fuel = max_fuel.max(s.fuel_cm3_s.unwrap());
            distance += v;
            n += 1;
            if truth.regime == 0 {
                assert_eq!((v, s.gear), (0.0, Some(0)));
            }
            assert!((0..=MAX_NOTCH).contains(&s.gear.unwrap()));
        }
        assert!(seen.iter().all(|&c| c > 0), "{seen:?}");
        assert!(
            max_v <= 100.0 / 3.6 + 1.0 && max_v > 100.0 / 3.6 - 2.5,
            "{max_v}"
        );
        // Out and back: 16 km (1 Hz sum of speeds: within a couple of per cent).
        assert!((distance - 16_000.0).abs() < 400.0, "{distance}");
        // Full power: three engines at rated power burn 3 x 38.7 cm^3/s.
        assert!(max_fuel > 110.0 && max_fuel < 120.0, "{max_fuel}");
        assert!(n < 3600, "{n} s for 16 km");
    }

    /// A station on a down grade closer than `coast_before_stop_m` to the next: the train used to
    /// choose coasting at rest (gravity would carry it) while its brakes held it, and stood
    /// "coasting" until the step limit (a week).
    #[test]
    fn a_train_leaves_a_station_on_a_down_grade_close_to_the_next() {
        let mut s = flat_line();
        s.round_trips = 1;
        s.sections[0].length_m = 1000.0;
        s.sections[0].gradient_permille = -12.0;
        let mut sim = RailcarSimulator::new(&s).unwrap();
        let steps = std::iter::from_fn(|| sim.step()).count();
        assert!(sim.done, "still running after {steps} s");
        assert!(steps < 600, "{steps} s for 2 km");
    }

    /// The speed sensor's noise: zero at standstill, never negative, and while moving the
    /// reading is off the true speed by `sigma sqrt(2 / pi)` on average (on the first leg, where
    /// the noisy and the exact run move alike: the random draws steer nothing before the first
    /// station's dwell).
    #[test]
    fn speed_noise_is_added_while_moving_only() {
        let mut noisy = flat_line();
        noisy.railcar.speed_noise_m_s = 0.1;
        let (mut a, mut b) = (
            RailcarSimulator::new(&flat_line()).unwrap(),
            RailcarSimulator::new(&noisy).unwrap(),
        );
        let (mut off, mut moving) = (0.0, 0);
        while let (Some((exact, _)), Some((read, truth))) = (a.step(), b.step()) {
            let (v, r) = (exact.speed_m_s.unwrap(), read.speed_m_s.unwrap());
            assert!(r >= 0.0);
            if truth.regime == 0 {
                assert_eq!(r, 0.0);
            }
            if b.leg > 0 {
                break;
            }
            if v > 1.0 {
                off += (r - v).abs();
                moving += 1;
            }
        }
        let mean = off / moving as f64;
        let expected = 0.1 * (2.0 / std::f64::consts::PI).sqrt();
        assert!(
            moving > 100 && (mean - expected).abs() < 0.15 * expected,
            "{mean} {moving}"
        );
    }

    #[test]
    fn uphill_costs_fuel_and_a_route_must_end_at_a_station() {
        let fuel = |gradient: f64| {
            let mut s = flat_line();
            s.sections[0].gradient_permille = gradient;
            s.round_trips = 1;
            let mut sim = RailcarSimulator::new(&s).unwrap();
            let mut out = 0.0;
            // The outward leg only (until the first station).
            while let Some((_, truth)) = sim.step() {
                out += truth.fuel_true_cm3_s;
                if sim.leg == 1 {
                    break;
                }
            }
            out
        };
        assert!(fuel(10.0) > 1.3 * fuel(0.0));
        let mut bad = flat_line();
        bad.sections[0].stop_s = 0.0;
        assert!(RailcarSimulator::new(&bad).is_err());
    }
}
