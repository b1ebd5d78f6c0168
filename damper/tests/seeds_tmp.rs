//! TEMP: degraded_particles' coverage over several seeds (not committed).
use railmon_damper::*;
mod common;
#[test]
fn seeds() {
    let k: u64 = std::env::var("SEEDS")
        .map(|s| s.parse().unwrap())
        .unwrap_or(6);
    let mut all = vec![];
    for s in 0..k {
        let (scenario, mut config) = common::csy_ramp_on_seed();
        config.rbpf.seed += s;
        let mut monitor = DamperMonitor::new(&config, config.rbpf.seed).unwrap();
        let mut sim = BogieSimulator::new(&scenario).unwrap();
        let (mut seen, mut covered) = ([0usize; 3], [0usize; 3]);
        let mut step = 0usize;
        let mut width = 0.0;
        while let Some((sample, truth)) = sim.step() {
            step += 1;
            if step == 40_000 || step == 100_000 {
                monitor
                    .set_particles(if step == 40_000 {
                        MIN_DEGRADED_PARTICLES
                    } else {
                        300
                    })
                    .unwrap();
            }
            let e = *monitor.step(sample).unwrap();
            let t = truth.dampers.csy_ns_per_m;
            if truth.time_s >= 20.0 && step.is_multiple_of(10) {
                let k = match step {
                    ..40_000 => 0,
                    40_000..100_000 => 1,
                    _ => 2,
                };
                seen[k] += 1;
                covered[k] += usize::from(e.csy.q05_ns_per_m <= t && t <= e.csy.q95_ns_per_m);
                if k == 2 {
                    width += (e.csy.q95_ns_per_m - e.csy.q05_ns_per_m) / t;
                }
            }
        }
        let c: Vec<f64> = (0..3).map(|k| covered[k] as f64 / seen[k] as f64).collect();
        eprintln!(
            "seed +{s}: {c:.3?} restored width {:.4}",
            width / seen[2] as f64
        );
        all.push(c);
    }
    let mean: Vec<f64> = (0..3)
        .map(|k| all.iter().map(|c| c[k]).sum::<f64>() / all.len() as f64)
        .collect();
    let min: Vec<f64> = (0..3)
        .map(|k| all.iter().map(|c| c[k]).fold(1.0, f64::min))
        .collect();
    eprintln!("MEAN {mean:.3?} MIN {min:.3?}");
}
