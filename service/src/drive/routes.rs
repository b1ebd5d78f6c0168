//! `/api/v1/drives...`: every drive, one drive, its history, the slip events.

use axum::extract::State;
use axum::routing::get;
use axum::{Json, Router};
use railmon_bus::StreamKind;
use serde::Serialize;
use utoipa::{OpenApi, ToSchema};

use super::view::{DriveView, DrivesView, SlipEventDetail};
use super::DriveShared;
use crate::http::events::{self, EventsPage, EventsQuery, Scope};
use crate::http::{require_stream, ApiPath, ApiQuery, AppError, ErrorBody, HistoryQuery};
use crate::AppState;

#[derive(OpenApi)]
#[openapi(
    paths(drives, drive, drive_history, drive_events),
    components(schemas(
        DrivesView,
        DriveView,
        DriveDetail,
        DriveHistory,
        DriveHistoryPoint,
        SlipEventDetail
    ))
)]
pub struct DriveApi;

pub fn routes() -> Router<AppState> {
    Router::new()
        .route("/api/v1/drives", get(drives))
        .route("/api/v1/drives/events", get(drive_events))
        .route("/api/v1/drives/{id}", get(drive))
        .route("/api/v1/drives/{id}/history", get(drive_history))
}

/// The drive stream's outbox, or `stream_disabled`.
fn outbox(state: &AppState) -> Result<&DriveShared, AppError> {
    require_stream(state, StreamKind::Drive)?;
    Ok(&state.drive)
}

/// Slip probability, speeds, load torque and slipping flag of every drive.
#[utoipa::path(get, path = "/api/v1/drives", tag = "drives",
    responses((status = 200, description = "Every drive's latest estimate", body = DrivesView),
              (status = 404, description = "The drive stream is disabled", body = ErrorBody)))]
async fn drives(State(state): State<AppState>) -> Result<Json<DrivesView>, AppError> {
    Ok(Json(DrivesView::clone(&outbox(&state)?.snapshot.load())))
}

/// `GET /api/v1/drives/{id}`: one drive with the context of its estimate.
#[derive(Debug, Serialize, ToSchema)]
pub struct DriveDetail {
    pub method: Option<String>,
    /// `group` or `train_speed`, as in `/api/v1/drives`.
    pub reference: Option<String>,
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

/// One drive's latest estimate.
#[utoipa::path(get, path = "/api/v1/drives/{id}", tag = "drives",
    params(("id" = usize, Path, description = "Drive number, 1-based")),
    responses((status = 200, description = "The drive's latest estimate", body = DriveDetail),
              (status = 404, description = "Unknown drive, or the stream is disabled", body = ErrorBody)))]
async fn drive(
    State(state): State<AppState>,
    ApiPath(id): ApiPath,
) -> Result<Json<DriveDetail>, AppError> {
    let snapshot = outbox(&state)?.snapshot.load();
    let k = drive_index(&id, snapshot.drives.len())?;
    Ok(Json(DriveDetail {
        method: snapshot.method.clone(),
        reference: snapshot.reference.clone(),
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
    pub electrical_speed_rad_s: f64,
    pub mechanical_speed_rad_s: f64,
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

/// One drive's estimates over the last `seconds` of stream time (default 10).
#[utoipa::path(get, path = "/api/v1/drives/{id}/history", tag = "drives",
    params(("id" = usize, Path, description = "Drive number, 1-based"), HistoryQuery),
    responses((status = 200, description = "Points of the window, oldest first", body = DriveHistory),
              (status = 400, description = "Bad query", body = ErrorBody),
              (status = 404, description = "Unknown drive, or the stream is disabled", body = ErrorBody)))]
async fn drive_history(
    State(state): State<AppState>,
    ApiPath(id): ApiPath,
    ApiQuery(query): ApiQuery<HistoryQuery>,
) -> Result<Json<DriveHistory>, AppError> {
    let outbox = outbox(&state)?;
    let seconds = query.seconds_or(10.0)?;
    let k = drive_index(&id, outbox.snapshot.load().drives.len())?;
    let points = outbox
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
                electrical_speed_rad_s: d.electrical_speed_rad_s,
                mechanical_speed_rad_s: d.mechanical_speed_rad_s,
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

/// Slip started / ended events, oldest first, in pages (`drive` picks one drive).
#[utoipa::path(get, path = "/api/v1/drives/events", tag = "drives",
    params(EventsQuery),
    responses((status = 200, description = "A page of events, oldest first", body = EventsPage),
              (status = 400, description = "Bad query", body = ErrorBody),
              (status = 404, description = "The drive stream is disabled", body = ErrorBody)))]
async fn drive_events(
    State(state): State<AppState>,
    ApiQuery(query): ApiQuery<EventsQuery>,
) -> Result<Json<EventsPage>, AppError> {
    events::page(state, Scope::Stream(StreamKind::Drive), query).await
}
