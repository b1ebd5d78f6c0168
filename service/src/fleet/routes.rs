//! The HTTP API of `railmon fleet` (axum, OpenAPI at `/openapi.json` as the vehicle's):
//! `/api/v1/vehicles`, `/api/v1/vehicles/{vehicle_id}/events`,
//! `/api/v1/vehicles/{vehicle_id}/health`, `/api/v1/alarms`, `/healthz`.

use std::sync::Arc;

use axum::extract::State;
use axum::routing::get;
use axum::{Json, Router};
use serde::{Deserialize, Serialize};
use utoipa::{IntoParams, OpenApi, ToSchema};

use super::{EventsRequest, Fleet, ReadError};
use crate::http::events::{DEFAULT_PAGE, MAX_PAGE};
use crate::http::{server, system, ApiPath, ApiQuery, AppError, ErrorBody, ErrorDetail};
use crate::store::{ActiveAlarm, EventView};
use crate::uplink::health::HealthSummary;

/// The event streams of a vehicle, as subjects name them.
const STREAMS: [&str; 4] = ["drive", "bogie", "vehicle", "service"];

#[derive(OpenApi)]
#[openapi(
    info(
        title = "railmon fleet",
        description = "The fleet's view from the vehicles' NATS JetStream stream: a vehicle's events, its latest health summary, and the vehicles with an active alarm. Stateless: every answer is read from the stream."
    ),
    paths(vehicles, vehicle_events, vehicle_health, alarms, system::healthz),
    components(schemas(
        VehiclesView,
        FleetVehicle,
        FleetEventsPage,
        EventView,
        VehicleHealth,
        HealthSummary,
        crate::drive::view::DrivesView,
        crate::drive::view::DriveView,
        crate::bogie::view::BogiesView,
        crate::bogie::view::BogieView,
        crate::bogie::view::DamperView,
        crate::bogie::view::SensorNoiseView,
        crate::vehicle::view::VehicleView,
        crate::vehicle::view::IntervalView,
        FleetAlarms,
        VehicleAlarmsView,
        ActiveAlarm,
        system::Health,
        ErrorBody,
        ErrorDetail
    )),
    tags((name = "fleet", description = "Fleet queries over the vehicles' event stream"))
)]
struct FleetApi;

/// The OpenAPI document of `railmon fleet`.
pub fn api_doc() -> utoipa::openapi::OpenApi {
    FleetApi::openapi()
}

type FleetState = Arc<Fleet>;

fn unavailable(what: &str, e: ReadError) -> AppError {
    tracing::warn!("{what}: {e}");
    AppError::Unavailable
}

/// A vehicle id as the uplink writes it into a subject token.
fn vehicle_id(id: String) -> Result<String, AppError> {
    match crate::uplink::config::is_token(&id) {
        true => Ok(id),
        false => Err(AppError::BadPath(format!(
            "vehicle id `{id}`: expected letters, digits, `_` or `-`"
        ))),
    }
}

/// One vehicle with events in the stream.
#[derive(Debug, Serialize, ToSchema)]
pub struct FleetVehicle {
    pub vehicle_id: String,
    /// `_`: the vehicle has no fleet set.
    pub fleet: String,
    /// Events in the stream per event stream (`drive`, `bogie`, `vehicle`, `service`).
    pub events: std::collections::BTreeMap<String, u64>,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct VehiclesView {
    pub vehicles: Vec<FleetVehicle>,
}

/// Every vehicle with events in the stream, by fleet and id.
#[utoipa::path(get, path = "/api/v1/vehicles", tag = "fleet",
    responses((status = 200, description = "The vehicles", body = VehiclesView),
              (status = 503, description = "The stream cannot be read now", body = ErrorBody)))]
async fn vehicles(State(fleet): State<FleetState>) -> Result<Json<VehiclesView>, AppError> {
    let vehicles = fleet
        .vehicles()
        .await
        .map_err(|e| unavailable("vehicles", e))?
        .into_iter()
        .map(|((fleet, vehicle_id), events)| FleetVehicle {
            vehicle_id,
            fleet,
            events,
        })
        .collect();
    Ok(Json(VehiclesView { vehicles }))
}

#[derive(Debug, Default, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct FleetEventsQuery {
    /// One event stream; every stream when not given.
    #[param(pattern = "^(drive|bogie|vehicle|service)$", example = "bogie")]
    pub stream: Option<String>,
    /// Only events acquired at or after this time (RFC 3339, e.g. 2026-11-22T08:00:00Z).
    #[param(example = "2026-11-22T00:00:00Z")]
    pub since: Option<String>,
    /// Only events acquired before this time (RFC 3339).
    #[param(example = "2026-11-23T00:00:00Z")]
    pub until: Option<String>,
    /// Only events of this kind (`slip_started`, `damper_degraded`, `regime_changed`, ...).
    pub kind: Option<String>,
    /// Only messages after this stream sequence: the previous page's `next_after_seq`.
    #[param(maximum = 9223372036854775807_i64, example = 0)]
    pub after_seq: Option<u64>,
    /// Events per page, 1..=1000 (default 100).
    #[param(minimum = 1, maximum = 1000, example = 100)]
    pub limit: Option<usize>,
}

/// A page of one vehicle's events, oldest first (stream order, which is event id order).
#[derive(Debug, Serialize, ToSchema)]
pub struct FleetEventsPage {
    pub vehicle_id: String,
    /// The events as the vehicle's `GET /api/v1/events` shows them, with `vehicle_id`,
    /// `fleet` and `stream_sequence` (their place in the JetStream stream).
    #[schema(value_type = Vec<EventView>)]
    pub events: Vec<serde_json::Value>,
    /// Pass as `after_seq` for the next page (the last message read; else the `after_seq`
    /// given). A page shorter than `limit` is the last one for now.
    pub next_after_seq: u64,
}

fn bad(message: String) -> AppError {
    AppError::BadQuery(message)
}

/// One vehicle's events for a time range, in pages by stream sequence.
#[utoipa::path(get, path = "/api/v1/vehicles/{vehicle_id}/events", tag = "fleet",
    params(("vehicle_id" = String, Path, description = "The vehicle's `identity.vehicle_id`"), FleetEventsQuery),
    responses((status = 200, description = "A page of events, oldest first", body = FleetEventsPage),
              (status = 400, description = "Bad query", body = ErrorBody),
              (status = 503, description = "The stream cannot be read now", body = ErrorBody)))]
async fn vehicle_events(
    State(fleet): State<FleetState>,
    ApiPath(id): ApiPath,
    ApiQuery(q): ApiQuery<FleetEventsQuery>,
) -> Result<Json<FleetEventsPage>, AppError> {
    let vehicle_id = vehicle_id(id)?;
    if let Some(stream) = q.stream.as_deref().filter(|s| !STREAMS.contains(s)) {
        return Err(bad(format!(
            "`stream={stream}`: expected drive, bogie, vehicle or service"
        )));
    }
    let limit = q.limit.unwrap_or(DEFAULT_PAGE);
    if !(1..=MAX_PAGE).contains(&limit) {
        return Err(bad(format!("`limit={limit}`: expected 1..={MAX_PAGE}")));
    }
    if let Some(after) = q.after_seq.filter(|&s| i64::try_from(s).is_err()) {
        return Err(bad(format!(
            "`after_seq={after}`: expected at most {}",
            i64::MAX
        )));
    }
    let time = |text: &Option<String>| -> Result<Option<i64>, AppError> {
        text.as_deref()
            .map(|t| railmon_bus::utc::parse_rfc3339(t).map_err(bad))
            .transpose()
    };
    let request = EventsRequest {
        vehicle_id: vehicle_id.clone(),
        stream: q.stream,
        since_utc_ns: time(&q.since)?,
        until_utc_ns: time(&q.until)?,
        kind: q.kind,
        after_seq: q.after_seq.unwrap_or(0),
        limit,
    };
    let page = fleet
        .events(&request)
        .await
        .map_err(|e| unavailable("events", e))?;
    Ok(Json(FleetEventsPage {
        vehicle_id,
        events: page.events,
        next_after_seq: page.next_after_seq,
    }))
}

/// A vehicle's latest health summary as the stream holds it.
#[derive(Debug, Serialize, ToSchema)]
pub struct VehicleHealth {
    pub vehicle_id: String,
    /// When the ground stored it, RFC 3339 UTC (the server's clock; the summary's
    /// `generated_utc` is the vehicle's).
    pub stored_utc: String,
    pub stream_sequence: u64,
    #[schema(value_type = HealthSummary)]
    pub summary: serde_json::Value,
}

/// The latest health summary of a vehicle (slip state per drive, damper estimates with their
/// intervals per bogie, fuel regime), as its uplink last sent it.
#[utoipa::path(get, path = "/api/v1/vehicles/{vehicle_id}/health", tag = "fleet",
    params(("vehicle_id" = String, Path, description = "The vehicle's `identity.vehicle_id`")),
    responses((status = 200, description = "The latest summary", body = VehicleHealth),
              (status = 400, description = "Bad vehicle id", body = ErrorBody),
              (status = 404, description = "No summary of this vehicle in the stream", body = ErrorBody),
              (status = 503, description = "The stream cannot be read now", body = ErrorBody)))]
async fn vehicle_health(
    State(fleet): State<FleetState>,
    ApiPath(id): ApiPath,
) -> Result<Json<VehicleHealth>, AppError> {
    let vehicle_id = vehicle_id(id)?;
    match fleet
        .health(&vehicle_id)
        .await
        .map_err(|e| unavailable("health", e))?
    {
        Some((stream_sequence, stored, summary)) => Ok(Json(VehicleHealth {
            vehicle_id,
            stored_utc: super::rfc3339(stored),
            stream_sequence,
            summary,
        })),
        None => Err(AppError::NotFound(format!(
            "a health summary of vehicle {vehicle_id}"
        ))),
    }
}

/// One vehicle's active alarms.
#[derive(Debug, Serialize, ToSchema)]
pub struct VehicleAlarmsView {
    pub vehicle_id: String,
    pub fleet: String,
    pub alarms: Vec<ActiveAlarm>,
    /// When the ground stored the vehicle's alarm snapshot this answer starts from, RFC 3339
    /// UTC; null: derived from every event of the vehicle (it sent no snapshot yet).
    pub snapshot_stored_utc: Option<String>,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct FleetAlarms {
    /// The vehicles with at least one active alarm, by fleet and id.
    pub vehicles: Vec<VehicleAlarmsView>,
    /// Vehicles looked at (with an alarm snapshot or events in the stream).
    pub vehicles_seen: usize,
}

/// The vehicles with an active alarm (a drive slipping, a damper degraded): an alarm raised
/// and not cleared by the events in the stream.
#[utoipa::path(get, path = "/api/v1/alarms", tag = "fleet",
    responses((status = 200, description = "The vehicles with active alarms", body = FleetAlarms),
              (status = 503, description = "The stream cannot be read now", body = ErrorBody)))]
async fn alarms(State(fleet): State<FleetState>) -> Result<Json<FleetAlarms>, AppError> {
    let all = fleet
        .active_alarms()
        .await
        .map_err(|e| unavailable("alarms", e))?;
    let vehicles_seen = all.len();
    let vehicles = all
        .into_iter()
        .filter(|v| !v.alarms.is_empty())
        .map(|v| VehicleAlarmsView {
            vehicle_id: v.vehicle_id,
            fleet: v.fleet,
            alarms: v.alarms,
            snapshot_stored_utc: v.snapshot_stored.map(super::rfc3339),
        })
        .collect();
    Ok(Json(FleetAlarms {
        vehicles,
        vehicles_seen,
    }))
}

/// The router of `railmon fleet`, with the vehicle's limits (`[http]`).
pub fn app(fleet: Fleet, http: &crate::config::HttpConfig) -> Router {
    let document = api_doc();
    Router::new()
        .route("/api/v1/vehicles", get(vehicles))
        .route("/api/v1/vehicles/{vehicle_id}/events", get(vehicle_events))
        .route("/api/v1/vehicles/{vehicle_id}/health", get(vehicle_health))
        .route("/api/v1/alarms", get(alarms))
        .route("/healthz", get(system::healthz))
        .route(
            "/openapi.json",
            get(move || std::future::ready(Json(document.clone()))),
        )
        .route("/docs", get(system::swagger_index))
        .route("/docs/", get(system::swagger_index))
        .route("/docs/{asset}", get(system::swagger_asset))
        .fallback(|uri: axum::http::Uri| async move { AppError::NotFound(uri.path().to_string()) })
        .method_not_allowed_fallback(|method: axum::http::Method| async move {
            AppError::MethodNotAllowed(method.to_string())
        })
        .layer(axum::middleware::from_fn_with_state(
            Arc::new(http.clone()),
            server::limits,
        ))
        .with_state(Arc::new(fleet))
}
