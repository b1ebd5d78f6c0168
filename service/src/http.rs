//! The HTTP API (axum): versioned JSON under `/api/v1`, probes, metrics, OpenAPI + Swagger UI.
//! Handlers only read atomics, `arc-swap` snapshots and the history/event rings.

use std::collections::HashMap;

use axum::extract::{Path, Query, State};
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::{Json, Router};
use railmon_bus::monotonic_ns;
use serde::Serialize;
use utoipa::{OpenApi, ToSchema};

use crate::bogie::{
    BogieHistoryEntry, BogieHistoryPoint, BogieShared, BogieView, BogiesView, DamperEventView,
    DamperView,
};
use crate::drive::{DriveView, DrivesView, SlipEventView};
use crate::stream::{RejectionRecord, StreamStatusView};
use crate::vehicle::{RegimeEventView, VehicleHistoryPoint, VehicleView};
use crate::AppState;
use railmon_bus::StreamKind;

/// Every error body: `{"error": {"status": 404, "code": "unknown_drive", "message": "..."}}`.
#[derive(Debug, Serialize, ToSchema)]
pub struct ErrorBody {
    pub error: ErrorDetail,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct ErrorDetail {
    pub status: u16,
    /// Stable machine-readable code: `unknown_drive`, `unknown_bogie`, `stream_disabled`, `bad_query`, `bad_path`,
    /// `not_found`, `internal`.
    pub code: String,
    pub message: String,
}

#[derive(Debug, thiserror::Error)]
pub enum AppError {
    #[error("drive {id} is not known ({known} drives)")]
    UnknownDrive { id: String, known: usize },
    #[error("bogie {id} is not known (bogies {known:?})")]
    UnknownBogie { id: String, known: Vec<u32> },
    #[error("the {0} stream is not enabled ({0}.enabled = false)")]
    StreamDisabled(StreamKind),
    #[error("{0}")]
    BadQuery(String),
    #[error("{0}")]
    BadPath(String),
    #[error("no such resource: {0}")]
    NotFound(String),
    #[error("internal error")]
    Internal(String),
}

impl IntoResponse for AppError {
    fn into_response(self) -> Response {
        let (status, code) = match &self {
            AppError::UnknownDrive { .. } => (StatusCode::NOT_FOUND, "unknown_drive"),
            AppError::UnknownBogie { .. } => (StatusCode::NOT_FOUND, "unknown_bogie"),
            AppError::StreamDisabled(_) => (StatusCode::NOT_FOUND, "stream_disabled"),
            AppError::BadQuery(_) => (StatusCode::BAD_REQUEST, "bad_query"),
            AppError::BadPath(_) => (StatusCode::BAD_REQUEST, "bad_path"),
            AppError::NotFound(_) => (StatusCode::NOT_FOUND, "not_found"),
            AppError::Internal(detail) => {
                // The client gets a short message; the detail goes to the log.
                tracing::error!("internal error: {detail}");
                (StatusCode::INTERNAL_SERVER_ERROR, "internal")
            }
        };
        let body = ErrorBody {
            error: ErrorDetail {
                status: status.as_u16(),
                code: code.into(),
                message: self.to_string(),
            },
        };
        (status, Json(body)).into_response()
    }
}

#[derive(OpenApi)]
#[openapi(
    info(
        title = "railmon",
        description = "Onboard condition monitoring: wheel slip of traction drives, fuel use and driving regime of road vehicles, damper health of bogies."
    ),
    paths(
        drives,
        drive,
        drive_history,
        events,
        vehicle,
        vehicle_history,
        vehicle_events,
        bogies,
        bogie,
        bogie_history,
        bogie_events,
        status,
        healthz,
        readyz,
        metrics
    ),
    components(schemas(
        DrivesView,
        DriveView,
        DriveDetail,
        DriveHistory,
        DriveHistoryPoint,
        SlipEventView,
        EventsView,
        VehicleView,
        VehicleHistory,
        VehicleHistoryPoint,
        RegimeEventView,
        VehicleEventsView,
        BogiesView,
        BogieView,
        DamperView,
        BogieDetail,
        BogieHistory,
        BogieHistoryEntry,
        BogieHistoryEntryAt,
        BogieHistoryPoint,
        DamperEventView,
        BogieEventsView,
        StatusView,
        StreamStatusView,
        RejectionRecord,
        Readiness,
        StreamReadiness,
        Health,
        ErrorBody,
        ErrorDetail
    ))
)]
pub struct ApiDoc;

/// The router; `state` carries everything the handlers read.
pub fn app(state: AppState) -> Router {
    Router::new()
        .route("/api/v1/drives", get(drives))
        .route("/api/v1/drives/{id}", get(drive))
        .route("/api/v1/drives/{id}/history", get(drive_history))
        .route("/api/v1/events", get(events))
        .route("/api/v1/vehicle", get(vehicle))
        .route("/api/v1/vehicle/history", get(vehicle_history))
        .route("/api/v1/vehicle/events", get(vehicle_events))
        .route("/api/v1/bogies", get(bogies))
        .route("/api/v1/bogies/events", get(bogie_events))
        .route("/api/v1/bogies/{id}", get(bogie))
        .route("/api/v1/bogies/{id}/history", get(bogie_history))
        .route("/api/v1/status", get(status))
        .route("/healthz", get(healthz))
        .route("/readyz", get(readyz))
        .route("/metrics", get(metrics))
        .route("/openapi.json", get(openapi))
        .route("/docs", get(swagger_index))
        .route("/docs/", get(swagger_index))
        .route("/docs/{asset}", get(swagger_asset))
        .fallback(|uri: axum::http::Uri| async move { AppError::NotFound(uri.path().to_string()) })
        .with_state(state)
}

#[utoipa::path(get, path = "/api/v1/drives", responses((status = 200, body = DrivesView)))]
async fn drives(State(state): State<AppState>) -> Json<DrivesView> {
    Json(DrivesView::clone(&state.drive.snapshot.load()))
}

/// `GET /api/v1/drives/{id}`: one drive with the context of its estimate.
#[derive(Debug, Serialize, ToSchema)]
pub struct DriveDetail {
    pub method: Option<String>,
    pub global_torque_nm: Option<f64>,
    pub time_s: Option<f64>,
    pub run: u32,
    pub run_time_s: Option<f64>,
    pub sequence: Option<u64>,
    pub drive: DriveView,
}

fn drive_index(id: &str, known: usize) -> Result<usize, AppError> {
    let unknown = || AppError::UnknownDrive {
        id: id.to_string(),
        known,
    };
    let n: usize = id.parse().map_err(|_| unknown())?;
    if n == 0 || n > known {
        return Err(unknown());
    }
    Ok(n - 1)
}

#[utoipa::path(get, path = "/api/v1/drives/{id}",
    params(("id" = usize, Path, description = "Drive number, 1-based")),
    responses((status = 200, body = DriveDetail), (status = 404, body = ErrorBody)))]
async fn drive(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<DriveDetail>, AppError> {
    let snapshot = state.drive.snapshot.load();
    let k = drive_index(&id, snapshot.drives.len())?;
    Ok(Json(DriveDetail {
        method: snapshot.method.clone(),
        global_torque_nm: snapshot.global_torque_nm,
        time_s: snapshot.time_s,
        run: snapshot.run,
        run_time_s: snapshot.run_time_s,
        sequence: snapshot.sequence,
        drive: snapshot.drives[k].clone(),
    }))
}

/// One history point of one drive.
#[derive(Debug, Serialize, ToSchema)]
pub struct DriveHistoryPoint {
    pub time_s: f64,
    pub run: u32,
    pub run_time_s: f64,
    pub slip_probability: f64,
    pub speed_rad_s: f64,
    pub load_torque_nm: f64,
    pub slipping: bool,
}

/// `GET /api/v1/drives/{id}/history?seconds=N`.
#[derive(Debug, Serialize, ToSchema)]
pub struct DriveHistory {
    pub drive: usize,
    /// The window, s of stream time before the newest point.
    pub seconds: f64,
    /// Stream time between points, s (`drive.history_interval_ms`).
    pub interval_s: f64,
    pub points: Vec<DriveHistoryPoint>,
}

const MAX_HISTORY_SECONDS: f64 = 86_400.0;

fn only_params(query: &HashMap<String, String>, known: &[&str]) -> Result<(), AppError> {
    match query.keys().find(|k| !known.contains(&k.as_str())) {
        Some(k) => Err(AppError::BadQuery(format!(
            "unknown query parameter `{k}` (known: {})",
            known.join(", ")
        ))),
        None => Ok(()),
    }
}

fn parse_param<T: std::str::FromStr>(
    query: &HashMap<String, String>,
    name: &str,
    default: T,
    valid: impl Fn(&T) -> bool,
    expected: &str,
) -> Result<T, AppError> {
    let Some(raw) = query.get(name) else {
        return Ok(default);
    };
    raw.parse::<T>()
        .ok()
        .filter(|v| valid(v))
        .ok_or_else(|| AppError::BadQuery(format!("`{name}={raw}`: expected {expected}")))
}

/// `?seconds=N` of a history endpoint (the only parameter it takes).
fn history_seconds(query: &HashMap<String, String>, default: f64) -> Result<f64, AppError> {
    only_params(query, &["seconds"])?;
    parse_param(
        query,
        "seconds",
        default,
        |s: &f64| s.is_finite() && *s > 0.0 && *s <= MAX_HISTORY_SECONDS,
        "a number of seconds in (0, 86400]",
    )
}

#[utoipa::path(get, path = "/api/v1/drives/{id}/history",
    params(("id" = usize, Path, description = "Drive number, 1-based"),
           ("seconds" = Option<f64>, Query, description = "Window of stream time, s (default 10, at most 86400)")),
    responses((status = 200, body = DriveHistory), (status = 400, body = ErrorBody), (status = 404, body = ErrorBody)))]
async fn drive_history(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Query(query): Query<HashMap<String, String>>,
) -> Result<Json<DriveHistory>, AppError> {
    let seconds = history_seconds(&query, 10.0)?;
    let k = drive_index(&id, state.drive.snapshot.load().drives.len())?;
    let points = state
        .drive
        .history
        .recent(seconds, |p| p.time_s, |p| k < p.drives.len())
        .into_iter()
        .map(|p| {
            let d = &p.drives[k];
            DriveHistoryPoint {
                time_s: p.time_s,
                run: p.run,
                run_time_s: p.run_time_s,
                slip_probability: d.slip_probability,
                speed_rad_s: d.speed_rad_s,
                load_torque_nm: d.load_torque_nm,
                slipping: d.slipping,
            }
        })
        .collect();
    Ok(Json(DriveHistory {
        drive: k + 1,
        seconds,
        interval_s: state.config.drive.history_interval_ms as f64 * 1e-3,
        points,
    }))
}

/// `GET /api/v1/events`: slip started / ended, oldest first.
#[derive(Debug, Serialize, ToSchema)]
pub struct EventsView {
    pub events: Vec<SlipEventView>,
}

#[utoipa::path(get, path = "/api/v1/events",
    params(("after_id" = Option<u64>, Query, description = "Only events with a larger id"),
           ("drive" = Option<usize>, Query, description = "Only this drive")),
    responses((status = 200, body = EventsView), (status = 400, body = ErrorBody)))]
async fn events(
    State(state): State<AppState>,
    Query(query): Query<HashMap<String, String>>,
) -> Result<Json<EventsView>, AppError> {
    only_params(&query, &["after_id", "drive"])?;
    let after_id = after_id(&query)?;
    let drive = parse_param(&query, "drive", 0usize, |d| *d > 0, "a drive number >= 1")?;
    let events = state
        .drive
        .events
        .collect(|e| e.id > after_id && (drive == 0 || e.drive == drive));
    Ok(Json(EventsView { events }))
}

fn after_id(query: &HashMap<String, String>) -> Result<u64, AppError> {
    parse_param(query, "after_id", 0u64, |_| true, "an event id")
}

/// The vehicle stream's outbox, or `stream_disabled`.
fn vehicle_outbox(state: &AppState) -> Result<&crate::vehicle::VehicleShared, AppError> {
    match state.config.vehicle.enabled {
        true => Ok(&state.vehicle),
        false => Err(AppError::StreamDisabled(StreamKind::Vehicle)),
    }
}

/// Fuel rate now, virtual sensor, forecast over the horizon, regime and its probabilities,
/// cumulative fuel (cm^3/s and cm^3).
#[utoipa::path(get, path = "/api/v1/vehicle",
    responses((status = 200, body = VehicleView), (status = 404, body = ErrorBody)))]
async fn vehicle(State(state): State<AppState>) -> Result<Json<VehicleView>, AppError> {
    Ok(Json(VehicleView::clone(
        &vehicle_outbox(&state)?.snapshot.load(),
    )))
}

/// `GET /api/v1/vehicle/history?seconds=N`.
#[derive(Debug, Serialize, ToSchema)]
pub struct VehicleHistory {
    /// The window, s of stream time before the newest point.
    pub seconds: f64,
    /// Stream time between points, s (`vehicle.history_interval_ms`).
    pub interval_s: f64,
    pub points: Vec<VehicleHistoryPoint>,
}

#[utoipa::path(get, path = "/api/v1/vehicle/history",
    params(("seconds" = Option<f64>, Query, description = "Window of stream time, s (default 600, at most 86400)")),
    responses((status = 200, body = VehicleHistory), (status = 400, body = ErrorBody), (status = 404, body = ErrorBody)))]
async fn vehicle_history(
    State(state): State<AppState>,
    Query(query): Query<HashMap<String, String>>,
) -> Result<Json<VehicleHistory>, AppError> {
    let outbox = vehicle_outbox(&state)?;
    let seconds = history_seconds(&query, 600.0)?;
    Ok(Json(VehicleHistory {
        seconds,
        interval_s: state.config.vehicle.history_interval_ms as f64 * 1e-3,
        points: outbox.history.recent(seconds, |p| p.time_s, |_| true),
    }))
}

/// `GET /api/v1/vehicle/events`: regime changes, oldest first.
#[derive(Debug, Serialize, ToSchema)]
pub struct VehicleEventsView {
    pub events: Vec<RegimeEventView>,
}

#[utoipa::path(get, path = "/api/v1/vehicle/events",
    params(("after_id" = Option<u64>, Query, description = "Only events with a larger id")),
    responses((status = 200, body = VehicleEventsView), (status = 400, body = ErrorBody), (status = 404, body = ErrorBody)))]
async fn vehicle_events(
    State(state): State<AppState>,
    Query(query): Query<HashMap<String, String>>,
) -> Result<Json<VehicleEventsView>, AppError> {
    let outbox = vehicle_outbox(&state)?;
    only_params(&query, &["after_id"])?;
    let after_id = after_id(&query)?;
    Ok(Json(VehicleEventsView {
        events: outbox.events.collect(|e| e.id > after_id),
    }))
}

/// The bogie stream's outbox, or `stream_disabled`.
fn bogie_outbox(state: &AppState) -> Result<&BogieShared, AppError> {
    match state.config.bogie.enabled {
        true => Ok(&state.bogie),
        false => Err(AppError::StreamDisabled(StreamKind::Bogie)),
    }
}

/// The configured bogie `id`, or `unknown_bogie`.
fn bogie_id(state: &AppState, id: &str) -> Result<u32, AppError> {
    let known = &state.config.bogie.bogies;
    id.parse::<u32>()
        .ok()
        .filter(|n| known.contains(n))
        .ok_or_else(|| AppError::UnknownBogie {
            id: id.to_string(),
            known: known.clone(),
        })
}

#[utoipa::path(get, path = "/api/v1/bogies",
    responses((status = 200, body = BogiesView), (status = 404, body = ErrorBody)))]
async fn bogies(State(state): State<AppState>) -> Result<Json<BogiesView>, AppError> {
    Ok(Json(BogiesView::clone(
        &bogie_outbox(&state)?.snapshot.load(),
    )))
}

/// `GET /api/v1/bogies/{id}`: one bogie with the context of its estimate.
#[derive(Debug, Serialize, ToSchema)]
pub struct BogieDetail {
    pub time_s: Option<f64>,
    pub run: u32,
    pub run_time_s: Option<f64>,
    pub sequence: Option<u64>,
    pub particles: usize,
    /// Null before the first frame.
    pub bogie: Option<BogieView>,
}

#[utoipa::path(get, path = "/api/v1/bogies/{id}",
    params(("id" = u32, Path, description = "Bogie id (as configured in bogie.bogies)")),
    responses((status = 200, body = BogieDetail), (status = 404, body = ErrorBody)))]
async fn bogie(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<BogieDetail>, AppError> {
    let snapshot = bogie_outbox(&state)?.snapshot.load();
    let id = bogie_id(&state, &id)?;
    Ok(Json(BogieDetail {
        time_s: snapshot.time_s,
        run: snapshot.run,
        run_time_s: snapshot.run_time_s,
        sequence: snapshot.sequence,
        particles: snapshot.particles,
        bogie: snapshot.bogies.iter().find(|b| b.bogie == id).cloned(),
    }))
}

/// `GET /api/v1/bogies/{id}/history?seconds=N`.
#[derive(Debug, Serialize, ToSchema)]
pub struct BogieHistory {
    pub bogie: u32,
    pub seconds: f64,
    /// Stream time between points, s (`bogie.history_interval_ms`).
    pub interval_s: f64,
    pub points: Vec<BogieHistoryEntryAt>,
}

/// One bogie's history entry at a time.
#[derive(Debug, Serialize, ToSchema)]
pub struct BogieHistoryEntryAt {
    pub time_s: f64,
    pub run: u32,
    pub run_time_s: f64,
    #[serde(flatten)]
    pub entry: BogieHistoryEntry,
}

#[utoipa::path(get, path = "/api/v1/bogies/{id}/history",
    params(("id" = u32, Path, description = "Bogie id"),
           ("seconds" = Option<f64>, Query, description = "Window of stream time, s (default 60, at most 86400)")),
    responses((status = 200, body = BogieHistory), (status = 400, body = ErrorBody), (status = 404, body = ErrorBody)))]
async fn bogie_history(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Query(query): Query<HashMap<String, String>>,
) -> Result<Json<BogieHistory>, AppError> {
    let outbox = bogie_outbox(&state)?;
    let seconds = history_seconds(&query, 60.0)?;
    let id = bogie_id(&state, &id)?;
    let points = outbox
        .history
        .recent(
            seconds,
            |p| p.time_s,
            |p| p.bogies.iter().any(|b| b.bogie == id),
        )
        .into_iter()
        .filter_map(|p| {
            let entry = p.bogies.iter().find(|b| b.bogie == id)?.clone();
            Some(BogieHistoryEntryAt {
                time_s: p.time_s,
                run: p.run,
                run_time_s: p.run_time_s,
                entry,
            })
        })
        .collect();
    Ok(Json(BogieHistory {
        bogie: id,
        seconds,
        interval_s: state.config.bogie.history_interval_ms as f64 * 1e-3,
        points,
    }))
}

/// `GET /api/v1/bogies/events`: damper degraded / recovered, oldest first.
#[derive(Debug, Serialize, ToSchema)]
pub struct BogieEventsView {
    pub events: Vec<DamperEventView>,
}

#[utoipa::path(get, path = "/api/v1/bogies/events",
    params(("after_id" = Option<u64>, Query, description = "Only events with a larger id"),
           ("bogie" = Option<u32>, Query, description = "Only this bogie")),
    responses((status = 200, body = BogieEventsView), (status = 400, body = ErrorBody), (status = 404, body = ErrorBody)))]
async fn bogie_events(
    State(state): State<AppState>,
    Query(query): Query<HashMap<String, String>>,
) -> Result<Json<BogieEventsView>, AppError> {
    let outbox = bogie_outbox(&state)?;
    only_params(&query, &["after_id", "bogie"])?;
    let after_id = after_id(&query)?;
    let bogie = match query.get("bogie") {
        Some(id) => Some(bogie_id(&state, id)?),
        None => None,
    };
    Ok(Json(BogieEventsView {
        events: outbox
            .events
            .collect(|e| e.id > after_id && bogie.is_none_or(|b| e.bogie == b)),
    }))
}

/// `GET /api/v1/status`.
#[derive(Debug, Serialize, ToSchema)]
pub struct StatusView {
    pub uptime_s: f64,
    pub version: String,
    pub streams: Vec<StreamStatusView>,
}

#[utoipa::path(get, path = "/api/v1/status", responses((status = 200, body = StatusView)))]
async fn status(State(state): State<AppState>) -> Json<StatusView> {
    let now = monotonic_ns();
    Json(StatusView {
        uptime_s: state.started.elapsed().as_secs_f64(),
        version: env!("CARGO_PKG_VERSION").into(),
        streams: state.streams.iter().map(|s| s.view(now)).collect(),
    })
}

#[derive(Debug, Serialize, ToSchema)]
pub struct Health {
    pub status: String,
}

/// Liveness: the process answers.
#[utoipa::path(get, path = "/healthz", responses((status = 200, body = Health)))]
async fn healthz() -> Json<Health> {
    Json(Health {
        status: "ok".into(),
    })
}

#[derive(Debug, Serialize, ToSchema)]
pub struct StreamReadiness {
    pub stream: String,
    pub fresh: bool,
    pub last_sample_age_s: Option<f64>,
    pub stale_after_s: f64,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct Readiness {
    pub ready: bool,
    pub streams: Vec<StreamReadiness>,
}

/// Readiness: 200 while every configured stream delivered within its staleness limit, else 503.
#[utoipa::path(get, path = "/readyz", responses((status = 200, body = Readiness), (status = 503, body = Readiness)))]
async fn readyz(State(state): State<AppState>) -> (StatusCode, Json<Readiness>) {
    let now = monotonic_ns();
    let streams: Vec<StreamReadiness> = state
        .streams
        .iter()
        .map(|s| StreamReadiness {
            stream: s.kind.name().into(),
            fresh: s.is_fresh(now),
            last_sample_age_s: s.last_sample_age_s(now),
            stale_after_s: s.stale_after.as_secs_f64(),
        })
        .collect();
    let ready = !streams.is_empty() && streams.iter().all(|s| s.fresh);
    let code = if ready {
        StatusCode::OK
    } else {
        StatusCode::SERVICE_UNAVAILABLE
    };
    (code, Json(Readiness { ready, streams }))
}

/// Prometheus text format.
#[utoipa::path(get, path = "/metrics", responses((status = 200, content_type = "text/plain", body = String)))]
async fn metrics(State(state): State<AppState>) -> Result<Response, AppError> {
    let now = monotonic_ns();
    for stream in &state.streams {
        stream.refresh_gauges(now);
    }
    let text = state
        .metrics
        .render()
        .map_err(|e| AppError::Internal(e.to_string()))?;
    Ok((
        [(
            header::CONTENT_TYPE,
            "text/plain; version=0.0.4; charset=utf-8",
        )],
        text,
    )
        .into_response())
}

async fn openapi() -> Json<utoipa::openapi::OpenApi> {
    Json(ApiDoc::openapi())
}

/// Swagger UI from the vendored `swagger-ui-dist` files (`service/assets/swagger-ui/`).
const SWAGGER_ASSETS: [(&str, &str, &[u8]); 4] = [
    (
        "index.html",
        "text/html; charset=utf-8",
        include_bytes!("../assets/swagger-ui/index.html"),
    ),
    (
        "init.js",
        "text/javascript",
        include_bytes!("../assets/swagger-ui/init.js"),
    ),
    (
        "swagger-ui.css",
        "text/css",
        include_bytes!("../assets/swagger-ui/swagger-ui.css"),
    ),
    (
        "swagger-ui-bundle.js",
        "text/javascript",
        include_bytes!("../assets/swagger-ui/swagger-ui-bundle.js"),
    ),
];

fn swagger_file(name: &str) -> Result<Response, AppError> {
    let (_, content_type, bytes) = SWAGGER_ASSETS
        .iter()
        .find(|(file, _, _)| *file == name)
        .ok_or_else(|| AppError::NotFound(format!("/docs/{name}")))?;
    Ok(([(header::CONTENT_TYPE, *content_type)], *bytes).into_response())
}

async fn swagger_index() -> Result<Response, AppError> {
    swagger_file("index.html")
}

async fn swagger_asset(Path(asset): Path<String>) -> Result<Response, AppError> {
    swagger_file(&asset)
}
