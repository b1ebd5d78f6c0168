//! Speed as an input (issue 9 item 1): the gain schedule against the direct steady state, and
//! the pause below the valid speed range.

use railmon_damper::*;

fn scenario(name: &str, duration_s: f64, profile: &[[f64; 2]]) -> DamperScenario {
    let text = std::fs::read_to_string(format!(
        "{}/../config/scenarios/{name}.toml",
        env!("CARGO_MANIFEST_DIR")
    ))
    .unwrap();
    let mut s = DamperScenario::from_toml_str(&text).unwrap();
    s.duration_s = duration_s;
    s.speed = Some(SpeedProfile {
        profile_m_s: profile.to_vec(),
    });
    s.validate().unwrap();
    s
}

fn samples(s: &DamperScenario) -> Vec<BogieSample> {
    let mut sim = BogieSimulator::new(s).unwrap();
    let mut out = vec![];
    while let Some((y, _)) = sim.step() {
        out.push(*y);
    }
    out
}

/// `ln p(y)` of the known-parameter filter (`DamperMonitorConfig::with_known_dampers`,
/// `C_say = ratio x nominal`) on `data`, its steady-state gains from `table`.
fn log_likelihood(
    c: &DamperMonitorConfig,
    table: &std::sync::Arc<gain_table::GainTable>,
    csay_ratio: f64,
    data: &[BogieSample],
) -> f64 {
    let c = c.with_known_dampers(Dampers {
        csay_ns_per_m: c.nominal.csay_ns_per_m * csay_ratio,
        ..c.nominal
    });
    let mut m = DamperMonitor::with_gain_table(&c, 1, Some(table.clone())).unwrap();
    for y in data {
        m.step(y).unwrap();
    }
    m.rbpf().log_evidence()
}

/// Mode and standard deviation (relative) of the parabola through `ln L` at `1 - h, 1, 1 + h`.
fn parabola(h: f64, l: [f64; 3]) -> (f64, f64) {
    let curvature = (l[0] - 2.0 * l[1] + l[2]) / (h * h);
    let slope = (l[2] - l[0]) / (2.0 * h);
    (-slope / curvature, (-1.0 / curvature).sqrt())
}

/// At a node's speed the scheduled filter is the filter built for that speed (to rounding);
/// at the edge of the node's cell (speed off by `sqrt(r) - 1` = 2.5 %) the gains are a
/// neighbour's, and the likelihood's `C_say` mode moves by a small fraction of its standard
/// deviation. The numbers are printed (`--nocapture`) for docs/damper.md.
#[test]
fn scheduled_gains_equal_the_direct_ones_at_a_node_and_stay_close_between() {
    let base = DamperMonitorConfig::default();
    let scheduled = Rbpf::gain_table(&base.filter_model(), &base.rbpf, &base.speed).unwrap();
    let node = scheduled.node_of(30.0);
    let v_node = scheduled.node_speed_m_s(node);
    let edge = v_node * base.speed.grid_ratio.sqrt() * 0.999;
    assert_eq!(scheduled.node_of(edge), node);
    let h = 0.05;
    for (v, exact) in [(v_node, true), (edge, false)] {
        let s = scenario("damper-seed", 10.0, &[[0.0, v]]);
        let data = samples(&s);
        let mut direct_config = base;
        direct_config.vehicle.speed_m_s = v;
        let direct = Rbpf::gain_table(
            &direct_config.filter_model(),
            &direct_config.rbpf,
            &direct_config.speed,
        )
        .unwrap();
        let ratios = [1.0 - h, 1.0, 1.0 + h];
        let ll_scheduled = ratios.map(|r| log_likelihood(&base, &scheduled, r, &data));
        let ll_direct = ratios.map(|r| log_likelihood(&direct_config, &direct, r, &data));
        let (mode_s, sd_s) = parabola(h, ll_scheduled);
        let (mode_d, sd_d) = parabola(h, ll_direct);
        println!(
            "v = {v:.3} m/s (node {v_node:.3}): lnL(truth) scheduled - direct = {:+.3} nats \
             over 10 s; C_say mode {:+.4} % vs {:+.4} % (sd {:.4} % / {:.4} %), shift {:.3} sd",
            ll_scheduled[1] - ll_direct[1],
            100.0 * mode_s,
            100.0 * mode_d,
            100.0 * sd_s,
            100.0 * sd_d,
            (mode_s - mode_d) / sd_d
        );
        if exact {
            // Equal to rounding: the drift null space is solved (SVD) at the configured speed
            // for the one and at the node's for the other; it does not depend on the speed.
            for (a, b) in ll_scheduled.iter().zip(&ll_direct) {
                assert!(((a - b) / b).abs() < 1e-10, "{a} against {b}");
            }
            assert!(((mode_s - mode_d) / sd_d).abs() < 1e-4);
        } else {
            assert!(ll_scheduled[1] != ll_direct[1]);
            assert!(((mode_s - mode_d) / sd_d).abs() < 0.1);
            assert!((sd_s / sd_d - 1.0).abs() < 0.05);
        }
    }
}

/// What a stop does to the parameter particles: runs `c` through 1 s at 45.3 m/s, 0.5 s at
/// 2 m/s, then 30 m/s, asserting that no particle's `ln theta` or weight moves while the
/// estimate says `paused`. Returns the paused steps, whether the filter learnt again after
/// them, and the jump search's log-odds at the last paused step (if it is on).
fn stop_and_go(c: &DamperMonitorConfig, duration_s: f64) -> (usize, bool, Option<Vec<f64>>) {
    let profile = [
        [0.0, 45.3],
        [1.0, 45.3],
        [1.001, 2.0],
        [1.5, 2.0],
        [1.501, 30.0],
    ];
    let s = scenario("damper-seed", duration_s, &profile);
    let n = c.rbpf.particles;
    let data = samples(&s);
    let mut m = DamperMonitor::new(c, 5).unwrap();
    let particles = |m: &DamperMonitor| {
        (0..n)
            .map(|i| {
                let (ln_theta, log_w, _, _) = m.rbpf().particle(i);
                (ln_theta, log_w)
            })
            .collect::<Vec<_>>()
    };
    let mut held = None;
    let mut paused_steps = 0;
    let mut learnt_after = false;
    let mut odds_at_resume = None;
    for y in &data {
        let before = particles(&m);
        let e = *m.step(y).unwrap();
        match e.paused {
            Some(reason) => {
                paused_steps += 1;
                let held = held.get_or_insert(before);
                assert_eq!(&particles(&m), held, "moved while paused at {} s", e.time_s);
                if y.speed_m_s < c.speed.min_m_s {
                    assert_eq!(reason, PauseReason::LowSpeed);
                }
                odds_at_resume = m.rbpf().jump_ln_odds().map(<[f64]>::to_vec);
            }
            None => {
                if held.is_some() {
                    learnt_after |= particles(&m) != before;
                }
            }
        }
    }
    (paused_steps, learnt_after, odds_at_resume)
}

/// Below `speed.min_m_s` nothing of the parameter posterior moves: every particle's
/// `ln theta` and weight is bit for bit what it was before the stop, through the stop and
/// the settling after it; then the filter learns again.
#[test]
fn a_low_speed_stretch_holds_the_parameter_particles_bit_for_bit() {
    let s = scenario("damper-seed", 2.5, &[[0.0, 45.3]]);
    let mut c = s.monitor_config();
    c.rbpf.particles = 64;
    c.speed.resume_settle_s = 0.5;
    // The settling of `speed.resume_settle_s` alone (the jump search lengthens it: next test).
    c.rbpf.jump_search.enabled = false;
    let (paused_steps, learnt_after, _) = stop_and_go(&c, 2.5);
    // 0.5 s at 2 m/s and 0.5 s of settling.
    assert!((999..=1002).contains(&paused_steps), "{paused_steps}");
    assert!(
        learnt_after,
        "the filter never learnt again after the pause"
    );
}

/// With the jump search the settling after a stop lasts `speed.resume_settle_s` at least
/// and ends at the first `SETTLE_WINDOW_S` window in which some hypothesis explains the data
/// (its mean normalised innovation squared at most `SETTLED_NIS_RATIO` x 5), the particles
/// held through it and the sentinels' odds started again from nothing; where no hypothesis
/// does (here: the filter assumes sensors 10 times quieter than they are, without the noise
/// estimate), it lasts the full `resume_hold_time_constants` time constants of the model's
/// slowest mode.
#[test]
fn with_the_jump_search_a_stop_settles_until_the_innovations_are_explained() {
    let s = scenario("damper-seed", 9.0, &[[0.0, 45.3]]);
    let mut c = s.monitor_config();
    c.rbpf.particles = 64;
    c.rbpf.jump_search.enabled = true;
    let tau = slowest_time_constant_s(&c.filter_model(), &c.speed).unwrap();
    let settle_max_s = c.rbpf.jump_search.resume_hold_time_constants * tau;
    assert!(settle_max_s > c.speed.resume_settle_s + 1.0);
    let steps = |s: f64| (s / c.dt_s).round();
    let (paused_steps, learnt_after, odds) = stop_and_go(&c, 9.0);
    // 0.5 s stopped, then whole windows of settling from the minimum on, below the cap.
    let settled = paused_steps as f64 - steps(0.5);
    let window = steps(railmon_damper::monitor::SETTLE_WINDOW_S);
    assert!(
        settled >= steps(c.speed.resume_settle_s)
            && settled < steps(settle_max_s)
            && (settled / window - (settled / window).round()).abs() < 2.0 / window,
        "{paused_steps} steps paused"
    );
    assert!(learnt_after);
    assert!(odds.unwrap().iter().all(|q| *q == f64::NEG_INFINITY));
    // Data no hypothesis explains: the whole hold.
    c.sensors.accel_std_m_s2 /= 10.0;
    c.sensors.gyro_std_rad_s /= 10.0;
    c.rbpf.noise_scale.enabled = false;
    let (paused_steps, learnt_after, _) = stop_and_go(&c, 9.0);
    let expected = steps(0.5 + settle_max_s);
    assert!(
        (paused_steps as f64 - expected).abs() <= 2.0,
        "{paused_steps} steps, {expected} expected"
    );
    assert!(learnt_after);
}

/// Solving speed nodes ahead of the filters (issue 9 item 4): `missing_near` names the
/// unsolved nodes nearest the speed first (the slower side first on a tie) and skips the
/// solved ones; a node solved on another thread is the very grid a filter then gets.
#[test]
fn nodes_solved_ahead_are_named_nearest_first_and_shared() {
    let c = DamperMonitorConfig::default();
    let table = Rbpf::gain_table(&c.filter_model(), &c.rbpf, &c.speed).unwrap();
    let (v0, m0) = (c.vehicle.speed_m_s, c.vehicle.half_body_mass_kg);
    let k = table.node_of(v0);
    // Built with the table: the configured speed's node, and no other.
    assert!(table.is_solved(k));
    assert!(!table.is_solved(k - 1) && !table.is_solved(k + 1));
    assert_eq!(table.missing_near(v0, m0..=m0, 0), None);
    assert_eq!(table.missing_near(v0, m0..=m0, 2), Some(k - 1));
    let warmer = table.clone();
    let solved = std::thread::spawn(move || warmer.grid_at(k - 1).unwrap())
        .join()
        .unwrap();
    assert!(table.is_solved(k - 1));
    assert_eq!(table.missing_near(v0, m0..=m0, 2), Some(k + 1));
    // A slower speed: its own node is now solved, the next missing one is below it.
    let v_low = table.node_speed_m_s(k - 1);
    assert_eq!(table.missing_near(v_low, m0..=m0, 1), Some(k - 2));
    assert!(std::sync::Arc::ptr_eq(
        &table.grid_at(k - 1).unwrap(),
        &solved
    ));
    // The range ends: nothing beyond the last node is named.
    let last = table.n_nodes() - 1;
    let top = table.node_speed_m_s(last);
    assert!(table
        .missing_near(top * 10.0, m0..=m0, 0)
        .is_some_and(|n| n == last));
    // A span of masses (the particles' own while no load is measured): the nodes of every
    // mass node in it at the speed, lightest first, before the next speed; beyond the
    // table's mass range, its last mass node.
    let (light, heavy) = (m0 / 1.05, m0 * 1.05);
    let at = |m: f64| table.node_at(v0, m);
    assert_eq!(table.missing_near(v0, light..=heavy, 0), Some(at(light)));
    table.grid_at(at(light)).unwrap();
    assert_eq!(table.missing_near(v0, light..=heavy, 0), Some(at(heavy)));
    table.grid_at(at(heavy)).unwrap();
    assert_eq!(table.missing_near(v0, light..=heavy, 0), None);
    // One speed node further: the slower one first, at the lightest mass (the design
    // mass's own was solved above).
    assert_eq!(
        table.missing_near(v0, light..=heavy, 1),
        Some(table.node_at(table.node_speed_m_s(k - 1), light))
    );
    assert_eq!(
        table.missing_near(v0, m0 * 10.0..=m0 * 10.0, 0),
        Some(at(m0 * 1.6))
    );
}

/// The speeds the low-speed measurements below are taken at (m/s).
const INFORMATION_SPEEDS_M_S: [f64; 5] = [10.0, 15.0, 20.0, 30.0, DEFAULT_SPEED_M_S];

/// What 10 s of data say about `C_say` at each speed (issue 9: the `C_say` step is found in
/// 13-15 s at 10 m/s, 3-7 s elsewhere). The exact Kalman log-likelihood of the known-parameter
/// filter (noise estimate off: the likelihood of the configured model) at `C_say` x (1 -+ h)
/// about the truth, for a healthy damper and for one at 40 % (the step's new value), three
/// plant seeds each; the curvature is the observed Fisher information of `ln C_say`. Printed
/// per speed (`--nocapture`): the information per second, the standard deviation 10 s of data
/// give, and the ideal time for a flat-prior posterior at 0.4 to put its whole 90 % interval
/// below the alarm's 0.7 (`(1.645 / ln(0.7 / 0.4))^2 / I`), and the log-likelihood ratio of
/// 0.4 against 1.0 on the first second of faulted data. Asserts what the physics says: the
/// information grows with speed (the creep forces ~1/v dominate at low speed) and stays
/// positive (a concave likelihood) at every speed.
#[test]
fn the_information_about_the_anti_yaw_damper_grows_with_speed() {
    let mut base = DamperMonitorConfig::default();
    base.rbpf.noise_scale.enabled = false;
    let table = Rbpf::gain_table(&base.filter_model(), &base.rbpf, &base.speed).unwrap();
    let h = 0.05;
    let seeds = [9000u64, 9001, 9002];
    let threshold = (base.alarm.degraded_below_ratio / 0.4_f64).ln();
    println!(
        "| speed (m/s) | I(ln C_say) healthy (1/s) | sd over 10 s | I at 40 % (1/s) | sd over 10 s | ideal time to 90 % below 0.7 (s) | ln L(0.4) - ln L(1.0), first 1 s (nats) |"
    );
    println!("|---|---|---|---|---|---|---|");
    let mut previous = 0.0;
    for v in INFORMATION_SPEEDS_M_S {
        let mut info = [0.0; 2];
        let mut llr_1s = 0.0;
        for &seed in &seeds {
            for (k, truth) in [1.0, 0.4].into_iter().enumerate() {
                let mut s = scenario("damper-seed", 10.0, &[[0.0, v]]);
                s.seed = seed;
                s.dampers.csay_ns_per_m *= truth;
                let data = samples(&s);
                let ll = [1.0 - h, 1.0, 1.0 + h]
                    .map(|r| log_likelihood(&base, &table, truth * r, &data));
                let curvature = (ll[0] - 2.0 * ll[1] + ll[2]) / (h * h);
                info[k] += -curvature / 10.0 / seeds.len() as f64;
                if truth < 1.0 {
                    let first = &data[..1000];
                    llr_1s += (log_likelihood(&base, &table, 0.4, first)
                        - log_likelihood(&base, &table, 1.0, first))
                        / seeds.len() as f64;
                }
            }
        }
        let sd10 = |i: f64| 100.0 / (10.0 * i).sqrt();
        println!(
            "| {v:.1} | {:.1} | {:.2} % | {:.1} | {:.2} % | {:.3} | {:.1} |",
            info[0],
            sd10(info[0]),
            info[1],
            sd10(info[1]),
            (1.645 / threshold).powi(2) / info[1],
            llr_1s,
        );
        assert!(info[0] > 0.0 && info[1] > 0.0, "{v} m/s: {info:?}");
        assert!(info[0] > previous, "{v} m/s: {} <= {previous}", info[0]);
        previous = info[0];
    }
}
