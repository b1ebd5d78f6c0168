use railmon_damper::*;
#[test]
fn run() {
    let n: usize = std::env::var("NP")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(200);
    let dur: f64 = std::env::var("DUR")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(20.0);
    let every: u32 = std::env::var("EVERYN")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(2000);
    let f = std::env::var("SC").unwrap_or("damper-seed".into());
    let text = std::fs::read_to_string(format!("../config/scenarios/{f}.toml")).unwrap();
    let mut s = DamperScenario::from_toml_str(&text).unwrap();
    s.duration_s = dur;
    let mut cfg = s.monitor_config();
    cfg.rbpf.particles = n;
    if std::env::var("EXACT").is_ok() {
        cfg.rbpf.propagation = Propagation::Exact;
    }
    if let Ok(g) = std::env::var("GRID") {
        cfg.rbpf.gain_grid.points_per_axis = g.parse().unwrap();
    }
    if let Ok(g) = std::env::var("DIF") {
        cfg.rbpf.ln_diffusion_per_sqrt_s = g.parse().unwrap();
    }
    if let Ok(g) = std::env::var("REGEN") {
        cfg.rbpf.regeneration_fraction = g.parse().unwrap();
    }
    if std::env::var("EVERY").is_ok() {
        cfg.rbpf.kernel = KernelSchedule::EveryStep;
    }
    let t0 = std::time::Instant::now();
    let mut m = DamperMonitor::new(&cfg, cfg.rbpf.seed).unwrap();
    println!("build {:?}", t0.elapsed());
    let mut sim = BogieSimulator::new(&s).unwrap();
    let t0 = std::time::Instant::now();
    let mut k: u32 = 0;
    while let Some((y, t)) = sim.step() {
        let e = *m.step(y).unwrap();
        k += 1;
        if k.is_multiple_of(every) {
            let ek = e.ekf.map(|e| {
                (
                    e.dampers.csy_ns_per_m / 16e3,
                    e.dampers.csay_ns_per_m / 160e3,
                )
            });
            println!("t={:.1} csy {:.3} [{:.3},{:.3}] csay {:.3} [{:.3},{:.3}] ess {:.0} truth {:.3} {:.3} ekf {:?}", t.time_s,
              e.csy.health_ratio, e.csy.q05_ns_per_m/16e3, e.csy.q95_ns_per_m/16e3,
              e.csay.health_ratio, e.csay.q05_ns_per_m/160e3, e.csay.q95_ns_per_m/160e3, e.effective_sample_size,
              t.dampers.csy_ns_per_m/16e3, t.dampers.csay_ns_per_m/160e3, ek);
        }
    }
    println!(
        "per step {:?} resamples {}",
        t0.elapsed() / k,
        m.rbpf().resample_count()
    );
}
