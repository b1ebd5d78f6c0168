//! `[fleet]`: what `railmon fleet` reads (the ground's NATS JetStream stream the vehicles'
//! uplinks write), as whom, and where it answers. `railmon serve` ignores this section.

use railmon_settings::SettingsError;
use serde::{Deserialize, Serialize};

use crate::stream_keys::invalid;
use crate::uplink::config::check_stream_and_login;

#[derive(Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct FleetConfig {
    /// Address and port `railmon fleet` answers on (port 0 picks a free one, see its
    /// `--addr-file`).
    pub listen: String,
    /// NATS server(s) holding the vehicles' stream, e.g. `nats://ground.example:4222`; several
    /// separated by commas. `railmon fleet` refuses to start without one.
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
    /// The vehicles' `uplink.subject_prefix`.
    pub subject_prefix: String,
    /// The vehicles' `uplink.stream`: the JetStream stream read (never written or created).
    pub stream: String,
}

impl Default for FleetConfig {
    fn default() -> Self {
        Self {
            listen: "127.0.0.1:8090".into(),
            url: String::new(),
            user: String::new(),
            password: String::new(),
            token: String::new(),
            creds_file: String::new(),
            tls_ca_file: String::new(),
            subject_prefix: "railmon".into(),
            stream: "RAILMON".into(),
        }
    }
}

// Secrets stay out of logs and `{:?}` output.
impl std::fmt::Debug for FleetConfig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let hidden = |s: &str| if s.is_empty() { "" } else { "***" };
        f.debug_struct("FleetConfig")
            .field("listen", &self.listen)
            .field("url", &self.url)
            .field("user", &self.user)
            .field("password", &hidden(&self.password))
            .field("token", &hidden(&self.token))
            .field("creds_file", &self.creds_file)
            .field("tls_ca_file", &self.tls_ca_file)
            .field("subject_prefix", &self.subject_prefix)
            .field("stream", &self.stream)
            .finish()
    }
}

impl<'a> From<&'a FleetConfig> for crate::nats_client::NatsLogin<'a> {
    fn from(c: &'a FleetConfig) -> Self {
        Self {
            section: "fleet",
            url: &c.url,
            user: &c.user,
            password: &c.password,
            token: &c.token,
            creds_file: &c.creds_file,
            tls_ca_file: &c.tls_ca_file,
        }
    }
}

impl FleetConfig {
    /// The listen address, or an error naming `fleet.listen`.
    pub fn listen_addr(&self) -> Result<std::net::SocketAddr, SettingsError> {
        self.listen.parse().map_err(|e| {
            invalid(
                "fleet.listen",
                format!("`{}` is not an address:port ({e})", self.listen),
            )
        })
    }

    /// Checks every value (also for `railmon serve`, so a shared file is right); the error
    /// names the key. An empty `url` is refused by `railmon fleet` only.
    pub(crate) fn validate(&self) -> Result<(), SettingsError> {
        self.listen_addr()?;
        check_stream_and_login(&self.into(), &self.subject_prefix, &self.stream)
    }
}
