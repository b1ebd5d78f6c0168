//! Trace of one drive's EKF torque estimate and load-jump test (`[ekf.jump]`, turned on here)
//! over a range of steps of a scenario: true load, estimate, the test's leading onset
//! (`2 log LR`, ML jump in N m), jumps found and applied. Used for docs/adhesion.md, "Short
//! losses".
//!
//! `cargo run --release -p railmon-slip --example jump_trace -- SCENARIO.toml DRIVE FROM TO`

use railmon_slip::{AdhesionScenario, DriveSimulator, EkfBank};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [path, drive, from, to] = args.as_slice() else {
        eprintln!("usage: jump_trace SCENARIO.toml DRIVE FROM TO");
        std::process::exit(2);
    };
    let text = std::fs::read_to_string(path).expect("scenario file");
    let scenario = AdhesionScenario::from_toml_str(&text).expect("scenario");
    let k = drive.parse::<usize>().expect("DRIVE") - 1;
    let range = from.parse::<usize>().expect("FROM")..=to.parse::<usize>().expect("TO");
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
