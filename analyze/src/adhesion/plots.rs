//! PNG plots after the paper's figures 5-9:
//! - `torque_drive{k}.png`: EKF torque estimate of drive k against the true load (the upper
//!   panels of figures 5-8; the same EKF feeds every method);
//! - `{method}_differences.png`: `M_z,i - M_z^(G)` of every drive (lower panels of 5-8);
//! - `{method}_histogram_drive{k}.png`: histogram of the same differences (figure 9);
//! - `{method}_slip_probability.png`: the per-drive probability of adhesion loss.

use std::path::Path;

use super::{AdhesionAnalysisError, AdhesionReport, AdhesionRun};
use crate::report::{histogram, line_plot, Axes, Series};

fn indexed(values: &[f64]) -> Vec<(f64, f64)> {
    values
        .iter()
        .enumerate()
        .map(|(i, &v)| (i as f64, v))
        .collect()
}

/// Writes every plot of `run` into `out`.
pub fn write_all(
    run: &AdhesionRun,
    _report: &AdhesionReport,
    out: &Path,
) -> Result<(), AdhesionAnalysisError> {
    let drive_labels: Vec<String> = (1..=run.n_drives).map(|k| format!("drive {k}")).collect();
    for k in 0..run.n_drives {
        let mut series = vec![Series {
            label: "EKF estimate",
            points: indexed(&run.ekf_torque_nm[k]),
        }];
        if let Some(truth) = &run.truth {
            let t: Vec<f64> = truth[k].iter().map(|&(torque, _)| torque).collect();
            series.insert(
                0,
                Series {
                    label: "true load",
                    points: indexed(&t),
                },
            );
        }
        let title = format!("Load torque of drive {}: true and EKF estimate", k + 1);
        let axes = Axes {
            title: &title,
            x_label: "step (125 us)",
            y_label: "torque [N m]",
        };
        line_plot(
            &out.join(format!("torque_drive{}.png", k + 1)),
            &axes,
            &series,
        )?;
    }
    for trace in &run.methods {
        let method = trace.method;
        let diffs: Vec<Vec<f64>> = run
            .ekf_torque_nm
            .iter()
            .map(|x| {
                x.iter()
                    .zip(&trace.global_torque_nm)
                    .map(|(a, g)| a - g)
                    .collect()
            })
            .collect();
        let series: Vec<Series> = diffs
            .iter()
            .zip(&drive_labels)
            .map(|(d, label)| Series {
                label,
                points: indexed(d),
            })
            .collect();
        let title = format!("{method}: M_z,i - M_z^(G)");
        let axes = Axes {
            title: &title,
            x_label: "step (125 us)",
            y_label: "difference [N m]",
        };
        line_plot(
            &out.join(format!("{method}_differences.png")),
            &axes,
            &series,
        )?;
        for (k, d) in diffs.iter().enumerate() {
            let title = format!("{method}: histogram of M_z,{} - M_z^(G)", k + 1);
            let axes = Axes {
                title: &title,
                x_label: "difference [N m]",
                y_label: "steps",
            };
            histogram(
                &out.join(format!("{method}_histogram_drive{}.png", k + 1)),
                &axes,
                d,
                100,
            )?;
        }
        let series: Vec<Series> = trace
            .slip_probability
            .iter()
            .zip(&drive_labels)
            .map(|(p, label)| Series {
                label,
                points: indexed(p),
            })
            .collect();
        let title = format!("{method}: probability of adhesion loss");
        let axes = Axes {
            title: &title,
            x_label: "step (125 us)",
            y_label: "probability",
        };
        line_plot(
            &out.join(format!("{method}_slip_probability.png")),
            &axes,
            &series,
        )?;
    }
    Ok(())
}
