//! The settings reference, generated from the settings types themselves: each key's path, type,
//! bounds, unit, default and meaning (the first sentence of its doc comment), read from the
//! type's JSON schema (`schemars`, which carries the doc comments) and its `Default`. Nothing
//! is written twice, so the reference cannot drift from the code (`railmon config reference`,
//! `docs/configuration.md`).

use schemars::JsonSchema;
use serde::Serialize;
use serde_json::Value;

/// One key of the reference.
#[derive(Clone, Debug, PartialEq)]
pub struct KeyDoc {
    /// Dotted path (`http.listen`, `bogie.estimator.rbpf.particles`).
    pub key: String,
    /// The value's kind: `integer`, `number`, `string`, `boolean`, `array of number`, one of
    /// the names of an enumeration, ...
    pub kind: String,
    /// Bounds the type itself sets (`>= 0` for an unsigned integer), if any.
    pub bounds: Option<String>,
    /// The unit read from the key's name (`_ms`: ms, `_m_s2`: m/s^2), if it has one.
    pub unit: Option<&'static str>,
    /// The default as TOML (`none` for an absent optional value).
    pub default: String,
    /// The first sentence of the key's doc comment.
    pub meaning: String,
}

/// A section (table) of the reference: its path and the first paragraph of its doc comment.
#[derive(Clone, Debug, PartialEq)]
pub struct SectionDoc {
    pub path: String,
    pub doc: String,
    /// Named presets the table may start from (`preset = "<name>"`), besides `default`.
    pub presets: Vec<&'static str>,
    pub keys: Vec<KeyDoc>,
}

/// Every section and key of `T`, in declaration order; `presets` names the tables (dotted
/// paths) that take `preset = "<name>"`, with their preset names.
pub fn sections<T: JsonSchema + Serialize + Default>(
    presets: &[(&str, &'static [&'static str])],
) -> Vec<SectionDoc> {
    let schema = schemars::schema_for!(T);
    let root = schema.as_value();
    let defaults = serde_json::to_value(T::default()).unwrap_or(Value::Null);
    let mut out = Vec::new();
    let walker = Walker { root, presets };
    walker.section(root, &defaults, "", "", &mut out);
    out
}

struct Walker<'a> {
    root: &'a Value,
    presets: &'a [(&'a str, &'static [&'static str])],
}

impl Walker<'_> {
    /// `schema` with its `$ref` (or a single-`$ref` `allOf`) followed.
    fn resolve<'s>(&'s self, schema: &'s Value) -> &'s Value {
        let reference = schema.get("$ref").and_then(Value::as_str).or_else(|| {
            match schema.get("allOf").and_then(Value::as_array) {
                Some(all) if all.len() == 1 => all[0].get("$ref").and_then(Value::as_str),
                _ => None,
            }
        });
        match reference.and_then(|r| r.strip_prefix("#/")) {
            Some(pointer) => self
                .root
                .pointer(&format!("/{pointer}"))
                .map(|s| self.resolve(s))
                .unwrap_or(schema),
            None => schema,
        }
    }

    fn section(
        &self,
        schema: &Value,
        defaults: &Value,
        path: &str,
        doc: &str,
        out: &mut Vec<SectionDoc>,
    ) {
        let schema = self.resolve(schema);
        let Some(properties) = schema.get("properties").and_then(Value::as_object) else {
            return;
        };
        let presets = (self.presets.iter())
            .find(|(p, _)| *p == path)
            .map(|(_, names)| names.to_vec())
            .unwrap_or_default();
        let at = out.len();
        out.push(SectionDoc {
            path: path.to_string(),
            doc: first_paragraph(doc),
            presets,
            keys: Vec::new(),
        });
        let mut subsections = Vec::new();
        for (name, property) in properties {
            let key = match path.is_empty() {
                true => name.clone(),
                false => format!("{path}.{name}"),
            };
            let resolved = self.resolve(property);
            let description = description(property).or_else(|| description(resolved));
            let default = defaults.get(name).unwrap_or(&Value::Null);
            if resolved.get("properties").is_some() {
                subsections.push((resolved, default, key, description.unwrap_or_default()));
                continue;
            }
            out[at].keys.push(KeyDoc {
                unit: unit_of(name),
                kind: self.kind(resolved),
                bounds: bounds(resolved),
                default: toml_text(default),
                meaning: first_sentence(&description.unwrap_or_default()),
                key,
            });
        }
        for (schema, default, key, doc) in subsections {
            self.section(schema, default, &key, &doc, out);
        }
    }

    fn kind(&self, schema: &Value) -> String {
        let schema = self.resolve(schema);
        if let Some(names) = enum_names(schema) {
            return format!("one of {}", names.join(", "));
        }
        for alternatives in ["anyOf", "oneOf"] {
            if let Some(list) = schema.get(alternatives).and_then(Value::as_array) {
                let kinds: Vec<String> = list
                    .iter()
                    .filter(|s| s.get("type").and_then(Value::as_str) != Some("null"))
                    .map(|s| self.kind(s))
                    .collect();
                let optional = kinds.len() < list.len();
                let kind = kinds.join(" or ");
                return match optional {
                    true => format!("{kind}, optional"),
                    false => kind,
                };
            }
        }
        let types: Vec<&str> = match schema.get("type") {
            Some(Value::String(t)) => vec![t.as_str()],
            Some(Value::Array(ts)) => ts.iter().filter_map(Value::as_str).collect(),
            _ => Vec::new(),
        };
        let optional = types.contains(&"null");
        let kind = match types.iter().find(|t| **t != "null") {
            Some(&"array") => match schema.get("items") {
                Some(items) => format!("array of {}", self.kind(items)),
                None => "array".into(),
            },
            Some(&"object") => "table".into(),
            Some(t) => (*t).to_string(),
            None => "any".into(),
        };
        match optional {
            true => format!("{kind}, optional"),
            false => kind,
        }
    }
}

fn description(schema: &Value) -> Option<String> {
    schema
        .get("description")
        .and_then(Value::as_str)
        .map(str::to_owned)
}

/// The names of a string enumeration (`enum: [...]`, or `oneOf` of constants).
fn enum_names(schema: &Value) -> Option<Vec<String>> {
    if let Some(values) = schema.get("enum").and_then(Value::as_array) {
        return Some(values.iter().map(|v| v.to_string()).collect());
    }
    let list = schema.get("oneOf").and_then(Value::as_array)?;
    list.iter()
        .map(|s| {
            s.get("const").map(Value::to_string).or_else(|| {
                let values = s.get("enum").and_then(Value::as_array)?;
                Some(
                    values
                        .iter()
                        .map(Value::to_string)
                        .collect::<Vec<_>>()
                        .join(", "),
                )
            })
        })
        .collect()
}

/// The bounds a schema (or an array's items) declares, as a user reads them at once: `>= 0`,
/// `> 0`, `(0, 1]`, `[0, 1)`, `< 1`, or `lo ..= hi` where both ends are closed (as integer
/// ranges are written). JSON Schema's `minimum`/`maximum` are closed ends,
/// `exclusiveMinimum`/`exclusiveMaximum` open ones (schemars: `range(min = ..)`, or
/// `extend("exclusiveMinimum" = ..)`); an open end wins where a key declares both.
fn bounds(schema: &Value) -> Option<String> {
    let item = schema.get("items").unwrap_or(schema);
    let end = |closed: &str, open: &str| {
        let value = |name: &str| item.get(name).and_then(Value::as_number).map(number_text);
        match (value(open), value(closed)) {
            (Some(o), _) => Some((o, false)),
            (None, Some(c)) => Some((c, true)),
            (None, None) => None,
        }
    };
    let lower = end("minimum", "exclusiveMinimum");
    let upper = end("maximum", "exclusiveMaximum");
    Some(match (lower, upper) {
        (Some((lo, true)), Some((hi, true))) => format!("{lo} ..= {hi}"),
        (Some((lo, lo_closed)), Some((hi, hi_closed))) => format!(
            "{}{lo}, {hi}{}",
            if lo_closed { '[' } else { '(' },
            if hi_closed { ']' } else { ')' }
        ),
        (Some((lo, closed)), None) => format!("{} {lo}", if closed { ">=" } else { ">" }),
        (None, Some((hi, closed))) => format!("{} {hi}", if closed { "<=" } else { "<" }),
        (None, None) => return None,
    })
}

/// A bound as text: integers as they are (`1000000000`), a float below 1e-4 or from 1e9 on
/// in exponent form (`1e-12`, not `0.000000000001`), otherwise as Rust prints it (`0.5`).
fn number_text(n: &serde_json::Number) -> String {
    match n.as_f64() {
        Some(f) if n.is_f64() && f != 0.0 && !(1e-4..1e9).contains(&f.abs()) => format!("{f:e}"),
        Some(f) if n.is_f64() => format!("{f}"),
        _ => n.to_string(),
    }
}

/// The unit a key's name ends in (the house rule: units in names where not obvious).
fn unit_of(name: &str) -> Option<&'static str> {
    const SUFFIXES: &[(&str, &str)] = &[
        ("_per_sqrt_s", "1/sqrt(s)"),
        ("_per_s", "1/s"),
        ("_ns_per_m", "N s/m"),
        ("_m_s2", "m/s^2"),
        ("_rpm", "rpm"),
        ("_pct", "%"),
        ("_rad_s", "rad/s"),
        ("_m_s", "m/s"),
        ("_cm3_s", "cm^3/s"),
        ("_n_s_m", "N s/m"),
        ("_nm2", "(N m)^2"),
        ("_nm", "N m"),
        ("_a2", "A^2"),
        ("_ms", "ms"),
        ("_us", "us"),
        ("_ns", "ns"),
        ("_s", "s"),
        ("_kg", "kg"),
        ("_kg_m2", "kg m^2"),
        ("_km_h", "km/h"),
        ("_permille", "per mille"),
        ("_bytes", "bytes"),
        ("_days", "days"),
        ("_hz", "Hz"),
        ("_rad", "rad"),
        ("_ohm", "ohm"),
        ("_wb", "Wb"),
        ("_h", "H"),
        ("_a", "A"),
        ("_v", "V"),
        ("_m", "m"),
        ("_kw", "kW"),
        ("_w", "W"),
    ];
    SUFFIXES
        .iter()
        .find(|(suffix, _)| name.ends_with(suffix))
        .map(|(_, unit)| *unit)
}

/// A default as TOML text (`none` for an absent optional value).
fn toml_text(value: &Value) -> String {
    match value {
        Value::Null => "none".into(),
        Value::String(s) => format!("{s:?}"),
        Value::Array(items) => {
            let items: Vec<String> = items.iter().map(toml_text).collect();
            format!("[{}]", items.join(", "))
        }
        Value::Object(map) => {
            let items: Vec<String> = map
                .iter()
                .map(|(k, v)| format!("{k} = {}", toml_text(v)))
                .collect();
            format!("{{ {} }}", items.join(", "))
        }
        Value::Number(n) => match n.as_f64() {
            // 1.0, not 1: the key is a float in TOML.
            Some(f) if n.is_f64() && f.fract() == 0.0 && f.abs() < 1e15 => format!("{f:.1}"),
            _ => n.to_string(),
        },
        Value::Bool(b) => b.to_string(),
    }
}

/// The first paragraph of a doc comment, on one line.
fn first_paragraph(doc: &str) -> String {
    let paragraph = doc.split("\n\n").next().unwrap_or_default();
    paragraph.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// Abbreviations whose full stop ends no sentence.
const ABBREVIATIONS: &[&str] = &["e.g", "i.e", "cf", "vs", "approx"];

/// The first sentence of a doc comment (up to a full stop followed by a space or the end, or
/// the end of its first paragraph), on one line.
fn first_sentence(doc: &str) -> String {
    let paragraph = first_paragraph(doc);
    let (mut depth, mut code) = (0i32, false);
    let bytes = paragraph.as_bytes();
    for (i, c) in paragraph.char_indices() {
        match c {
            '`' => code = !code,
            '(' | '[' if !code => depth += 1,
            ')' | ']' if !code => depth -= 1,
            '.' if !code
                && depth <= 0
                && bytes.get(i + 1).is_none_or(|b| *b == b' ')
                && !ABBREVIATIONS.iter().any(|a| paragraph[..i].ends_with(a)) =>
            {
                return paragraph[..=i].to_string();
            }
            _ => {}
        }
    }
    paragraph
}

/// The reference as Markdown: a table per section; `site` tells the site settings (tier `site`)
/// from the expert tuning (tier `expert`).
pub fn markdown(
    title: &str,
    preamble: &str,
    sections: &[SectionDoc],
    site: impl Fn(&str) -> bool,
) -> String {
    let mut out = format!("# {title}\n\n{preamble}\n");
    for section in sections.iter().filter(|s| !s.keys.is_empty()) {
        let name = match section.path.is_empty() {
            true => "(top level)".to_string(),
            false => format!("[{}]", section.path),
        };
        out.push_str(&format!("\n## `{name}`\n\n"));
        if !section.doc.is_empty() {
            out.push_str(&format!("{}\n\n", section.doc));
        }
        if !section.presets.is_empty() {
            out.push_str(&format!(
                "Starts from `preset = \"default\"`; also `{}`. Keys given override single values of the preset.\n\n",
                section
                    .presets
                    .iter()
                    .map(|p| format!("\"{p}\""))
                    .collect::<Vec<_>>()
                    .join("`, `")
            ));
        }
        out.push_str(
            "| key | default | type | unit | tier | meaning |\n|---|---|---|---|---|---|\n",
        );
        for key in &section.keys {
            let short = key.key.rsplit('.').next().unwrap_or(&key.key);
            let kind = match &key.bounds {
                Some(b) => format!("{}, {b}", key.kind),
                None => key.kind.clone(),
            };
            out.push_str(&format!(
                "| `{short}` | `{}` | {} | {} | {} | {} |\n",
                cell(&key.default),
                cell(&kind),
                key.unit.unwrap_or(""),
                if site(&key.key) { "site" } else { "expert" },
                cell(&key.meaning)
            ));
        }
    }
    out
}

/// Text for a Markdown table cell.
fn cell(text: &str) -> String {
    text.replace('|', "\\|")
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Deserialize;

    /// How a limb is measured.
    #[derive(Clone, Copy, Debug, Default, Serialize, Deserialize, JsonSchema)]
    #[serde(rename_all = "snake_case")]
    enum Mode {
        #[default]
        Fast,
        Exact,
    }

    /// The inner part. More text.
    #[derive(Clone, Debug, Serialize, Deserialize, JsonSchema)]
    #[serde(default)]
    struct Inner {
        /// A delay (it counts). Then more.
        delay_ms: u64,
        /// Gains per axis.
        gains: Vec<f64>,
        /// Optional limit.
        limit_m_s: Option<f64>,
        mode: Mode,
    }

    impl Default for Inner {
        fn default() -> Self {
            Inner {
                delay_ms: 250,
                gains: vec![1.0, 0.5],
                limit_m_s: None,
                mode: Mode::Fast,
            }
        }
    }

    #[derive(Clone, Debug, Default, Serialize, Deserialize, JsonSchema)]
    #[serde(default)]
    struct Outer {
        /// The name, e.g. `a.b`.
        name: String,
        /// Where the inner part lives.
        inner: Inner,
    }

    /// Closed ends as `>=`/`<=` or `lo ..= hi` (the integer ranges), open ones as `>`/`<`, and a
    /// mixed or open pair in interval notation; an array's bounds are its items'.
    #[test]
    fn bounds_read_as_intervals() {
        let b = |schema: Value| bounds(&schema);
        use serde_json::json;
        assert_eq!(b(json!({"type": "number"})), None);
        assert_eq!(b(json!({"minimum": 0})).as_deref(), Some(">= 0"));
        assert_eq!(b(json!({"exclusiveMinimum": 0.0})).as_deref(), Some("> 0"));
        assert_eq!(b(json!({"maximum": 1.0})).as_deref(), Some("<= 1"));
        assert_eq!(b(json!({"exclusiveMaximum": 1})).as_deref(), Some("< 1"));
        assert_eq!(
            b(json!({"minimum": 1, "maximum": 10000})).as_deref(),
            Some("1 ..= 10000")
        );
        assert_eq!(
            b(json!({"exclusiveMinimum": 0, "maximum": 1})).as_deref(),
            Some("(0, 1]")
        );
        assert_eq!(
            b(json!({"minimum": 0, "exclusiveMaximum": 1})).as_deref(),
            Some("[0, 1)")
        );
        assert_eq!(
            b(json!({"exclusiveMinimum": -0.5, "exclusiveMaximum": 0.25})).as_deref(),
            Some("(-0.5, 0.25)")
        );
        assert_eq!(
            b(json!({"minimum": 0, "exclusiveMinimum": 0})).as_deref(),
            Some("> 0")
        );
        assert_eq!(
            b(json!({"type": "array", "items": {"exclusiveMinimum": 0}})).as_deref(),
            Some("> 0")
        );
        assert_eq!(b(json!({"minimum": 1e-9})).as_deref(), Some(">= 1e-9"));
        assert_eq!(
            b(json!({"minimum": 0.0, "maximum": 1e9})).as_deref(),
            Some("0 ..= 1e9")
        );
        assert_eq!(
            b(json!({"minimum": 1, "maximum": 1_000_000_000})).as_deref(),
            Some("1 ..= 1000000000")
        );
    }

    /// Every key with its path, kind, unit, default and first sentence; sections in order,
    /// presets where named.
    #[test]
    fn keys_carry_path_kind_unit_default_and_meaning() {
        let sections = sections::<Outer>(&[("inner", &["paper"])]);
        assert_eq!(sections.len(), 2);
        assert_eq!(sections[0].keys.len(), 1);
        let name = &sections[0].keys[0];
        assert_eq!(
            (name.key.as_str(), name.kind.as_str(), name.default.as_str()),
            ("name", "string", "\"\"")
        );
        assert_eq!(name.meaning, "The name, e.g. `a.b`.");
        let inner = &sections[1];
        assert_eq!(inner.path, "inner");
        assert_eq!(inner.doc, "Where the inner part lives.");
        assert_eq!(inner.presets, vec!["paper"]);
        let keys: Vec<_> = inner.keys.iter().map(|k| k.key.as_str()).collect();
        assert_eq!(
            keys,
            [
                "inner.delay_ms",
                "inner.gains",
                "inner.limit_m_s",
                "inner.mode"
            ]
        );
        let delay = &inner.keys[0];
        assert_eq!(delay.unit, Some("ms"));
        assert_eq!(delay.default, "250");
        assert_eq!(delay.bounds.as_deref(), Some(">= 0"));
        assert_eq!(delay.meaning, "A delay (it counts).");
        assert_eq!(inner.keys[1].kind, "array of number");
        assert_eq!(inner.keys[1].default, "[1.0, 0.5]");
        assert_eq!(inner.keys[2].default, "none");
        assert_eq!(inner.keys[2].unit, Some("m/s"));
        assert!(
            inner.keys[2].kind.ends_with("optional"),
            "{:?}",
            inner.keys[2]
        );
        assert_eq!(inner.keys[3].kind, "one of \"fast\", \"exact\"");
        let text = markdown("T", "P", &sections, |key| key.starts_with("inner."));
        assert!(text.contains("## `[inner]`"), "{text}");
        assert!(
            text.contains(
                "| `delay_ms` | `250` | integer, >= 0 | ms | site | A delay (it counts). |"
            ),
            "{text}"
        );
        assert!(
            text.contains("| `name` | `\"\"` | string |  | expert |"),
            "{text}"
        );
    }
}
