//! What `railmon analyze <domain>` says when it is done: the files it wrote into `--out` and
//! the headline numbers of its report, in a few lines on stdout.

use std::fmt::Write as _;
use std::path::Path;
use std::time::SystemTime;

use railmon_analyze::adhesion::AdhesionReport;
use railmon_analyze::damper::DamperReport;
use railmon_analyze::fuel::Evaluation;

/// The files of `out` written since `started` (name and size), sorted by name.
pub fn written(out: &Path, started: SystemTime) -> String {
    let files = fresh_files(out, started);
    let (n, mb) = count_and_mb(&files);
    let names: Vec<&str> = files.iter().map(|(n, _)| n.as_str()).collect();
    format!(
        "wrote {n} files ({mb:.1} MB) to {}: {}",
        out.display(),
        names.join(", ")
    )
}

/// `wrote N files (X MB) to OUT`, without the names: a many-input run's line per input.
pub fn written_briefly(out: &Path, started: SystemTime) -> String {
    let (n, mb) = count_and_mb(&fresh_files(out, started));
    format!("wrote {n} files ({mb:.1} MB) to {}", out.display())
}

fn count_and_mb(files: &[(String, u64)]) -> (usize, f64) {
    let total: u64 = files.iter().map(|(_, n)| n).sum();
    (files.len(), total as f64 / 1e6)
}

/// The files of `out` modified since `started`: name and size, sorted by name.
fn fresh_files(out: &Path, started: SystemTime) -> Vec<(String, u64)> {
    let mut files: Vec<(String, u64)> = std::fs::read_dir(out)
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|entry| {
            let meta = entry.metadata().ok()?;
            let fresh = meta.is_file() && meta.modified().ok()? >= started;
            fresh.then(|| (entry.file_name().to_string_lossy().into_owned(), meta.len()))
        })
        .collect();
    files.sort();
    files
}

/// A headline of several lines on one: its lines trimmed and joined by `; ` (by a space after
/// a line that ends in `:`).
pub fn as_one_line(text: &str) -> String {
    let mut line = String::new();
    for part in text.lines().map(str::trim).filter(|l| !l.is_empty()) {
        if !line.is_empty() {
            line.push_str(if line.ends_with(':') { " " } else { "; " });
        }
        line.push_str(part);
    }
    line
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or("-".into(), |v| format!("{v:.digits$}"))
}

/// Detection per method: F1 of every drive.
pub fn adhesion(report: &AdhesionReport) -> String {
    let mut out = format!("{} steps; detection F1 per drive:", report.n_steps);
    let mut method = None;
    for row in &report.detection {
        let name = row.method.to_string();
        if method.as_ref() != Some(&name) {
            let _ = write!(out, "\n  {name:>9}:");
            method = Some(name);
        }
        let _ = write!(out, " drive {} {}", row.drive, opt(row.score.f1, 3));
    }
    let _ = write!(out, "\n  {}", report.refused.line());
    let _ = write!(out, "\n  {}", report.timeline.line());
    out
}

/// Per method and damper: error at the end and whether the 90 % interval covers the truth.
pub fn damper(report: &DamperReport) -> String {
    let mut out = format!(
        "{} steps, {:.1} us per step; error at the end (90 % interval covers the truth):",
        report.steps, report.mean_step_us
    );
    for row in &report.summary {
        let _ = write!(
            out,
            "\n  {:>4} {:>4}: {} % ({})",
            row.method,
            row.damper,
            opt(row.error_end.map(|e| 100.0 * e), 2),
            if row.covered_end {
                "covered"
            } else {
                "not covered"
            }
        );
    }
    let _ = write!(out, "\n  {}", report.refused.line());
    let _ = write!(out, "\n  {}", report.timeline.line());
    out
}

/// RMSE of every method at its shortest horizon, and the regime accuracy when labelled.
pub fn fuel(report: &Evaluation) -> String {
    let mut out = format!("{} samples; RMSE, cm^3/s:", report.samples);
    let mut seen = Vec::new();
    for row in &report.scores {
        if seen.contains(&row.method) {
            continue;
        }
        seen.push(row.method);
        let _ = write!(
            out,
            "\n  {} ({} s ahead): {:.3}",
            row.method, row.horizon_s, row.rmse
        );
    }
    if let Some(regimes) = &report.regimes {
        let _ = write!(
            out,
            "\n  regime accuracy: {:.1} % (reported regime: {:.1} %)",
            100.0 * regimes.accuracy(),
            100.0 * regimes.confirmed_accuracy()
        );
    }
    if let Some(named) = &report.named_regimes {
        let _ = write!(
            out,
            "\n  named regime accuracy: {:.1} % (reported regime: {:.1} %)",
            100.0 * named.accuracy(),
            100.0 * named.confirmed_accuracy()
        );
    }
    let _ = write!(out, "\n  {}", report.refused.line());
    let _ = write!(out, "\n  {}", report.timeline.line());
    out
}
