//! The acceleration bound of the vehicle stream (`ChannelRanges::acceleration_m_s2`) on every
//! vehicle input we ship: the three Camry files, the two railcar routes and the drive cycles of
//! `fuel-cycles.toml` (the demo's vehicle data). With the settings each is analysed with, no
//! sample is refused (a false refusal aborts `analyze fuel`); with the speed multiplied by 3.6
//! (km/h read as m/s) the tally says how much of each is refused and how early. The table in
//! docs/fuel.md ("Speed in the wrong unit") is printed by
//!   cargo test -p railmon-analyze --test fuel_acceleration -- --nocapture

use std::path::{Path, PathBuf};

use railmon_analyze::fuel::{load_recording, simulate_scenario, FuelInput};
use railmon_fuel::ChannelRanges;
use railmon_fuel::{Channel, FuelError, VehicleSample};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// What the monitor's speed checks make of a run: the speed's range, then its change since
/// the last accepted sample (a refused sample is never the reference, as in `FuelMonitor`).
#[derive(Debug, Default)]
struct Tally {
    samples: usize,
    range_refused: usize,
    acceleration_refused: usize,
    /// Seconds from the first sample to the first refusal of either kind.
    first_refusal_s: Option<f64>,
    /// Largest |acceleration| between accepted samples, m/s^2.
    max_abs_acceleration_m_s2: f64,
}

fn tally(samples: &[VehicleSample], ranges: &ChannelRanges, speed_factor: f64) -> Tally {
    let mut t = Tally {
        samples: samples.len(),
        ..Tally::default()
    };
    let mut previous: Option<(f64, f64)> = None;
    for s in samples {
        let scaled = VehicleSample {
            speed_m_s: s.speed_m_s.map(|v| v * speed_factor),
            ..*s
        };
        let checked = scaled.checked(Channel::Speed, ranges).and_then(|v| {
            let a = ranges.check_acceleration(previous, s.time_s, v)?;
            Ok((v, a))
        });
        match checked {
            Ok((v, a)) => {
                t.max_abs_acceleration_m_s2 = t.max_abs_acceleration_m_s2.max(a.abs());
                previous = Some((s.time_s, v));
            }
            Err(e) => {
                match e {
                    FuelError::OutOfRange { .. } => t.range_refused += 1,
                    FuelError::AccelerationOutOfRange { .. } => t.acceleration_refused += 1,
                    other => panic!("not a speed refusal: {other}"),
                }
                t.first_refusal_s
                    .get_or_insert(s.time_s - samples[0].time_s);
            }
        }
    }
    t
}

fn inputs() -> Vec<FuelInput> {
    let mut inputs: Vec<FuelInput> = ["61811011.csv", "61811013.csv", "61811014.csv"]
        .iter()
        .map(|f| load_recording(&root().join("data/anl-camry-2018").join(f)).unwrap())
        .collect();
    for scenario in ["fuel-railcar", "fuel-railcar-hilly", "fuel-cycles"] {
        let path = root().join(format!("config/scenarios/{scenario}.toml"));
        inputs.push(simulate_scenario(&path).unwrap().0);
    }
    inputs
}

#[test]
fn shipped_inputs_pass_and_their_speed_in_km_h_is_refused() {
    println!(
        "input,samples,max_abs_acceleration_m_s2,km_h_range_refused,km_h_acceleration_refused,\
         km_h_refused_share,km_h_first_refusal_s"
    );
    for input in inputs() {
        let ranges = &input.config.ranges;
        let good = tally(&input.samples, ranges, 1.0);
        let kmh = tally(&input.samples, ranges, 3.6);
        let refused = kmh.range_refused + kmh.acceleration_refused;
        println!(
            "{},{},{:.3},{},{},{:.4},{}",
            input.name,
            good.samples,
            good.max_abs_acceleration_m_s2,
            kmh.range_refused,
            kmh.acceleration_refused,
            refused as f64 / kmh.samples as f64,
            kmh.first_refusal_s.map_or("none".into(), |s| s.to_string()),
        );
        if *ranges == ChannelRanges::road_car() {
            // Tighter bounds than a car's grip, for the record (docs/fuel.md): what they
            // would catch of the km/h data.
            for bounds in [[-12.0, 10.0], [-10.0, 8.0]] {
                let tighter = ChannelRanges {
                    acceleration_m_s2: bounds,
                    ..ChannelRanges::road_car()
                };
                let t = tally(&input.samples, &tighter, 3.6);
                println!(
                    "  {} with acceleration {bounds:?}: {} refused by acceleration in km/h",
                    input.name, t.acceleration_refused
                );
            }
        }
        // No false refusal: every input we ship passes with the settings it is analysed with.
        assert_eq!(
            good.range_refused + good.acceleration_refused,
            0,
            "{}: {good:?}",
            input.name
        );
        // Every one of them in km/h is refused somewhere (range or acceleration).
        assert!(refused > 0, "{}: {kmh:?}", input.name);
        if input.config.ranges == ChannelRanges::railcar() {
            // A railcar in km/h: refused at its first departure (60 s of dwell), by the
            // acceleration bound, long before its speed leaves the range.
            assert!(
                kmh.first_refusal_s.is_some_and(|s| s < 90.0),
                "{}: {kmh:?}",
                input.name
            );
            assert!(kmh.acceleration_refused > 0, "{}: {kmh:?}", input.name);
        }
    }
}

/// The bound judges the speed's change since the last accepted sample: after a refused
/// sample or a gap the step is longer, and a good sample passes however long it is.
#[test]
fn a_gap_or_a_refused_sample_does_not_make_the_next_good_one_look_bad() {
    let ranges = ChannelRanges::road_car();
    // 20 m/s in one second: refused.
    let err = ranges
        .check_acceleration(Some((4.0, 10.0)), 5.0, 30.0)
        .unwrap_err();
    assert!(matches!(err, FuelError::AccelerationOutOfRange { .. }));
    assert_eq!(err.field(), Some(("speed_m_s", "30".to_string())));
    let msg = err.to_string();
    assert!(
        msg.contains("20.000 m/s^2") && msg.contains("[-12, 12]"),
        "{msg}"
    );
    // The next sample judged against the last accepted one (t = 4), over 2 s: 0 m/s^2.
    assert_eq!(
        ranges.check_acceleration(Some((4.0, 10.0)), 6.0, 10.0),
        Ok(0.0)
    );
    // The same 20 m/s over a 3 s gap: a mean of 6.7 m/s^2, as a car can.
    let a = ranges
        .check_acceleration(Some((4.0, 10.0)), 7.0, 30.0)
        .unwrap();
    assert!((a - 20.0 / 3.0).abs() < 1e-12, "{a}");
    // Braking is bounded too, and without a previous sample there is nothing to judge.
    assert!(ranges
        .check_acceleration(Some((4.0, 30.0)), 5.0, 17.0)
        .is_err());
    assert_eq!(ranges.check_acceleration(None, 5.0, 30.0), Ok(0.0));
}

/// The first sample of a source has no reference: a spike there makes the good samples after
/// it look implausible until the mean acceleration since it is inside the bounds again, at
/// most the speed range's width over the bound (docs/fuel.md): a railcar's spike of 60 m/s
/// over a standing train refuses 14 samples and the 15th (-4 m/s^2 on average) is accepted.
#[test]
fn a_spike_in_the_first_sample_costs_at_most_its_height_over_the_bound() {
    let samples: Vec<VehicleSample> = (0..40)
        .map(|t| VehicleSample {
            time_s: t as f64,
            speed_m_s: Some(if t == 0 { 60.0 } else { 0.0 }),
            ..VehicleSample::default()
        })
        .collect();
    let t = tally(&samples, &ChannelRanges::railcar(), 1.0);
    assert_eq!((t.acceleration_refused, t.range_refused), (14, 0), "{t:?}");
    assert_eq!(t.first_refusal_s, Some(1.0));
}
