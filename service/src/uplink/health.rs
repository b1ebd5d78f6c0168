//! The health summary over the uplink (issue 29 item 1): every `uplink.health_interval_s`
//! (default 60 s), while the link is up, `railmon serve` publishes what its API serves now —
//! `GET /api/v1/drives` (slip state per drive), `GET /api/v1/bogies` (damper estimates with
//! their 90 % intervals per bogie), `GET /api/v1/vehicle` (fuel and regime) — on
//! `<prefix>.<fleet>.<vehicle>.health`, and its active alarms (`GET /api/v1/alarms`) with the
//! store's last event id on `<prefix>.<fleet>.<vehicle>.alarms`.
//!
//! Latest wins: a summary is the state now, so none is kept or sent again after a failure
//! (the next one replaces it), and none carries a message id. The alarm snapshot lets
//! `railmon fleet` answer "which vehicles have an active alarm" from one small message per
//! vehicle plus the few events after it, instead of every event ever sent (docs/fleet.md).
//!
//! Its own task and connection beside the event uplink: a summary never waits for a page of
//! events, and the event uplink's cursor logic stays as it is.

use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::Arc;
use std::time::Duration;

use async_nats::jetstream;
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use crate::bogie::view::BogiesView;
use crate::drive::view::DrivesView;
use crate::store::ActiveAlarm;
use crate::vehicle::view::VehicleView;
use crate::AppState;

/// A publish not acknowledged within this is a failure (and the summary is dropped).
const ACK_TIMEOUT: Duration = Duration::from_secs(5);

/// What went wrong, as `railmon_uplink_health_failures_total{kind}` counts it: the link was
/// down at a tick (nothing sent), the client could not be set up, the event store could not
/// be read, publish or acknowledgement failed or timed out.
pub const HEALTH_FAILURE_KINDS: [&str; 5] = ["disconnected", "connect", "store", "publish", "ack"];

/// The health publisher's counters, shared with `/metrics`.
#[derive(Debug, Default)]
pub struct HealthCounters {
    /// Summaries the stream acknowledged (each with its alarm snapshot).
    pub sent: AtomicU64,
    /// By [`HEALTH_FAILURE_KINDS`].
    pub failures: [AtomicU64; HEALTH_FAILURE_KINDS.len()],
}

impl HealthCounters {
    fn fail(&self, kind: &str) {
        if let Some(i) = HEALTH_FAILURE_KINDS.iter().position(|k| *k == kind) {
            self.failures[i].fetch_add(1, Relaxed);
        }
    }
}

/// `<prefix>.<fleet>.<vehicle>.health`: the vehicle's estimates now, as its API serves them.
#[derive(Clone, Debug, Serialize, ToSchema)]
pub struct HealthSummary {
    pub vehicle_id: String,
    pub fleet: String,
    /// When it was made, RFC 3339 UTC (the vehicle's clock).
    pub generated_utc: String,
    /// `GET /api/v1/drives`: slip probability and slipping flag per drive (null: the drive
    /// stream is disabled).
    pub drives: Option<DrivesView>,
    /// `GET /api/v1/bogies`: each damper's damping with its 90 % interval, health ratio and
    /// degraded flag, per bogie (null: disabled).
    pub bogies: Option<BogiesView>,
    /// `GET /api/v1/vehicle`: fuel rate and driving regime (null: disabled).
    pub vehicle: Option<VehicleView>,
}

/// `<prefix>.<fleet>.<vehicle>.alarms`: the alarms active on the vehicle.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct AlarmSnapshot {
    pub vehicle_id: String,
    pub fleet: String,
    pub generated_utc: String,
    /// The store's last event id, read before the alarms: they reflect every event up to it
    /// (and possibly a few after, which changes nothing when applied again).
    pub last_event_id: u64,
    /// `GET /api/v1/alarms`.
    pub alarms: Vec<ActiveAlarm>,
}

/// The subjects of a vehicle's summaries: `<prefix>.<fleet>.<vehicle>.{health,alarms}`
/// (`_` for an empty fleet, as the events' subjects).
pub fn subject(prefix: &str, fleet: &str, vehicle_id: &str, what: &str) -> String {
    let fleet = if fleet.is_empty() { "_" } else { fleet };
    format!("{prefix}.{fleet}.{vehicle_id}.{what}")
}

/// The summary and the alarm snapshot of now.
async fn read(state: &AppState) -> Result<(HealthSummary, AlarmSnapshot), String> {
    let now = railmon_bus::utc::format_rfc3339(railmon_bus::utc_now_ns());
    let enabled = |kind| state.stream(kind).is_some();
    use railmon_bus::StreamKind::{Bogie, Drive, Vehicle};
    let summary = HealthSummary {
        vehicle_id: state.identity.vehicle_id.clone(),
        fleet: state.identity.fleet.clone(),
        generated_utc: now.clone(),
        drives: enabled(Drive).then(|| DrivesView::clone(&state.drive.snapshot.load())),
        bogies: enabled(Bogie).then(|| BogiesView::clone(&state.bogie.snapshot.load())),
        vehicle: enabled(Vehicle).then(|| VehicleView::clone(&state.vehicle.snapshot.load())),
    };
    let store = state.store.clone();
    let (last_event_id, alarms) = tokio::task::spawn_blocking(move || {
        // The id first: the counter moves after a commit, so the alarms read next reflect
        // at least every event up to it.
        let last = store.counters.last_id.load(Relaxed);
        store.active_alarms().map(|alarms| (last, alarms))
    })
    .await
    .map_err(|e| format!("alarms task: {e}"))?
    .map_err(|e| e.to_string())?;
    let alarms = AlarmSnapshot {
        vehicle_id: summary.vehicle_id.clone(),
        fleet: summary.fleet.clone(),
        generated_utc: now,
        last_event_id,
        alarms,
    };
    Ok((summary, alarms))
}

/// Publishes one message and waits for its acknowledgement.
async fn publish(
    js: &jetstream::Context,
    subject: String,
    payload: Vec<u8>,
) -> Result<(), (&'static str, String)> {
    let ack = tokio::time::timeout(ACK_TIMEOUT, js.publish(subject.clone(), payload.into()))
        .await
        .map_err(|_| ("publish", format!("{subject}: timed out")))?
        .map_err(|e| ("publish", format!("{subject}: {e}")))?;
    tokio::time::timeout(ACK_TIMEOUT, std::future::IntoFuture::into_future(ack))
        .await
        .map_err(|_| ("ack", format!("{subject}: timed out")))?
        .map_err(|e| ("ack", format!("{subject}: {e}")))?;
    Ok(())
}

/// The health publisher: runs until the runtime stops.
pub async fn run(state: AppState, counters: Arc<HealthCounters>) {
    let config = state.config.uplink.clone();
    let login = crate::nats_client::NatsLogin::from(&config);
    let client = loop {
        match crate::nats_client::connect(&login, "railmon-health", false).await {
            Ok(client) => break client,
            Err(e) => {
                counters.fail("connect");
                tracing::warn!("uplink health: {e}");
                tokio::time::sleep(Duration::from_secs(5)).await;
            }
        }
    };
    let js = jetstream::ContextBuilder::new()
        .timeout(ACK_TIMEOUT)
        .build(client.clone());
    let prefix = config.subject_prefix.as_str();
    let (vehicle, fleet) = (&state.identity.vehicle_id, &state.identity.fleet);
    let health_subject = subject(prefix, fleet, vehicle, "health");
    let alarms_subject = subject(prefix, fleet, vehicle, "alarms");
    let interval = Duration::from_secs_f64(config.health_interval_s);
    // The first a little after the start: the event uplink creates the stream if missing.
    let first = tokio::time::Instant::now() + interval.min(Duration::from_secs(2));
    let mut tick = tokio::time::interval_at(first, interval);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut last_warning: Option<std::time::Instant> = None;
    loop {
        tick.tick().await;
        // Latest wins: nothing queues in the client while the link is down.
        if client.connection_state() != async_nats::connection::State::Connected {
            counters.fail("disconnected");
            continue;
        }
        let sent = async {
            let (summary, alarms) = read(&state).await.map_err(|e| ("store", e))?;
            publish(&js, alarms_subject.clone(), to_json(&alarms)?).await?;
            publish(&js, health_subject.clone(), to_json(&summary)?).await
        };
        match sent.await {
            Ok(()) => {
                counters.sent.fetch_add(1, Relaxed);
            }
            Err((kind, message)) => {
                counters.fail(kind);
                // At most one line a minute: a link that flaps must not flood the log.
                if last_warning.is_none_or(|t| t.elapsed() >= Duration::from_secs(60)) {
                    tracing::warn!(kind, "uplink health: {message}");
                    last_warning = Some(std::time::Instant::now());
                }
            }
        }
    }
}

fn to_json<T: Serialize>(value: &T) -> Result<Vec<u8>, (&'static str, String)> {
    serde_json::to_vec(value).map_err(|e| ("publish", e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn summaries_go_beside_the_events_of_the_vehicle() {
        assert_eq!(
            subject("railmon", "", "unit-7", "health"),
            "railmon._.unit-7.health"
        );
        assert_eq!(
            subject("a.b", "north", "unit-7", "alarms"),
            "a.b.north.unit-7.alarms"
        );
    }
}
