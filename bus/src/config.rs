//! Transport settings shared by the publisher (`sensors-replay`) and the subscriber (`railmon
//! serve`): the `[bus]` section of `config/railmon.toml`.

use serde::{Deserialize, Serialize};

use railmon_settings::SettingsError;

/// The three sensor streams. Each has its own publish-subscribe service and event service.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum StreamKind {
    /// Traction drives: voltages and currents of every drive, one frame per control step.
    Drive,
    /// Bogie: accelerometers and yaw-rate gyro (damper monitoring).
    Bogie,
    /// Vehicle: fuel flow, speed, pedal, torque, engine speed, gear (fuel monitoring).
    Vehicle,
}

impl StreamKind {
    pub const ALL: [StreamKind; 3] = [StreamKind::Drive, StreamKind::Bogie, StreamKind::Vehicle];

    /// The stream's name in config keys, metric labels and the HTTP API.
    pub fn name(self) -> &'static str {
        match self {
            StreamKind::Drive => "drive",
            StreamKind::Bogie => "bogie",
            StreamKind::Vehicle => "vehicle",
        }
    }
}

impl std::fmt::Display for StreamKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// `[bus]`: where iceoryx2 keeps its files, and one `[bus.<stream>]` table per stream.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct BusConfig {
    /// Prefix of every iceoryx2 file (shared memory in /dev/shm, discovery files): processes
    /// only see each other with the same prefix and root path.
    pub prefix: String,
    /// Directory for iceoryx2 discovery files, liveness locks and event sockets; empty: a
    /// private directory of the user (`crate::root_path`).
    pub root_path: String,
    pub drive: StreamConfig,
    pub bogie: StreamConfig,
    pub vehicle: StreamConfig,
}

impl Default for BusConfig {
    fn default() -> Self {
        Self {
            prefix: "railmon_".into(),
            root_path: String::new(),
            drive: StreamConfig::default(),
            bogie: StreamConfig::default(),
            vehicle: StreamConfig::default(),
        }
    }
}

/// Bounds of [`StreamConfig`]'s numbers, declared to the reference and checked.
const SUBSCRIBER_BUFFER_SIZE: std::ops::RangeInclusive<usize> = 1..=65_536;
const BACKPRESSURE_TIMEOUT_MS: std::ops::RangeInclusive<u64> = 1..=60_000;

/// `[bus.<stream>]`: one publish-subscribe service (and the event service of the same name).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct StreamConfig {
    /// iceoryx2 service name of the stream; empty means `railmon/<stream>`.
    pub service_name: String,
    /// Frames a subscriber can hold unread before the publisher waits (or overwrites).
    #[schemars(range(min = *SUBSCRIBER_BUFFER_SIZE.start(), max = *SUBSCRIBER_BUFFER_SIZE.end()))]
    pub subscriber_buffer_size: usize,
    /// true: a full subscriber buffer silently drops its oldest frame (the publisher never waits).
    /// false: lossless, the publisher waits for the subscriber, at most `backpressure_timeout_ms`.
    pub safe_overflow: bool,
    /// Lossless mode: how long one send may wait for a full subscriber before the frame is
    /// dropped for that subscriber (a SIGKILLed subscriber would otherwise block the publisher).
    #[schemars(range(min = *BACKPRESSURE_TIMEOUT_MS.start(), max = *BACKPRESSURE_TIMEOUT_MS.end()))]
    pub backpressure_timeout_ms: u64,
}

impl Default for StreamConfig {
    fn default() -> Self {
        Self {
            service_name: String::new(),
            subscriber_buffer_size: 1024,
            safe_overflow: false,
            backpressure_timeout_ms: 250,
        }
    }
}

impl StreamConfig {
    fn validate(&self, key: &str) -> Result<(), SettingsError> {
        let bad =
            |field: &str, reason: String| SettingsError::new(format!("{key}.{field}"), reason);
        if self.service_name.len() > 200 || self.service_name.contains(char::is_whitespace) {
            return Err(bad(
                "service_name",
                format!(
                    "`{}` must have at most 200 characters and no spaces",
                    self.service_name
                ),
            ));
        }
        railmon_settings::check_in_range(
            &format!("{key}.subscriber_buffer_size"),
            self.subscriber_buffer_size,
            &SUBSCRIBER_BUFFER_SIZE,
        )?;
        railmon_settings::check_in_range(
            &format!("{key}.backpressure_timeout_ms"),
            self.backpressure_timeout_ms,
            &BACKPRESSURE_TIMEOUT_MS,
        )
    }
}

impl BusConfig {
    /// Checks every value; the error names the key (`bus.drive.subscriber_buffer_size`).
    pub fn validate(&self) -> Result<(), SettingsError> {
        let file_name_ok = |c: char| c.is_ascii_alphanumeric() || "_-.".contains(c);
        if self.prefix.is_empty()
            || self.prefix.len() > 64
            || !self.prefix.chars().all(file_name_ok)
        {
            return Err(SettingsError::new(
                "bus.prefix",
                format!(
                    "`{}` must be 1 to 64 characters of A-Z a-z 0-9 _ - .",
                    self.prefix
                ),
            ));
        }
        let root_ok = self.root_path.is_empty()
            || (self.root_path.starts_with('/') && self.root_path.len() <= 200);
        if !root_ok {
            return Err(SettingsError::new(
                "bus.root_path",
                format!(
                    "`{}` must be empty (a private default) or an absolute path of at most 200 characters",
                    self.root_path
                ),
            ));
        }
        for kind in StreamKind::ALL {
            self.stream(kind)
                .validate(&format!("bus.{}", kind.name()))?;
        }
        Ok(())
    }

    /// The settings of one stream, with the default service name `railmon/<stream>` filled in.
    pub fn stream(&self, kind: StreamKind) -> StreamConfig {
        let mut stream = match kind {
            StreamKind::Drive => &self.drive,
            StreamKind::Bogie => &self.bogie,
            StreamKind::Vehicle => &self.vehicle,
        }
        .clone();
        if stream.service_name.is_empty() {
            stream.service_name = format!("railmon/{kind}");
        }
        stream
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rejected(edit: impl FnOnce(&mut BusConfig)) -> String {
        let mut config = BusConfig::default();
        edit(&mut config);
        config.validate().unwrap_err().to_string()
    }

    #[test]
    fn defaults_are_valid() {
        BusConfig::default().validate().unwrap();
    }

    #[test]
    fn empty_prefix_is_rejected() {
        assert!(rejected(|c| c.prefix.clear()).contains("bus.prefix"));
    }

    #[test]
    fn prefix_with_slash_is_rejected() {
        assert!(rejected(|c| c.prefix = "a/b".into()).contains("bus.prefix"));
    }

    #[test]
    fn relative_root_path_is_rejected() {
        assert!(rejected(|c| c.root_path = "tmp/x".into()).contains("bus.root_path"));
    }

    #[test]
    fn service_name_with_space_is_rejected() {
        let message = rejected(|c| c.bogie.service_name = "a b".into());
        assert!(message.contains("bus.bogie.service_name"), "{message}");
    }

    #[test]
    fn empty_service_name_means_railmon_slash_stream() {
        let config = BusConfig::default();
        assert_eq!(
            config.stream(StreamKind::Vehicle).service_name,
            "railmon/vehicle"
        );
    }

    #[test]
    fn zero_buffer_is_rejected() {
        let message = rejected(|c| c.drive.subscriber_buffer_size = 0);
        assert!(
            message.contains("bus.drive.subscriber_buffer_size"),
            "{message}"
        );
    }

    #[test]
    fn zero_backpressure_timeout_is_rejected() {
        let message = rejected(|c| c.vehicle.backpressure_timeout_ms = 0);
        assert!(
            message.contains("bus.vehicle.backpressure_timeout_ms"),
            "{message}"
        );
    }
}
