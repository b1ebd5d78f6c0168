//! `/api/v1/bogies...`: every bogie, one bogie, its history, the damper events.

use axum::extract::State;
use axum::routing::get;
use axum::{Json, Router};
use railmon_bus::StreamKind;
use serde::Serialize;
use utoipa::{OpenApi, ToSchema};

use super::view::{
    BogieHistoryEntry, BogieHistoryPoint, BogieShared, BogieView, BogiesView, ComputeEventDetail,
    ComputeView, DamperEventDetail, DamperTrendView, DamperView, SensorNoiseView,
};
use crate::http::events::{self, EventsPage, EventsQuery, Scope};
use crate::http::{require_stream, ApiPath, ApiQuery, AppError, ErrorBody, HistoryQuery};
use crate::AppState;

#[derive(OpenApi)]
#[openapi(
    paths(bogies, bogie, bogie_history, bogie_events),
    components(schemas(
        BogiesView,
        BogieView,
        DamperView,
        DamperTrendView,
        SensorNoiseView,
        BogieDetail,
        BogieHistory,
        BogieHistoryEntry,
        BogieHistoryEntryAt,
        BogieHistoryPoint,
        DamperEventDetail,
        ComputeView,
        ComputeEventDetail
    ))
)]
pub struct BogieApi;

pub fn routes() -> Router<AppState> {
    Router::new()
        .route("/api/v1/bogies", get(bogies))
        .route("/api/v1/bogies/events", get(bogie_events))
        .route("/api/v1/bogies/{id}", get(bogie))
        .route("/api/v1/bogies/{id}/history", get(bogie_history))
}

/// The bogie stream's outbox, or `stream_disabled`.
fn outbox(state: &AppState) -> Result<&BogieShared, AppError> {
    require_stream(state, StreamKind::Bogie)?;
    Ok(&state.bogie)
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

/// Damping of both dampers with their 90% intervals, health ratios and flags, every bogie.
#[utoipa::path(get, path = "/api/v1/bogies", tag = "bogies",
    responses((status = 200, description = "Every configured bogie", body = BogiesView),
              (status = 404, description = "The bogie stream is disabled", body = ErrorBody)))]
async fn bogies(State(state): State<AppState>) -> Result<Json<BogiesView>, AppError> {
    Ok(Json(BogiesView::clone(&outbox(&state)?.snapshot.load())))
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

/// One bogie's latest estimate.
#[utoipa::path(get, path = "/api/v1/bogies/{id}", tag = "bogies",
    params(("id" = u32, Path, description = "Bogie id (as configured in bogie.bogies)")),
    responses((status = 200, description = "The bogie's latest estimate", body = BogieDetail),
              (status = 404, description = "Unknown bogie, or the stream is disabled", body = ErrorBody)))]
async fn bogie(
    State(state): State<AppState>,
    ApiPath(id): ApiPath,
) -> Result<Json<BogieDetail>, AppError> {
    let snapshot = outbox(&state)?.snapshot.load();
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

/// One bogie's estimates over the last `seconds` of stream time (default 60).
#[utoipa::path(get, path = "/api/v1/bogies/{id}/history", tag = "bogies",
    params(("id" = u32, Path, description = "Bogie id"), HistoryQuery),
    responses((status = 200, description = "Points of the window, oldest first", body = BogieHistory),
              (status = 400, description = "Bad query", body = ErrorBody),
              (status = 404, description = "Unknown bogie, or the stream is disabled", body = ErrorBody)))]
async fn bogie_history(
    State(state): State<AppState>,
    ApiPath(id): ApiPath,
    ApiQuery(query): ApiQuery<HistoryQuery>,
) -> Result<Json<BogieHistory>, AppError> {
    let outbox = outbox(&state)?;
    let seconds = query.seconds_or(60.0)?;
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

/// Damper events of every bogie, oldest first, in pages (`bogie` picks one bogie): health
/// (`damper_degraded` / `damper_recovered`, subject `<bogie>/<damper>`), status
/// (`damper_paused` / `damper_resumed`, `damper_model_mismatch` / `damper_model_ok`, subject
/// `<bogie>`), and `snapshot_refused` (subject empty) when a saved state did not fit at start.
#[utoipa::path(get, path = "/api/v1/bogies/events", tag = "bogies",
    params(EventsQuery),
    responses((status = 200, description = "A page of events, oldest first", body = EventsPage),
              (status = 400, description = "Bad query", body = ErrorBody),
              (status = 404, description = "Unknown bogie, or the stream is disabled", body = ErrorBody)))]
async fn bogie_events(
    State(state): State<AppState>,
    ApiQuery(query): ApiQuery<EventsQuery>,
) -> Result<Json<EventsPage>, AppError> {
    events::page(state, Scope::Stream(StreamKind::Bogie), query).await
}
