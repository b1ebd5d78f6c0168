/// Errors of the bus: configuration, iceoryx2 failures (with what was being done) and timeouts.
#[derive(Debug, thiserror::Error)]
pub enum BusError {
    #[error("config key `{key}`: {reason}")]
    Config { key: String, reason: String },
    #[error("iceoryx2: {what}: {detail}")]
    Ipc { what: String, detail: String },
    #[error("no subscriber on service `{service}` after {waited_ms} ms")]
    NoSubscriber { service: String, waited_ms: u64 },
    #[error("stopped while waiting for a subscriber on `{service}`")]
    Stopped { service: String },
}

impl BusError {
    pub(crate) fn ipc(what: impl Into<String>, detail: impl std::fmt::Debug) -> Self {
        BusError::Ipc {
            what: what.into(),
            detail: format!("{detail:?}"),
        }
    }
}

impl From<railmon_settings::SettingsError> for BusError {
    fn from(e: railmon_settings::SettingsError) -> Self {
        BusError::Config {
            key: e.key,
            reason: e.reason,
        }
    }
}
