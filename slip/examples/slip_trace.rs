//! Per-step trace of one drive through the temporal and VB methods over a range of steps of a
//! scenario: true and healthy load, the slip truth, the EKF torque estimate, the temporal
//! reference `M` and the terms of its threshold (`0.1 |M|`, the 0.5 N m floor, `3 s_i`), both
//! methods' slip probabilities, and the drive's learnt healthy offset `b_i` (`dev_nm` is
//! `x_i - M`; temporal tests `dev_nm - offset_nm` against `limit_nm`). Used for the low-load
//! traces of docs/notes/adhesion-log.md.
//!
//! `cargo run --release -p railmon-slip --example slip_trace -- SCENARIO.toml DRIVE FROM TO`

mod trace_args;
use trace_args::trace_args;

use railmon_slip::adhesion::temporal::TemporalEstimator;
use railmon_slip::{AdhesionEstimator, AdhesionMethod, DriveSimulator, EkfBank};

fn main() {
    let (scenario, k, range) = trace_args("slip_trace");
    let n = scenario.n_drives();
    let config = scenario.monitor_config();
    let mut sim = DriveSimulator::new(&scenario).expect("simulator");
    let mut bank = EkfBank::new(config.model().expect("model"), &config.ekf, n).expect("bank");
    let mut temporal = TemporalEstimator::new(config.adhesion.temporal.clone(), n);
    let mut vb = AdhesionEstimator::new(AdhesionMethod::Vb, &config.adhesion, n).expect("vb");
    let t = &config.adhesion.temporal;
    println!("step,true_nm,healthy_nm,truth,torque_nm,reference_nm,rel_nm,floor_nm,sig_nm,limit_nm,dev_nm,p_temporal,p_vb,vb_global_nm,offset_nm");
    let mut torque = vec![0.0; n];
    let mut step = 0;
    while let Some((samples, truth)) = sim.step() {
        bank.step(samples).expect("step");
        for (x, f) in torque.iter_mut().zip(bank.filters()) {
            *x = f.torque_nm();
        }
        let spread = temporal.spread_nm().nth(k).expect("drive");
        let offset = temporal.offset_nm()[k];
        let out = temporal.estimate(&torque).expect("temporal");
        let (m, p_t) = (out.global_torque_nm, out.slip_probability[k]);
        let vb_out = vb.estimate(&torque).expect("vb");
        if range.contains(&step) {
            let rel = t.relative_tolerance * m.abs();
            let sig = t.significance_sigmas * spread;
            let limit = rel.max(t.min_tolerance_nm).max(sig);
            println!(
                "{step},{:.3},{:.3},{},{:.3},{:.3},{rel:.3},{:.3},{sig:.3},{limit:.3},{:.3},{p_t:.3},{:.3},{:.3},{offset:.3}",
                truth[k].torque_nm,
                scenario.healthy_load_nm(k, step as f64),
                u8::from(truth[k].slipping),
                torque[k],
                m,
                t.min_tolerance_nm,
                torque[k] - m,
                vb_out.slip_probability[k],
                vb_out.global_torque_nm,
            );
        }
        step += 1;
    }
}
