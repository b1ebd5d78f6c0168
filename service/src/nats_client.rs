//! A NATS connection from the credentials every NATS section shares (`[uplink]`'s health
//! publisher, `[fleet]`): servers, user and password, token, creds file, TLS CA. The event
//! uplink (`uplink::run`) builds its own, with its counters on the client's events.

use std::time::Duration;

/// Where and as whom to connect; `section` names the keys in errors (`uplink`, `fleet`).
pub struct NatsLogin<'a> {
    pub section: &'static str,
    pub url: &'a str,
    pub user: &'a str,
    pub password: &'a str,
    pub token: &'a str,
    pub creds_file: &'a str,
    pub tls_ca_file: &'a str,
}

/// The servers of a comma-separated `url`.
pub fn servers(section: &str, url: &str) -> Result<Vec<async_nats::ServerAddr>, String> {
    url.split(',')
        .filter(|s| !s.trim().is_empty())
        .map(|s| {
            s.trim()
                .parse()
                .map_err(|e| format!("{section}.url `{s}`: {e}"))
        })
        .collect()
}

/// A client named `name` that reconnects by itself (backoff up to 5 s, for ever); with
/// `wait_for_server` false it also returns before the first connection (publishes fail until
/// then), else the first connection must succeed.
pub async fn connect(
    login: &NatsLogin<'_>,
    name: &str,
    wait_for_server: bool,
) -> Result<async_nats::Client, String> {
    let section = login.section;
    let mut options = async_nats::ConnectOptions::new()
        .name(name)
        .connection_timeout(Duration::from_secs(5))
        .reconnect_delay_callback(|attempts| {
            Duration::from_millis(250 * 2u64.pow(attempts.min(5) as u32))
                .min(Duration::from_secs(5))
        });
    if !wait_for_server {
        options = options.retry_on_initial_connect();
    }
    if !login.user.is_empty() {
        options = options.user_and_password(login.user.into(), login.password.into());
    }
    if !login.token.is_empty() {
        options = options.token(login.token.into());
    }
    if !login.creds_file.is_empty() {
        options = options
            .credentials_file(login.creds_file)
            .await
            .map_err(|e| format!("{section}.creds_file {}: {e}", login.creds_file))?;
    }
    if !login.tls_ca_file.is_empty() {
        options = options
            .add_root_certificates(login.tls_ca_file.into())
            .require_tls(true);
    }
    options
        .connect(servers(section, login.url)?)
        .await
        .map_err(|e| format!("connecting to {} ({section}.url): {e}", login.url))
}
