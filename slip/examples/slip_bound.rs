//! The information bound on each loss of a scenario (`railmon_slip::bound`): for every drive
//! that loses adhesion, each loss's length by the slip rule, its depth, the earliest detection
//! and release any detector with mean time `gamma` to a false alarm can reach (steps after
//! the truth's edges), and the drive's F1 at those delays. Printed for `gamma` = 1000 steps
//! (one false alarm per 1000 steps, the 0.1 % bar read as loosely as it goes) and 20,000 (one
//! per drive and scenario run). Used for docs/adhesion.md, "Short losses".
//!
//! `cargo run --release -p railmon-slip --example slip_bound -- SCENARIO.toml [DRIVE ...]`

use railmon_slip::bound::{delay_bound_steps, f1_bound, LoadChangeInformation, LossAtBound};
use railmon_slip::model::DriveState;
use railmon_slip::{AdhesionScenario, DriveModel, DriveSimulator};

/// Steps of data before a loss's first flagged step that the bound's detector may use.
const LEAD_STEPS: usize = 300;

/// One loss of one drive: the truth's flagged steps `[on, off)` and the true departure from
/// the healthy load over the scenario.
struct Loss {
    on: usize,
    off: usize,
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(path) = args.first() else {
        eprintln!("usage: slip_bound SCENARIO.toml [DRIVE ...]");
        std::process::exit(2);
    };
    let text = std::fs::read_to_string(path).expect("scenario file");
    let scenario = AdhesionScenario::from_toml_str(&text).expect("scenario");
    let drives: Vec<usize> = args[1..]
        .iter()
        .map(|d| d.parse::<usize>().expect("DRIVE") - 1)
        .collect();
    let n = scenario.n_drives();
    let model = DriveModel::new(scenario.plant.motor, scenario.dt_s()).expect("model");
    let noise = scenario.noise;
    let mut info: Vec<LoadChangeInformation> = (0..n)
        .map(|_| {
            LoadChangeInformation::new(
                model,
                noise.current_std_a,
                noise.voltage_std_v,
                noise.load_std_nm,
            )
        })
        .collect();
    let mut slipping = vec![Vec::new(); n];
    let mut sim = DriveSimulator::new(&scenario).expect("simulator");
    while let Some((samples, truth)) = sim.step() {
        for k in 0..n {
            let (s, t) = (&samples[k], &truth[k]);
            info[k].push(&DriveState::new(
                s.i_alpha_a,
                s.i_beta_a,
                t.speed_rad_s,
                t.angle_rad,
                t.torque_nm,
            ));
            slipping[k].push(t.slipping);
        }
    }
    let departure = |k: usize, t: usize| {
        scenario.true_load_nm(k, t as f64).0 - scenario.healthy_load_nm(k, t as f64)
    };
    println!("| scenario | drive | loss (steps by the slip rule) | depth [N m] | onset bound, gamma 1000 / 20000 [steps] | release bound [steps] | F1 bound, gamma 1000 / 20000 | the same, delays 10 % shorter |");
    println!("|---|---|---|---|---|---|---|---|");
    for k in 0..n {
        if !drives.is_empty() && !drives.contains(&k) {
            continue;
        }
        let losses = losses(&slipping[k]);
        if losses.is_empty() {
            continue;
        }
        let mut rows = Vec::new();
        let mut at_bound = [Vec::new(), Vec::new()];
        let mut shorter = [Vec::new(), Vec::new()];
        let mut after = 0;
        for loss in &losses {
            // The onset: the departure as it happens up to its deepest point, held there
            // (the loss as if it never ended); the release: the change from that held level.
            let peak = (loss.on..loss.off)
                .max_by(|&a, &b| departure(k, a).abs().total_cmp(&departure(k, b).abs()))
                .expect("a loss has steps");
            let depth = departure(k, peak);
            let from = loss.on.saturating_sub(LEAD_STEPS).max(after);
            let end = (loss.off + LEAD_STEPS).min(info[k].len());
            let onset: Vec<f64> = (from..end)
                .map(|t| if t <= peak { departure(k, t) } else { depth })
                .collect();
            let release: Vec<f64> = (peak..end).map(|t| departure(k, t) - depth).collect();
            let k_on = info[k].cumulative_kl(from, &onset);
            let k_off = info[k].cumulative_kl(peak, &release);
            let mut cells = Vec::new();
            for (g, gamma) in [1000f64, 20_000.0].into_iter().enumerate() {
                // Detection at step `from + i` at the earliest (the load of step `from + i - 1`
                // is first seen in that step's currents).
                let seen =
                    |start: usize, kl: &[f64]| delay_bound_steps(kl, gamma.ln()).map(|i| start + i);
                let on = seen(from, &k_on).map_or(usize::MAX, |t| t.saturating_sub(loss.on));
                let off = seen(peak, &k_off).map_or(usize::MAX, |t| t.saturating_sub(loss.off));
                cells.push((on, off));
                let l = loss.off - loss.on;
                at_bound[g].push(LossAtBound {
                    slipping_steps: l,
                    onset_delay_steps: on,
                    release_delay_steps: off,
                });
                shorter[g].push(LossAtBound {
                    slipping_steps: l,
                    onset_delay_steps: on * 9 / 10,
                    release_delay_steps: off * 9 / 10,
                });
            }
            rows.push((loss, depth, cells));
            after = loss.off;
        }
        let steps = |v: usize| {
            if v == usize::MAX {
                "never".to_owned()
            } else {
                v.to_string()
            }
        };
        let losses_cell: Vec<String> = rows
            .iter()
            .map(|(l, _, _)| format!("{} ({}-{})", l.off - l.on, l.on, l.off - 1))
            .collect();
        let depth_cell: Vec<String> = rows.iter().map(|(_, d, _)| format!("{d:.1}")).collect();
        let onset_cell: Vec<String> = rows
            .iter()
            .map(|(_, _, c)| format!("{} / {}", steps(c[0].0), steps(c[1].0)))
            .collect();
        let release_cell: Vec<String> = rows
            .iter()
            .map(|(_, _, c)| format!("{} / {}", steps(c[0].1), steps(c[1].1)))
            .collect();
        println!(
            "| {} | {} | {} | {} | {} | {} | {:.3} / {:.3} | {:.3} / {:.3} |",
            scenario.name,
            k + 1,
            losses_cell.join(", "),
            depth_cell.join(", "),
            onset_cell.join(", "),
            release_cell.join(", "),
            f1_bound(&at_bound[0]),
            f1_bound(&at_bound[1]),
            f1_bound(&shorter[0]),
            f1_bound(&shorter[1]),
        );
    }
}

/// The truth's runs of flagged steps.
fn losses(slipping: &[bool]) -> Vec<Loss> {
    let mut out = Vec::new();
    let mut start = None;
    for (t, &s) in slipping.iter().chain(std::iter::once(&false)).enumerate() {
        match (s, start) {
            (true, None) => start = Some(t),
            (false, Some(on)) => {
                out.push(Loss { on, off: t });
                start = None;
            }
            _ => {}
        }
    }
    out
}
