//! The RBPF and the per-particle Kalman filters against independent implementations, and
//! the invariants that must hold on seeded simulations.

use nalgebra::{Matrix2, SMatrix};
use railmon_damper::kalman::initial_covariance;
use railmon_damper::kalman::{self, StateEstimate};
use railmon_damper::model::{BogieModel, Matrix17, Matrix5, Matrix5x17, Vector17, Vector5};
use railmon_damper::*;
use railmon_filter::kalman::is_symmetric_positive_definite;

fn scenario(name: &str, duration_s: f64) -> DamperScenario {
    let text = std::fs::read_to_string(format!(
        "{}/../config/scenarios/{name}.toml",
        env!("CARGO_MANIFEST_DIR")
    ))
    .unwrap();
    let mut s = DamperScenario::from_toml_str(&text).unwrap();
    s.duration_s = duration_s;
    s
}

fn samples(s: &DamperScenario) -> Vec<(BogieSample, BogieTruth)> {
    let mut sim = BogieSimulator::new(s).unwrap();
    let mut out = vec![];
    while let Some((y, t)) = sim.step() {
        out.push((*y, *t));
    }
    out
}

/// Parameters known: every particle at the truth, no kernel, no regeneration; the sensor
/// noise known too (no noise-scale estimate), as the textbook filter assumes.
fn known_parameter_config(s: &DamperScenario, propagation: Propagation) -> DamperMonitorConfig {
    let mut c = s.monitor_config();
    c.rbpf.noise_scale.enabled = false;
    c.rbpf.particles = 3;
    c.rbpf.prior_ln_std = 0.0;
    c.rbpf.ln_diffusion_per_sqrt_s = 0.0;
    c.rbpf.regeneration_fraction = 0.0;
    c.rbpf.jump_search.enabled = false;
    c.rbpf.kernel = KernelSchedule::EveryStep;
    c.rbpf.propagation = propagation;
    c
}

/// A textbook Kalman filter written independently of the crate's: `Phi`, `Gamma` from a long
/// Taylor series of the augmented matrix (not Padé), gain by explicit inverse, covariance by
/// the short form `(I - K H) P`, log-density by the determinant.
struct TextbookKf {
    phi: Matrix17,
    gamma: SMatrix<f64, 17, 2>,
    q_w: Matrix2<f64>,
    q_floor: f64,
    h: Matrix5x17,
    r: Matrix5,
    x: Vector17,
    p: Matrix17,
}

impl TextbookKf {
    fn new(model: &BogieModel, d: &Dampers, c: &DamperMonitorConfig, p0: Matrix17) -> Self {
        let a = model.a_matrix(d) * c.dt_s;
        let g = model.g_matrix() * c.dt_s;
        // Phi = sum (A T)^k / k!, Gamma = sum (A T)^k / (k+1)! G T.
        let mut phi = Matrix17::zeros();
        let mut int = Matrix17::zeros();
        let mut term = Matrix17::identity();
        for k in 0..40 {
            phi += term;
            int += term / (k + 1) as f64;
            term = term * a / (k + 1) as f64;
        }
        let noise = c.noise();
        TextbookKf {
            phi,
            gamma: int * g,
            q_w: noise.q_w,
            q_floor: noise.q_floor,
            h: model.h_matrix(),
            r: noise.q_v,
            x: Vector17::zeros(),
            p: p0,
        }
    }

    fn step(&mut self, y: &Vector5) -> f64 {
        self.x = self.phi * self.x;
        self.p = self.phi * self.p * self.phi.transpose()
            + self.gamma * self.q_w * self.gamma.transpose()
            + Matrix17::identity() * self.q_floor;
        let s = self.h * self.p * self.h.transpose() + self.r;
        let s_inv = s.try_inverse().unwrap();
        let e = y - self.h * self.x;
        let k = self.p * self.h.transpose() * s_inv;
        self.x += k * e;
        self.p = (Matrix17::identity() - k * self.h) * self.p;
        self.p = (self.p + self.p.transpose()) * 0.5;
        -0.5 * (5.0 * (2.0 * std::f64::consts::PI).ln()
            + s.determinant().ln()
            + (e.transpose() * s_inv * e)[0])
    }
}

#[test]
fn rbpf_equals_a_plain_kalman_filter_when_the_parameters_are_known() {
    let s = scenario("damper-seed", 2.0);
    let c = known_parameter_config(&s, Propagation::Exact);
    let mut rbpf = Rbpf::new(&c.filter_model(), &c.rbpf, &c.speed).unwrap();
    let model = BogieModel::new(&c.vehicle, c.drift_leak_per_s).unwrap();
    let mut kf = TextbookKf::new(&model, &c.nominal, &c, initial_covariance());
    let mut total = 0.0;
    for (y, _) in samples(&s) {
        rbpf.step(&y.to_vector()).unwrap();
        total += kf.step(&y.to_vector());
    }
    let (_, log_w, x, p) = rbpf.particle(1);
    // Uniform up to the roundoff of 2000 normalisations.
    assert!(
        (log_w + 3f64.ln()).abs() < 1e-9,
        "weights stay uniform: {log_w}"
    );
    let p = p.unwrap();
    assert!(
        (x - kf.x).amax() <= 1e-9 * kf.x.amax(),
        "{}",
        (x - kf.x).amax()
    );
    assert!(
        (p - kf.p).amax() <= 1e-8 * kf.p.amax(),
        "{}",
        (p - kf.p).amax()
    );
    let rel = (rbpf.log_evidence() - total).abs() / total.abs();
    assert!(
        rel < 1e-10,
        "log-evidence {} vs {total}",
        rbpf.log_evidence()
    );
    let e = rbpf.estimate();
    assert!((e.csy.mean_ns_per_m - 16e3).abs() < 1e-9);
    assert_eq!(e.csay.q05_ns_per_m, e.csay.q95_ns_per_m);
}

/// The fast filter with the parameters on a gain-grid node is the textbook filter started
/// at the Riccati steady state (which it then never leaves).
#[test]
fn steady_state_rbpf_equals_a_kalman_filter_at_steady_state() {
    let s = scenario("damper-seed", 2.0);
    let mut c = known_parameter_config(&s, Propagation::SteadyState);
    c.rbpf.gain_grid = GainGridConfig {
        points_per_axis: 3,
        min_ratio: 0.5,
        max_ratio: 2.0,
    };
    // The Taylor series to 1e-9 whatever the default (at 1e-4 the states are 1.8e-5 apart
    // after 2 s, an error `benches/accuracy.rs` measures in the likelihood): what this
    // compares is the steady-state gain against the textbook filter's.
    c.rbpf.taylor_truncation = 1e-9;
    let mut rbpf = Rbpf::new(&c.filter_model(), &c.rbpf, &c.speed).unwrap();
    let model = BogieModel::new(&c.vehicle, c.drift_leak_per_s).unwrap();
    let disc = expm::discretize(&model.a_matrix(&c.nominal), &model.g_matrix(), c.dt_s).unwrap();
    let ss = kalman::steady_state(&disc, &model.h_matrix(), &c.noise()).unwrap();
    // The textbook filter holds the posterior covariance: P+ = (I - K H) P-, so that its
    // first predict gives P- again.
    let p_post = (Matrix17::identity() - ss.gain * model.h_matrix()) * ss.p_pred;
    let mut kf = TextbookKf::new(&model, &c.nominal, &c, p_post);
    let mut total = 0.0;
    for (y, _) in samples(&s) {
        rbpf.step(&y.to_vector()).unwrap();
        total += kf.step(&y.to_vector());
    }
    let (_, _, x, _) = rbpf.particle(0);
    assert!(
        (x - kf.x).amax() <= 1e-7 * kf.x.amax(),
        "{}",
        (x - kf.x).amax() / kf.x.amax()
    );
    let rel = (rbpf.log_evidence() - total).abs() / total.abs();
    assert!(
        rel < 1e-9,
        "log-evidence {} vs {total}",
        rbpf.log_evidence()
    );
}

/// Model docs: the drift leak makes the track position mean-reverting and changes nothing
/// the sensors see. The exact filter's per-step log-likelihoods agree for two leaks, while
/// without a leak the covariance along the drift grows without bound.
#[test]
fn drift_leak_changes_nothing_observable_and_bounds_the_covariance() {
    let s = scenario("damper-seed", 20.0);
    let c = s.monitor_config();
    let noise = c.noise();
    let data = samples(&s);
    let run = |leak: f64| {
        let model = BogieModel::new(&c.vehicle, leak).unwrap();
        let disc =
            expm::discretize(&model.a_matrix(&c.nominal), &model.g_matrix(), c.dt_s).unwrap();
        let h = model.h_matrix();
        let mut est = StateEstimate {
            x: Vector17::zeros(),
            p: initial_covariance(),
        };
        let mut lls = vec![];
        let mut drift_var = vec![];
        let w = model::track_position_rows();
        for (y, _) in &data {
            est = kalman::predict(&est, &disc, &noise);
            let (post, ll) = kalman::update(&est, &y.to_vector(), &h, &noise.q_v).unwrap();
            est = post;
            assert!(is_symmetric_positive_definite(&est.p, 1e-12));
            lls.push(ll);
            drift_var.push((w * est.p * w.transpose())[(0, 0)]);
        }
        (lls, drift_var)
    };
    let (ll_a, var_a) = run(0.05);
    let (ll_b, var_b) = run(0.5);
    let (ll_0, var_0) = run(0.0);
    let max_diff = |x: &[f64], y: &[f64]| {
        x.iter()
            .zip(y)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max)
    };
    // Equal in exact arithmetic; measured 4e-7 per step (of ~13) from the roundoff of a
    // covariance that spans 1e-16..1e-3.
    assert!(max_diff(&ll_a, &ll_b) < 2e-6, "{}", max_diff(&ll_a, &ll_b));
    let total = |v: &[f64]| v.iter().sum::<f64>();
    assert!((total(&ll_a) - total(&ll_b)).abs() < 1e-8 * total(&ll_a).abs());
    // Without the leak the same holds over the first seconds, but the track-position
    // variance grows linearly for ever (the sensors see part of each track increment, so
    // the slope is below Q_w T^2 per step, but it does not bend).
    assert!(max_diff(&ll_a[..5000], &ll_0[..5000]) < 2e-6);
    let n = var_0.len();
    let slope = |from: usize, to: usize| (var_0[to] - var_0[from]) / (to - from) as f64;
    let (early, late) = (slope(5000, 10000), slope(15000, n - 1));
    let q_step = c.track_velocity_std_m_s.powi(2) * c.dt_s * c.dt_s;
    assert!(
        early > 0.1 * q_step && early <= q_step,
        "{early} vs {q_step}"
    );
    assert!((late / early - 1.0).abs() < 0.05, "{early} {late}");
    // With it, bounded by the prior's stationary variance of the OU track position,
    // q / (2 eps) with q = Q_w T^2 / T.
    for (var, eps) in [(&var_a, 0.05), (&var_b, 0.5)] {
        let bound = q_step / (2.0 * eps * c.dt_s);
        assert!(var[n - 1] < bound, "{} vs {bound}", var[n - 1]);
    }
    assert!(var_a[n - 1] < var_0[n - 1]);
}

#[test]
fn exact_rbpf_and_ekf_covariances_stay_symmetric_positive_definite() {
    let s = scenario("damper-fault", 3.0);
    let mut c = s.monitor_config();
    c.rbpf.particles = 4;
    c.rbpf.propagation = Propagation::Exact;
    c.rbpf.kernel = KernelSchedule::EveryStep;
    c.rbpf.jump_search.enabled = false;
    c.ekf.enabled = true;
    let mut m = DamperMonitor::new(&c, 5).unwrap();
    for (k, (y, _)) in samples(&s).iter().enumerate() {
        m.step(y).unwrap();
        if k % 50 == 0 {
            for i in 0..4 {
                let p = m.rbpf().particle(i).3.unwrap();
                assert!(
                    is_symmetric_positive_definite(&p, 1e-12),
                    "particle {i} step {k}"
                );
            }
            let p = m.ekf().unwrap().covariance();
            assert!(is_symmetric_positive_definite(p, 1e-12), "EKF step {k}");
        }
    }
}

#[test]
fn rbpf_converges_on_a_short_seeded_scenario() {
    let s = scenario("damper-seed", 10.0);
    let mut c = s.monitor_config();
    c.rbpf.particles = 300;
    let mut m = DamperMonitor::new(&c, 21).unwrap();
    let data = samples(&s);
    for (y, _) in &data {
        m.step(y).unwrap();
    }
    let e = m.estimate();
    for (name, post, truth) in [("csy", e.csy, 16e3), ("csay", e.csay, 160e3)] {
        let err = post.mean_ns_per_m / truth - 1.0;
        // After 10 s the exact likelihood has standard deviations of about 0.3% (C_sy) and
        // 1.5% (C_say): 4% is wide for both, yet far inside the prior's 50%.
        assert!(err.abs() < 0.04, "{name}: relative error {err}");
        assert!(post.covers(truth), "{name}: {post:?}");
        assert!(
            post.q95_ns_per_m / post.q05_ns_per_m < 1.15,
            "{name} has narrowed"
        );
    }
    assert!(e.effective_sample_size > 1.0 && e.effective_sample_size <= 300.0);
}

#[test]
fn same_seed_same_estimates_other_seed_other_particles() {
    let s = scenario("damper-seed", 0.5);
    let mut c = s.monitor_config();
    c.rbpf.particles = 50;
    let table = Rbpf::gain_table(&c.filter_model(), &c.rbpf, &c.speed).unwrap();
    let run = |seed: u64| {
        let mut m = DamperMonitor::with_gain_table(&c, seed, Some(table.clone())).unwrap();
        samples(&s)
            .iter()
            .map(|(y, _)| *m.step(y).unwrap())
            .collect::<Vec<_>>()
    };
    let a = run(1);
    assert_eq!(a, run(1));
    assert_ne!(a, run(2));
}

#[test]
fn a_nan_sample_is_rejected_and_leaves_the_monitor_untouched() {
    let s = scenario("damper-seed", 0.3);
    let mut c = s.monitor_config();
    c.rbpf.particles = 20;
    let data = samples(&s);
    let mut clean = DamperMonitor::new(&c, 3).unwrap();
    let mut hit = clean.clone();
    for (k, (y, _)) in data.iter().enumerate() {
        if k == 100 {
            let bad = BogieSample {
                body_accel_m_s2: f64::INFINITY,
                ..*y
            };
            match hit.step(&bad) {
                Err(DamperError::InvalidSample { field, .. }) => {
                    assert_eq!(field, "body_accel_m_s2")
                }
                other => panic!("{other:?}"),
            }
        }
        let a = *clean.step(y).unwrap();
        let b = *hit.step(y).unwrap();
        assert_eq!(a, b, "step {k}");
    }
}

/// The innovation variances of the steady-state filter of `config` (gain built for its noise)
/// when the sensors' true noise is `true_sensors`: `S' = H P' H' + R'` with `P'` the predicted
/// error covariance of that (suboptimal) filter, the fixed point of
/// `P' = F P' F' + Phi K R' K' Phi' + Q`, `F = Phi (I - K H)`, solved by doubling. Divided by
/// the filter's own `S_ii`: what the noise-scale estimate must converge to.
fn innovation_variance_ratio(config: &DamperMonitorConfig, true_sensors: &SensorNoise) -> Vector5 {
    let model = BogieModel::new(&config.vehicle, config.drift_leak_per_s).unwrap();
    let h = model.h_matrix();
    let noise = config.noise();
    let disc = expm::discretize(
        &model.a_matrix(&config.nominal),
        &model.g_matrix(),
        config.dt_s,
    )
    .unwrap();
    let ss = kalman::steady_state(&disc, &h, &noise).unwrap();
    let r_true = true_sensors.covariance();
    let mut f = disc.phi * (Matrix17::identity() - ss.gain * h);
    let mut p = disc.phi * ss.gain * r_true * ss.gain.transpose() * disc.phi.transpose()
        + noise.process(&disc.gamma);
    for _ in 0..40 {
        p += f * p * f.transpose();
        f *= f;
    }
    let s_true = h * p * h.transpose() + r_true;
    let s_filter = ss.s_inv.try_inverse().unwrap();
    Vector5::from_fn(|i, _| s_true[(i, i)] / s_filter[(i, i)])
}

/// Issue 9 item 2: the RBPF's noise-scale estimate converges to the innovation variance of
/// its own filter under the true noise (analytic, above), for sensors at 2x and at 1x the
/// configured noise; at 1x it does not drift from 1.
#[test]
fn noise_scale_estimate_matches_the_analytic_innovation_variance() {
    for k in [2.0, 1.0] {
        let mut s = scenario("damper-seed", 30.0);
        s.sensors.accel_std_m_s2 *= k;
        s.sensors.gyro_std_rad_s *= k;
        let mut c = DamperScenario::from_toml_str(
            &std::fs::read_to_string(format!(
                "{}/../config/scenarios/damper-seed.toml",
                env!("CARGO_MANIFEST_DIR")
            ))
            .unwrap(),
        )
        .unwrap()
        .monitor_config();
        c.rbpf.particles = 200;
        let expected = innovation_variance_ratio(&c, &s.sensors);
        let mut rbpf = Rbpf::new(&c.filter_model(), &c.rbpf, &c.speed).unwrap();
        for (y, _) in samples(&s) {
            rbpf.step(&y.to_vector()).unwrap();
        }
        let got = Vector5::from(rbpf.noise_std_ratio().map(|r| r * r));
        for i in 0..5 {
            assert!(
                (got[i] / expected[i] - 1.0).abs() < 0.05,
                "noise {k}x, channel {i}: estimated {got}, analytic {expected}"
            );
        }
        if k == 1.0 {
            assert!((expected.add_scalar(-1.0)).amax() < 1e-8, "{expected}");
        }
    }
}

/// The jump search's sentinels carry the Shiryaev-Roberts posterior odds of a jump,
/// `Q_k = (Q_{k-1} + lambda dt) p_j(y_k) / p_mix(y_k)`: recomputed here from independent
/// known-parameter filters, one at each sentinel's coefficients, and the mixture's own
/// evidence (every particle at nominal, so no resampling and no move: the sentinels stay put).
#[test]
fn jump_odds_are_the_shiryaev_roberts_statistic_of_independent_filters() {
    let s = scenario("damper-seed", 0.3);
    let mut c = known_parameter_config(&s, Propagation::SteadyState);
    c.rbpf.kernel = KernelSchedule::AtResampling;
    c.rbpf.jump_search.enabled = true;
    c.rbpf.jump_search.materialise_odds = 1e300;
    let table = Rbpf::gain_table(&c.filter_model(), &c.rbpf, &c.speed).unwrap();
    let mut mixture =
        Rbpf::with_gain_table(&c.filter_model(), &c.rbpf, &c.speed, Some(table.clone())).unwrap();
    let sentinels = mixture.jump_sentinels().unwrap().to_vec();
    assert_eq!(sentinels.len(), N_SENTINELS);
    let mut singles: Vec<Rbpf> = sentinels
        .iter()
        .map(|th| {
            let mut cj = c;
            cj.rbpf.jump_search.enabled = false;
            cj.nominal = Dampers::from_ln(*th);
            Rbpf::with_gain_table(&cj.filter_model(), &cj.rbpf, &cj.speed, Some(table.clone()))
                .unwrap()
        })
        .collect();
    let ln_hazard_step = (c.rbpf.jump_search.hazard_per_s * c.dt_s).ln();
    let mut q = vec![f64::NEG_INFINITY; N_SENTINELS];
    for (y, _) in samples(&s) {
        let y = y.to_vector();
        let mix_before = mixture.log_evidence();
        mixture.step(&y).unwrap();
        let ll_mix = mixture.log_evidence() - mix_before;
        for (qj, f) in q.iter_mut().zip(singles.iter_mut()) {
            let before = f.log_evidence();
            f.step(&y).unwrap();
            let ll_j = f.log_evidence() - before;
            let prior = if *qj == f64::NEG_INFINITY {
                ln_hazard_step
            } else {
                (qj.exp() + ln_hazard_step.exp()).ln()
            };
            *qj = prior + ll_j - ll_mix;
        }
        for (got, want) in mixture.jump_ln_odds().unwrap().iter().zip(&q) {
            assert!((got - want).abs() < 1e-6, "{got} against {want}");
        }
    }
    assert_eq!(mixture.jump_sentinels().unwrap(), &sentinels[..]);
    assert_eq!(mixture.jump_count(), 0);
}
