//! Golden files: seeded headline numbers pinned in `tests/data/golden/<name>` (CSV with a header
//! line), compared at a tight relative tolerance, rewritten by one switch
//! (`RAILMON_UPDATE_GOLDEN=1`, which `scripts/regen-golden` sets). One format and one comparison
//! for every estimator's golden test, so that they cannot drift apart. And the layouts of the
//! estimators' saved states, pinned under their format versions ([`check_state_layout`]).
//! A dev-dependency only.
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

/// Pins the serialised layout of an estimator's saved state: the formats of every type in
/// `value` as bincode sees them (field names and order, primitive types, sequences, options,
/// the enum variants the `values` hold), traced by `serde-reflection`, in the text file `name`
/// under the state's format `version`. A layout that changed under the same version fails:
/// the service would decode an old snapshot into other numbers, or not at all, without the
/// version saying why (`service/src/snapshot.rs`). Raise the version, then rewrite the file
/// with `RAILMON_UPDATE_GOLDEN=1`; it refuses to rewrite a changed layout under the pinned
/// version. What it cannot see: an enum variant no value holds, the element type of a
/// sequence empty in every value or of an option `None` in every value (written `?`, so that
/// a reviewer sees it): give it values that between them hold each.
///
/// `pinned_elsewhere` names other layout files whose types this check leaves out: a state that
/// wraps an estimator's (the service's snapshot around `SlipMonitor`) pins only its own types,
/// under its own version.
pub fn check_state_layout<T: serde::Serialize>(
    name: &str,
    version: u32,
    values: &[T],
    pinned_elsewhere: &[&str],
) {
    let mut now = state_layout(values);
    for other in pinned_elsewhere {
        let other = path(other);
        let text =
            std::fs::read_to_string(&other).unwrap_or_else(|e| panic!("{}: {e}", other.display()));
        now = without_types_of(&now, &text);
    }
    let path = path(name);
    let pinned = std::fs::read_to_string(&path).ok();
    let update = std::env::var_os(UPDATE_VARIABLE).is_some();
    match layout_verdict(pinned.as_deref(), version, &now, update) {
        Ok(None) => {}
        Ok(Some(text)) => {
            std::fs::create_dir_all(path.parent().expect("a parent")).expect("tests/data/golden");
            std::fs::write(&path, text).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        }
        Err(why) => panic!("{}: {why}", path.display()),
    }
}

/// What [`check_state_layout`] does with the pinned text and the layout now: `Ok(None)` they
/// agree, `Ok(Some(text))` write `text` (`update`), `Err` why not.
fn layout_verdict(
    pinned: Option<&str>,
    version: u32,
    now: &str,
    update: bool,
) -> Result<Option<String>, String> {
    let pinned = match pinned {
        Some(text) => {
            let (first, layout) = text.split_once('\n').unwrap_or((text, ""));
            let pinned_version = first
                .strip_prefix("format version ")
                .and_then(|v| v.parse::<u32>().ok())
                .ok_or_else(|| format!("first line {first:?}, not `format version N`"))?;
            Some((pinned_version, layout))
        }
        None => None,
    };
    if let Some((pinned_version, layout)) = pinned {
        if pinned_version == version && layout != now {
            return Err(format!(
                "the serialised layout changed under format version {version}: raise the \
                 state's format version, then rewrite the file with {UPDATE_VARIABLE}=1 \
                 (first difference: {})",
                first_difference(layout, now)
            ));
        }
    }
    match pinned {
        _ if update => Ok(Some(format!("format version {version}\n{now}"))),
        None => Err(format!("missing ({UPDATE_VARIABLE}=1 writes it)")),
        Some((pinned_version, _)) if pinned_version != version => Err(format!(
            "pinned under format version {pinned_version}, the state is version {version}: \
             rewrite the file with {UPDATE_VARIABLE}=1"
        )),
        Some(_) => Ok(None),
    }
}

/// `layout` without the blocks of the types that `other` (a layout file) has a block of.
fn without_types_of(layout: &str, other: &str) -> String {
    let type_of = |line: &str| -> Option<String> {
        let starts_block = !line.starts_with(' ') && !line.starts_with("root:");
        (starts_block && !line.starts_with("format version "))
            .then(|| line.split(' ').next().unwrap_or("").to_string())
    };
    let theirs: std::collections::BTreeSet<String> = other.lines().filter_map(type_of).collect();
    let mut kept = String::new();
    let mut keep = true;
    for line in layout.lines() {
        if line.starts_with("root:") {
            keep = true;
        } else if let Some(name) = type_of(line) {
            keep = !theirs.contains(&name);
        }
        if keep {
            kept.push_str(line);
            kept.push('\n');
        }
    }
    kept
}

/// The first line where two texts differ, both sides, for a message.
fn first_difference(pinned: &str, now: &str) -> String {
    let mut now_lines = now.lines();
    for (i, p) in pinned.lines().enumerate() {
        match now_lines.next() {
            Some(n) if n == p => continue,
            n => return format!("line {}: pinned {p:?}, now {:?}", i + 2, n.unwrap_or("")),
        }
    }
    match now_lines.next() {
        Some(n) => format!("now has more lines: {n:?}"),
        None => "none".into(),
    }
}

/// The formats of every container type in `values`, one block per type, sorted by name:
/// `Name struct` and a line per field (`  field: format`), or `Name enum` and a line per
/// variant seen.
pub fn state_layout<T: serde::Serialize>(values: &[T]) -> String {
    // serde-reflection 0.6 does not fill in a type it saw as `None` in an earlier value (the
    // option's content stays unknown): trace the values starting from each in turn and keep the
    // most complete layout.
    (0..values.len().max(1))
        .map(|first| {
            let order = values[first..].iter().chain(&values[..first]);
            state_layout_in_order(order)
        })
        .min_by_key(|layout| layout.matches('?').count())
        .expect("at least one order")
}

fn state_layout_in_order<'a, T: serde::Serialize + 'a>(
    values: impl Iterator<Item = &'a T>,
) -> String {
    use serde_reflection::{ContainerFormat, Samples, Tracer, TracerConfig};
    let mut tracer = Tracer::new(TracerConfig::default());
    let mut samples = Samples::new();
    let mut roots = std::collections::BTreeSet::new();
    for value in values {
        let (root, _) = tracer
            .trace_value(&mut samples, value)
            .unwrap_or_else(|e| panic!("tracing the state's layout: {e}"));
        roots.insert(format_of(&root));
    }
    let roots: Vec<String> = roots.into_iter().collect();
    let mut text = format!("root: {}\n", roots.join(" | "));
    for (name, container) in tracer.registry_unchecked() {
        match container {
            ContainerFormat::UnitStruct => text.push_str(&format!("{name} unit\n")),
            ContainerFormat::NewTypeStruct(f) => {
                text.push_str(&format!("{name} newtype {}\n", format_of(&f)))
            }
            ContainerFormat::TupleStruct(fs) => {
                text.push_str(&format!("{name} tuple {}\n", formats_of(&fs)))
            }
            ContainerFormat::Struct(fields) => {
                text.push_str(&format!("{name} struct\n"));
                for field in fields {
                    text.push_str(&format!("  {}: {}\n", field.name, format_of(&field.value)));
                }
            }
            ContainerFormat::Enum(variants) => {
                text.push_str(&format!("{name} enum\n"));
                for (index, variant) in variants {
                    text.push_str(&format!(
                        "  {index} {}{}\n",
                        variant.name,
                        variant_of(&variant.value)
                    ));
                }
            }
        }
    }
    text
}

fn variant_of(v: &serde_reflection::VariantFormat) -> String {
    use serde_reflection::VariantFormat;
    match v {
        VariantFormat::Unit => String::new(),
        VariantFormat::NewType(f) => format!("({})", format_of(f)),
        VariantFormat::Tuple(fs) => formats_of(fs),
        VariantFormat::Struct(fields) => {
            let fields: Vec<String> = fields
                .iter()
                .map(|f| format!("{}: {}", f.name, format_of(&f.value)))
                .collect();
            format!(" {{ {} }}", fields.join(", "))
        }
        VariantFormat::Variable(_) => " ?".into(),
    }
}

fn formats_of(formats: &[serde_reflection::Format]) -> String {
    let formats: Vec<String> = formats.iter().map(format_of).collect();
    format!("({})", formats.join(", "))
}

fn format_of(f: &serde_reflection::Format) -> String {
    use serde_reflection::Format;
    match f {
        Format::Variable(_) => "?".into(),
        Format::TypeName(name) => name.clone(),
        Format::Option(f) => format!("Option<{}>", format_of(f)),
        Format::Seq(f) => format!("[{}]", format_of(f)),
        Format::Map { key, value } => format!("{{{}: {}}}", format_of(key), format_of(value)),
        Format::Tuple(fs) => formats_of(fs),
        Format::TupleArray { content, size } => format!("[{}; {size}]", format_of(content)),
        primitive => format!("{primitive:?}").to_lowercase(),
    }
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

    /// A changed layout under the pinned version fails, with or without the rewrite switch;
    /// under a raised version it is rewritten, and without the switch it names the versions.
    #[test]
    fn a_changed_layout_needs_a_raised_version() {
        let pinned = "format version 3\nA struct\n  x: f64\n";
        let (same, changed) = ("A struct\n  x: f64\n", "A struct\n  x: f32\n");
        assert_eq!(layout_verdict(Some(pinned), 3, same, false), Ok(None));
        for update in [false, true] {
            let e = layout_verdict(Some(pinned), 3, changed, update).unwrap_err();
            assert!(
                e.contains("raise") && e.contains("pinned \"  x: f64\""),
                "{e}"
            );
        }
        let e = layout_verdict(Some(pinned), 4, changed, false).unwrap_err();
        assert!(e.contains("version 3, the state is version 4"), "{e}");
        assert_eq!(
            layout_verdict(Some(pinned), 4, changed, true),
            Ok(Some(format!("format version 4\n{changed}")))
        );
        assert!(layout_verdict(None, 1, same, false).is_err());
        assert!(layout_verdict(Some("A struct\n"), 1, same, false).is_err());
    }

    #[test]
    fn types_pinned_elsewhere_are_left_out() {
        let ours = "root: W\nInner struct\n  x: f64\nW struct\n  inner: Inner\n  t: u64\n";
        let theirs = "format version 2\nroot: Inner\nInner struct\n  x: f64\n";
        assert_eq!(
            without_types_of(ours, theirs),
            "root: W\nW struct\n  inner: Inner\n  t: u64\n"
        );
    }

    #[derive(serde::Serialize)]
    struct Saved {
        weights: Vec<f64>,
        pause: Option<u32>,
        mode: Mode,
        pair: (u8, [f32; 2]),
    }

    #[derive(serde::Serialize)]
    enum Mode {
        Paused,
        Running { since_s: f64 },
    }

    /// The layout names every type, field and primitive as bincode sees them, and an empty
    /// sequence's element as unknown.
    #[test]
    fn a_state_layout_names_fields_types_and_variants_seen() {
        let saved = Saved {
            weights: vec![0.5],
            pause: Some(3),
            mode: Mode::Running { since_s: 1.0 },
            pair: (1, [0.0; 2]),
        };
        assert_eq!(
            state_layout(&[&saved]),
            "root: Saved\nMode enum\n  1 Running { since_s: f64 }\nSaved struct\n  weights: [f64]\n  \
             pause: Option<u32>\n  mode: Mode\n  pair: (u8, [f32; 2])\n"
        );
        let empty = Saved {
            weights: vec![],
            ..saved
        };
        assert!(state_layout(&[&empty]).contains("weights: [?]"));
        let paused = Saved {
            mode: Mode::Paused,
            ..empty
        };
        assert!(state_layout(&[&paused]).contains("Mode enum\n  0 Paused\n"));
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
