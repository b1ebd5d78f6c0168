//! The report's figures, after the paper's: fuel and its estimates over time (fig. 1), the
//! regime probabilities (in place of fig. 2's gear prediction) and the clusters (fig. 3:
//! fuel against vehicle and engine speed, coloured by the active component).

use std::path::Path;

use super::Evaluation;
use crate::report::{line_plot, scatter_plot, Axes, ReportError, Series};

pub(super) fn write_all(
    out: &Path,
    name: &str,
    ev: &Evaluation,
    labels: Option<&[String]>,
) -> Result<(), ReportError> {
    let series = |rows: &[super::PredictionRow]| {
        let pick = |f: fn(&super::PredictionRow) -> f64| {
            rows.iter().map(|r| (r.time_s, f(r))).collect::<Vec<_>>()
        };
        vec![
            Series {
                label: "measured",
                points: pick(|r| r.fuel_cm3_s),
            },
            Series {
                label: "mixture 0-step",
                points: pick(|r| r.zero_step_cm3_s),
            },
            Series {
                label: "mixture 1-step forecast",
                points: pick(|r| r.one_step_cm3_s),
            },
            Series {
                label: "virtual sensor",
                points: pick(|r| r.virtual_sensor_cm3_s),
            },
        ]
    };
    let title = format!("{name}: fuel flow and its estimates");
    let axes = Axes {
        title: &title,
        x_label: "time (s)",
        y_label: "fuel (cm^3/s)",
    };
    line_plot(&out.join("fuel_predictions.png"), &axes, &series(&ev.rows))?;
    let zoom = &ev.rows[..ev.rows.len().min(300)];
    let title_zoom = format!("{name}: first 300 s after initialisation");
    line_plot(
        &out.join("fuel_predictions_zoom.png"),
        &Axes {
            title: &title_zoom,
            ..axes
        },
        &series(zoom),
    )?;

    let names: Vec<String> = (0..ev.components).map(|i| format!("regime {i}")).collect();
    let mut regime_series: Vec<Series> = names
        .iter()
        .enumerate()
        .map(|(i, n)| Series {
            label: n,
            points: ev
                .rows
                .iter()
                .map(|r| (r.time_s, r.regime_probabilities[i]))
                .collect(),
        })
        .collect();
    if let Some(labels) = labels {
        // The label index scaled to [0, 1], drawn over the probabilities.
        let scale = (labels.len().max(2) - 1) as f64;
        let points = ev
            .rows
            .iter()
            .filter_map(|r| r.label.map(|l| (r.time_s, l as f64 / scale)))
            .collect();
        regime_series.push(Series {
            label: "label index / (labels - 1)",
            points,
        });
    }
    let title_regimes = format!("{name}: regime probabilities w_t");
    line_plot(
        &out.join("regime_probabilities.png"),
        &Axes {
            title: &title_regimes,
            x_label: "time (s)",
            y_label: "probability",
        },
        &regime_series,
    )?;

    let by_component = |x: fn(&super::PredictionRow) -> Option<f64>| -> Vec<Vec<(f64, f64)>> {
        let mut groups = vec![Vec::new(); ev.components];
        for r in &ev.rows {
            if let Some(v) = x(r) {
                groups[r.active_regime].push((v, r.fuel_cm3_s));
            }
        }
        groups
    };
    let speed = by_component(|r| r.speed_m_s);
    if speed.iter().any(|g| !g.is_empty()) {
        scatter(
            &out.join("clusters_fuel_speed.png"),
            &format!("{name}: fuel vs speed by active component"),
            "speed (m/s)",
            speed,
        )?;
    }
    let rpm = by_component(|r| r.engine_speed_rpm);
    if rpm.iter().any(|g| !g.is_empty()) {
        scatter(
            &out.join("clusters_fuel_engine_speed.png"),
            &format!("{name}: fuel vs engine speed by active component"),
            "engine speed (rpm)",
            rpm,
        )?;
    }
    Ok(())
}

/// Fuel against `x`, one colour per component (fig. 3).
fn scatter(
    path: &Path,
    title: &str,
    x_label: &str,
    groups: Vec<Vec<(f64, f64)>>,
) -> Result<(), ReportError> {
    let labels: Vec<String> = (0..groups.len())
        .map(|i| format!("component {i}"))
        .collect();
    let series: Vec<Series> = groups
        .into_iter()
        .zip(&labels)
        .map(|(points, label)| Series { label, points })
        .collect();
    let axes = Axes {
        title,
        x_label,
        y_label: "fuel (cm^3/s)",
    };
    scatter_plot(path, &axes, &series)
}
