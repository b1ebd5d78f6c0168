//! Endpoints about the service itself: status, probes, metrics, OpenAPI and Swagger UI.

use axum::extract::{Path, State};
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use railmon_bus::monotonic_ns;
use serde::Serialize;
use std::sync::atomic::Ordering::Relaxed;
use utoipa::ToSchema;

use super::AppError;
use crate::ingest::{ReadinessReason, StreamStatusView};
use crate::AppState;

/// `GET /api/v1/status`.
#[derive(Debug, Serialize, ToSchema)]
pub struct StatusView {
    pub uptime_s: f64,
    pub version: String,
    pub streams: Vec<StreamStatusView>,
    /// Connections refused because `http.max_connections` were open, each serving a request.
    pub http_connections_refused: u64,
    /// Idle connections closed to admit a new one when `http.max_connections` were open.
    pub http_connections_evicted: u64,
    /// The event store.
    pub events: crate::store::StoreStatus,
    /// The event uplink to the ground (absent when `uplink.url` is empty).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub uplink: Option<crate::uplink::UplinkStatus>,
}

/// Every enabled stream: freshness, counters, rejections, timings, whether it keeps up.
#[utoipa::path(get, path = "/api/v1/status", tag = "service",
    responses((status = 200, description = "Every enabled stream", body = StatusView)))]
pub async fn status(State(state): State<AppState>) -> Json<StatusView> {
    let now = monotonic_ns();
    Json(StatusView {
        uptime_s: state.started.elapsed().as_secs_f64(),
        version: env!("CARGO_PKG_VERSION").into(),
        streams: state
            .streams
            .iter()
            .map(|s| {
                let mut view = s.view(now);
                if s.kind == railmon_bus::StreamKind::Drive {
                    view.reference = state.drive.snapshot.load().reference.clone();
                }
                if s.kind == railmon_bus::StreamKind::Bogie {
                    view.compute = Some(state.bogie.snapshot.load().compute.clone());
                }
                view
            })
            .collect(),
        http_connections_refused: state.http.connections_refused.load(Relaxed),
        http_connections_evicted: state.http.connections_evicted.load(Relaxed),
        events: state.store.status(),
        uplink: state.config.uplink.enabled().then(|| state.uplink.status()),
    })
}

#[derive(Debug, Serialize, ToSchema)]
pub struct Health {
    pub status: String,
}

/// Liveness: the process answers.
#[utoipa::path(get, path = "/healthz", tag = "service",
    responses((status = 200, description = "The process answers", body = Health)))]
pub async fn healthz() -> Json<Health> {
    Json(Health {
        status: "ok".into(),
    })
}

#[derive(Debug, Serialize, ToSchema)]
pub struct StreamReadiness {
    pub stream: String,
    /// Estimates are being produced from this stream's data now.
    pub ready: bool,
    /// Why not (`stale`, `rejecting`, `lagging`, `competing_sources`, ...), or `ready`.
    pub readiness: ReadinessReason,
    pub fresh: bool,
    pub last_sample_age_s: Option<f64>,
    pub stale_after_s: f64,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct Readiness {
    pub ready: bool,
    pub streams: Vec<StreamReadiness>,
}

/// Readiness: 200 while estimates are being produced from every enabled stream's data (recent
/// frames, estimated, keeping up, one source), else 503 with each stream's reason.
#[utoipa::path(get, path = "/readyz", tag = "service",
    responses((status = 200, description = "Every enabled stream is fresh", body = Readiness),
              (status = 503, description = "A stream is not fresh", body = Readiness)))]
pub async fn readyz(State(state): State<AppState>) -> (StatusCode, Json<Readiness>) {
    let now = monotonic_ns();
    let streams: Vec<StreamReadiness> = state
        .streams
        .iter()
        .map(|s| StreamReadiness {
            stream: s.kind.name().into(),
            ready: s.readiness(now) == ReadinessReason::Ready,
            readiness: s.readiness(now),
            fresh: s.is_fresh(now),
            last_sample_age_s: s.last_sample_age_s(now),
            stale_after_s: s.stale_after.as_secs_f64(),
        })
        .collect();
    let ready = !streams.is_empty() && streams.iter().all(|s| s.ready);
    let code = if ready {
        StatusCode::OK
    } else {
        StatusCode::SERVICE_UNAVAILABLE
    };
    (code, Json(Readiness { ready, streams }))
}

/// Prometheus text format.
#[utoipa::path(get, path = "/metrics", tag = "service",
    responses((status = 200, description = "Prometheus text exposition format", content_type = "text/plain", body = String)))]
pub async fn metrics(State(state): State<AppState>) -> Result<Response, AppError> {
    let now = monotonic_ns();
    for stream in &state.streams {
        stream.refresh_gauges(now);
    }
    state.metrics.count_connections(
        state.http.connections_refused.load(Relaxed),
        state.http.connections_evicted.load(Relaxed),
    );
    state.metrics.count_store(&state.store.status());
    if state.config.uplink.enabled() {
        state.metrics.count_uplink(&state.uplink);
        state.metrics.count_uplink_health(&state.health);
    }
    let text = state.metrics.render().map_err(|e| {
        tracing::error!("rendering metrics: {e}");
        AppError::Internal
    })?;
    Ok((
        [(
            header::CONTENT_TYPE,
            "text/plain; version=0.0.4; charset=utf-8",
        )],
        text,
    )
        .into_response())
}

/// `GET /`: a browser that opens the service's address lands on the API documentation.
pub async fn root() -> axum::response::Redirect {
    axum::response::Redirect::temporary("/docs")
}

/// Swagger UI from the vendored `swagger-ui-dist` files (`service/assets/swagger-ui/`).
const SWAGGER_ASSETS: [(&str, &str, &[u8]); 4] = [
    (
        "index.html",
        "text/html; charset=utf-8",
        include_bytes!("../../assets/swagger-ui/index.html"),
    ),
    (
        "init.js",
        "text/javascript",
        include_bytes!("../../assets/swagger-ui/init.js"),
    ),
    (
        "swagger-ui.css",
        "text/css",
        include_bytes!("../../assets/swagger-ui/swagger-ui.css"),
    ),
    (
        "swagger-ui-bundle.js",
        "text/javascript",
        include_bytes!("../../assets/swagger-ui/swagger-ui-bundle.js"),
    ),
];

fn swagger_file(name: &str) -> Result<Response, AppError> {
    let (_, content_type, bytes) = SWAGGER_ASSETS
        .iter()
        .find(|(file, _, _)| *file == name)
        .ok_or_else(|| AppError::NotFound(format!("/docs/{name}")))?;
    Ok(([(header::CONTENT_TYPE, *content_type)], *bytes).into_response())
}

pub async fn swagger_index() -> Result<Response, AppError> {
    swagger_file("index.html")
}

pub async fn swagger_asset(Path(asset): Path<String>) -> Result<Response, AppError> {
    swagger_file(&asset)
}
