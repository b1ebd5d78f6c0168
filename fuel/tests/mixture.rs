//! The mixture's statistics against independent computations.

use nalgebra::{DMatrix, DVector};
use railmon_fuel::{CountTable, Mixture, MixtureInput, MixtureSpec, RegressionStats};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

fn spec(components: usize, k_y: usize, k_psi: usize) -> MixtureSpec {
    MixtureSpec {
        components,
        k_y,
        k_psi,
        categories: 0,
        categorical_rows: 1,
        switching_rows: 1,
        forgetting: 1.0,
        parameter_uncertainty: true,
        prior_information: 1e-3,
        prior_kappa: 1.0,
        min_noise_variance: 1e-12,
        dirichlet_prior: 1.0,
        switching_prior_stay: 2.0,
        switching_prior_move: 1.0,
        level_channels: Vec::new(),
        level_min_variance: 0.0,
        standing_level_channels: None,
    }
}

/// `y = theta' psi + e` with `k_y = 2`, `psi = [x1, x2, 1]`, correlated noise.
fn regression_data(n: usize, seed: u64) -> (Vec<DVector<f64>>, Vec<DVector<f64>>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let normal = Normal::new(0.0, 1.0).unwrap();
    let theta = DMatrix::from_row_slice(3, 2, &[0.8, -0.3, 0.2, 1.5, 2.0, -1.0]);
    let (mut ys, mut psis) = (Vec::new(), Vec::new());
    for _ in 0..n {
        let psi = DVector::from_vec(vec![
            rng.random_range(-2.0..2.0),
            rng.random_range(0.0..5.0),
            1.0,
        ]);
        let e1 = 0.3 * normal.sample(&mut rng);
        let e2 = 0.5 * e1 + 0.2 * normal.sample(&mut rng);
        ys.push(theta.tr_mul(&psi) + DVector::from_vec(vec![e1, e2]));
        psis.push(psi);
    }
    (ys, psis)
}

#[test]
fn regression_statistics_match_a_batch_least_squares_fit() {
    let (ys, psis) = regression_data(500, 1);
    let eps = 1e-3;
    let mut stats = RegressionStats::new(2, DMatrix::identity(5, 5) * eps, 1.0, 1e-12).unwrap();
    for (y, psi) in ys.iter().zip(&psis) {
        let d = DVector::from_iterator(5, y.iter().chain(psi.iter()).copied());
        stats.update(&d, 1.0, None).unwrap();
    }
    // Batch ridge least squares by SVD of the stacked system [X; sqrt(eps) I] theta = [Y; 0],
    // a different route from the normal equations the statistics use.
    let n = ys.len();
    let mut x = DMatrix::zeros(n + 3, 3);
    let mut y = DMatrix::zeros(n + 3, 2);
    for t in 0..n {
        x.row_mut(t).copy_from(&psis[t].transpose());
        y.row_mut(t).copy_from(&ys[t].transpose());
    }
    for j in 0..3 {
        x[(n + j, j)] = eps.sqrt();
    }
    let theta = x.clone().svd(true, true).solve(&y, 1e-14).unwrap();
    assert!(
        (stats.theta() - &theta).amax() < 1e-9,
        "theta {} vs {}",
        stats.theta(),
        theta
    );
    // r = (V_yy - V_psiy' theta) / kappa = (eps I + E'E + eps theta'theta) / (1 + n) for the
    // ridge solution, E the residuals of the data rows.
    let e = y.rows(0, n) - x.rows(0, n) * &theta;
    let r = (DMatrix::identity(2, 2) * eps + e.transpose() * &e + theta.transpose() * &theta * eps)
        / (1.0 + n as f64);
    assert!((stats.r() - &r).amax() < 1e-10, "r {} vs {}", stats.r(), r);
    // And the estimates are near the truth.
    assert!((stats.theta()[(2, 0)] - 2.0).abs() < 0.1);
    assert!((stats.r()[(0, 0)] - 0.09).abs() < 0.02);
}

#[test]
fn single_component_mixture_is_recursive_least_squares() {
    let (ys, psis) = regression_data(300, 2);
    let mut mix = Mixture::new(spec(1, 2, 3)).unwrap();
    // Textbook RLS: P0 = I / eps, theta0 = 0, K = P psi / (1 + psi' P psi).
    let mut p = DMatrix::<f64>::identity(3, 3) / 1e-3;
    let mut theta = DMatrix::<f64>::zeros(3, 2);
    for (y, psi) in ys.iter().zip(&psis) {
        mix.step(&MixtureInput {
            y,
            psi,
            category: None,
            switching_row: 0,
            standing: false,
            given: None,
        })
        .unwrap();
        assert_eq!(mix.weights(), vec![1.0]);
        let p_psi = &p * psi;
        let gain = &p_psi / (1.0 + psi.dot(&p_psi));
        let innovation = y.transpose() - psi.transpose() * &theta;
        theta += &gain * innovation;
        p -= &gain * p_psi.transpose();
        let est = mix.components()[0].theta();
        assert!(
            (est - &theta).amax() < 1e-8 * theta.amax().max(1.0),
            "{est} vs {theta}"
        );
    }
}

/// Categorical-only information: two components that see the same y, so only the Dirichlet
/// tables and the switching counts tell them apart.
fn categorical_spec(components: usize) -> MixtureSpec {
    MixtureSpec {
        categories: 3,
        categorical_rows: 2,
        switching_rows: 2,
        ..spec(components, 1, 1)
    }
}

#[test]
fn one_component_counts_are_the_hand_counted_transitions() {
    // (q, l, k) per step.
    let seq = [
        (0, 2, 0),
        (1, 2, 1),
        (1, 0, 1),
        (0, 2, 0),
        (1, 1, 0),
        (0, 2, 1),
    ];
    let mut mix = Mixture::new(categorical_spec(1)).unwrap();
    let y = DVector::from_element(1, 0.0);
    let psi = DVector::from_element(1, 1.0);
    for &(q, l, k) in &seq {
        mix.step(&MixtureInput {
            y: &y,
            psi: &psi,
            category: Some((q, l)),
            switching_row: k,
            standing: false,
            given: None,
        })
        .unwrap();
    }
    // Prior 1 in each cell; q = 0 saw l = 2 three times; q = 1 saw l = 2, 0, 1 once each.
    let t = &mix.categorical()[0];
    let expected = [[1.0, 1.0, 4.0], [2.0, 2.0, 2.0]];
    for (q, row) in expected.iter().enumerate() {
        for (l, c) in row.iter().enumerate() {
            assert_eq!(t.count(q, l), *c, "cell ({q}, {l})");
        }
    }
    // Eq. (15) corrected: normalised over the categories of the row.
    assert!((t.probability(0, 2) - 4.0 / 6.0).abs() < 1e-15);
    // Switching: prior stay 2 plus 3 steps in each configuration k.
    assert_eq!(mix.switching().count(0, 0), 5.0);
    assert_eq!(mix.switching().count(1, 0), 5.0);
}

#[test]
fn two_component_counts_add_the_joint_posterior() {
    let mut mix = Mixture::new(categorical_spec(2)).unwrap();
    let y = DVector::from_element(1, 0.0);
    let psi = DVector::from_element(1, 1.0);
    let seq = [(0, 2, 0), (1, 2, 1), (1, 0, 1), (0, 2, 0), (1, 1, 0)];
    for (step, &(q, l, k)) in seq.iter().enumerate() {
        let before = mix.clone();
        mix.step(&MixtureInput {
            y: &y,
            psi: &psi,
            category: Some((q, l)),
            switching_row: k,
            standing: false,
            given: None,
        })
        .unwrap();
        // Brute force in probabilities (not logs): W_ij ∝ prox_i beta_i(l|q) alpha_{i|j,k} w_j.
        let w_prev = before.weights();
        let mut w_joint = [[0.0; 2]; 2];
        for (i, row) in w_joint.iter_mut().enumerate() {
            let prox = before.components()[i].log_proximity(&y, &psi, true).exp();
            let beta = before.categorical()[i].probability(q, l);
            for (j, cell) in row.iter_mut().enumerate() {
                *cell = prox * beta * before.switching().probability(k * 2 + j, i) * w_prev[j];
            }
        }
        let total: f64 = w_joint.iter().flatten().sum();
        for (i, row) in w_joint.iter().enumerate() {
            let w_i = (row[0] + row[1]) / total;
            assert!((mix.weights()[i] - w_i).abs() < 1e-12, "step {step} w_{i}");
            let dirichlet = mix.categorical()[i].count(q, l) - before.categorical()[i].count(q, l);
            assert!(
                (dirichlet - w_i).abs() < 1e-12,
                "step {step} eq. 12 for component {i}"
            );
            for (j, cell) in row.iter().enumerate() {
                let gamma =
                    mix.switching().count(k * 2 + j, i) - before.switching().count(k * 2 + j, i);
                assert!(
                    (gamma - cell / total).abs() < 1e-12,
                    "step {step} eq. 16 ({i}|{j})"
                );
                assert!((mix.joint()[i * 2 + j] - cell / total).abs() < 1e-12);
            }
        }
        let s: f64 = mix.weights().iter().sum();
        assert!((s - 1.0).abs() < 1e-14);
    }
    // The two components started equal and saw the same data: they stay exchangeable.
    assert!((mix.weights()[0] - 0.5).abs() < 1e-12);
}

#[test]
fn count_tables_normalise_over_categories_not_components() {
    // Erratum to eq. (15): 3 categories, 2 components; the row must sum to one over categories.
    let mut t = CountTable::new(1, 3, |_, _| 0.5);
    t.add(0, 1, 2.0);
    let s: f64 = (0..3).map(|l| t.probability(0, l)).sum();
    assert!((s - 1.0).abs() < 1e-15);
    assert!((t.probability(0, 1) - 2.5 / 3.5).abs() < 1e-15);
}

/// Pointer weights sum to one and stay finite over 10^6 steps of extreme inputs: values
/// jumping by 10^6, long constant runs (zero variance), exact zeros, and categories and
/// switching configurations changing at random; 3 components with forgetting.
#[test]
fn pointer_weights_sum_to_one_over_a_million_extreme_steps() {
    let spec = MixtureSpec {
        categories: 5,
        categorical_rows: 20,
        switching_rows: 9,
        forgetting: 0.99,
        min_noise_variance: 1e-6,
        ..spec(3, 2, 4)
    };
    let mut mix = Mixture::new(spec).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(1_000_000);
    let mut mode = 0u32;
    let mut y = DVector::zeros(2);
    let mut psi = DVector::from_vec(vec![0.0, 0.0, 0.0, 1.0]);
    for t in 0..1_000_000usize {
        if t % 1000 == 0 {
            mode = rng.random_range(0..5);
        }
        let value = |rng: &mut ChaCha8Rng| match mode {
            0 => 1e6,
            1 => -1e6,
            2 => 0.0,
            3 => {
                if rng.random::<bool>() {
                    1e6
                } else {
                    -1e6
                }
            }
            _ => rng.random_range(-1e3..1e3),
        };
        // psi = [y_{t-1}, category, 1]
        psi[0] = y[0];
        psi[1] = y[1];
        psi[2] = rng.random_range(0..5) as f64;
        y[0] = value(&mut rng);
        y[1] = if mode == 2 { 0.0 } else { value(&mut rng) };
        mix.step(&MixtureInput {
            y: &y,
            psi: &psi,
            category: Some((rng.random_range(0..20), rng.random_range(0..5))),
            switching_row: rng.random_range(0..9),
            standing: false,
            given: None,
        })
        .unwrap();
        let w = mix.weights();
        let sum: f64 = w.iter().sum();
        assert!((sum - 1.0).abs() < 1e-12, "step {t}: weights sum to {sum}");
        assert!(
            w.iter().all(|p| p.is_finite() && *p >= 0.0),
            "step {t}: {w:?}"
        );
        assert!(mix.log_weights().iter().all(|l| !l.is_nan()), "step {t}");
    }
    let s: f64 = mix.joint().iter().sum();
    assert!((s - 1.0).abs() < 1e-12);
}

/// The switching probabilities the mixture keeps for the forecast (`ln alpha` and `alpha` of
/// every cell, refreshed where a step changes the table) are the table's own to the bit: after
/// batch initialisation, after on-line steps with forgetting over several switching rows, and
/// after a snapshot round trip (which leaves them out, so they are computed when asked).
#[test]
fn kept_switching_probabilities_are_the_tables_to_the_bit() {
    let (ys, psis) = regression_data(300, 7);
    let spec = MixtureSpec {
        switching_rows: 3,
        forgetting: 0.99,
        ..spec(3, 2, 3)
    };
    let inputs: Vec<MixtureInput> = ys
        .iter()
        .zip(&psis)
        .enumerate()
        .map(|(t, (y, psi))| MixtureInput {
            y,
            psi,
            category: None,
            switching_row: t % 3,
            standing: false,
            given: None,
        })
        .collect();
    let labels: Vec<usize> = (0..100).map(|t| t % 3).collect();
    let mut mixture = Mixture::from_batch(spec, &inputs[..100], &labels, 2, 1.0).unwrap();
    let check = |mixture: &Mixture| {
        let table = mixture.switching();
        for k in 0..3 {
            for j in 0..3 {
                for i in 0..3 {
                    let want = table.log_probability(k * 3 + j, i);
                    assert_eq!(mixture.log_alpha(k, j, i).to_bits(), want.to_bits());
                    assert_eq!(mixture.alpha(k, j, i).to_bits(), want.exp().to_bits());
                    assert_eq!(
                        mixture.log_alpha_block(k)[j * 3 + i].to_bits(),
                        want.to_bits()
                    );
                }
            }
        }
    };
    check(&mixture);
    for input in &inputs[100..] {
        mixture.step(input).unwrap();
        check(&mixture);
    }
    let restored: Mixture =
        serde_json::from_str(&serde_json::to_string(&mixture).unwrap()).unwrap();
    check(&restored);
}

/// A step that fails (a data vector so large that its proximities overflow) leaves the mixture
/// as it was, and the next steps give the same numbers, to the bit, as on a mixture that never
/// saw it (the statistics are updated in spare buffers, which a failure leaves dirty, and
/// swapped in only when every component succeeded).
#[test]
fn a_failed_step_changes_nothing_and_the_next_steps_are_unaffected() {
    let (ys, psis) = regression_data(200, 3);
    let inputs: Vec<MixtureInput> = ys
        .iter()
        .zip(&psis)
        .map(|(y, psi)| MixtureInput {
            y,
            psi,
            category: None,
            switching_row: 0,
            standing: false,
            given: None,
        })
        .collect();
    let labels: Vec<usize> = (0..50).map(|t| t % 2).collect();
    let mut mixture = Mixture::from_batch(spec(2, 2, 3), &inputs[..50], &labels, 1, 1.0).unwrap();
    for input in &inputs[50..100] {
        mixture.step(input).unwrap();
    }
    let mut twin = mixture.clone();
    let state = |m: &Mixture| serde_json::to_string(m).unwrap();
    let before = state(&mixture);
    let huge = DVector::from_vec(vec![1e200, -1e200]);
    let failing = MixtureInput {
        y: &huge,
        ..inputs[100].clone()
    };
    assert!(mixture.step(&failing).is_err());
    assert_eq!(state(&mixture), before);
    for input in &inputs[100..] {
        mixture.step(input).unwrap();
        twin.step(input).unwrap();
        assert_eq!(state(&mixture), state(&twin));
    }
}

/// `[fuel, speed, acceleration]` regressed on `[fuel, speed]` a sample ago and a constant, the
/// speed and acceleration as level channels.
fn level_spec(components: usize) -> MixtureSpec {
    MixtureSpec {
        min_noise_variance: 1e-6,
        level_channels: vec![1, 2],
        ..spec(components, 3, 3)
    }
}

/// A railcar-like sequence: stretches of `stretch` samples alternating between standing
/// (regime 0: speed ~0) and coasting (regime 1: ~20 m/s, slowing by 0.05 m/s^2), both at the
/// idle fuel rate (10 cm^3/s, noise 0.5). `y = [fuel, speed, acceleration]` with the
/// acceleration exactly the speed now minus the speed a sample ago (in `psi`), as the monitor's
/// derived channel. Returns `(y, psi, regime)` per sample.
fn standing_and_coasting(
    stretches: usize,
    stretch: usize,
    seed: u64,
) -> Vec<(DVector<f64>, DVector<f64>, usize)> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let fuel_noise = Normal::new(0.0, 0.5).unwrap();
    let speed_noise = Normal::new(0.0, 0.02).unwrap();
    let (mut fuel_lag, mut speed_lag) = (10.0, 0.0);
    let mut out = Vec::new();
    for s in 0..stretches {
        let regime = s % 2;
        for t in 0..stretch {
            let speed: f64 = match regime {
                0 => f64::abs(speed_noise.sample(&mut rng)),
                _ => 20.0 - 0.05 * t as f64 + speed_noise.sample(&mut rng),
            };
            let fuel = 10.0 + fuel_noise.sample(&mut rng);
            let y = DVector::from_vec(vec![fuel, speed, speed - speed_lag]);
            let psi = DVector::from_vec(vec![fuel_lag, speed_lag, 1.0]);
            out.push((y, psi, regime));
            (fuel_lag, speed_lag) = (fuel, speed);
        }
    }
    out
}

fn inputs(data: &[(DVector<f64>, DVector<f64>, usize)]) -> Vec<MixtureInput<'_>> {
    data.iter()
        .map(|(y, psi, _)| MixtureInput {
            y,
            psi,
            category: None,
            switching_row: 0,
            standing: false,
            given: None,
        })
        .collect()
}

#[test]
fn level_statistics_are_the_weighted_mean_and_covariance_of_the_level_channels() {
    let data = standing_and_coasting(6, 40, 3);
    let (init, online) = data.split_at(80);
    let labels: Vec<usize> = init.iter().map(|d| d.2).collect();
    let spec = level_spec(2);
    let eps = spec.prior_information;
    let mut mix = Mixture::from_batch(spec, &inputs(init), &labels, 0, 1.0).unwrap();
    // Sums of w, w x, w x x' per component, from the initial partition and the pointer.
    let mut sums = vec![(0.0, DVector::zeros(2), DMatrix::zeros(2, 2)); 2];
    let mut add = |w: &[f64], y: &DVector<f64>| {
        let x = DVector::from_vec(vec![y[1], y[2]]);
        for (s, w) in sums.iter_mut().zip(w) {
            s.0 += w;
            s.1 += &x * *w;
            s.2 += &x * x.transpose() * *w;
        }
    };
    for (y, _, l) in init {
        add(if *l == 0 { &[1.0, 0.0] } else { &[0.0, 1.0] }, y);
    }
    for input in inputs(online) {
        mix.step(&input).unwrap();
        add(&mix.weights(), input.y);
    }
    for (level, (w, wx, wxx)) in mix.levels().iter().zip(&sums) {
        // Prior V_0 = eps I over [x; 1], kappa_0 = 1: mean = sum w x / (eps + sum w),
        // r = (eps I + sum w x x' - (sum w x)(sum w x)' / (eps + sum w)) / (1 + sum w).
        let mean = wx / (eps + w);
        let r = (DMatrix::identity(2, 2) * eps + wxx - wx * wx.transpose() / (eps + w)) / (1.0 + w);
        for c in 0..2 {
            assert!((level.theta()[(0, c)] - mean[c]).abs() < 1e-9 * (1.0 + mean[c].abs()));
            for d in 0..2 {
                assert!(
                    (level.r()[(c, d)] - r[(c, d)]).abs() < 1e-9 * (1.0 + r[(c, d)].abs()),
                    "r[{c},{d}] {} vs {}",
                    level.r()[(c, d)],
                    r[(c, d)]
                );
            }
        }
        assert!(*w > 50.0, "each component took a share of the data ({w})");
    }
}

#[test]
fn level_evidence_is_the_fuel_regression_plus_the_levels_not_the_derived_channels_density() {
    let data = standing_and_coasting(4, 40, 5);
    let (init, online) = data.split_at(80);
    let labels: Vec<usize> = init.iter().map(|d| d.2).collect();
    let mut mix = Mixture::from_batch(level_spec(2), &inputs(init), &labels, 0, 1.0).unwrap();
    for input in inputs(&online[..30]) {
        mix.step(&input).unwrap();
    }
    let (y, psi, _) = &online[30];
    let before = mix.clone();
    mix.step(&inputs(std::slice::from_ref(&online[30]))[0])
        .unwrap();
    // w_i ~ exp(evidence_i) sum_j alpha_{i|j} w_j, with evidence_i = ln N(fuel | speed,
    // acceleration, psi) + ln N([speed, acceleration] | level statistics).
    let one = DVector::from_element(1, 1.0);
    let x = DVector::from_vec(vec![y[1], y[2]]);
    let y_other = DVector::from_vec(vec![y[1], y[2]]);
    let evidence = |i: usize| {
        before.components()[i]
            .condition_first_on_rest(psi, &y_other, true)
            .log_density_of(y[0])
            + before.levels()[i].log_proximity(&x, &one, true)
    };
    let w0 = before.weights();
    let unnormalised: Vec<f64> = (0..2)
        .map(|i| evidence(i).exp() * (0..2).map(|j| before.alpha(0, j, i) * w0[j]).sum::<f64>())
        .collect();
    let total: f64 = unnormalised.iter().sum();
    for (w, u) in mix.weights().iter().zip(&unnormalised) {
        assert!((w - u / total).abs() < 1e-9, "{w} vs {}", u / total);
    }
    // The joint density of all of y (the paper's) differs: it holds the acceleration's
    // degenerate density given the speeds, which the level evidence leaves out.
    let joint = |i: usize| before.components()[i].log_proximity(y, psi, true);
    let gap_levels = evidence(1) - evidence(0);
    let gap_joint = joint(1) - joint(0);
    assert!(
        (gap_levels - gap_joint).abs() > 1.0,
        "{gap_levels} vs {gap_joint}"
    );
}

#[test]
fn levels_separate_standing_from_coasting_at_the_same_fuel() {
    let data = standing_and_coasting(20, 60, 11);
    let (init, online) = data.split_at(120);
    let labels: Vec<usize> = init.iter().map(|d| d.2).collect();
    let accuracy = |spec: MixtureSpec| {
        let mut mix = Mixture::from_batch(spec, &inputs(init), &labels, 0, 1.0).unwrap();
        let mut right = 0;
        for (input, d) in inputs(online).iter().zip(online) {
            mix.step(input).unwrap();
            right += usize::from(mix.active() == d.2);
        }
        right as f64 / online.len() as f64
    };
    // Fuel by its regression and speed, acceleration as levels; and fuel as a level too (no
    // regression term). Both burn the same fuel: the speed's level alone tells them apart.
    let levels = accuracy(level_spec(2));
    let with_fuel = accuracy(MixtureSpec {
        level_channels: vec![0, 1, 2],
        ..level_spec(2)
    });
    assert!(levels > 0.95, "levels: {levels}");
    assert!(with_fuel > 0.95, "levels with fuel: {with_fuel}");
    // Only the fuel's level: the regimes share it, so no separation beyond chance.
    let fuel_only = accuracy(MixtureSpec {
        level_channels: vec![0],
        ..level_spec(2)
    });
    assert!(fuel_only < 0.8, "fuel level only: {fuel_only}");
}
