//! The information bound on each loss of a scenario (`railmon_slip::bound`): for every drive
//! that loses adhesion, each loss's length by the slip rule, its depth, the earliest detection
//! and release any detector with mean time `gamma` to a false alarm can reach (steps after
//! the truth's edges), and the drive's F1 at those delays. Printed for `gamma` = 1000 steps
//! (one false alarm per 1000 steps, the 0.1 % bar read as loosely as it goes) and 20,000 (one
//! per drive and scenario run). Used for docs/adhesion.md, "Short losses".
//!
//! `cargo run --release -p railmon-slip --example slip_bound -- SCENARIO.toml [DRIVE ...]`

use railmon_slip::bound::{f1_bound, losses_at_bound, LoadChangeInformation, LossAtBound};
use railmon_slip::model::DriveState;
use railmon_slip::{AdhesionScenario, DriveModel, DriveSimulator};

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
        let losses = losses_at_bound(&info[k], &slipping[k], |t| departure(k, t));
        if losses.is_empty() {
            continue;
        }
        let at_bound = [0, 1].map(|g| losses.iter().map(|l| l.at_bound[g]).collect::<Vec<_>>());
        let shorter = at_bound.clone().map(|v| {
            v.into_iter()
                .map(|l| LossAtBound {
                    onset_delay_steps: shorten(l.onset_delay_steps),
                    release_delay_steps: shorten(l.release_delay_steps),
                    ..l
                })
                .collect::<Vec<_>>()
        });
        let rows: Vec<_> = losses
            .iter()
            .map(|l| {
                let cells = l
                    .at_bound
                    .map(|b| (b.onset_delay_steps, b.release_delay_steps));
                ((l.on, l.off), l.depth_nm, cells)
            })
            .collect();
        let steps = |v: usize| {
            if v == usize::MAX {
                "never".to_owned()
            } else {
                v.to_string()
            }
        };
        let losses_cell: Vec<String> = rows
            .iter()
            .map(|((on, off), _, _)| format!("{} ({on}-{})", off - on, off - 1))
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

/// A delay 10 % shorter ("never" stays never).
fn shorten(steps: usize) -> usize {
    if steps == usize::MAX {
        steps
    } else {
        steps * 9 / 10
    }
}
