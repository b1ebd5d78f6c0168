//! `railmon serve` settings: embedded defaults < `config/railmon.toml` (or `--config FILE`) <
//! environment (`RAILMON_<SECTION>__<KEY>`, see [`railmon_settings`]). Every key is documented
//! in `config/railmon.toml`, whose values are the defaults (a test checks it). Each stream's
//! section is defined next to its pipeline (`drive::DriveConfig`, ...).

use std::net::SocketAddr;
use std::ops::RangeInclusive;
use std::path::{Path, PathBuf};

use railmon_bus::BusConfig;
use railmon_settings::{self as settings, Presets, SettingsError};
use serde::{Deserialize, Serialize};

// Each stream's section is defined beside its pipeline; the paths name those leaf files, not
// the stream modules (which use the event store, which uses this module).
pub use crate::bogie::config::{BogieConfig, MAX_BOGIES};
pub use crate::drive::config::DriveConfig;
pub use crate::fleet::config::FleetConfig;
pub use crate::uplink::config::UplinkConfig;
pub use crate::vehicle::config::VehicleConfig;

/// A configuration that cannot be used: a file that cannot be read, or a key and why.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read config file {file}: {reason}")]
    Read { file: String, reason: String },
    #[error(transparent)]
    Invalid(#[from] SettingsError),
}

pub(crate) fn invalid(key: &str, reason: String) -> ConfigError {
    ConfigError::Invalid(SettingsError::new(key, reason))
}

// Bounds of the service's numeric settings, declared to the reference on their fields
// (`railmon config reference`) and checked by `validate` with the same constants.
const MAX_EVENTS: RangeInclusive<u64> = 1..=1_000_000_000;
const MAX_AGE_DAYS: RangeInclusive<u32> = 0..=36_500;
const SNAPSHOT_MAX_AGE_S: RangeInclusive<f64> = 0.0..=86_400.0 * 365.0;
/// `snapshot_interval_s` is 0 (never) or in this range; the reference shows `0 ..= 3600`.
const SNAPSHOT_INTERVAL_S: RangeInclusive<f64> = 0.1..=3600.0;
const HTTP_TIME_MS: RangeInclusive<u64> = 1..=600_000;
const MAX_CONNECTIONS: RangeInclusive<usize> = 1..=65_536;
const HTTP_REQUEST_BYTES: RangeInclusive<usize> = 256..=262_144;
const WAKE_INTERVAL_MS: RangeInclusive<u64> = 1..=10_000;
const MAX_BATCH: RangeInclusive<usize> = 1..=65_536;
const CLEANUP_INTERVAL_MS: RangeInclusive<u64> = 10..=600_000;

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ServiceConfig {
    pub identity: IdentityConfig,
    pub storage: StorageConfig,
    pub http: HttpConfig,
    pub bus: BusConfig,
    pub ingest: IngestConfig,
    pub drive: DriveConfig,
    pub bogie: BogieConfig,
    pub vehicle: VehicleConfig,
    pub uplink: UplinkConfig,
    /// `railmon fleet` only.
    pub fleet: FleetConfig,
}

/// `[storage]`: where events and active alarms are kept, and for how long.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct StorageConfig {
    /// Directory of the event database (`events.sqlite3`), the estimator snapshots and the
    /// damper filters' solved gain grids (`gain-cache/`, `railmon damper warm-cache`), created
    /// if missing (mode 0700, files 0600); refused if others may write into it or it is a
    /// symlink.
    /// Empty: `$XDG_STATE_HOME/railmon`, else `~/.local/state/railmon`. `:memory:` keeps
    /// events in memory only (tests): they are then lost at a restart.
    pub data_dir: String,
    /// Events stored longer ago than this are pruned (0: kept however old). By the time they
    /// were stored, not acquired: a replay of an old recording keeps its events.
    #[schemars(range(min = *MAX_AGE_DAYS.start(), max = *MAX_AGE_DAYS.end()))]
    pub max_age_days: u32,
    /// At most this many events are kept; the oldest are pruned beyond it.
    #[schemars(range(min = *MAX_EVENTS.start(), max = *MAX_EVENTS.end()))]
    pub max_events: u64,
    /// Each stream's estimator state is saved this often (and at shutdown) under
    /// `data_dir/snapshots` (0: never).
    #[schemars(range(min = 0.0, max = *SNAPSHOT_INTERVAL_S.end()))]
    pub snapshot_interval_s: f64,
    /// A snapshot older than this is not resumed at start (the estimator starts from its prior).
    #[schemars(range(min = *SNAPSHOT_MAX_AGE_S.start(), max = *SNAPSHOT_MAX_AGE_S.end()))]
    pub snapshot_max_age_s: f64,
}

impl Default for StorageConfig {
    fn default() -> Self {
        Self {
            data_dir: String::new(),
            max_age_days: 365,
            max_events: 1_000_000,
            snapshot_interval_s: 5.0,
            snapshot_max_age_s: 600.0,
        }
    }
}

impl StorageConfig {
    pub(crate) fn validate(&self) -> Result<(), ConfigError> {
        settings::check_in_range("storage.max_events", self.max_events, &MAX_EVENTS)?;
        if !(self.snapshot_interval_s == 0.0
            || SNAPSHOT_INTERVAL_S.contains(&self.snapshot_interval_s))
        {
            return Err(invalid(
                "storage.snapshot_interval_s",
                format!("{} is not 0 or in [0.1, 3600]", self.snapshot_interval_s),
            ));
        }
        settings::check_in_range(
            "storage.snapshot_max_age_s",
            self.snapshot_max_age_s,
            &SNAPSHOT_MAX_AGE_S,
        )?;
        settings::check_in_range("storage.max_age_days", self.max_age_days, &MAX_AGE_DAYS)?;
        Ok(())
    }

    /// The damper filters' stored gain grids, `<data_dir>/gain-cache` (`railmon damper
    /// warm-cache` fills it ahead); `None` for the in-memory store.
    pub fn gain_cache(&self) -> Option<railmon_records::gain_cache::GainCache> {
        let db = self.database_path()?;
        let dir = db.parent()?;
        Some(railmon_records::gain_cache::GainCache::new(
            dir.join(railmon_records::gain_cache::DIR_NAME),
        ))
    }

    /// The database file, or `None` for the in-memory store.
    pub fn database_path(&self) -> Option<PathBuf> {
        if self.data_dir == ":memory:" {
            return None;
        }
        let dir = match self.data_dir.is_empty() {
            false => PathBuf::from(&self.data_dir),
            true => match (std::env::var_os("XDG_STATE_HOME"), std::env::var_os("HOME")) {
                (Some(state), _) if !state.is_empty() => Path::new(&state).join("railmon"),
                (_, Some(home)) => Path::new(&home).join(".local/state/railmon"),
                _ => PathBuf::from("/var/lib/railmon"),
            },
        };
        Some(dir.join("events.sqlite3"))
    }
}

/// `[identity]`: which vehicle this service monitors, in every API answer, event and metric.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct IdentityConfig {
    /// The vehicle's id in the fleet (letters, digits, `.`, `_`, `-`; at most 64); empty: the
    /// host name.
    pub vehicle_id: String,
    /// The fleet it belongs to (same characters; may stay empty).
    pub fleet: String,
}

impl IdentityConfig {
    fn validate(&self) -> Result<(), ConfigError> {
        for (key, value) in [("vehicle_id", &self.vehicle_id), ("fleet", &self.fleet)] {
            let ok = value.len() <= 64
                && value
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-'));
            if !ok {
                return Err(invalid(
                    &format!("identity.{key}"),
                    format!("`{value}`: use at most 64 letters, digits, `.`, `_` or `-`"),
                ));
            }
        }
        Ok(())
    }

    /// The identity in force: `vehicle_id` or, when empty, the host name.
    pub fn resolve(&self) -> Identity {
        let vehicle_id = match self.vehicle_id.is_empty() {
            false => self.vehicle_id.clone(),
            true => host_name().unwrap_or_else(|| "unknown".into()),
        };
        Identity {
            vehicle_id,
            fleet: self.fleet.clone(),
        }
    }
}

/// The vehicle a service monitors, as it appears in answers, events and metric labels.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Identity {
    pub vehicle_id: String,
    pub fleet: String,
}

fn host_name() -> Option<String> {
    let name = std::fs::read_to_string("/proc/sys/kernel/hostname").ok()?;
    let name: String = name
        .trim()
        .chars()
        .map(
            |c| match c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-') {
                true => c,
                false => '_',
            },
        )
        .take(64)
        .collect();
    (!name.is_empty()).then_some(name)
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct HttpConfig {
    /// Address and port of the HTTP API; port 0 picks a free one (see `--addr-file`).
    pub listen: String,
    /// A client must send a request's headers within this long; also how long an idle
    /// keep-alive connection is kept (10,000 half-open connections once held 266 MB).
    #[schemars(range(min = *HTTP_TIME_MS.start(), max = *HTTP_TIME_MS.end()))]
    pub header_timeout_ms: u64,
    /// Longest time one request may take; then it is answered 503 `timeout`.
    #[schemars(range(min = *HTTP_TIME_MS.start(), max = *HTTP_TIME_MS.end()))]
    pub request_timeout_ms: u64,
    /// Open connections at most; a further one takes the slot of the longest-idle connection, or
    /// is closed at once when every one is serving a request (both counted).
    #[schemars(range(min = *MAX_CONNECTIONS.start(), max = *MAX_CONNECTIONS.end()))]
    pub max_connections: usize,
    /// On SIGTERM, open requests get this long to finish before their connections are cut.
    #[schemars(range(min = *HTTP_TIME_MS.start(), max = *HTTP_TIME_MS.end()))]
    pub shutdown_deadline_ms: u64,
    /// Longer request targets are answered 414, larger header sections 431 (JSON bodies).
    #[schemars(range(min = *HTTP_REQUEST_BYTES.start(), max = *HTTP_REQUEST_BYTES.end()))]
    pub max_uri_bytes: usize,
    /// Largest header section of a request (bytes); a larger one is answered 431.
    #[schemars(range(min = *HTTP_REQUEST_BYTES.start(), max = *HTTP_REQUEST_BYTES.end()))]
    pub max_header_bytes: usize,
}

impl Default for HttpConfig {
    fn default() -> Self {
        Self {
            listen: "127.0.0.1:8787".into(),
            header_timeout_ms: 10_000,
            request_timeout_ms: 10_000,
            max_connections: 256,
            shutdown_deadline_ms: 5_000,
            max_uri_bytes: 8 * 1024,
            max_header_bytes: 16 * 1024,
        }
    }
}

impl HttpConfig {
    fn validate(&self) -> Result<(), ConfigError> {
        for (key, value) in [
            ("header_timeout_ms", self.header_timeout_ms),
            ("request_timeout_ms", self.request_timeout_ms),
            ("shutdown_deadline_ms", self.shutdown_deadline_ms),
        ] {
            settings::check_in_range(&format!("http.{key}"), value, &HTTP_TIME_MS)?;
        }
        settings::check_in_range(
            "http.max_connections",
            self.max_connections,
            &MAX_CONNECTIONS,
        )?;
        for (key, value) in [
            ("max_uri_bytes", self.max_uri_bytes),
            ("max_header_bytes", self.max_header_bytes),
        ] {
            settings::check_in_range(&format!("http.{key}"), value, &HTTP_REQUEST_BYTES)?;
        }
        Ok(())
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct IngestConfig {
    /// Longest sleep of an ingest thread without a notification (shutdown and housekeeping latency).
    #[schemars(range(min = *WAKE_INTERVAL_MS.start(), max = *WAKE_INTERVAL_MS.end()))]
    pub wake_interval_ms: u64,
    /// Frames handled before the results are published to the HTTP side.
    #[schemars(range(min = *MAX_BATCH.start(), max = *MAX_BATCH.end()))]
    pub max_batch: usize,
    /// How often dead bus peers are cleaned up.
    #[schemars(range(min = *CLEANUP_INTERVAL_MS.start(), max = *CLEANUP_INTERVAL_MS.end()))]
    pub cleanup_interval_ms: u64,
}

impl Default for IngestConfig {
    fn default() -> Self {
        Self {
            wake_interval_ms: 50,
            max_batch: 256,
            cleanup_interval_ms: 1000,
        }
    }
}

impl ServiceConfig {
    /// Reads `file` (or only the defaults), applies the environment, validates.
    pub fn load(
        file: Option<&Path>,
        env: impl IntoIterator<Item = (String, String)>,
    ) -> Result<Self, ConfigError> {
        Self::load_reporting(file, env).map(|(config, _)| config)
    }

    /// [`ServiceConfig::load`], and the environment overrides it applied: `(dotted key,
    /// variable)` each (`railmon config check` lists them).
    pub fn load_reporting(
        file: Option<&Path>,
        env: impl IntoIterator<Item = (String, String)>,
    ) -> Result<(Self, Vec<(String, String)>), ConfigError> {
        let mut table = match file {
            Some(path) => {
                let text =
                    railmon_records::read_text_file(path, railmon_records::MAX_SETTINGS_FILE_BYTES)
                        .map_err(|e| ConfigError::Read {
                            file: path.display().to_string(),
                            reason: e.to_string(),
                        })?;
                settings::parse_table(&text, &path.display().to_string())?
            }
            None => toml::Table::new(),
        };
        let env: Vec<(String, String)> = env.into_iter().collect();
        let keys = settings::reference::sections::<ServiceConfig>(&PRESET_TABLES);
        settings::refuse_misspelt_overrides(
            &env,
            keys.iter()
                .flat_map(|s| s.keys.iter().map(|k| k.key.as_str())),
        )?;
        let overrides = settings::apply_env_overrides(&mut table, env)?;
        let config = Self::load_table(table, &overrides)?;
        Ok((config, overrides))
    }

    /// Reads a settings table (a file's, with the environment applied), validates.
    pub fn load_table(
        table: toml::Table,
        overrides: &[(String, String)],
    ) -> Result<Self, ConfigError> {
        let config: ServiceConfig =
            settings::deserialize(toml::Value::Table(table), "", overrides)?;
        config.validate()?;
        Ok(config)
    }

    /// Checks every value; the error names the key.
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.listen_addr()?;
        self.identity.validate()?;
        self.storage.validate()?;
        self.http.validate()?;
        self.bus.validate()?;
        let i = &self.ingest;
        settings::check_in_range(
            "ingest.wake_interval_ms",
            i.wake_interval_ms,
            &WAKE_INTERVAL_MS,
        )?;
        settings::check_in_range("ingest.max_batch", i.max_batch, &MAX_BATCH)?;
        settings::check_in_range(
            "ingest.cleanup_interval_ms",
            i.cleanup_interval_ms,
            &CLEANUP_INTERVAL_MS,
        )?;
        self.drive.validate()?;
        self.vehicle.validate()?;
        self.bogie.validate()?;
        self.uplink.validate()?;
        self.fleet.validate()?;
        if self.uplink.enabled() {
            for (key, value) in [
                ("vehicle_id", &self.identity.vehicle_id),
                ("fleet", &self.identity.fleet),
            ] {
                if value.contains('.') {
                    return Err(invalid(
                        &format!("identity.{key}"),
                        format!(
                            "`{value}` contains `.`, which would split the uplink's NATS \
                             subject tokens (uplink.url is set)"
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    pub fn listen_addr(&self) -> Result<SocketAddr, ConfigError> {
        self.http.listen.parse().map_err(|e| {
            invalid(
                "http.listen",
                format!("`{}` is not an address:port ({e})", self.http.listen),
            )
        })
    }
}

/// The estimator tables that start from a named preset (`preset = "paper"`), and the names.
pub const PRESET_TABLES: [(&str, &[&str]); 3] = [
    ("drive.estimator", railmon_slip::SlipMonitorConfig::PRESETS),
    (
        "bogie.estimator",
        railmon_damper::DamperMonitorConfig::PRESETS,
    ),
    (
        "vehicle.estimator",
        railmon_fuel::FuelMonitorConfig::PRESETS,
    ),
];

/// The site settings: what one vehicle's installation sets (its identity, storage, HTTP, the
/// bus, the streams and their plausible ranges, the vehicle's parameters, the nominal dampers,
/// the channels and the alarm thresholds). `config/railmon.toml` shows every one of them (a
/// test compares the key sets); the rest of the estimator tables is expert tuning, in the
/// generated reference only. An entry covers its key or table; keys under an estimator table
/// are site settings only through an entry inside it.
pub const SITE_SETTINGS: &[&str] = &[
    "identity",
    "storage",
    "http",
    "bus",
    "ingest",
    "drive",
    "drive.estimator.dt_s",
    "drive.estimator.motor",
    "drive.estimator.alarm",
    "bogie",
    "bogie.estimator.dt_s",
    "bogie.estimator.vehicle",
    "bogie.estimator.nominal",
    "bogie.estimator.sensors",
    "bogie.estimator.alarm",
    "bogie.estimator.speed.min_m_s",
    "bogie.estimator.speed.max_m_s",
    "vehicle",
    "vehicle.estimator.channels",
    "vehicle.estimator.categorical",
    "vehicle.estimator.ranges",
    "vehicle.estimator.sample_period_s",
    "vehicle.estimator.speed_noise_m_s",
    "vehicle.estimator.regime_confirm_samples",
    "uplink",
];

/// Whether the dotted `key` is a site setting ([`SITE_SETTINGS`]).
pub fn is_site_setting(key: &str) -> bool {
    let in_estimator = key.contains(".estimator.");
    SITE_SETTINGS.iter().any(|entry| {
        (key == *entry || key.starts_with(&format!("{entry}.")))
            && (!in_estimator || entry.contains(".estimator."))
    })
}

/// Every setting of `railmon serve` as Markdown (`railmon config reference`, checked in as
/// `docs/configuration.md`), generated from the settings types: their doc comments, types and
/// defaults.
pub fn reference_markdown() -> String {
    use settings::reference;
    const PREAMBLE: &str = "Every setting of `railmon serve`: its key, default, type, unit and \
meaning, generated from the settings' own types by `railmon config reference` (do not edit: \
`cargo test -p railmon-service` checks this file against the code; regenerate with \
`cargo run -p railmon-service -- config reference > docs/configuration.md`).\n\n\
Settings are layered: these defaults < a preset (`preset = \"...\"` in an estimator table) < \
the file given with `--config` < `RAILMON_<SECTION>__<KEY>` environment variables (levels \
separated by a double underscore, e.g. `RAILMON_BOGIE__ESTIMATOR__RBPF__PARTICLES=500`; \
a key spelt with single underscores, `RAILMON_HTTP_LISTEN`, is refused with the right spelling, \
and so are two variables for one key). The site settings (identity, storage, HTTP, bus, streams and their ranges) are shown with \
comments in `config/railmon.toml`; the estimator tables (`[*.estimator]`) are expert tuning, \
validated on the scenarios in `config/scenarios/`. `railmon config check FILE` validates a file \
and the environment without starting anything.";
    reference::markdown(
        "Configuration reference",
        PREAMBLE,
        &reference::sections::<ServiceConfig>(&PRESET_TABLES),
        is_site_setting,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use railmon_damper::DamperMonitorConfig;
    use railmon_fuel::FuelMonitorConfig;

    fn load_with(vars: &[(&str, &str)]) -> Result<ServiceConfig, ConfigError> {
        let env = vars.iter().map(|(k, v)| (k.to_string(), v.to_string()));
        ServiceConfig::load(None, env)
    }

    fn error_of(vars: &[(&str, &str)]) -> String {
        load_with(vars).unwrap_err().to_string()
    }

    #[test]
    fn shipped_config_file_equals_the_embedded_defaults() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/railmon.toml");
        let from_file = ServiceConfig::load(Some(&path), []).unwrap();
        assert_eq!(from_file, ServiceConfig::default());
    }

    /// `config/railmon.toml` with its commented estimator site settings (`# key = value` and
    /// `# [table]` lines, one space after the `#`) uncommented.
    fn railmon_toml_uncommented() -> String {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/railmon.toml");
        let text = std::fs::read_to_string(path).unwrap();
        let is_setting = |line: &str| {
            let Some(rest) = line.strip_prefix("# ") else {
                return false;
            };
            let key_end = rest.find(" = ").unwrap_or(0);
            (rest.starts_with('[') && rest.trim_end().ends_with(']'))
                || (key_end > 0
                    && rest[..key_end]
                        .chars()
                        .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_'))
        };
        let lines: Vec<&str> = text
            .lines()
            .map(|line| match is_setting(line) {
                true => &line[2..],
                false => line,
            })
            .collect();
        lines.join("\n")
    }

    /// The dotted paths of every value in `table` (arrays are values).
    fn leaves(table: &toml::Table, prefix: &str, out: &mut Vec<String>) {
        for (key, value) in table {
            let path = match prefix.is_empty() {
                true => key.clone(),
                false => format!("{prefix}.{key}"),
            };
            match value {
                toml::Value::Table(t) => leaves(t, &path, out),
                _ => out.push(path),
            }
        }
    }

    fn all_keys() -> Vec<settings::reference::KeyDoc> {
        settings::reference::sections::<ServiceConfig>(&PRESET_TABLES)
            .into_iter()
            .flat_map(|s| s.keys)
            .collect()
    }

    /// Loads the defaults with one key set to `value`.
    fn load_key(key: &str, value: toml::Value) -> Result<ServiceConfig, ConfigError> {
        let mut table = toml::Table::new();
        let path: Vec<String> = key.split('.').map(String::from).collect();
        let (last, parents) = path.split_last().unwrap();
        let mut current = &mut table;
        for level in parents {
            current = current
                .entry(level.clone())
                .or_insert_with(|| toml::Value::Table(toml::Table::new()))
                .as_table_mut()
                .unwrap();
        }
        current.insert(last.clone(), value);
        ServiceConfig::load_table(table, &[])
    }

    /// Whether a refusal names `key`. An estimator's error names its own key under the
    /// estimator's table; the bogie model's vehicle, nominal and sensor parameters by their
    /// name alone (`wheelset_mass_kg`, as the damper crate has always reported them).
    fn names_key(key: &str, e: &ConfigError) -> bool {
        let e = e.to_string();
        match key.split_once(".estimator.") {
            Some((stream, inner)) => {
                let field = match inner.split_once('.') {
                    Some(("vehicle" | "nominal" | "sensors", field)) if stream == "bogie" => field,
                    _ => inner,
                };
                e.contains(&format!("{stream}.estimator")) && e.contains(field)
            }
            None => e.contains(key),
        }
    }

    /// Every integer setting, site or expert, declares the bounds its check applies (the
    /// reference shows them): its lowest and highest values load, one beyond either is refused
    /// naming the key. A seed takes any value its type holds; where a bound also depends on
    /// other keys (`DEPENDENT`), the declared outer bounds are checked from outside only.
    #[test]
    fn integer_settings_declare_the_bounds_they_are_checked_against() {
        const DEPENDENT: [&str; 2] = [
            "vehicle.estimator.switching_memory",
            "vehicle.estimator.init_samples",
        ];
        let mut undeclared = Vec::new();
        let mut checked = 0;
        for key in all_keys() {
            if key.kind != "integer" || key.key.ends_with(".seed") {
                continue;
            }
            checked += 1;
            let bounds = key.bounds.clone().unwrap_or_default();
            let Some((lo, hi)) = bounds.split_once(" ..= ") else {
                undeclared.push(format!("{} ({bounds})", key.key));
                continue;
            };
            let (lo, hi): (i64, i64) = (lo.parse().unwrap(), hi.parse().unwrap());
            let load = |value: i64| load_key(&key.key, toml::Value::Integer(value));
            for value in [lo, hi] {
                if DEPENDENT.contains(&key.key.as_str()) {
                    continue;
                }
                if let Err(e) = load(value) {
                    panic!("{} = {value} (a declared bound) refused: {e}", key.key);
                }
            }
            for value in [lo - 1, hi + 1] {
                match load(value) {
                    Ok(_) => panic!("{} = {value} (beyond {bounds}) accepted", key.key),
                    Err(e) => assert!(names_key(&key.key, &e), "{}: {e}", key.key),
                }
            }
        }
        assert!(undeclared.is_empty(), "no declared bounds: {undeclared:?}");
        // The site settings and the 13 integer expert keys (the three seeds aside).
        assert!(checked >= 25, "{checked} integer settings checked");
    }

    /// The bounds a float key declares, read back from the reference: each end as
    /// `(value, closed)`.
    type FloatBounds = (Option<(f64, bool)>, Option<(f64, bool)>);

    fn parse_float_bounds(text: &str) -> FloatBounds {
        let num = |s: &str| s.trim().parse::<f64>().unwrap_or_else(|_| panic!("{text}"));
        if let Some((lo, hi)) = text.split_once(" ..= ") {
            return (Some((num(lo), true)), Some((num(hi), true)));
        }
        for (op, lower, closed) in [
            (">= ", true, true),
            ("> ", true, false),
            ("<= ", false, true),
            ("< ", false, false),
        ] {
            if let Some(v) = text.strip_prefix(op) {
                let end = Some((num(v), closed));
                return if lower { (end, None) } else { (None, end) };
            }
        }
        let (lo, hi) = text.split_once(", ").unwrap_or_else(|| panic!("{text}"));
        let lo_closed = lo.starts_with('[');
        let hi_closed = hi.ends_with(']');
        (
            Some((num(&lo[1..]), lo_closed)),
            Some((num(&hi[..hi.len() - 1]), hi_closed)),
        )
    }

    /// Every float setting (`number`, optional or an array's items) declares the bounds its
    /// check applies, or is one of the few that take any finite value (`ANY_FINITE`, each with
    /// its reason). A closed end loads and a value just beyond it is refused naming the key;
    /// an open end is refused and a value just inside loads. Where the admissible range also
    /// depends on other keys (`DEPENDENT`), the declared outer bounds are probed from outside
    /// only.
    #[test]
    fn float_settings_declare_the_bounds_they_are_checked_against() {
        const ANY_FINITE: [(&str, &str); 10] = [
            (
                "drive.estimator.ekf.initial_speed_rad_s",
                "an initial guess, either direction",
            ),
            (
                "drive.estimator.ekf.initial_angle_rad",
                "an initial guess, wrapped",
            ),
            (
                "drive.estimator.ekf.initial_torque_nm",
                "an initial guess, motoring or braking",
            ),
            (
                "drive.estimator.adhesion.vb.loss_mean_nm",
                "a torque, motoring or braking",
            ),
            (
                "drive.estimator.adhesion.vmp.loss_mean_nm",
                "a torque, motoring or braking",
            ),
            (
                "vehicle.estimator.speed_bins_m_s",
                "bin edges: strictly increasing",
            ),
            (
                "vehicle.estimator.fuel_bins_cm3_s",
                "bin edges: strictly increasing",
            ),
            (
                "vehicle.estimator.acceleration_bins_m_s2",
                "bin edges: strictly increasing",
            ),
            // Every `[low, high]` pair: low < high (acceleration: low < 0 < high).
            (
                "vehicle.estimator.ranges.",
                "plausible ranges of the data, low < high",
            ),
            (
                "vehicle.estimator.naming.coasting_fuel_cm3_s",
                "a fuel threshold, either sign",
            ),
        ];
        const DEPENDENT: [&str; 11] = [
            "drive.estimator.alarm.on_probability",
            "drive.estimator.alarm.off_probability",
            "bogie.estimator.rbpf.gain_grid.max_ratio",
            "bogie.estimator.rbpf.unmeasured_mass.min_ratio",
            "bogie.estimator.rbpf.unmeasured_mass.max_ratio",
            "bogie.estimator.rbpf.noise_scale.max_std_ratio",
            "bogie.estimator.speed.max_m_s",
            "bogie.estimator.alarm.degraded_below_ratio",
            "bogie.estimator.alarm.recovered_above_ratio",
            "bogie.estimator.consistency.nis_high_ratio",
            "vehicle.estimator.max_gap_s",
        ];
        let any_finite = |key: &str| ANY_FINITE.iter().any(|(k, _)| key.starts_with(k));
        let (mut undeclared, mut failures) = (Vec::new(), Vec::new());
        let mut checked = 0;
        for key in all_keys() {
            if !key.kind.contains("number") {
                continue;
            }
            let Some(bounds) = key.bounds.clone() else {
                if !any_finite(&key.key) {
                    undeclared.push(key.key.clone());
                }
                continue;
            };
            assert!(!any_finite(&key.key), "{} declares {bounds}", key.key);
            checked += 1;
            // An array gets every item set to the value probed.
            let items = toml::from_str::<toml::Table>(&format!("v = {}", key.default))
                .ok()
                .and_then(|t| t["v"].as_array().map(Vec::len));
            let load = |value: f64| {
                let value = match items {
                    Some(n) => toml::Value::Array(vec![toml::Value::Float(value); n]),
                    None => toml::Value::Float(value),
                };
                load_key(&key.key, value)
            };
            let step = |b: f64| (b.abs() * 1e-6).max(1e-9);
            let dependent = DEPENDENT.contains(&key.key.as_str());
            let (lower, upper) = parse_float_bounds(&bounds);
            for (end, outward) in [(lower, -1.0), (upper, 1.0)] {
                let Some((b, closed)) = end else { continue };
                let (inside, outside) = match closed {
                    true => (b, b + outward * step(b)),
                    false => (b - outward * step(b), b),
                };
                if !dependent {
                    if let Err(e) = load(inside) {
                        failures.push(format!(
                            "{} = {inside} (within {bounds}) refused: {e}",
                            key.key
                        ));
                    }
                }
                match load(outside) {
                    Ok(_) => failures.push(format!(
                        "{} = {outside} (beyond {bounds}) accepted",
                        key.key
                    )),
                    Err(e) if !names_key(&key.key, &e) => {
                        failures.push(format!("{}: {e}", key.key))
                    }
                    Err(_) => {}
                }
            }
        }
        assert!(failures.is_empty(), "{failures:#?}");
        assert!(undeclared.is_empty(), "no declared bounds: {undeclared:?}");
        assert!(checked >= 110, "{checked} float settings checked");
    }

    /// The two tiers of settings: `config/railmon.toml` shows every site setting (live, or
    /// commented out in an estimator table) and nothing else, each at its default; the
    /// estimators' expert tuning is only in the generated reference.
    #[test]
    fn shipped_config_shows_every_site_setting_at_its_default() {
        let mut table: toml::Table = railmon_toml_uncommented().parse().unwrap();
        let keys = all_keys();
        let site: Vec<_> = keys.iter().filter(|k| is_site_setting(&k.key)).collect();
        let lookup = |table: &toml::Table, key: &str| {
            let mut value: Option<&toml::Value> = None;
            let mut current = Some(table);
            for level in key.split('.') {
                value = current.and_then(|t| t.get(level));
                current = value.and_then(toml::Value::as_table);
            }
            value.is_some()
        };
        for key in &site {
            assert!(
                lookup(&table, &key.key),
                "config/railmon.toml does not show the site setting `{}`",
                key.key
            );
        }
        let mut shown = Vec::new();
        leaves(&table, "", &mut shown);
        for leaf in &shown {
            assert!(
                site.iter()
                    .any(|k| *leaf == k.key || leaf.starts_with(&format!("{}.", k.key))),
                "config/railmon.toml shows `{leaf}`, which is not a site setting \
                 (SITE_SETTINGS; expert tuning is in docs/configuration.md only)"
            );
        }
        // Shown as an example where the default is none (an optional setting); every other
        // value is the default.
        let all = ServiceConfig::load_table(table.clone(), &[]).unwrap();
        assert_eq!(all.bogie.worker_threads, Some(1));
        for key in site.iter().filter(|k| k.default == "none") {
            let (parent, last) = key.key.rsplit_once('.').unwrap();
            let mut t = &mut table;
            for level in parent.split('.') {
                t = t
                    .get_mut(level)
                    .and_then(toml::Value::as_table_mut)
                    .unwrap();
            }
            t.remove(last);
        }
        let from_file = ServiceConfig::load_table(table, &[]).unwrap();
        assert_eq!(from_file, ServiceConfig::default());
    }

    /// Every setting has a meaning in the reference (its doc comment), so a new key cannot
    /// ship undocumented.
    #[test]
    fn every_setting_has_a_meaning() {
        let missing: Vec<_> = all_keys()
            .into_iter()
            .filter(|k| k.meaning.is_empty())
            .map(|k| k.key)
            .collect();
        assert!(
            missing.is_empty(),
            "settings without a doc comment: {missing:?}"
        );
    }

    /// docs/configuration.md is the generated reference (the settings types' doc comments,
    /// types and defaults), so it cannot drift from the code.
    #[test]
    fn docs_configuration_md_is_the_generated_reference() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/configuration.md");
        let checked_in = std::fs::read_to_string(path).unwrap_or_default();
        assert!(
            checked_in == reference_markdown(),
            "docs/configuration.md is not the settings reference of this code; regenerate it: \
             cargo run -p railmon-service -- config reference > docs/configuration.md"
        );
    }

    /// The demo runs the estimators the way the scenarios it replays were validated: its
    /// settings cannot drift from theirs.
    #[test]
    fn demo_config_runs_the_scenarios_validated_monitors() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let demo = ServiceConfig::load(Some(&root.join("config/demo.toml")), []).unwrap();
        let read = |name: &str| std::fs::read_to_string(root.join(name)).unwrap();
        let fuel = railmon_fuel::VehicleScenario::from_toml_str(&read(
            "config/scenarios/fuel-cycles.toml",
        ))
        .unwrap();
        assert_eq!(demo.vehicle.estimator, fuel.monitor);
        let damper = railmon_damper::DamperScenario::from_toml_str(&read(
            "config/scenarios/damper-fault.toml",
        ))
        .unwrap();
        assert_eq!(
            demo.bogie.estimator.track_velocity_std_m_s,
            damper.monitor.track_velocity_std_m_s
        );
        assert!(demo.bogie.enabled && demo.vehicle.enabled && demo.drive.enabled);
    }

    #[test]
    fn runs_without_a_file_and_binds_loopback_by_default() {
        let config = load_with(&[]).unwrap();
        assert!(config.listen_addr().unwrap().ip().is_loopback());
    }

    #[test]
    fn env_overrides_nested_keys() {
        let config = load_with(&[
            ("RAILMON_HTTP__LISTEN", "127.0.0.1:0"),
            ("RAILMON_DRIVE__ESTIMATOR__DT_S", "0.0001"),
            ("RAILMON_BUS__DRIVE__SUBSCRIBER_BUFFER_SIZE", "16"),
        ])
        .unwrap();
        assert_eq!(config.http.listen, "127.0.0.1:0");
        assert_eq!(config.drive.estimator.dt_s, 1e-4);
        assert_eq!(config.bus.drive.subscriber_buffer_size, 16);
    }

    #[test]
    fn estimator_keys_override_single_values_of_the_default_or_the_preset() {
        let key = "RAILMON_DRIVE__ESTIMATOR__EKF__MEASUREMENT_NOISE_A2";
        let config = load_with(&[(key, "0.02")]).unwrap();
        let mut expected = railmon_slip::SlipMonitorConfig::default();
        expected.ekf.measurement_noise_a2 = 0.02;
        assert_eq!(config.drive.estimator, expected);
        let config =
            load_with(&[(key, "0.02"), ("RAILMON_DRIVE__ESTIMATOR__PRESET", "paper")]).unwrap();
        let mut expected = railmon_slip::SlipMonitorConfig::paper();
        expected.ekf.measurement_noise_a2 = 0.02;
        assert_eq!(config.drive.estimator, expected);
        let err = error_of(&[("RAILMON_DRIVE__ESTIMATOR__PRESET", "magic")]);
        assert!(
            err.contains("drive.estimator") && err.contains("magic"),
            "{err}"
        );
    }

    #[test]
    fn missing_file_is_named() {
        let err = ServiceConfig::load(Some(Path::new("/nonexistent/railmon.toml")), [])
            .unwrap_err()
            .to_string();
        assert!(err.contains("/nonexistent/railmon.toml"), "{err}");
    }

    #[test]
    fn uplink_settings_are_checked_naming_the_key() {
        let url = ("RAILMON_UPLINK__URL", "nats://127.0.0.1:4222");
        assert!(load_with(&[url]).unwrap().uplink.enabled());
        assert!(!ServiceConfig::default().uplink.enabled());
        assert!(error_of(&[("RAILMON_UPLINK__URL", "nats://host:notaport")]).contains("uplink.url"));
        assert!(error_of(&[("RAILMON_UPLINK__SUBJECT_PREFIX", "rail.*")])
            .contains("uplink.subject_prefix"));
        assert!(error_of(&[("RAILMON_UPLINK__STREAM", "A.B")]).contains("uplink.stream"));
        assert!(error_of(&[("RAILMON_UPLINK__USER", "u")]).contains("uplink.password"));
        assert!(error_of(&[
            ("RAILMON_UPLINK__TOKEN", "t"),
            ("RAILMON_UPLINK__CREDS_FILE", "/x.creds")
        ])
        .contains("uplink.token"));
        // A dotted vehicle id splits a subject token: refused only with the uplink on.
        let dotted = ("RAILMON_IDENTITY__VEHICLE_ID", "unit.7");
        assert!(load_with(&[dotted]).is_ok());
        assert!(error_of(&[dotted, url]).contains("identity.vehicle_id"));
    }

    #[test]
    fn unknown_key_is_named() {
        // One underscore between levels: refused, naming the spelling that works (it was
        // ignored, and the service bound the default address).
        let err = error_of(&[("RAILMON_HTTP_LISTEN", "0.0.0.0:9999")]);
        assert!(
            err.contains("http.listen") && err.contains("write RAILMON_HTTP__LISTEN"),
            "{err}"
        );
        let err = error_of(&[("RAILMON_DRIVE__SLIP_THRESHOLD", "0.5")]);
        assert!(err.contains("slip_threshold"), "{err}");
    }

    #[test]
    fn bad_listen_address_is_rejected() {
        assert!(error_of(&[("RAILMON_HTTP__LISTEN", "localhost")]).contains("http.listen"));
    }

    #[test]
    fn zero_wake_interval_is_rejected() {
        assert!(error_of(&[("RAILMON_INGEST__WAKE_INTERVAL_MS", "0")])
            .contains("ingest.wake_interval_ms"));
    }

    #[test]
    fn zero_batch_is_rejected() {
        assert!(error_of(&[("RAILMON_INGEST__MAX_BATCH", "0")]).contains("ingest.max_batch"));
    }

    #[test]
    fn tiny_cleanup_interval_is_rejected() {
        assert!(error_of(&[("RAILMON_INGEST__CLEANUP_INTERVAL_MS", "1")])
            .contains("ingest.cleanup_interval_ms"));
    }

    #[test]
    fn zero_staleness_is_rejected() {
        assert!(
            error_of(&[("RAILMON_DRIVE__STALE_AFTER_MS", "0")]).contains("drive.stale_after_ms")
        );
    }

    #[test]
    fn max_drives_above_frame_capacity_is_rejected() {
        assert!(error_of(&[("RAILMON_DRIVE__MAX_DRIVES", "33")]).contains("drive.max_drives"));
    }

    #[test]
    fn slip_on_probability_above_one_is_rejected() {
        assert!(
            error_of(&[("RAILMON_DRIVE__ESTIMATOR__ALARM__ON_PROBABILITY", "1.5")])
                .contains("alarm.on_probability")
        );
    }

    #[test]
    fn slip_off_probability_not_below_on_probability_is_rejected() {
        assert!(
            error_of(&[("RAILMON_DRIVE__ESTIMATOR__ALARM__OFF_PROBABILITY", "0.9")])
                .contains("alarm.off_probability")
        );
    }

    #[test]
    fn zero_history_interval_is_rejected() {
        assert!(error_of(&[("RAILMON_DRIVE__HISTORY_INTERVAL_MS", "0")])
            .contains("drive.history_interval_ms"));
    }

    #[test]
    fn zero_history_capacity_is_rejected() {
        assert!(error_of(&[("RAILMON_DRIVE__HISTORY_CAPACITY", "0")])
            .contains("drive.history_capacity"));
    }

    #[test]
    fn bad_estimator_value_is_rejected() {
        assert!(error_of(&[("RAILMON_DRIVE__ESTIMATOR__DT_S", "-1.0")]).contains("drive.estimator"));
    }

    #[test]
    fn empty_bogie_list_is_rejected() {
        assert!(error_of(&[("RAILMON_BOGIE__BOGIES", "[]")]).contains("bogie.bogies"));
    }

    #[test]
    fn repeated_bogie_id_is_rejected() {
        let err = error_of(&[("RAILMON_BOGIE__BOGIES", "[1, 2, 1]")]);
        assert!(
            err.contains("bogie.bogies") && err.contains("twice"),
            "{err}"
        );
    }

    #[test]
    fn too_many_bogies_are_rejected() {
        let ids: Vec<String> = (0..=MAX_BOGIES).map(|k| k.to_string()).collect();
        let list = format!("[{}]", ids.join(","));
        assert!(error_of(&[("RAILMON_BOGIE__BOGIES", list.as_str())]).contains("bogie.bogies"));
    }

    #[test]
    fn degraded_ratio_of_one_is_rejected() {
        let err = error_of(&[(
            "RAILMON_BOGIE__ESTIMATOR__ALARM__DEGRADED_BELOW_RATIO",
            "1.0",
        )]);
        assert!(
            err.contains("bogie.estimator") && err.contains("alarm.degraded_below_ratio"),
            "{err}"
        );
    }

    #[test]
    fn recovered_ratio_not_above_degraded_is_rejected() {
        let err = error_of(&[(
            "RAILMON_BOGIE__ESTIMATOR__ALARM__RECOVERED_ABOVE_RATIO",
            "0.7",
        )]);
        assert!(
            err.contains("bogie.estimator") && err.contains("alarm.recovered_above_ratio"),
            "{err}"
        );
    }

    #[test]
    fn zero_bogie_history_interval_is_rejected() {
        assert!(error_of(&[("RAILMON_BOGIE__HISTORY_INTERVAL_MS", "0")])
            .contains("bogie.history_interval_ms"));
    }

    #[test]
    fn bad_bogie_estimator_value_is_rejected() {
        let err = error_of(&[("RAILMON_BOGIE__ESTIMATOR__RBPF__PARTICLES", "1")]);
        assert!(
            err.contains("bogie.estimator") && err.contains("particles"),
            "{err}"
        );
    }

    #[test]
    fn bogie_estimator_keys_override_single_defaults() {
        let config = ServiceConfig::load(
            None,
            [
                ("RAILMON_BOGIE__ENABLED".to_string(), "true".to_string()),
                (
                    "RAILMON_BOGIE__ESTIMATOR__RBPF__PARTICLES".to_string(),
                    "50".to_string(),
                ),
            ],
        )
        .unwrap();
        let mut expected = DamperMonitorConfig::default();
        expected.rbpf.particles = 50;
        assert_eq!(config.bogie.estimator, expected);
    }

    #[test]
    fn vehicle_estimator_keys_override_single_defaults() {
        let config = load_with(&[
            ("RAILMON_VEHICLE__ENABLED", "true"),
            ("RAILMON_VEHICLE__ESTIMATOR__COMPONENTS", "4"),
        ])
        .unwrap();
        assert!(config.vehicle.enabled);
        let expected = FuelMonitorConfig {
            components: 4,
            ..FuelMonitorConfig::default()
        };
        assert_eq!(config.vehicle.estimator, expected);
    }

    #[test]
    fn zero_vehicle_staleness_is_rejected() {
        assert!(error_of(&[("RAILMON_VEHICLE__STALE_AFTER_MS", "0")])
            .contains("vehicle.stale_after_ms"));
    }

    #[test]
    fn zero_vehicle_history_interval_is_rejected() {
        assert!(error_of(&[("RAILMON_VEHICLE__HISTORY_INTERVAL_MS", "0")])
            .contains("vehicle.history_interval_ms"));
    }

    #[test]
    fn zero_vehicle_history_capacity_is_rejected() {
        assert!(error_of(&[("RAILMON_VEHICLE__HISTORY_CAPACITY", "0")])
            .contains("vehicle.history_capacity"));
    }

    #[test]
    fn bad_vehicle_estimator_value_is_rejected() {
        let err = error_of(&[("RAILMON_VEHICLE__ESTIMATOR__FORGETTING", "1.5")]);
        assert!(
            err.contains("vehicle.estimator") && err.contains("forgetting"),
            "{err}"
        );
    }

    #[test]
    fn bad_bus_value_is_rejected() {
        assert!(error_of(&[("RAILMON_BUS__PREFIX", "a/b")]).contains("bus.prefix"));
    }
}
