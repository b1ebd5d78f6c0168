//! `[uplink]`: where `railmon serve` forwards its stored events (NATS JetStream), as whom, and
//! how fast. Off while `url` is empty (the default).

use std::ops::RangeInclusive;

use railmon_settings::{self as settings, SettingsError};
use serde::{Deserialize, Serialize};

use crate::stream_keys::invalid;

/// Bounds of `uplink.max_events_per_s`, declared to the reference and checked by `validate`.
pub const MAX_EVENTS_PER_S: RangeInclusive<u32> = 1..=100_000;
/// Bounds of `uplink.health_interval_s` (s), declared to the reference and checked by
/// `validate`: a summary is a few kB, so even the shortest interval is no load on the link.
pub const HEALTH_INTERVAL_S: RangeInclusive<f64> = 1.0..=3600.0;

#[derive(Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct UplinkConfig {
    /// NATS server(s) to forward the events to (empty: no uplink), e.g.
    /// `nats://ground.example:4222` (`tls://...` requires TLS); several separated by commas.
    pub url: String,
    /// NATS user (with `password`); empty: none.
    pub user: String,
    /// NATS password of `user`.
    pub password: String,
    /// NATS token (instead of user and password); empty: none.
    pub token: String,
    /// NATS credentials file (JWT and nkey seed, `.creds`), instead of user or token; empty:
    /// none.
    pub creds_file: String,
    /// PEM file of the CA that signed the server's TLS certificate (empty: the system roots).
    pub tls_ca_file: String,
    /// First token of every subject: events go to
    /// `<subject_prefix>.<fleet>.<vehicle_id>.<stream>.events` (`_` for an empty fleet).
    pub subject_prefix: String,
    /// The JetStream stream that stores them; created (subjects `<subject_prefix>.>`, a
    /// 2-minute duplicate window) if the server has none of that name.
    pub stream: String,
    /// Events forwarded per second at most: a backlog (a vehicle offline for a day) drains
    /// at this rate, oldest first.
    #[schemars(range(min = *MAX_EVENTS_PER_S.start(), max = *MAX_EVENTS_PER_S.end()))]
    pub max_events_per_s: u32,
    /// How often a health summary (every drive's slip state, every bogie's damper estimates
    /// with their 90 % intervals, the fuel regime, and the active alarms) goes to
    /// `<subject_prefix>.<fleet>.<vehicle_id>.health` (and the alarms to `...alarms`), s.
    #[schemars(range(min = *HEALTH_INTERVAL_S.start(), max = *HEALTH_INTERVAL_S.end()))]
    pub health_interval_s: f64,
}

impl Default for UplinkConfig {
    fn default() -> Self {
        Self {
            url: String::new(),
            user: String::new(),
            password: String::new(),
            token: String::new(),
            creds_file: String::new(),
            tls_ca_file: String::new(),
            subject_prefix: "railmon".into(),
            stream: "RAILMON".into(),
            max_events_per_s: 200,
            health_interval_s: 60.0,
        }
    }
}

// Secrets stay out of logs and `{:?}` output.
impl std::fmt::Debug for UplinkConfig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let hidden = |s: &str| if s.is_empty() { "" } else { "***" };
        f.debug_struct("UplinkConfig")
            .field("url", &self.url)
            .field("user", &self.user)
            .field("password", &hidden(&self.password))
            .field("token", &hidden(&self.token))
            .field("creds_file", &self.creds_file)
            .field("tls_ca_file", &self.tls_ca_file)
            .field("subject_prefix", &self.subject_prefix)
            .field("stream", &self.stream)
            .field("max_events_per_s", &self.max_events_per_s)
            .field("health_interval_s", &self.health_interval_s)
            .finish()
    }
}

/// A subject token we write: letters, digits, `_`, `-` (no `.`, which splits tokens, no
/// wildcards, no white space).
pub(crate) fn is_token(s: &str) -> bool {
    !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-'))
}

impl<'a> From<&'a UplinkConfig> for crate::nats_client::NatsLogin<'a> {
    fn from(c: &'a UplinkConfig) -> Self {
        Self {
            section: "uplink",
            url: &c.url,
            user: &c.user,
            password: &c.password,
            token: &c.token,
            creds_file: &c.creds_file,
            tls_ca_file: &c.tls_ca_file,
        }
    }
}

impl UplinkConfig {
    pub fn enabled(&self) -> bool {
        !self.url.trim().is_empty()
    }

    /// Checks every value (also when off, so a file is right before the url is set); the
    /// error names the key. (`ServiceConfig::validate` also refuses a `.` in the vehicle id or
    /// fleet while the uplink is on: it would split the subject's tokens.)
    pub(crate) fn validate(&self) -> Result<(), SettingsError> {
        settings::check_in_range(
            "uplink.max_events_per_s",
            self.max_events_per_s,
            &MAX_EVENTS_PER_S,
        )?;
        settings::check_in_range(
            "uplink.health_interval_s",
            self.health_interval_s,
            &HEALTH_INTERVAL_S,
        )?;
        check_stream_and_login(&self.into(), &self.subject_prefix, &self.stream)
    }
}

/// The checks `[uplink]` and `[fleet]` share: the servers, the subject prefix and stream as
/// NATS tokens, and at most one way to log in; errors name `<section>.<key>`.
pub(crate) fn check_stream_and_login(
    login: &crate::nats_client::NatsLogin,
    subject_prefix: &str,
    stream: &str,
) -> Result<(), SettingsError> {
    let key = |k: &str| format!("{}.{k}", login.section);
    crate::nats_client::servers(login.section, login.url).map_err(|e| invalid(&key("url"), e))?;
    if !subject_prefix.split('.').all(is_token) {
        return Err(invalid(
            &key("subject_prefix"),
            format!(
                "`{subject_prefix}`: use tokens of letters, digits, `_` or `-`, separated by `.`"
            ),
        ));
    }
    if !is_token(stream) {
        return Err(invalid(
            &key("stream"),
            format!("`{stream}`: use letters, digits, `_` or `-`"),
        ));
    }
    if login.password.is_empty() != login.user.is_empty() {
        let which = match login.user.is_empty() {
            true => "user",
            false => "password",
        };
        return Err(invalid(&key(which), "user and password go together".into()));
    }
    let methods = [
        !login.user.is_empty(),
        !login.token.is_empty(),
        !login.creds_file.is_empty(),
    ];
    if methods.iter().filter(|m| **m).count() > 1 {
        return Err(invalid(
            &key("token"),
            "set one of user and password, token, or creds_file".into(),
        ));
    }
    Ok(())
}
