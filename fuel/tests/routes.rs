//! The railcar simulator on generated lines (issue 25 item 2): a train that cannot stop at the
//! platform is a simulator bug.

use railmon_fuel::railcar::RouteSection;
use railmon_fuel::{generated_line, RailcarScenario, RailcarSimulator, RailcarTruth};

const G_M_S2: f64 = 9.81;

fn run(scenario: &RailcarScenario) -> Vec<RailcarTruth> {
    let mut sim = RailcarSimulator::new(scenario).unwrap();
    std::iter::from_fn(|| sim.step().map(|(_, t)| t)).collect()
}

/// Checks every station stop of a run: the train stands at every station of every leg, the
/// last second before it stands it moved at walking pace at most, and no second's speed change
/// exceeds what brakes, traction and the steepest grade can do.
fn check_stops(what: &str, scenario: &RailcarScenario) {
    let truth = run(scenario);
    let r = &scenario.railcar;
    let steepest = scenario
        .sections
        .iter()
        .map(|s| s.gradient_permille.abs())
        .fold(0.0, f64::max);
    let grade = G_M_S2 * steepest / 1000.0;
    let max_braking = 1.3 * r.service_brake_m_s2 + grade + 0.05;
    let max_traction = r.max_tractive_effort_kn / r.mass_t + grade;
    let legs =
        2 * scenario.round_trips * scenario.sections.iter().filter(|s| s.stop_s > 0.0).count();
    let mut stops = 0;
    for (t, w) in truth.windows(2).enumerate() {
        let dv = w[1].speed_m_s - w[0].speed_m_s;
        assert!(
            (-max_braking..=max_traction).contains(&dv),
            "{what}: {dv:.2} m/s in one second at t = {t} s (bounds -{max_braking:.2}, +{max_traction:.2})"
        );
        if w[0].speed_m_s > 0.0 && w[1].speed_m_s == 0.0 {
            assert!(
                w[0].speed_m_s <= 1.5,
                "{what}: reached the platform at {:.2} m/s at t = {t} s",
                w[0].speed_m_s
            );
            stops += 1;
        }
    }
    assert_eq!(stops, legs, "{what}: {stops} stops on {legs} legs");
}

/// The case of issue 25: a station at the foot of a 4 km descent at 20 per mille, reached at
/// 140 km/h. The driver braked for the kinematic deceleration only, gravity undid it, and the
/// train reached the platform at 6 m/s and stopped within a second.
#[test]
fn a_train_stops_at_a_station_at_the_foot_of_a_long_descent() {
    let section = |length_m: f64, gradient_permille: f64, stop_s: f64| RouteSection {
        length_m,
        gradient_permille,
        speed_limit_km_h: 140.0,
        stop_s,
    };
    let mut scenario = generated_line(1);
    scenario.railcar = Default::default();
    scenario.round_trips = 1;
    scenario.sections = vec![
        section(3000.0, 0.0, 0.0),
        section(4000.0, -20.0, 40.0),
        section(2000.0, 0.0, 40.0),
    ];
    check_stops("4 km at -20 per mille", &scenario);
}

/// Every stop of 40 generated lines, tuning and held-out seeds alike.
#[test]
fn every_station_stop_of_generated_lines_is_reached_at_low_speed() {
    for seed in 0..40 {
        check_stops(&format!("seed {seed}"), &generated_line(seed));
    }
}

/// Issue 25 item 4: with 0.3 m/s of speed-sensor noise, a monitor told the noise (the kinematic
/// filter) refuses no sample of two generated lines, and still refuses the speed read in km/h
/// (the acceleration bound widened by the noise, not dropped). Without the filter one sample
/// of each line is refused (seeds 28 and 57 were the two of seeds 0-59 where that happened).
#[test]
fn a_noisy_speed_is_not_refused_and_km_h_still_is() {
    use railmon_fuel::FuelMonitor;
    for seed in [28, 57] {
        let mut line = generated_line(seed);
        line.railcar.speed_noise_m_s = 0.3;
        line.monitor.speed_noise_m_s = 0.3;
        let mut sim = RailcarSimulator::new(&line).unwrap();
        let (mut ok, mut km_h) = (
            FuelMonitor::new(&line.monitor).unwrap(),
            FuelMonitor::new(&line.monitor).unwrap(),
        );
        let (mut n, mut refused_km_h) = (0, 0);
        while let Some((sample, _)) = sim.step() {
            n += 1;
            if let Err(e) = ok.update(&sample) {
                panic!("seed {seed}: refused at {} s: {e}", sample.time_s);
            }
            let mut wrong = sample;
            wrong.speed_m_s = sample.speed_m_s.map(|v| 3.6 * v);
            refused_km_h += usize::from(km_h.update(&wrong).is_err());
        }
        assert!(
            refused_km_h * 20 > n,
            "seed {seed}: {refused_km_h} of {n} km/h samples refused"
        );
    }
}

/// Issue 25 item 1: the railcar preset names each second's regime by what the train does
/// (`pointer_regimes`), so on lines it never saw the named regime is right on most seconds and
/// every label on most of its own. Two short held-out lines, one with a noisy speed sensor
/// (0.25 m/s, told to the estimator): measured 92.7 % and 87.5 % named, the weakest label
/// 65.5 % (cruising, seed 149). The published probability of the named regime says how sure
/// the rule is (the speed filter's spread of the acceleration against its thresholds): it
/// scores better than certainty would (Brier against being right), and with the noisy sensor
/// it is not certain on every second.
#[test]
fn regimes_are_named_by_physics_on_generated_lines() {
    use railmon_fuel::railcar::RAILCAR_REGIMES;
    use railmon_fuel::{FuelMonitor, RegimeName};
    for seed in [103, 149] {
        let mut line = generated_line(seed);
        line.monitor.speed_noise_m_s = line.railcar.speed_noise_m_s;
        let mut sim = RailcarSimulator::new(&line).unwrap();
        let mut monitor = FuelMonitor::new(&line.monitor).unwrap();
        let mut per_label = [(0usize, 0usize); 5];
        let (mut brier, mut unsure) = (0.0, 0);
        while let Some((sample, truth)) = sim.step() {
            let Some(m) = &monitor.update(&sample).unwrap().mixture else {
                continue;
            };
            let name = m.regime_names[m.active_regime].regime;
            let total: f64 = m.regime_probabilities.iter().sum();
            assert!((total - 1.0).abs() < 1e-9, "seed {seed}: {total}");
            let regime_probability: f64 = (0..m.regime_names.len())
                .filter(|&i| m.regime_names[i].regime == name)
                .map(|i| m.regime_probabilities[i])
                .sum();
            let label = RegimeName::parse(RAILCAR_REGIMES[truth.regime]).unwrap();
            let right = name == label;
            per_label[truth.regime].0 += usize::from(right);
            per_label[truth.regime].1 += 1;
            brier += (regime_probability - f64::from(u8::from(right))).powi(2);
            unsure += usize::from(regime_probability < 0.99);
        }
        let (right, n) = per_label
            .iter()
            .fold((0, 0), |(r, n), (a, b)| (r + a, n + b));
        let what = format!("seed {seed}: {per_label:?}, Brier {brier}, {unsure} unsure");
        assert!(right as f64 >= 0.75 * n as f64, "{what}");
        // Certainty's Brier score is the share of seconds named wrong.
        assert!(brier < 0.9 * (n - right) as f64, "{what}");
        assert!(line.railcar.speed_noise_m_s == 0.0 || unsure > 0, "{what}");
        for (right, n) in per_label.into_iter().filter(|(_, n)| *n >= 30) {
            assert!(right as f64 >= 0.6 * n as f64, "{what}");
        }
    }
}
