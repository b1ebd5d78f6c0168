//! The report's figures, after the paper's: fuel and its estimates over time (fig. 1), the
//! regime probabilities (in place of fig. 2's gear prediction) and the clusters (fig. 3:
//! fuel against vehicle and engine speed, coloured by the active component).

use std::path::Path;

use plotters::prelude::*;

use super::Evaluation;
use crate::report::{line_plot, Axes, ReportError, Series};

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
            &speed,
        )?;
    }
    let rpm = by_component(|r| r.engine_speed_rpm);
    if rpm.iter().any(|g| !g.is_empty()) {
        scatter(
            &out.join("clusters_fuel_engine_speed.png"),
            &format!("{name}: fuel vs engine speed by active component"),
            "engine speed (rpm)",
            &rpm,
        )?;
    }
    Ok(())
}

/// A scatter plot of `(x, fuel)` points, one colour per group (component).
fn scatter(
    path: &Path,
    title: &str,
    x_label: &str,
    groups: &[Vec<(f64, f64)>],
) -> Result<(), ReportError> {
    let err = |e: &dyn std::fmt::Display| ReportError::new(path, e);
    let all = groups.iter().flatten();
    let (x_lo, x_hi, y_lo, y_hi) = all.fold(
        (
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ),
        |a, p| (a.0.min(p.0), a.1.max(p.0), a.2.min(p.1), a.3.max(p.1)),
    );
    let pad = |lo: f64, hi: f64| {
        let p = ((hi - lo) * 0.05).max(1e-6);
        (lo - p)..(hi + p)
    };
    let root = BitMapBackend::new(path, (900, 700)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(pad(x_lo, x_hi), pad(y_lo, y_hi))
        .map_err(|e| err(&e))?;
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc("fuel (cm^3/s)")
        .draw()
        .map_err(|e| err(&e))?;
    for (i, g) in groups.iter().enumerate() {
        let color = Palette99::pick(i).to_rgba();
        chart
            .draw_series(g.iter().map(|&p| Circle::new(p, 2, color.filled())))
            .map_err(|e| err(&e))?
            .label(format!("component {i}"))
            .legend(move |(x, y)| Circle::new((x + 10, y), 4, color.filled()));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(|e| err(&e))?;
    root.present().map_err(|e| err(&e))
}
