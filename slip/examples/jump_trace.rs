//! Trace of one drive's EKF torque estimate and load-jump test (`[ekf.jump]`, turned on here)
//! over a range of steps of a scenario: true load, estimate, the test's leading onset
//! (`2 log LR`, ML jump in N m), jumps found and applied. Used for docs/adhesion.md, "Short
//! losses".
//!
//! `cargo run --release -p railmon-slip --example jump_trace -- SCENARIO.toml DRIVE FROM TO`

mod trace_args;
use trace_args::trace_args;

use railmon_slip::{DriveSimulator, EkfBank};

fn main() {
    let (scenario, k, range) = trace_args("jump_trace");
    let mut config = scenario.monitor_config();
    config.ekf.jump.enabled = true;
    let mut sim = DriveSimulator::new(&scenario).expect("simulator");
    let model = config.model().expect("model");
    let mut bank = EkfBank::new(model, &config.ekf, scenario.n_drives()).expect("bank");
    println!("step,true_torque_nm,torque_nm,lead_2_log_lr,lead_jump_nm,found,applied");
    let mut step = 0;
    while let Some((samples, truth)) = sim.step() {
        bank.step(samples).expect("step");
        if range.contains(&step) {
            let d = &bank.jump_detectors()[k];
            let (l, nu) = d.lead().unwrap_or((f64::NAN, f64::NAN));
            println!(
                "{step},{:.2},{:.2},{l:.1},{nu:.1},{},{}",
                truth[k].torque_nm,
                bank.filters()[k].torque_nm(),
                d.detections(),
                bank.jump_corrections()[k]
            );
        }
        step += 1;
    }
}
