//! Where the offline pipeline's time goes, per section, in one run (issue 10 item 4): for each
//! adhesion scenario of `config/scenarios/` (pre-simulated, so the plant is not timed), the
//! thread CPU time of
//! - the EKF bank alone,
//! - the EKF step with dense products (`ekf_step_dense`, the reference) against the one the
//!   bank runs (`ekf_step`, which skips the zeros), over the same frames: their speed
//!   ratio (same run, so the machine's load cancels),
//! - each adhesion method alone, over the EKF torque estimates of the whole run,
//! - the whole pipeline (EKFs, all five methods, their alarms: `MultiMethodPipeline`),
//! - what the service runs: the EKFs and the default method (`SlipMonitor`, temporal),
//! - the same with a train speed on every frame (`step_with_train_speed`, a constant 5.75 m/s:
//!   the cost of the train-speed reference),
//! - the temporal method behind the fixed-lag stage (`FixedLagEstimator`, the stage
//!   `SlipMonitor` and `MultiMethodPipeline` run per method inside their `FixedLagLine`) over
//!   the same torque estimates, alone and summed with the EKF bank,
//!
//! printed as drive-steps per second of CPU time (one core), with the sum of the sections next
//! to the measured whole. CPU time (`railmon_bench_support`) instead of wall clock: on the
//! shared machine the wall clock includes waiting for a core.
//!
//! `cargo bench -p railmon-slip --bench sections [-- NAME]` (NAME: only scenarios whose file
//! name contains it).

use std::hint::black_box;

mod scenarios_dir;
use scenarios_dir::scenario_paths;

use railmon_bench_support::thread_cpu_time;
use railmon_slip::ekf::{ekf_step, ekf_step_dense};
use railmon_slip::fixed_lag::FixedLagEstimator;
use railmon_slip::model::DriveMatrix;
use railmon_slip::{
    AdhesionEstimator, AdhesionMethod, AdhesionScenario, DriveSample, DriveSimulator, EkfBank,
    MultiMethodPipeline, SlipMonitor,
};

/// CPU seconds of one run of `f`: the mean over as many runs as take 0.3 s of CPU time (at
/// least one), so that the short sections are averaged over several runs.
fn cpu_seconds(mut f: impl FnMut()) -> f64 {
    let start = thread_cpu_time();
    let mut runs = 0;
    loop {
        f();
        runs += 1;
        let spent = (thread_cpu_time() - start).as_secs_f64();
        if spent >= 0.3 {
            return spent / runs as f64;
        }
    }
}

fn main() {
    let filter = std::env::args().skip(1).find(|a| !a.starts_with('-'));
    print!("| scenario | drives | EKF bank |");
    for m in AdhesionMethod::ALL {
        print!(" {m} |");
    }
    println!(
        " sum of sections | whole pipeline | EKFs + temporal (service) | service with a train speed | EKF step sparse / dense | temporal, fixed lag | EKF bank + temporal, fixed lag (sum) |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for path in scenario_paths(filter.as_deref()) {
        let text = std::fs::read_to_string(&path).expect("scenario file");
        let scenario = AdhesionScenario::from_toml_str(&text)
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let n = scenario.n_drives();
        let config = scenario.monitor_config();
        let mut sim = DriveSimulator::new(&scenario).expect("simulator");
        let mut frames: Vec<Vec<DriveSample>> = Vec::with_capacity(scenario.n_steps());
        while let Some((samples, _)) = sim.step() {
            frames.push(samples.to_vec());
        }
        let drive_steps = (frames.len() * n) as f64;
        let model = config.model().expect("model");
        // The torque estimates of the whole run, step after step (one allocation).
        let mut torque = vec![0.0; frames.len() * n];
        let ekf_s = cpu_seconds(|| {
            let mut bank = EkfBank::new(model, &config.ekf, n).expect("bank");
            for (f, t) in frames.iter().zip(torque.chunks_exact_mut(n)) {
                bank.step(f).expect("step");
                for (tk, filter) in t.iter_mut().zip(bank.filters()) {
                    *tk = filter.torque_nm();
                }
            }
        });
        // Both EKF steps from the bank's filters after its first two frames (the back-EMF
        // start), drive by drive over the remaining frames.
        let mut started = EkfBank::new(model, &config.ekf, n).expect("bank");
        for f in &frames[..2] {
            started.step(f).expect("step");
        }
        let q = DriveMatrix::from_diagonal(&config.ekf.process_noise_diag.into());
        let r = nalgebra::Matrix2::identity() * config.ekf.measurement_noise_a2;
        let chain_s = |dense: bool| {
            cpu_seconds(|| {
                let mut filters = started.filters().to_vec();
                for frame in &frames[2..] {
                    for (f, s) in filters.iter_mut().zip(frame) {
                        *f = if dense {
                            ekf_step_dense(&model, &q, &r, f, s).expect("step")
                        } else {
                            ekf_step(&model, &q, &r, f, s).expect("step")
                        };
                    }
                }
                black_box(filters[0].x[0]);
            })
        };
        let dense_s = chain_s(true);
        let sparse_s = chain_s(false);
        let method_s: Vec<f64> = AdhesionMethod::ALL
            .iter()
            .map(|&m| {
                cpu_seconds(|| {
                    let mut e = AdhesionEstimator::new(m, &config.adhesion, n).expect("method");
                    for t in torque.chunks_exact(n) {
                        black_box(e.estimate(t).expect("estimate").global_torque_nm);
                    }
                })
            })
            .collect();
        let lagged_s = cpu_seconds(|| {
            let e = AdhesionEstimator::new(AdhesionMethod::Temporal, &config.adhesion, n)
                .expect("method");
            let mut stage = FixedLagEstimator::new(e);
            for t in torque.chunks_exact(n) {
                black_box(stage.estimate(t).expect("estimate").map(|p| p[0]));
            }
        });
        let whole_s = cpu_seconds(|| {
            let mut pipe = MultiMethodPipeline::new(&config, n).expect("pipeline");
            for f in &frames {
                pipe.step(f).expect("step");
            }
            black_box(pipe.torque_nm()[0]);
        });
        let service_s = cpu_seconds(|| {
            let mut monitor = SlipMonitor::new(&config, n).expect("monitor");
            for f in &frames {
                black_box(monitor.step(f).expect("step").map(|e| e.global_torque_nm));
            }
        });
        let service_train_s = cpu_seconds(|| {
            let mut monitor = SlipMonitor::new(&config, n).expect("monitor");
            for f in &frames {
                let e = monitor.step_with_train_speed(f, Some(5.75)).expect("step");
                black_box(e.map(|e| e.global_torque_nm));
            }
        });
        let rate = |s: f64| format!("{:.2}", drive_steps / s / 1e6);
        print!("| {} | {n} | {} |", scenario.name, rate(ekf_s));
        for s in &method_s {
            print!(" {} |", rate(*s));
        }
        println!(
            " {} | {} | {} | {} | {:.2} | {} | {} |",
            rate(ekf_s + method_s.iter().sum::<f64>()),
            rate(whole_s),
            rate(service_s),
            rate(service_train_s),
            dense_s / sparse_s,
            rate(lagged_s),
            rate(ekf_s + lagged_s)
        );
    }
    println!();
    println!("M drive-steps per second of one core's CPU time (each: mean over >= 0.3 s of CPU).");
}
