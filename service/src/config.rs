//! `railmon serve` settings: embedded defaults < `config/railmon.toml` (or `--config FILE`) <
//! environment (`RAILMON_<SECTION>__<KEY>`, see [`railmon_settings`]). Every key is documented
//! in `config/railmon.toml`, whose values are the defaults (a test checks it). Each stream's
//! section is defined next to its pipeline (`drive::DriveConfig`, ...).

use std::net::SocketAddr;
use std::path::Path;

use railmon_bus::{BusConfig, BusError};
use railmon_settings as settings;
use serde::{Deserialize, Serialize};

pub use crate::bogie::{BogieConfig, MAX_BOGIES};
pub use crate::drive::DriveConfig;
pub use crate::vehicle::VehicleConfig;

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read config file {file}: {reason}")]
    Read { file: String, reason: String },
    #[error("{0}")]
    Invalid(#[from] BusError),
}

impl From<settings::SettingsError> for ConfigError {
    fn from(e: settings::SettingsError) -> Self {
        ConfigError::Invalid(e.into())
    }
}

pub(crate) fn invalid(key: &str, reason: String) -> ConfigError {
    ConfigError::Invalid(BusError::Config {
        key: key.into(),
        reason,
    })
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ServiceConfig {
    pub identity: IdentityConfig,
    pub storage: crate::store::StorageConfig,
    pub http: HttpConfig,
    pub bus: BusConfig,
    pub ingest: IngestConfig,
    pub drive: DriveConfig,
    pub bogie: BogieConfig,
    pub vehicle: VehicleConfig,
}

/// `[identity]`: which vehicle this service monitors, in every API answer, event and metric.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
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

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HttpConfig {
    /// Address and port of the HTTP API; port 0 picks a free one (see `--addr-file`).
    pub listen: String,
    /// A client must send a request's headers within this long; also how long an idle
    /// keep-alive connection is kept (10,000 half-open connections once held 266 MB).
    pub header_timeout_ms: u64,
    /// Longest time one request may take; then it is answered 503 `timeout`.
    pub request_timeout_ms: u64,
    /// Open connections at most; further ones are closed at once (and counted).
    pub max_connections: usize,
    /// On SIGTERM, open requests get this long to finish before their connections are cut.
    pub shutdown_deadline_ms: u64,
    /// Longer request targets are answered 414, larger header sections 431 (JSON bodies).
    pub max_uri_bytes: usize,
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
            if !(1..=600_000).contains(&value) {
                return Err(invalid(
                    &format!("http.{key}"),
                    format!("{value} is not in 1..=600000"),
                ));
            }
        }
        if !(1..=65_536).contains(&self.max_connections) {
            return Err(invalid(
                "http.max_connections",
                format!("{} is not in 1..=65536", self.max_connections),
            ));
        }
        for (key, value) in [
            ("max_uri_bytes", self.max_uri_bytes),
            ("max_header_bytes", self.max_header_bytes),
        ] {
            if !(256..=262_144).contains(&value) {
                return Err(invalid(
                    &format!("http.{key}"),
                    format!("{value} is not in 256..=262144"),
                ));
            }
        }
        Ok(())
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
        let config: ServiceConfig =
            settings::deserialize(toml::Value::Table(table), "", &overrides)?;
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
        self.bogie.validate()?;
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
pub(crate) fn validate_stream_keys(
    section: &str,
    stale_after_ms: u64,
    history_interval_ms: u64,
    history_capacity: usize,
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
    if !(1..=1_000_000).contains(&history_capacity) {
        return Err(invalid(
            &format!("{section}.history_capacity"),
            format!("{history_capacity} is not in 1..=1000000"),
        ));
    }
    Ok(())
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
