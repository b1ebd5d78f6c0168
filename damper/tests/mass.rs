//! The measured body mass as the filters' input (issue 24 item 1): with it the estimate of a
//! loaded car is the truth's, without it biased; a reading out of range is refused.

use railmon_damper::*;

/// The seed scenario on a plant whose body is `mass_ratio` times the design mass, the
/// filter configured with the design vehicle.
fn loaded(mass_ratio: f64, duration_s: f64) -> DamperScenario {
    let text = std::fs::read_to_string(format!(
        "{}/../config/scenarios/damper-seed.toml",
        env!("CARGO_MANIFEST_DIR")
    ))
    .unwrap();
    let mut s = DamperScenario::from_toml_str(&text).unwrap();
    s.duration_s = duration_s;
    s.monitor.vehicle = s.vehicle;
    s.monitor_vehicle_given = true;
    s.vehicle.half_body_mass_kg *= mass_ratio;
    s
}

/// The monitor's estimate at the end of `s` (N = 300, seed 21), the samples carrying the mass
/// or not (`gives_mass`), the particles carrying their own when not (`mass_particles`:
/// `rbpf.unmeasured_mass.enabled`), and the filter's estimate of the mass (kg) if they did.
fn final_estimate(
    s: &DamperScenario,
    gives_mass: bool,
    mass_particles: bool,
) -> (DamperEstimate, BodyMass) {
    let mut c = s.monitor_config();
    c.rbpf.particles = 300;
    c.rbpf.unmeasured_mass.enabled = mass_particles;
    let mut m = DamperMonitor::new(&c, 21).unwrap();
    let mut sim = BogieSimulator::new(s).unwrap().with_mass_input(gives_mass);
    while let Some((y, _)) = sim.step() {
        assert_eq!(y.half_body_mass_kg.is_some(), gives_mass);
        m.step(y).unwrap();
    }
    (*m.estimate(), m.body_mass())
}

/// The final `C_sy` and `C_say` posterior means over the truth, minus 1.
fn final_errors(s: &DamperScenario, gives_mass: bool, mass_particles: bool) -> [f64; 2] {
    let (e, _) = final_estimate(s, gives_mass, mass_particles);
    [
        e.csy.mean_ns_per_m / s.dampers.csy_ns_per_m - 1.0,
        e.csay.mean_ns_per_m / s.dampers.csay_ns_per_m - 1.0,
    ]
}

/// The body 30 % heavier than designed (a crowded car), 20 s at 45.3 m/s. Measured
/// (`cargo test --release -p railmon-damper --test mass -- --nocapture`, 28 Nov): given the
/// mass, `C_sy` reads -0.06 % and `C_say` -2.5 %; withheld with the design mass assumed,
/// `C_sy` reads -14.3 % (27 Nov, before later changes to the filter: -56.8 %; with the body
/// 15 % heavier -5.7 % after 20 s, the 5.3-5.6 %): the filter explains the heavier
/// body's slower sway by a weaker lateral damper. Bounds: `C_sy` 2 % given (+0.2 % after 60 s), `C_say` 4 % (the seed scenario's own
/// wander: -5.7 % after 60 s at the design mass, mass or not); withheld below -5 % (the test
/// fails if the input stops mattering).
#[test]
fn a_loaded_car_reads_its_dampers_right_given_its_mass() {
    let s = loaded(1.3, 20.0);
    let given = final_errors(&s, true, true);
    let withheld = final_errors(&s, false, false);
    eprintln!("given {given:?}, withheld (design mass) {withheld:?}");
    assert!(given[0].abs() < 0.02, "C_sy given the mass: {given:?}");
    assert!(given[1].abs() < 0.04, "C_say given the mass: {given:?}");
    assert!(withheld[0] < -0.05, "C_sy without the mass: {withheld:?}");
}

/// The same crowded car (1.3x) without a load signal, the particles carrying the mass
/// (`rbpf.unmeasured_mass`, the default): the filter must not be confidently wrong. Either
/// the published 90 % interval of each damper holds the truth, or the filter says its model
/// does not explain the data (`model_mismatch`). Fails with the design mass assumed (above:
/// `C_sy` -14.3 %, an interval a few percent wide). Measured: the mass read 16,823 kg of
/// 16,900, `C_sy` 15,988 [15,764, 16,245] of 16,000, `C_say` 157,188 [151,461, 163,524] of
/// 160,000, no mismatch.
#[test]
fn a_loaded_car_without_its_mass_is_not_read_as_a_weaker_damper() {
    let s = loaded(1.3, 20.0);
    let (e, mass) = final_estimate(&s, false, true);
    // Published as the particles' estimate (API `mass_source`, `estimates.csv`).
    assert_eq!(mass.source, MassSource::Estimated);
    let truth = [s.dampers.csy_ns_per_m, s.dampers.csay_ns_per_m];
    let covered = [e.csy, e.csay]
        .iter()
        .zip(truth)
        .map(|(p, t)| (p.q05_ns_per_m..=p.q95_ns_per_m).contains(&t))
        .collect::<Vec<_>>();
    eprintln!(
        "mass read {:.0} of {} kg; C_sy {:.0} [{:.0}, {:.0}] truth {:.0}; C_say {:.0} [{:.0}, {:.0}] truth {:.0}; mismatch {}",
        mass.half_body_mass_kg,
        s.vehicle.half_body_mass_kg,
        e.csy.mean_ns_per_m,
        e.csy.q05_ns_per_m,
        e.csy.q95_ns_per_m,
        truth[0],
        e.csay.mean_ns_per_m,
        e.csay.q05_ns_per_m,
        e.csay.q95_ns_per_m,
        truth[1],
        e.model_mismatch
    );
    assert!(
        e.model_mismatch || covered.iter().all(|c| *c),
        "covered {covered:?}, no mismatch reported"
    );
}

/// A mass outside 0.7-1.6 times the design value (a broken load signal) is refused by name
/// and value, the monitor unchanged; with `rbpf.unmeasured_mass` off a sample without a mass
/// is the design mass's, bit for bit.
#[test]
fn a_mass_out_of_range_is_refused_and_none_is_the_design_mass() {
    let s = loaded(1.0, 0.3);
    let mut c = s.monitor_config();
    c.rbpf.particles = 20;
    c.rbpf.unmeasured_mass.enabled = false;
    let design = c.vehicle.half_body_mass_kg;
    let data: Vec<BogieSample> = {
        let mut sim = BogieSimulator::new(&s).unwrap().with_mass_input(false);
        std::iter::from_fn(|| sim.step().map(|(y, _)| *y)).collect()
    };
    let mut none = DamperMonitor::new(&c, 3).unwrap();
    let mut hit = none.clone();
    for (k, y) in data.iter().enumerate() {
        if k == 100 {
            for bad in [0.5 * design, 1.7 * design, 0.0, f64::NAN] {
                let sample = BogieSample {
                    half_body_mass_kg: Some(bad),
                    ..*y
                };
                match hit.step(&sample) {
                    Err(e @ DamperError::InvalidSample { field, .. }) => {
                        assert_eq!(field, "half_body_mass_kg");
                        assert!(e.to_string().contains("half_body_mass_kg"), "{e}");
                    }
                    other => panic!("{bad}: {other:?}"),
                }
            }
        }
        let with_design = BogieSample {
            half_body_mass_kg: Some(design),
            ..*y
        };
        let a = *none.step(y).unwrap();
        let mut b = *hit.step(&with_design).unwrap();
        // The estimate says which mass the filters took; the rest is the same to the bit.
        assert_eq!(
            (a.measured_half_body_mass_kg, b.measured_half_body_mass_kg),
            (None, Some(design)),
            "step {k}"
        );
        b.measured_half_body_mass_kg = None;
        assert_eq!(a, b, "step {k}");
    }
}

/// Without a load signal the particles' masses are part of the saved state: a resumed monitor
/// goes on exactly as the one that saved it (mass estimate included).
#[test]
fn a_resumed_monitor_keeps_the_particles_masses() {
    let s = loaded(1.3, 6.0);
    let mut c = s.monitor_config();
    c.rbpf.particles = 100;
    let mut sim = BogieSimulator::new(&s).unwrap().with_mass_input(false);
    let samples: Vec<BogieSample> = std::iter::from_fn(|| sim.step().map(|(y, _)| *y)).collect();
    let (before, after) = samples.split_at(5_000);
    let mut running = DamperMonitor::new(&c, 4).unwrap();
    for y in before {
        running.step(y).unwrap();
    }
    assert!(running.rbpf().estimated_half_body_mass_kg().is_some());
    let bytes = bincode::serialize(&running.state()).unwrap();
    let mut resumed =
        DamperMonitor::resume(&c, None, bincode::deserialize(&bytes).unwrap()).unwrap();
    for y in after {
        assert_eq!(*running.step(y).unwrap(), *resumed.step(y).unwrap());
    }
    assert_eq!(
        running.rbpf().estimated_half_body_mass_kg(),
        resumed.rbpf().estimated_half_body_mass_kg()
    );
}
