//! The fixed-lag stage (`railmon_slip::fixed_lag`) on the draw where the EKF's lag per edge
//! alone kept the causal method under the F1 target: draw 1002 (7 of 14 drives braking,
//! 531-step losses, F1 0.947-0.950 causal against 0.990 at the information bound;
//! docs/adhesion.md, "Fixed-lag publication").

use railmon_slip::fixed_lag::FIXED_LAG_STEPS;
use railmon_slip::sampler::draw;
use railmon_slip::{
    AdhesionEstimator, AdhesionMethod, DetectionCounter, DriveSimulator, MultiMethodPipeline,
};

#[test]
fn the_fixed_lag_lifts_draw_1002s_slipping_drives_over_the_target_without_false_steps() {
    let d = draw(1002);
    let n = d.scenario.n_drives();
    let cfg = d.scenario.monitor_config();
    assert_eq!(cfg.method, AdhesionMethod::Temporal);
    // The product path (behind the fixed lag) against the same method run causally on the
    // same EKF torque estimates.
    let mut pipe = MultiMethodPipeline::with_methods(&cfg, n, &[cfg.method]).unwrap();
    let mut causal_method = AdhesionEstimator::new(cfg.method, &cfg.adhesion, n).unwrap();
    let mut sim = DriveSimulator::new(&d.scenario).unwrap();
    let mut causal = vec![DetectionCounter::default(); n];
    let mut lagged = vec![DetectionCounter::default(); n];
    let mut truths: Vec<Vec<bool>> = Vec::new();
    let score =
        |pipe: &MultiMethodPipeline, truths: &[Vec<bool>], lagged: &mut [DetectionCounter]| {
            let at = pipe.step_index() as usize;
            let (_, q) = pipe.slip_probability().next().unwrap();
            for k in 0..n {
                lagged[k].push(at, q[k] > 0.5, truths[at][k]);
            }
        };
    while let Some((samples, truth)) = sim.step() {
        let step = truths.len();
        truths.push(truth.iter().map(|t| t.slipping).collect());
        if pipe.step(samples).unwrap() {
            // The answer names the step `FIXED_LAG_STEPS` back.
            assert_eq!(pipe.step_index() as usize, step - FIXED_LAG_STEPS);
            score(&pipe, &truths, &mut lagged);
        }
        let p = &causal_method
            .estimate(pipe.torque_nm())
            .unwrap()
            .slip_probability;
        for k in 0..n {
            causal[k].push(step, p[k] > 0.5, truths[step][k]);
        }
    }
    while pipe.drain().unwrap() {
        score(&pipe, &truths, &mut lagged);
    }
    for k in 0..n {
        let (c, l) = (causal[k].score(), lagged[k].score());
        if d.slipping.contains(&k) {
            let (cf, lf) = (c.f1.unwrap(), l.f1.unwrap());
            assert!(
                lf >= 0.95 && lf > cf,
                "drive {}: F1 {lf:.3} lagged, {cf:.3} causal",
                k + 1
            );
            assert!(
                l.median_delay_steps.unwrap() < c.median_delay_steps.unwrap(),
                "drive {}: {l:?} against {c:?}",
                k + 1
            );
        } else {
            assert_eq!(l.false_pos, 0, "healthy drive {}", k + 1);
        }
    }
}
