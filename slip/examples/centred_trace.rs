//! Per-step trace of one drive through what the default method judges on every path: the
//! temporal method on the centred mean of the torque estimates (`railmon_slip::fixed_lag`,
//! before its edges are moved and short episodes dropped). Columns: the step the mean is of,
//! the true and healthy load, the slip truth, the centred mean `x_i`, the reference `M`, the
//! drive's learnt offset `b_i` and spread `s_i`, `u = x_i - M - b_i`, the limit (`max(0.1 |M|,
//! 0.5 N m, 3 s_i)`, without the reference's variance), the slip probability, and the
//! largest `x - M - b` of the other drives in the effort's direction (the top of the group).
//!
//! `[TRACE_EVERY=N] cargo run --release -p railmon-slip --example centred_trace -- SCENARIO.toml DRIVE FROM TO`
//! (`TRACE_EVERY`: every N-th step of the range; used for the traces of docs/notes/adhesion-log.md,
//! "eleventh round").

mod trace_args;
use trace_args::trace_args;

use railmon_slip::adhesion::temporal::TemporalEstimator;
use railmon_slip::fixed_lag::{CentredMean, CENTRED_HALF_WINDOW_STEPS};
use railmon_slip::{DriveSimulator, EkfBank};

fn main() {
    let (scenario, k, range) = trace_args("centred_trace");
    let every: usize = std::env::var("TRACE_EVERY")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1);
    let n = scenario.n_drives();
    let config = scenario.monitor_config();
    let mut sim = DriveSimulator::new(&scenario).expect("simulator");
    let mut bank = EkfBank::new(config.model().expect("model"), &config.ekf, n).expect("bank");
    let mut temporal = TemporalEstimator::new(config.adhesion.temporal.clone(), n);
    let mut window = CentredMean::new(CENTRED_HALF_WINDOW_STEPS, n);
    let t = &config.adhesion.temporal;
    println!("step,true_nm,healthy_nm,truth,x_nm,reference_nm,offset_nm,spread_nm,u_nm,limit_nm,p,max_other_u_nm,n_flagged");
    let mut torque = vec![0.0; n];
    let mut history = Vec::new();
    let mut step = 0usize;
    while let Some((samples, truth)) = sim.step() {
        bank.step(samples).expect("step");
        for (x, f) in torque.iter_mut().zip(bank.filters()) {
            *x = f.torque_nm();
        }
        history.push((truth[k].torque_nm, u8::from(truth[k].slipping)));
        step += 1;
        let Some(mean) = window.push(&torque) else {
            continue;
        };
        let mean = mean.to_vec();
        let named = step - 1 - CENTRED_HALF_WINDOW_STEPS;
        let offsets = temporal.offset_nm().to_vec();
        let spread = temporal.spread_nm().nth(k).expect("drive");
        let out = temporal.estimate(&mean).expect("temporal");
        let m = out.global_torque_nm;
        if range.contains(&named) && (named - range.start()).is_multiple_of(every) {
            let u = mean[k] - m - offsets[k];
            let limit = (t.relative_tolerance * m.abs())
                .max(t.min_tolerance_nm)
                .max(t.significance_sigmas * spread);
            let flagged = out.slip_probability.iter().filter(|&&p| p > 0.5).count();
            let top = (0..n)
                .filter(|&j| j != k)
                .map(|j| m.signum() * (mean[j] - m - offsets[j]))
                .fold(f64::NEG_INFINITY, f64::max);
            let (true_nm, tr) = history[named];
            println!(
                "{named},{true_nm:.3},{:.3},{tr},{:.3},{m:.3},{:.3},{spread:.3},{u:.3},{limit:.3},{:.3},{top:.3},{flagged}",
                scenario.healthy_load_nm(k, named as f64),
                mean[k],
                offsets[k],
                out.slip_probability[k],
            );
        }
    }
}
