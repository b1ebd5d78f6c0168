//! Layered settings for the railmon binaries: embedded defaults < TOML file < environment.
//!
//! An environment variable `RAILMON_<SECTION>__<KEY>` (levels separated by a double underscore,
//! because keys contain single ones) overrides `<section>.<key>`: `RAILMON_HTTP__LISTEN`,
//! `RAILMON_BUS__DRIVE__SERVICE_NAME`. Variables without `__` (`RAILMON_CONFIG`, `RAILMON_LOG`)
//! are not overrides. Values are read as TOML (`true`, `42`, `[1, 2]`), else as a plain string.
//! Deserialisation errors name the key path and, for an overridden key, the variable.

use serde::de::DeserializeOwned;

use crate::BusError;

pub const ENV_PREFIX: &str = "RAILMON_";

/// Parses TOML text; `source` (a file name) goes into the error.
pub fn parse_table(text: &str, source: &str) -> Result<toml::Table, BusError> {
    text.parse::<toml::Table>().map_err(|e| BusError::Config {
        key: source.to_string(),
        reason: e.to_string(),
    })
}

/// Applies `RAILMON_A__B=value` overrides to `table`; returns `(dotted key, variable)` per override.
pub fn apply_env_overrides(
    table: &mut toml::Table,
    vars: impl IntoIterator<Item = (String, String)>,
) -> Result<Vec<(String, String)>, BusError> {
    let mut applied = Vec::new();
    for (name, value) in vars {
        let Some(rest) = name.strip_prefix(ENV_PREFIX) else {
            continue;
        };
        if !rest.contains("__") {
            continue;
        }
        let path: Vec<String> = rest.split("__").map(str::to_ascii_lowercase).collect();
        if path.iter().any(String::is_empty) {
            return Err(BusError::Config {
                key: name,
                reason: "empty key level (use RAILMON_SECTION__KEY)".into(),
            });
        }
        set_path(table, &path, parse_env_value(&value)).map_err(|reason| BusError::Config {
            key: path.join("."),
            reason: format!("{reason} (from {name})"),
        })?;
        applied.push((path.join("."), name));
    }
    Ok(applied)
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

/// Deserialises `value` into `T` (which should `deny_unknown_fields`); the error names the key
/// path below `root` (`http.listen`) and the variable if that key came from the environment.
pub fn deserialize<T: DeserializeOwned>(
    value: toml::Value,
    root: &str,
    overrides: &[(String, String)],
) -> Result<T, BusError> {
    serde_path_to_error::deserialize(value).map_err(|e| {
        let inner = e.path().to_string();
        let key = match (root.is_empty(), inner == ".") {
            (true, _) => inner,
            (false, true) => root.to_string(),
            (false, false) => format!("{root}.{inner}"),
        };
        let from_env = overrides
            .iter()
            .find(|(dotted, _)| dotted.starts_with(&key) || key.starts_with(dotted.as_str()))
            .map(|(_, var)| format!(" (from {var})"))
            .unwrap_or_default();
        BusError::Config {
            key,
            reason: format!("{}{from_env}", e.inner()),
        }
    })
}

/// The process environment's variables, for [`apply_env_overrides`].
pub fn process_env() -> Vec<(String, String)> {
    std::env::vars().collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::BusConfig;

    fn env(pairs: &[(&str, &str)]) -> Vec<(String, String)> {
        pairs
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect()
    }

    fn bus_from(text: &str, vars: &[(&str, &str)]) -> Result<BusConfig, BusError> {
        let mut table = parse_table(text, "test.toml")?;
        let overrides = apply_env_overrides(&mut table, env(vars))?;
        let bus = table
            .remove("bus")
            .unwrap_or(toml::Value::Table(Default::default()));
        deserialize(bus, "bus", &overrides)
    }

    #[test]
    fn env_overrides_file_and_parses_types() {
        let bus = bus_from(
            "[bus]\nprefix = \"file_\"\n[bus.drive]\nsafe_overflow = false\n",
            &[
                ("RAILMON_BUS__PREFIX", "env_"),
                ("RAILMON_BUS__DRIVE__SAFE_OVERFLOW", "true"),
                ("RAILMON_BUS__DRIVE__SUBSCRIBER_BUFFER_SIZE", "64"),
                ("RAILMON_CONFIG", "ignored.toml"),
                ("OTHER__THING", "ignored"),
            ],
        )
        .unwrap();
        assert_eq!(bus.prefix, "env_");
        assert!(bus.drive.safe_overflow);
        assert_eq!(bus.drive.subscriber_buffer_size, 64);
        assert_eq!(bus.bogie, BusConfig::default().bogie);
    }

    #[test]
    fn unknown_key_is_named() {
        let err = bus_from("[bus.drive]\nbuffer = 3\n", &[])
            .unwrap_err()
            .to_string();
        assert!(err.contains("bus.drive") && err.contains("buffer"), "{err}");
    }

    #[test]
    fn bad_type_from_env_names_key_and_variable() {
        let err = bus_from("", &[("RAILMON_BUS__DRIVE__SAFE_OVERFLOW", "maybe")])
            .unwrap_err()
            .to_string();
        assert!(err.contains("bus.drive.safe_overflow"), "{err}");
        assert!(err.contains("RAILMON_BUS__DRIVE__SAFE_OVERFLOW"), "{err}");
    }

    #[test]
    fn toml_syntax_error_names_the_file() {
        let err = bus_from("[bus\n", &[]).unwrap_err().to_string();
        assert!(err.contains("test.toml"), "{err}");
    }

    #[test]
    fn override_of_a_value_with_a_section_is_rejected() {
        let err = bus_from(
            "[bus]\nprefix = \"x\"\n",
            &[("RAILMON_BUS__PREFIX__A", "1")],
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("bus.prefix.a"), "{err}");
    }
}
