//! Layered settings for the railmon binaries and estimators:
//! defaults < named preset < TOML file < environment.
//!
//! - Every settings type has one `Default`: the validated setting, defined next to the code it
//!   configures. Other starting points (the paper's values) are named [`Presets`]; a table may
//!   ask for one with `preset = "<name>"` and override single keys on top ([`with_preset`]).
//! - An environment variable `RAILMON_<SECTION>__<KEY>` (levels separated by a double
//!   underscore, because keys contain single ones) overrides `<section>.<key>`:
//!   `RAILMON_HTTP__LISTEN`, `RAILMON_BUS__DRIVE__SERVICE_NAME`. Variables without `__`
//!   (`RAILMON_CONFIG`, `RAILMON_LOG`) are not overrides. Values are read as TOML (`true`, `42`,
//!   `[1, 2]`), else as a plain string.
//! - Deserialisation errors name the key path and, for an overridden key, the variable.
#![forbid(unsafe_code)]

pub mod reference;

use serde::de::DeserializeOwned;
use serde::Serialize;

/// A schemars transform declaring an open lower bound on an array's items
/// (`#[schemars(transform = railmon_settings::items_above(0.0))]`): `extend` would set it on
/// the array itself, and `inner(range(..))` declares closed bounds only.
pub fn items_above(lo: f64) -> impl FnMut(&mut schemars::Schema) {
    move |schema: &mut schemars::Schema| {
        if let Some(items) = schema.get_mut("items").and_then(|i| i.as_object_mut()) {
            items.insert("exclusiveMinimum".into(), lo.into());
        }
    }
}

pub const ENV_PREFIX: &str = "RAILMON_";

/// The key a table uses to start from a named preset instead of the default.
pub const PRESET_KEY: &str = "preset";

/// A setting that could not be used: which key (or file), and why.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("config key `{key}`: {reason}")]
pub struct SettingsError {
    pub key: String,
    pub reason: String,
}

impl SettingsError {
    pub fn new(key: impl Into<String>, reason: impl Into<String>) -> Self {
        Self {
            key: key.into(),
            reason: reason.into(),
        }
    }
}

/// `Err` naming `key` unless `value` is in `range`. The range is the one the key's field
/// declares to the reference (`#[schemars(range(min = *RANGE.start(), max = *RANGE.end()))]`),
/// so that the bounds a user reads are the bounds the check applies.
pub fn check_in_range<T: PartialOrd + std::fmt::Display>(
    key: &str,
    value: T,
    range: &std::ops::RangeInclusive<T>,
) -> Result<(), SettingsError> {
    if range.contains(&value) {
        return Ok(());
    }
    Err(SettingsError::new(
        key,
        format!("{value} is not in {}..={}", range.start(), range.end()),
    ))
}

/// Parses TOML text; `source` (a file name) goes into the error.
pub fn parse_table(text: &str, source: &str) -> Result<toml::Table, SettingsError> {
    text.parse::<toml::Table>()
        .map_err(|e| SettingsError::new(source, e.to_string()))
}

/// Applies `RAILMON_A__B=value` overrides to `table`; returns `(dotted key, variable)` per override.
pub fn apply_env_overrides(
    table: &mut toml::Table,
    vars: impl IntoIterator<Item = (String, String)>,
) -> Result<Vec<(String, String)>, SettingsError> {
    let mut applied: Vec<(String, String)> = Vec::new();
    for (name, value) in vars {
        let Some(rest) = name.strip_prefix(ENV_PREFIX) else {
            continue;
        };
        if !rest.contains("__") {
            continue;
        }
        let path: Vec<String> = rest.split("__").map(str::to_ascii_lowercase).collect();
        if path.iter().any(String::is_empty) {
            return Err(SettingsError::new(
                name,
                "empty key level (use RAILMON_SECTION__KEY)",
            ));
        }
        // Two variables for one key (`RAILMON_HTTP__LISTEN` and `RAILMON_http__listen`), or
        // for a table and a key inside it: which one wins would depend on the environment's
        // order, so neither does.
        let dotted = path.join(".");
        if let Some((other_key, other)) = applied.iter().find(|(key, _)| {
            *key == dotted
                || dotted.starts_with(&format!("{key}."))
                || key.starts_with(&format!("{dotted}."))
        }) {
            return Err(SettingsError::new(
                dotted.clone(),
                format!("set by both {other} (`{other_key}`) and {name}: keep one"),
            ));
        }
        set_path(table, &path, parse_env_value(&value)).map_err(|reason| {
            SettingsError::new(path.join("."), format!("{reason} (from {name})"))
        })?;
        applied.push((path.join("."), name));
    }
    Ok(applied)
}

/// Refuses a `RAILMON_` variable without `__` that spells one of `keys` (dotted paths) with
/// single underscores (`RAILMON_HTTP_LISTEN` for `http.listen`): it is not read as an override,
/// and a service that silently ignored it would run with the default the user meant to
/// change. Other such variables (`RAILMON_CONFIG`, `RAILMON_LOG`, the scripts' own) pass.
pub fn refuse_misspelt_overrides<'k>(
    vars: &[(String, String)],
    keys: impl IntoIterator<Item = &'k str>,
) -> Result<(), SettingsError> {
    let spelt: Vec<(String, &str)> = vars
        .iter()
        .filter_map(|(name, _)| name.strip_prefix(ENV_PREFIX).map(|rest| (rest, name)))
        .filter(|(rest, _)| !rest.contains("__"))
        .map(|(rest, name)| (rest.to_ascii_lowercase(), name.as_str()))
        .collect();
    if spelt.is_empty() {
        return Ok(());
    }
    for key in keys {
        let single = key.replace('.', "_");
        if let Some((_, name)) = spelt.iter().find(|(rest, _)| *rest == single) {
            let meant = format!(
                "{ENV_PREFIX}{}",
                key.replace('.', "__").to_ascii_uppercase()
            );
            return Err(SettingsError::new(
                key,
                format!(
                    "{name} is not read (levels are separated by a double underscore): \
                     write {meant}"
                ),
            ));
        }
    }
    Ok(())
}

fn parse_env_value(value: &str) -> toml::Value {
    format!("v = {value}")
        .parse::<toml::Table>()
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(value.to_string()))
}

fn set_path(table: &mut toml::Table, path: &[String], value: toml::Value) -> Result<(), String> {
    let (last, parents) = path.split_last().expect("path has at least two levels");
    let mut current = table;
    for level in parents {
        let entry = current
            .entry(level.clone())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        current = entry
            .as_table_mut()
            .ok_or_else(|| format!("`{level}` is a value, not a section"))?;
    }
    current.insert(last.clone(), value);
    Ok(())
}

/// `overlay` on top of `base`, key by key through nested tables.
pub fn merge_tables(base: &mut toml::Table, overlay: toml::Table) {
    for (key, value) in overlay {
        match (base.get_mut(&key), value) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge_tables(b, o),
            (_, value) => {
                base.insert(key, value);
            }
        }
    }
}

/// Deserialises `value` into `T` (which should `deny_unknown_fields`); the error names the key
/// path below `root` (`http.listen`) and the variable if that key came from the environment.
pub fn deserialize<T: DeserializeOwned>(
    value: toml::Value,
    root: &str,
    overrides: &[(String, String)],
) -> Result<T, SettingsError> {
    serde_path_to_error::deserialize(value).map_err(|e| {
        let inner = e.path().to_string();
        let key = join_key(root, &inner);
        let from_env = overrides
            .iter()
            .find(|(dotted, _)| dotted.starts_with(&key) || key.starts_with(dotted.as_str()))
            .map(|(_, var)| format!(" (from {var})"))
            .unwrap_or_default();
        SettingsError::new(key, format!("{}{from_env}", e.inner()))
    })
}

fn join_key(root: &str, inner: &str) -> String {
    match (root.is_empty(), inner == ".") {
        (true, _) => inner.to_string(),
        (false, true) => root.to_string(),
        (false, false) => format!("{root}.{inner}"),
    }
}

/// The process environment's variables, for [`apply_env_overrides`].
pub fn process_env() -> Vec<(String, String)> {
    std::env::vars().collect()
}

/// Named starting points of a settings type besides its `Default` (the validated setting).
pub trait Presets: Serialize + DeserializeOwned + Default {
    /// The preset names a table may ask for, besides `default`.
    const PRESETS: &'static [&'static str];
    /// The preset of that name (one of [`Presets::PRESETS`]).
    fn preset(name: &str) -> Option<Self>;
}

/// Reads `table` as a `T`: from the preset its `preset` key names (else `T::default()`), with
/// every other key of the table overriding a single value of it. Errors name the key below
/// `root`.
pub fn with_preset<T: Presets>(mut table: toml::Table, root: &str) -> Result<T, SettingsError> {
    let base = match table.remove(PRESET_KEY) {
        None => T::default(),
        Some(toml::Value::String(name)) if name == "default" => T::default(),
        Some(toml::Value::String(name)) => T::preset(&name).ok_or_else(|| {
            SettingsError::new(
                join_key(root, PRESET_KEY),
                format!(
                    "unknown preset `{name}` (known: default, {})",
                    T::PRESETS.join(", ")
                ),
            )
        })?,
        Some(other) => {
            return Err(SettingsError::new(
                join_key(root, PRESET_KEY),
                format!("{other} is not a preset name"),
            ))
        }
    };
    layer(&base, table, root, &[])
}

/// For `#[serde(deserialize_with = "railmon_settings::deserialize_with_preset")]` on a field
/// holding an estimator's settings (the service's `[drive.estimator]`, `[bogie.estimator]`,
/// `[vehicle.estimator]`, a scenario's `[monitor]`): the table is read with its presets, as
/// [`with_preset`] (not validated: the owner validates). The one preset loader of every
/// estimator, so that a preset is asked for the same way everywhere.
pub fn deserialize_with_preset<'de, D, T>(deserializer: D) -> Result<T, D::Error>
where
    D: serde::Deserializer<'de>,
    T: Presets,
{
    let table = <toml::Table as serde::Deserialize>::deserialize(deserializer)?;
    with_preset(table, "").map_err(|e| serde::de::Error::custom(format!("{}: {}", e.key, e.reason)))
}

/// `overlay`'s keys on top of `base` (through nested tables), read back as a `T`.
pub fn layer<T: Serialize + DeserializeOwned>(
    base: &T,
    overlay: toml::Table,
    root: &str,
    overrides: &[(String, String)],
) -> Result<T, SettingsError> {
    let mut table = toml::Table::try_from(base)
        .map_err(|e| SettingsError::new(root, format!("cannot represent the base setting: {e}")))?;
    merge_tables(&mut table, overlay);
    deserialize(toml::Value::Table(table), root, overrides)
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Deserialize;

    fn env(pairs: &[(&str, &str)]) -> Vec<(String, String)> {
        pairs
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect()
    }

    #[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
    #[serde(deny_unknown_fields, default)]
    struct Inner {
        gain: f64,
        on: bool,
    }

    impl Default for Inner {
        fn default() -> Self {
            Inner {
                gain: 2.0,
                on: true,
            }
        }
    }

    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    #[serde(deny_unknown_fields, default)]
    struct Outer {
        name: String,
        inner: Inner,
    }

    impl Presets for Outer {
        const PRESETS: &'static [&'static str] = &["paper"];
        fn preset(name: &str) -> Option<Self> {
            (name == "paper").then(|| Outer {
                name: "paper".into(),
                inner: Inner {
                    gain: 9.0,
                    on: false,
                },
            })
        }
    }

    fn outer_from(text: &str, vars: &[(&str, &str)]) -> Result<Outer, SettingsError> {
        let mut table = parse_table(text, "test.toml")?;
        let overrides = apply_env_overrides(&mut table, env(vars))?;
        let outer = table
            .remove("outer")
            .unwrap_or(toml::Value::Table(Default::default()));
        deserialize(outer, "outer", &overrides)
    }

    #[test]
    fn env_overrides_file_and_parses_types() {
        let outer = outer_from(
            "[outer]\nname = \"file\"\n[outer.inner]\non = false\n",
            &[
                ("RAILMON_OUTER__NAME", "env"),
                ("RAILMON_OUTER__INNER__GAIN", "3.5"),
                ("RAILMON_CONFIG", "ignored.toml"),
                ("OTHER__THING", "ignored"),
            ],
        )
        .unwrap();
        assert_eq!(outer.name, "env");
        assert_eq!(
            outer.inner,
            Inner {
                gain: 3.5,
                on: false
            }
        );
    }

    #[test]
    fn unknown_key_is_named() {
        let err = outer_from("[outer.inner]\nbuffer = 3\n", &[])
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("outer.inner") && err.contains("buffer"),
            "{err}"
        );
    }

    #[test]
    fn a_key_spelt_with_single_underscores_is_refused_with_the_right_spelling() {
        let keys = ["http.listen", "bogie.estimator.rbpf.particles"];
        let vars = env(&[("RAILMON_HTTP_LISTEN", "0.0.0.0:1")]);
        let e = refuse_misspelt_overrides(&vars, keys).unwrap_err();
        assert_eq!(e.key, "http.listen");
        assert!(e.reason.contains("write RAILMON_HTTP__LISTEN"), "{e}");
        let vars = env(&[("RAILMON_bogie_estimator_rbpf_particles", "5")]);
        let e = refuse_misspelt_overrides(&vars, keys).unwrap_err();
        assert!(
            e.reason
                .contains("RAILMON_BOGIE__ESTIMATOR__RBPF__PARTICLES"),
            "{e}"
        );
        // Not settings: the binaries' and scripts' own variables, and real overrides.
        let vars = env(&[
            ("RAILMON_LOG", "warn"),
            ("RAILMON_BOGIE_PARTICLES", "200"),
            ("RAILMON_HTTP__LISTEN", "0.0.0.0:1"),
            ("OTHER_HTTP_LISTEN", "x"),
        ]);
        assert_eq!(refuse_misspelt_overrides(&vars, keys), Ok(()));
    }

    /// Two variables for one key, or for a table and a key in it, are refused naming both,
    /// whatever their order in the environment.
    #[test]
    fn two_variables_for_one_key_are_refused() {
        for pair in [
            [
                ("RAILMON_HTTP__LISTEN", "a:1"),
                ("RAILMON_http__listen", "b:2"),
            ],
            [
                ("RAILMON_OUTER__INNER", "{ gain = 1.0 }"),
                ("RAILMON_OUTER__INNER__GAIN", "2.0"),
            ],
        ] {
            for order in [[0, 1], [1, 0]] {
                let vars = env(&[pair[order[0]], pair[order[1]]]);
                let e = apply_env_overrides(&mut toml::Table::new(), vars).unwrap_err();
                assert!(
                    e.reason.contains(pair[0].0) && e.reason.contains(pair[1].0),
                    "{e}"
                );
            }
        }
    }

    #[test]
    fn bad_type_from_env_names_key_and_variable() {
        let err = outer_from("", &[("RAILMON_OUTER__INNER__ON", "maybe")])
            .unwrap_err()
            .to_string();
        assert!(err.contains("outer.inner.on"), "{err}");
        assert!(err.contains("RAILMON_OUTER__INNER__ON"), "{err}");
    }

    #[test]
    fn toml_syntax_error_names_the_file() {
        let err = outer_from("[outer\n", &[]).unwrap_err().to_string();
        assert!(err.contains("test.toml"), "{err}");
    }

    #[test]
    fn override_of_a_value_with_a_section_is_rejected() {
        let err = outer_from(
            "[outer]\nname = \"x\"\n",
            &[("RAILMON_OUTER__NAME__A", "1")],
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("outer.name.a"), "{err}");
    }

    #[test]
    fn a_preset_is_the_base_and_single_keys_override_it() {
        let table = parse_table("preset = \"paper\"\n[inner]\ngain = 1.5\n", "t").unwrap();
        let outer: Outer = with_preset(table, "monitor").unwrap();
        assert_eq!(outer.name, "paper");
        assert_eq!(
            outer.inner,
            Inner {
                gain: 1.5,
                on: false
            }
        );
    }

    #[test]
    fn without_a_preset_single_keys_override_the_default() {
        let table = parse_table("[inner]\non = false\n", "t").unwrap();
        let outer: Outer = with_preset(table, "monitor").unwrap();
        assert_eq!(
            outer.inner,
            Inner {
                gain: 2.0,
                on: false
            }
        );
        assert_eq!(outer.name, "");
    }

    #[test]
    fn an_unknown_preset_is_named_with_the_known_ones() {
        let table = parse_table("preset = \"magic\"\n", "t").unwrap();
        let err = with_preset::<Outer>(table, "monitor").unwrap_err();
        assert_eq!(err.key, "monitor.preset");
        assert!(
            err.reason.contains("magic") && err.reason.contains("paper"),
            "{err}"
        );
    }

    #[test]
    fn an_unknown_key_next_to_a_preset_is_named() {
        let table = parse_table("preset = \"paper\"\n[inner]\ngian = 1.0\n", "t").unwrap();
        let err = with_preset::<Outer>(table, "monitor").unwrap_err();
        assert!(
            err.key.contains("monitor.inner") && err.reason.contains("gian"),
            "{err}"
        );
    }
}
