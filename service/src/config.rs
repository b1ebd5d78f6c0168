//! `railmon serve` settings: embedded defaults < `config/railmon.toml` (or `--config FILE`) <
//! environment (`RAILMON_<SECTION>__<KEY>`, see [`railmon_bus::settings`]). Every key is
//! documented in `config/railmon.toml`, whose values are the defaults (a test checks it).

use std::net::SocketAddr;
use std::path::Path;

use railmon_bus::{settings, BusConfig, BusError, MAX_DRIVES};
use railmon_fuel::FuelMonitorConfig;
use railmon_slip::SlipMonitorConfig;
use serde::{Deserialize, Serialize};

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read config file {file}: {reason}")]
    Read { file: String, reason: String },
    #[error("{0}")]
    Invalid(#[from] BusError),
}

fn invalid(key: &str, reason: String) -> ConfigError {
    ConfigError::Invalid(BusError::Config {
        key: key.into(),
        reason,
    })
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ServiceConfig {
    pub http: HttpConfig,
    pub bus: BusConfig,
    pub ingest: IngestConfig,
    pub drive: DriveConfig,
    pub bogie: PendingStreamConfig,
    pub vehicle: VehicleConfig,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HttpConfig {
    /// Address and port of the HTTP API; port 0 picks a free one (see `--addr-file`).
    pub listen: String,
}

impl Default for HttpConfig {
    fn default() -> Self {
        Self {
            listen: "127.0.0.1:8787".into(),
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IngestConfig {
    /// Longest sleep of an ingest thread without a notification (shutdown and housekeeping latency).
    pub wake_interval_ms: u64,
    /// Frames handled before the results are published to the HTTP side.
    pub max_batch: usize,
    /// How often dead bus peers are cleaned up.
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

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DriveConfig {
    pub enabled: bool,
    /// The stream is stale (and `/readyz` fails) when no frame came for this long.
    pub stale_after_ms: u64,
    /// Frames with more drives are rejected (at most the frame capacity, 32).
    pub max_drives: usize,
    /// Hysteresis of the slipping flag: on when the slip probability reaches `slip_on_ratio`,
    /// off when it falls to `slip_off_ratio`.
    pub slip_on_ratio: f64,
    pub slip_off_ratio: f64,
    /// One history point per this much stream time.
    pub history_interval_ms: u64,
    /// History points kept (the oldest are dropped).
    pub history_capacity: usize,
    /// Slip events kept.
    pub events_capacity: usize,
    /// The estimator (`railmon_slip::SlipMonitorConfig`).
    pub estimator: SlipMonitorConfig,
}

impl Default for DriveConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            stale_after_ms: 500,
            max_drives: MAX_DRIVES,
            slip_on_ratio: 0.8,
            slip_off_ratio: 0.2,
            history_interval_ms: 10,
            history_capacity: 60_000,
            events_capacity: 1000,
            estimator: default_estimator(),
        }
    }
}

/// The estimator settings validated on the paper's experiment: the `[monitor]` section of
/// `config/scenarios/adhesion-seed.toml`, embedded at build time. `[drive.estimator]` in the
/// config file (or RAILMON_DRIVE__ESTIMATOR__... variables) override single keys of it.
const SEED_SCENARIO_TOML: &str = include_str!("../../config/scenarios/adhesion-seed.toml");

fn seed_monitor_table() -> toml::Table {
    let mut seed: toml::Table = SEED_SCENARIO_TOML
        .parse()
        .expect("config/scenarios/adhesion-seed.toml is valid TOML (checked by the slip tests)");
    match seed.remove("monitor") {
        Some(toml::Value::Table(monitor)) => monitor,
        _ => toml::Table::new(),
    }
}

fn default_estimator() -> SlipMonitorConfig {
    SlipMonitorConfig::deserialize(toml::Value::Table(seed_monitor_table()))
        .expect("the seed scenario's [monitor] section is a valid SlipMonitorConfig")
}

/// `overlay` on top of `base`, key by key through nested tables.
fn merge_tables(base: &mut toml::Table, overlay: toml::Table) {
    for (key, value) in overlay {
        match (base.get_mut(&key), value) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge_tables(b, o),
            (_, value) => {
                base.insert(key, value);
            }
        }
    }
}

/// `[vehicle]`: the road-vehicle stream (fuel flow, speed, ... at 1 Hz) -> `railmon_fuel::FuelMonitor`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VehicleConfig {
    /// Off by default: only vehicles with a fuel meter publish this stream, and `/readyz`
    /// requires every enabled stream to be fresh.
    pub enabled: bool,
    /// The stream is stale (and `/readyz` fails) when no frame came for this long.
    pub stale_after_ms: u64,
    /// One history point per this much stream time.
    pub history_interval_ms: u64,
    /// History points kept (the oldest are dropped).
    pub history_capacity: usize,
    /// Regime-change events kept.
    pub events_capacity: usize,
    /// The estimator (`railmon_fuel::FuelMonitorConfig`); keys given override single defaults.
    pub estimator: FuelMonitorConfig,
}

impl Default for VehicleConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            stale_after_ms: 3000,
            history_interval_ms: 1000,
            history_capacity: 86_400,
            events_capacity: 1000,
            estimator: FuelMonitorConfig::default(),
        }
    }
}

/// Streams whose estimators join in later issues (bogie: damper health).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PendingStreamConfig {
    pub enabled: bool,
}

impl ServiceConfig {
    /// Reads `file` (or only the defaults), applies the environment, validates.
    pub fn load(
        file: Option<&Path>,
        env: impl IntoIterator<Item = (String, String)>,
    ) -> Result<Self, ConfigError> {
        let mut table = match file {
            Some(path) => {
                let text = std::fs::read_to_string(path).map_err(|e| ConfigError::Read {
                    file: path.display().to_string(),
                    reason: e.to_string(),
                })?;
                settings::parse_table(&text, &path.display().to_string())?
            }
            None => toml::Table::new(),
        };
        let overrides = settings::apply_env_overrides(&mut table, env)?;
        // The estimator's defaults are the seed scenario's, not SlipMonitorConfig::default():
        // lay the given keys over them before deserialising.
        if let Some(toml::Value::Table(drive)) = table.get_mut("drive") {
            if let Some(toml::Value::Table(given)) = drive.remove("estimator") {
                let mut estimator = seed_monitor_table();
                merge_tables(&mut estimator, given);
                drive.insert("estimator".into(), toml::Value::Table(estimator));
            }
        }
        let config: ServiceConfig =
            settings::deserialize(toml::Value::Table(table), "", &overrides)?;
        config.validate()?;
        Ok(config)
    }

    /// Checks every value; the error names the key.
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.listen_addr()?;
        self.bus.validate()?;
        let i = &self.ingest;
        if !(1..=10_000).contains(&i.wake_interval_ms) {
            return Err(invalid(
                "ingest.wake_interval_ms",
                format!("{} is not in 1..=10000", i.wake_interval_ms),
            ));
        }
        if !(1..=65_536).contains(&i.max_batch) {
            return Err(invalid(
                "ingest.max_batch",
                format!("{} is not in 1..=65536", i.max_batch),
            ));
        }
        if !(10..=600_000).contains(&i.cleanup_interval_ms) {
            return Err(invalid(
                "ingest.cleanup_interval_ms",
                format!("{} is not in 10..=600000", i.cleanup_interval_ms),
            ));
        }
        self.drive.validate()?;
        self.vehicle.validate()?;
        if self.bogie.enabled {
            return Err(invalid(
                "bogie.enabled",
                "the bogie stream has no estimator in this version; set false".into(),
            ));
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

/// The keys every stream section has: staleness, history and event ring sizes.
fn validate_stream_keys(
    section: &str,
    stale_after_ms: u64,
    history_interval_ms: u64,
    history_capacity: usize,
    events_capacity: usize,
) -> Result<(), ConfigError> {
    for (key, value) in [
        ("stale_after_ms", stale_after_ms),
        ("history_interval_ms", history_interval_ms),
    ] {
        if !(1..=3_600_000).contains(&value) {
            return Err(invalid(
                &format!("{section}.{key}"),
                format!("{value} is not in 1..=3600000"),
            ));
        }
    }
    for (key, value) in [
        ("history_capacity", history_capacity),
        ("events_capacity", events_capacity),
    ] {
        if !(1..=1_000_000).contains(&value) {
            return Err(invalid(
                &format!("{section}.{key}"),
                format!("{value} is not in 1..=1000000"),
            ));
        }
    }
    Ok(())
}

impl VehicleConfig {
    fn validate(&self) -> Result<(), ConfigError> {
        validate_stream_keys(
            "vehicle",
            self.stale_after_ms,
            self.history_interval_ms,
            self.history_capacity,
            self.events_capacity,
        )?;
        self.estimator
            .validate()
            .map_err(|e| invalid("vehicle.estimator", e.to_string()))
    }
}

impl DriveConfig {
    fn validate(&self) -> Result<(), ConfigError> {
        validate_stream_keys(
            "drive",
            self.stale_after_ms,
            self.history_interval_ms,
            self.history_capacity,
            self.events_capacity,
        )?;
        if !(1..=MAX_DRIVES).contains(&self.max_drives) {
            return Err(invalid(
                "drive.max_drives",
                format!("{} is not in 1..={MAX_DRIVES}", self.max_drives),
            ));
        }
        if !(self.slip_on_ratio > 0.0 && self.slip_on_ratio <= 1.0) {
            return Err(invalid(
                "drive.slip_on_ratio",
                format!("{} is not in (0, 1]", self.slip_on_ratio),
            ));
        }
        if !(self.slip_off_ratio >= 0.0 && self.slip_off_ratio < self.slip_on_ratio) {
            return Err(invalid(
                "drive.slip_off_ratio",
                format!(
                    "{} is not in [0, slip_on_ratio = {})",
                    self.slip_off_ratio, self.slip_on_ratio
                ),
            ));
        }
        self.estimator
            .validate()
            .map_err(|e| invalid("drive.estimator", e.to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
    fn estimator_keys_override_single_seed_values() {
        let config = load_with(&[(
            "RAILMON_DRIVE__ESTIMATOR__EKF__MEASUREMENT_NOISE_A2",
            "0.02",
        )])
        .unwrap();
        let mut expected = default_estimator();
        expected.ekf.measurement_noise_a2 = 0.02;
        assert_eq!(config.drive.estimator, expected);
    }

    #[test]
    fn missing_file_is_named() {
        let err = ServiceConfig::load(Some(Path::new("/nonexistent/railmon.toml")), [])
            .unwrap_err()
            .to_string();
        assert!(err.contains("/nonexistent/railmon.toml"), "{err}");
    }

    #[test]
    fn unknown_key_is_named() {
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
    fn slip_on_ratio_above_one_is_rejected() {
        assert!(
            error_of(&[("RAILMON_DRIVE__SLIP_ON_RATIO", "1.5")]).contains("drive.slip_on_ratio")
        );
    }

    #[test]
    fn slip_off_ratio_not_below_on_ratio_is_rejected() {
        assert!(
            error_of(&[("RAILMON_DRIVE__SLIP_OFF_RATIO", "0.9")]).contains("drive.slip_off_ratio")
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
    fn zero_events_capacity_is_rejected() {
        assert!(
            error_of(&[("RAILMON_DRIVE__EVENTS_CAPACITY", "0")]).contains("drive.events_capacity")
        );
    }

    #[test]
    fn bad_estimator_value_is_rejected() {
        assert!(error_of(&[("RAILMON_DRIVE__ESTIMATOR__DT_S", "-1.0")]).contains("drive.estimator"));
    }

    #[test]
    fn enabling_a_stream_without_estimator_is_rejected() {
        assert!(error_of(&[("RAILMON_BOGIE__ENABLED", "true")]).contains("bogie.enabled"));
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
    fn zero_vehicle_events_capacity_is_rejected() {
        assert!(error_of(&[("RAILMON_VEHICLE__EVENTS_CAPACITY", "0")])
            .contains("vehicle.events_capacity"));
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
