//! The fuel condition sampler (issue 25 item 2): a seed gives a random railcar line and the
//! conditions it is run under, drawn from the envelope of real regional and suburban lines, as a
//! [`RailcarScenario`] (so a draw can be written as TOML and replayed with `railmon analyze fuel
//! --scenario`). Pure: no I/O, one `ChaCha8Rng` seeded from the seed.
//!
//! The envelope ([`LineEnvelope::default`]), with where each range comes from:
//! - station spacing 0.8-20 km: suburban stops 0.8-3 km apart (S-Bahn and RER outer sections),
//!   regional lines up to 20 km between stations; a line has 3-7 stations and 8-45 km;
//! - grades -25..+25 per mille (the steepest adhesion main lines in Europe, e.g. the
//!   Schwarzwaldbahn's 20 per mille, the Semmering's 28), held for 0.3-4 km;
//! - speed limits 40-160 km/h: a line speed of 80-160 km/h, a quarter of the sections
//!   restricted (curves, junctions) to 40 km/h up to the line speed;
//! - dwell 20-90 s; load tare to crush (the default set's 190 t is three cars with a normal
//!   load: 165 t tare .. 225 t crush, **assumed**); one engine of three isolated on one line
//!   in six;
//! - the driver: coasting from 300-2500 m before a stop, a notch every 1-3 s, a service brake of
//!   0.5-0.9 m/s^2;
//! - the meters: fuel noise 0.3-0.8 cm^3/s, speed-sensor noise 0-0.3 m/s.
//!
//! Each line runs out and back twice, starting after a 60 s dwell, with the shipped `railcar`
//! estimator preset. Seeds are split by a fixed rule ([`Split::of`]): even seeds are for
//! tuning, odd seeds held out.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::railcar::{RailcarParameters, RailcarScenario, RouteSection};
use crate::{FuelError, FuelMonitorConfig};

/// Which use a seed's line is for: tuning settings or reporting on lines not tuned on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Split {
    Tuning,
    HeldOut,
}

impl Split {
    /// The fixed rule: even seeds tune, odd seeds are held out.
    pub fn of(seed: u64) -> Split {
        match seed % 2 {
            0 => Split::Tuning,
            _ => Split::HeldOut,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Split::Tuning => "tuning",
            Split::HeldOut => "held-out",
        }
    }

    /// `"tuning"`, `"held-out"`.
    pub fn parse(s: &str) -> Option<Split> {
        [Split::Tuning, Split::HeldOut]
            .into_iter()
            .find(|x| x.name() == s)
    }
}

/// The ranges lines and conditions are drawn from. See the module documentation.
#[derive(Clone, Debug, PartialEq)]
pub struct LineEnvelope {
    pub stations: [usize; 2],
    /// Suburban spacing, m, and the share of suburban legs on a suburban line.
    pub suburban_spacing_m: [f64; 2],
    pub regional_spacing_m: [f64; 2],
    /// Lines longer than this are cut short at a station (bounds the run time), m.
    pub max_line_m: f64,
    pub max_gradient_permille: f64,
    pub grade_length_m: [f64; 2],
    pub line_speed_km_h: [f64; 2],
    pub min_speed_limit_km_h: f64,
    pub restricted_share: f64,
    pub dwell_s: [f64; 2],
    pub mass_t: [f64; 2],
    pub isolated_engine_share: f64,
    pub coast_before_stop_m: [f64; 2],
    pub notch_interval_s: [f64; 2],
    pub service_brake_m_s2: [f64; 2],
    pub fuel_noise_cm3_s: [f64; 2],
    pub speed_noise_m_s: [f64; 2],
}

impl Default for LineEnvelope {
    fn default() -> Self {
        LineEnvelope {
            stations: [3, 7],
            suburban_spacing_m: [800.0, 3000.0],
            regional_spacing_m: [3000.0, 20_000.0],
            max_line_m: 45_000.0,
            max_gradient_permille: 25.0,
            grade_length_m: [300.0, 4000.0],
            line_speed_km_h: [80.0, 160.0],
            min_speed_limit_km_h: 40.0,
            restricted_share: 0.25,
            dwell_s: [20.0, 90.0],
            mass_t: [165.0, 225.0],
            isolated_engine_share: 1.0 / 6.0,
            coast_before_stop_m: [300.0, 2500.0],
            notch_interval_s: [1.0, 3.0],
            service_brake_m_s2: [0.5, 0.9],
            fuel_noise_cm3_s: [0.3, 0.8],
            speed_noise_m_s: [0.0, 0.3],
        }
    }
}

fn uniform(rng: &mut ChaCha8Rng, [lo, hi]: [f64; 2]) -> f64 {
    if hi > lo {
        rng.random_range(lo..hi)
    } else {
        lo
    }
}

/// Rounded to `step` (so that a written scenario reads as a drawn one).
fn round_to(x: f64, step: f64) -> f64 {
    (x / step).round() * step
}

impl LineEnvelope {
    /// The line and conditions of `seed`, with the `railcar` preset as its estimator.
    pub fn line(&self, seed: u64) -> RailcarScenario {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let stations = rng.random_range(self.stations[0]..=self.stations[1]);
        // A suburban line has mostly close stations, a regional one mostly distant ones.
        let suburban_share = uniform(&mut rng, [0.0, 1.0]);
        let line_speed = round_to(uniform(&mut rng, self.line_speed_km_h), 10.0);
        let mut sections = Vec::new();
        let mut line_m = 0.0;
        let mut gradient = 0.0;
        for _ in 1..stations {
            let spacing = match rng.random_bool(suburban_share) {
                true => uniform(&mut rng, self.suburban_spacing_m),
                // Log-uniform: short regional legs are as common as long ones per octave.
                false => uniform(
                    &mut rng,
                    [
                        self.regional_spacing_m[0].ln(),
                        self.regional_spacing_m[1].ln(),
                    ],
                )
                .exp(),
            };
            let spacing = round_to(spacing, 100.0);
            if line_m > 0.0 && line_m + spacing > self.max_line_m {
                break;
            }
            line_m += spacing;
            let mut left = spacing;
            while left > 0.0 {
                let length = round_to(uniform(&mut rng, self.grade_length_m), 100.0).min(left);
                // Grades follow each other: the next one is the last plus a step, so climbs
                // and descents last several sections.
                let g = self.max_gradient_permille;
                gradient = (gradient + uniform(&mut rng, [-0.6 * g, 0.6 * g])).clamp(-g, g);
                let limit = match rng.random_bool(self.restricted_share) {
                    true => round_to(
                        uniform(&mut rng, [self.min_speed_limit_km_h, line_speed]),
                        10.0,
                    )
                    .max(self.min_speed_limit_km_h),
                    false => line_speed,
                };
                left -= length;
                sections.push(RouteSection {
                    length_m: length,
                    gradient_permille: round_to(gradient, 0.5),
                    speed_limit_km_h: limit,
                    stop_s: match left <= 0.0 {
                        true => round_to(uniform(&mut rng, self.dwell_s), 5.0),
                        false => 0.0,
                    },
                });
            }
        }
        let engines = match rng.random_bool(self.isolated_engine_share) {
            true => 2,
            false => 3,
        };
        let railcar = RailcarParameters {
            mass_t: round_to(uniform(&mut rng, self.mass_t), 1.0),
            engines,
            coast_before_stop_m: round_to(uniform(&mut rng, self.coast_before_stop_m), 50.0),
            notch_interval_s: round_to(uniform(&mut rng, self.notch_interval_s), 0.5),
            service_brake_m_s2: round_to(uniform(&mut rng, self.service_brake_m_s2), 0.05),
            fuel_noise_cm3_s: round_to(uniform(&mut rng, self.fuel_noise_cm3_s), 0.05),
            speed_noise_m_s: round_to(uniform(&mut rng, self.speed_noise_m_s), 0.05),
            ..RailcarParameters::default()
        };
        // The estimator is told the sensor's noise (its data sheet's, an input like the grade).
        let monitor = FuelMonitorConfig {
            speed_noise_m_s: railcar.speed_noise_m_s,
            ..FuelMonitorConfig::railcar()
        };
        RailcarScenario {
            seed,
            round_trips: 2,
            initial_dwell_s: 60.0,
            railcar,
            sections,
            monitor,
        }
    }
}

/// `scenario` as a scenario file (`railmon analyze fuel --scenario FILE` replays it): the
/// estimator as `preset = "railcar"` (with its `speed_noise_m_s`) when it is that preset but
/// for the sensor's noise, else every setting.
pub fn scenario_toml(scenario: &RailcarScenario) -> Result<String, FuelError> {
    let invalid = |e: toml::ser::Error| FuelError::Scenario(e.to_string());
    let mut table = toml::Table::try_from(scenario).map_err(invalid)?;
    let noise = scenario.monitor.speed_noise_m_s;
    let preset = FuelMonitorConfig {
        speed_noise_m_s: noise,
        ..FuelMonitorConfig::railcar()
    };
    if scenario.monitor == preset {
        let mut monitor = toml::Table::new();
        monitor.insert("preset".into(), "railcar".into());
        if noise > 0.0 {
            monitor.insert("speed_noise_m_s".into(), noise.into());
        }
        table.insert("monitor".into(), monitor.into());
    }
    toml::to_string(&table).map_err(invalid)
}

/// The line of `seed` from the default envelope.
pub fn generated_line(seed: u64) -> RailcarScenario {
    LineEnvelope::default().line(seed)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_seed_gives_one_line_inside_the_envelope() {
        let e = LineEnvelope::default();
        for seed in 0..200 {
            let line = generated_line(seed);
            assert_eq!(line, generated_line(seed));
            line.validate().unwrap();
            let length: f64 = line.sections.iter().map(|s| s.length_m).sum();
            assert!(
                length <= e.max_line_m + 1.0 && length >= 700.0,
                "{seed}: {length}"
            );
            for s in &line.sections {
                assert!(s.gradient_permille.abs() <= 25.0, "{seed}: {s:?}");
                assert!(
                    (40.0..=160.0).contains(&s.speed_limit_km_h),
                    "{seed}: {s:?}"
                );
            }
            let stops = line.sections.iter().filter(|s| s.stop_s > 0.0).count();
            assert!((2..=6).contains(&stops), "{seed}: {stops} legs");
            let r = &line.railcar;
            assert!((165.0..=225.0).contains(&r.mass_t) && (2..=3).contains(&r.engines));
            assert!((0.0..=0.3 + 1e-9).contains(&r.speed_noise_m_s));
        }
        assert_ne!(generated_line(1), generated_line(2));
    }

    /// The draws cover the envelope: steep grades both ways, close and distant stations, an
    /// isolated engine, fast lines.
    #[test]
    fn many_seeds_reach_the_corners_of_the_envelope() {
        let lines: Vec<_> = (0..100).map(generated_line).collect();
        let sections = || lines.iter().flat_map(|l| l.sections.iter());
        assert!(sections().any(|s| s.gradient_permille >= 18.0));
        assert!(sections().any(|s| s.gradient_permille <= -18.0));
        assert!(sections().any(|s| s.speed_limit_km_h >= 150.0));
        assert!(sections().any(|s| s.speed_limit_km_h <= 50.0));
        assert!(lines.iter().any(|l| l.railcar.engines == 2));
        assert!(lines.iter().any(|l| l.railcar.speed_noise_m_s >= 0.25));
        let spacings: Vec<f64> = lines
            .iter()
            .flat_map(|l| {
                let mut out = Vec::new();
                let mut leg = 0.0;
                for s in &l.sections {
                    leg += s.length_m;
                    if s.stop_s > 0.0 {
                        out.push(leg);
                        leg = 0.0;
                    }
                }
                out
            })
            .collect();
        assert!(spacings.iter().any(|&d| d <= 1000.0));
        assert!(spacings.iter().any(|&d| d >= 12_000.0));
    }

    #[test]
    fn a_written_line_reads_back_as_the_same_scenario() {
        for seed in [3, 8] {
            let line = generated_line(seed);
            let text = scenario_toml(&line).unwrap();
            assert!(text.contains("preset = \"railcar\""), "{text}");
            assert_eq!(RailcarScenario::from_toml_str(&text).unwrap(), line);
        }
    }

    #[test]
    fn the_split_is_fixed_by_the_seed() {
        assert_eq!(Split::of(100), Split::Tuning);
        assert_eq!(Split::of(101), Split::HeldOut);
        assert_eq!(Split::parse("held-out"), Some(Split::HeldOut));
        assert_eq!(Split::parse("tuning"), Some(Split::Tuning));
        assert_eq!(Split::parse("other"), None);
    }
}
