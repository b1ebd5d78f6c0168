//! One simulated hour at 1 kHz (3.6 M steps): the estimates stay finite and bounded, every
//! covariance stays symmetric positive definite (the model's unobservable drift is leaked,
//! see `model` docs), and memory stays flat.

use railmon_damper::kalman::initial_covariance;
use railmon_damper::kalman::{self, StateEstimate};
use railmon_damper::model::{track_position_rows, BogieModel, Vector17};
use railmon_damper::*;
use railmon_filter::kalman::is_symmetric_positive_definite;

/// Resident set size in kB (Linux).
fn rss_kb() -> Option<u64> {
    let statm = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: u64 = statm.split_whitespace().nth(1)?.parse().ok()?;
    Some(pages * 4)
}

#[test]
#[ignore = "3.6 M steps with N = 1000, about 15 min in release: \
            cargo test --release -p railmon-damper --test long_run -- --ignored --nocapture"]
fn one_hour_stays_finite_bounded_and_flat() {
    let text = include_str!("../../config/scenarios/damper-seed.toml");
    let mut scenario = DamperScenario::from_toml_str(text).unwrap();
    scenario.duration_s = 3600.0;
    let config = scenario.monitor_config();
    let mut rbpf = Rbpf::new(&config.filter_model(), &config.rbpf, &config.speed).unwrap();
    let mut ekf = Some(AugmentedEkf::new(&config.filter_model(), &config.ekf).unwrap());
    // The exact filter of the true parameters alongside: its covariance is the one that
    // would grow along the drift without the leak.
    let model = BogieModel::new(&config.vehicle, config.drift_leak_per_s).unwrap();
    let disc = expm::discretize(
        &model.a_matrix(&config.nominal),
        &model.g_matrix(),
        config.dt_s,
    )
    .unwrap();
    let noise = config.noise();
    let h = model.h_matrix();
    let w = track_position_rows();
    let mut kf = StateEstimate {
        x: Vector17::zeros(),
        p: initial_covariance(),
    };
    let mut sim = BogieSimulator::new(&scenario).unwrap();
    let mut rss_after_warm_up = None;
    let mut max_track_var: f64 = 0.0;
    let mut k = 0u64;
    while let Some((y, _)) = sim.step() {
        let y = y.to_vector();
        rbpf.step(&y).unwrap();
        if let Some(e) = ekf.as_mut() {
            if e.step(&y).is_err() {
                eprintln!("EKF diverged at {} s", k as f64 * config.dt_s);
                ekf = None;
            }
        }
        kf = kalman::predict(&kf, &disc, &noise);
        kf = kalman::update(&kf, &y, &h, &noise.q_v).unwrap().0;
        k += 1;
        if k.is_multiple_of(60_000) {
            let e = rbpf.estimate();
            for post in [e.csy, e.csay] {
                assert!(post.mean_ns_per_m.is_finite());
                assert!((0.8..1.25).contains(&post.health_ratio), "{k}: {e:?}");
                assert!(post.q05_ns_per_m <= post.q95_ns_per_m);
            }
            assert!(is_symmetric_positive_definite(&kf.p, 1e-12), "step {k}");
            if let Some(e) = &ekf {
                assert!(
                    is_symmetric_positive_definite(e.covariance(), 1e-12),
                    "EKF {k}"
                );
            }
            let track_var = (w * kf.p * w.transpose())[(0, 0)];
            max_track_var = max_track_var.max(track_var);
            if k == 60_000 {
                rss_after_warm_up = rss_kb();
            }
            eprintln!(
                "{:>5.0} s: C_sy {:.4} C_say {:.4} ESS {:.0} track var {:.3e} rss {:?} kB",
                k as f64 * config.dt_s,
                e.csy.health_ratio,
                e.csay.health_ratio,
                e.effective_sample_size,
                track_var,
                rss_kb()
            );
        }
    }
    assert_eq!(k, 3_600_000);
    // Bounded by the stationary variance of the leaked (OU) track position.
    let q_step = config.track_velocity_std_m_s.powi(2) * config.dt_s.powi(2);
    assert!(max_track_var < q_step / (2.0 * config.drift_leak_per_s * config.dt_s));
    if let (Some(before), Some(after)) = (rss_after_warm_up, rss_kb()) {
        assert!(
            after <= before + 1024,
            "memory grew from {before} kB to {after} kB"
        );
    }
}
