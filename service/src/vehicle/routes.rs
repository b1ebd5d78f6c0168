//! `/api/v1/vehicle...`: the fuel estimate now, its history, the regime-change events.

use axum::extract::State;
use axum::routing::get;
use axum::{Json, Router};
use railmon_bus::StreamKind;
use serde::Serialize;
use utoipa::{OpenApi, ToSchema};

use super::view::{
    IntervalView, RegimeEventDetail, VehicleHistoryPoint, VehicleShared, VehicleView,
};
use crate::http::events::{self, EventsPage, EventsQuery, Scope};
use crate::http::{require_stream, ApiQuery, AppError, ErrorBody, HistoryQuery};
use crate::AppState;

#[derive(OpenApi)]
#[openapi(
    paths(vehicle, vehicle_history, vehicle_events),
    components(schemas(
        VehicleView,
        VehicleHistory,
        VehicleHistoryPoint,
        RegimeEventDetail,
        IntervalView
    ))
)]
pub struct VehicleApi;

pub fn routes() -> Router<AppState> {
    Router::new()
        .route("/api/v1/vehicle", get(vehicle))
        .route("/api/v1/vehicle/history", get(vehicle_history))
        .route("/api/v1/vehicle/events", get(vehicle_events))
}

/// The vehicle stream's outbox, or `stream_disabled`.
fn outbox(state: &AppState) -> Result<&VehicleShared, AppError> {
    require_stream(state, StreamKind::Vehicle)?;
    Ok(&state.vehicle)
}

/// Fuel rate now, virtual sensor, forecast over the horizon, regime and its probabilities,
/// cumulative fuel (cm^3/s and cm^3).
#[utoipa::path(get, path = "/api/v1/vehicle", tag = "vehicle",
    responses((status = 200, description = "The latest fuel estimate", body = VehicleView),
              (status = 404, description = "The vehicle stream is disabled", body = ErrorBody)))]
async fn vehicle(State(state): State<AppState>) -> Result<Json<VehicleView>, AppError> {
    Ok(Json(VehicleView::clone(&outbox(&state)?.snapshot.load())))
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

/// The fuel estimates over the last `seconds` of stream time (default 600).
#[utoipa::path(get, path = "/api/v1/vehicle/history", tag = "vehicle",
    params(HistoryQuery),
    responses((status = 200, description = "Points of the window, oldest first", body = VehicleHistory),
              (status = 400, description = "Bad query", body = ErrorBody),
              (status = 404, description = "The vehicle stream is disabled", body = ErrorBody)))]
async fn vehicle_history(
    State(state): State<AppState>,
    ApiQuery(query): ApiQuery<HistoryQuery>,
) -> Result<Json<VehicleHistory>, AppError> {
    let outbox = outbox(&state)?;
    let seconds = query.seconds_or(600.0)?;
    Ok(Json(VehicleHistory {
        seconds,
        interval_s: state.config.vehicle.history_interval_ms as f64 * 1e-3,
        points: outbox.history.recent(seconds, |p| p.time_s, |_| true),
    }))
}

/// Regime changes, oldest first, in pages.
#[utoipa::path(get, path = "/api/v1/vehicle/events", tag = "vehicle",
    params(EventsQuery),
    responses((status = 200, description = "A page of events, oldest first", body = EventsPage),
              (status = 400, description = "Bad query", body = ErrorBody),
              (status = 404, description = "The vehicle stream is disabled", body = ErrorBody)))]
async fn vehicle_events(
    State(state): State<AppState>,
    ApiQuery(query): ApiQuery<EventsQuery>,
) -> Result<Json<EventsPage>, AppError> {
    events::page(state, Scope::Stream(StreamKind::Vehicle), query).await
}
