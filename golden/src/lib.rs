//! Golden files: seeded headline numbers pinned in `tests/data/golden/<name>` (CSV with a header
//! line), compared at a tight relative tolerance, rewritten by one switch
//! (`RAILMON_UPDATE_GOLDEN=1`, which `scripts/regen-golden` sets). One format and one comparison
//! for every estimator's golden test, so that they cannot drift apart. A dev-dependency only.
#![forbid(unsafe_code)]

use std::path::PathBuf;

/// The variable that makes [`check`] write the file instead of comparing with it.
pub const UPDATE_VARIABLE: &str = "RAILMON_UPDATE_GOLDEN";

/// `tests/data/golden/<name>` of the workspace.
pub fn path(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/data/golden")
        .join(name)
}

/// A number as the golden files write it: shortest round-trip, exponent form (`1.5e4`).
pub fn number(value: f64) -> String {
    format!("{value:e}")
}

/// Whether a pinned cell and the cell now agree: both numbers within `relative_tolerance` of
/// the pinned value (at least 1e-9 of its unit, for values that are 0), else the same text.
fn agree(pinned: &str, now: &str, relative_tolerance: f64) -> bool {
    match (pinned.parse::<f64>(), now.parse::<f64>()) {
        (Ok(p), Ok(n)) if p.is_finite() && n.is_finite() => {
            (p - n).abs() <= relative_tolerance * p.abs().max(1e-9)
        }
        _ => pinned == now,
    }
}

/// Compares `rows` (each as many cells as `header`) with the golden file `name`: the same
/// header, the same number of rows, and cell by cell [`agree`]. With `RAILMON_UPDATE_GOLDEN`
/// set it writes the file instead (review the diff and say in the commit why numbers moved).
/// Panics naming the file, the row and the cell that differ.
pub fn check(name: &str, header: &[&str], rows: &[Vec<String>], relative_tolerance: f64) {
    let path = path(name);
    let now = render(header, rows);
    if std::env::var_os(UPDATE_VARIABLE).is_some() {
        std::fs::create_dir_all(path.parent().expect("a parent")).expect("tests/data/golden");
        std::fs::write(&path, now).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        return;
    }
    let pinned = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("{}: {e} ({UPDATE_VARIABLE}=1 writes it)", path.display()));
    let mut pinned_lines = pinned.lines();
    assert_eq!(
        pinned_lines.next(),
        Some(header.join(",").as_str()),
        "{}: header",
        path.display()
    );
    let pinned_rows: Vec<&str> = pinned_lines.collect();
    assert_eq!(
        pinned_rows.len(),
        rows.len(),
        "{}: row count (pinned, now)",
        path.display()
    );
    for (line, (pinned, now)) in pinned_rows.iter().zip(rows).enumerate() {
        let pinned: Vec<&str> = pinned.split(',').collect();
        assert_eq!(
            pinned.len(),
            now.len(),
            "{} line {}: cell count",
            path.display(),
            line + 2
        );
        for ((p, n), column) in pinned.iter().zip(now).zip(header) {
            assert!(
                agree(p, n, relative_tolerance),
                "{} line {}: {column} pinned {p}, now {n} (row {:?})",
                path.display(),
                line + 2,
                now
            );
        }
    }
}

/// [`check`] of `quantity,value` rows, the format of most golden files.
pub fn check_quantities(name: &str, values: &[(String, f64)], relative_tolerance: f64) {
    let rows: Vec<Vec<String>> = values
        .iter()
        .map(|(quantity, value)| vec![quantity.clone(), number(*value)])
        .collect();
    check(name, &["quantity", "value"], &rows, relative_tolerance);
}

fn render(header: &[&str], rows: &[Vec<String>]) -> String {
    let mut text = header.join(",");
    text.push('\n');
    for row in rows {
        text.push_str(&row.join(","));
        text.push('\n');
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Numbers agree within the relative tolerance of the pinned value and not beyond it; text
    /// and empty cells only when equal; a number never agrees with text.
    #[test]
    fn cells_agree_by_relative_tolerance_or_equal_text() {
        assert!(agree("1.5e4", "15000.000001", 1e-9));
        assert!(!agree("1.5e4", "15000.0001", 1e-9));
        assert!(agree("0e0", "1e-19", 1e-9));
        assert!(!agree("0e0", "1e-17", 1e-9));
        assert!(agree("vb", "vb", 1e-9) && !agree("vb", "vmp", 1e-9));
        assert!(agree("", "", 1e-9) && !agree("", "0", 1e-9));
        assert!(!agree("1", "one", 1e-9));
        assert!(agree("NaN", "NaN", 1e-9) && !agree("NaN", "1", 1e-9));
    }

    #[test]
    fn rows_render_as_csv_with_the_header_first() {
        let rows = vec![vec!["a".to_string(), number(1.5e4)]];
        assert_eq!(
            render(&["quantity", "value"], &rows),
            "quantity,value\na,1.5e4\n"
        );
    }
}
