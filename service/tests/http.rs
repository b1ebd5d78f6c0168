//! The HTTP API through `tower::ServiceExt::oneshot`, over state fed by the drive pipeline.

mod common;

use axum::body::{to_bytes, Body};
use axum::http::{Request, StatusCode};
use common::Harness;
use railmon_service::{app, AppState, ServiceConfig};
use serde_json::Value;
use tower::ServiceExt;

async fn get(state: &AppState, uri: &str) -> (StatusCode, String, String) {
    let response = app(state.clone())
        .oneshot(Request::get(uri).body(Body::empty()).unwrap())
        .await
        .unwrap();
    let status = response.status();
    let content_type = response
        .headers()
        .get("content-type")
        .map(|v| v.to_str().unwrap().to_string())
        .unwrap_or_default();
    let body = to_bytes(response.into_body(), 16 << 20).await.unwrap();
    (
        status,
        content_type,
        String::from_utf8_lossy(&body).into_owned(),
    )
}

async fn get_json(state: &AppState, uri: &str) -> (StatusCode, Value) {
    let (status, content_type, body) = get(state, uri).await;
    assert!(
        content_type.starts_with("application/json"),
        "{uri}: {content_type}"
    );
    (status, serde_json::from_str(&body).unwrap())
}

/// State after `steps` frames of the seed scenario.
fn state_after(steps: usize) -> AppState {
    let state = AppState::new(ServiceConfig::default()).unwrap();
    let mut harness = Harness::with(state.drive.clone(), state.metrics.clone());
    for _ in 0..steps {
        harness.advance().unwrap();
    }
    harness.view();
    state
}

fn assert_error(body: &Value, status: u16, code: &str) {
    assert_eq!(body["error"]["status"], status, "{body}");
    assert_eq!(body["error"]["code"], code, "{body}");
    assert!(body["error"]["message"]
        .as_str()
        .is_some_and(|m| !m.is_empty()));
}

#[tokio::test]
async fn drives_list_every_drive_with_its_estimate() {
    // Step 1000: drive 1 is inside its first slip interval [500, 1500].
    let state = state_after(1000);
    let (status, body) = get_json(&state, "/api/v1/drives").await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(body["method"], "temporal");
    assert_eq!(body["sequence"], 999);
    let drives = body["drives"].as_array().unwrap();
    assert_eq!(drives.len(), 3);
    assert!(
        drives[0]["slip_probability"].as_f64().unwrap() > 0.9,
        "{body}"
    );
    assert_eq!(drives[0]["slipping"], true);
    for d in &drives[1..] {
        assert!(d["slip_probability"].as_f64().unwrap() < 0.1, "{body}");
    }
    let (status, one) = get_json(&state, "/api/v1/drives/2").await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(one["drive"], drives[1]);
}

#[tokio::test]
async fn metrics_carry_the_same_numbers_as_the_api() {
    let state = state_after(1000);
    let (_, body) = get_json(&state, "/api/v1/drives").await;
    let (status, content_type, text) = get(&state, "/metrics").await;
    assert_eq!(status, StatusCode::OK);
    assert!(content_type.starts_with("text/plain"), "{content_type}");
    for d in body["drives"].as_array().unwrap() {
        let line = format!(
            "railmon_drive_slip_probability_ratio{{drive=\"{}\"}} ",
            d["id"]
        );
        let value: f64 = text
            .lines()
            .find_map(|l| l.strip_prefix(&line))
            .unwrap_or_else(|| panic!("no {line} in metrics"))
            .parse()
            .unwrap();
        assert_eq!(value, d["slip_probability"].as_f64().unwrap());
    }
    assert!(text.contains("railmon_process_resident_memory_bytes"));
    assert!(text.contains("railmon_stream_samples_received_total{stream=\"drive\"}"));
}

#[tokio::test]
async fn unknown_drive_is_a_json_404() {
    let state = state_after(10);
    for uri in [
        "/api/v1/drives/0",
        "/api/v1/drives/4",
        "/api/v1/drives/x",
        "/api/v1/drives/4/history",
    ] {
        let (status, body) = get_json(&state, uri).await;
        assert_eq!(status, StatusCode::NOT_FOUND, "{uri}");
        assert_error(&body, 404, "unknown_drive");
    }
    let (status, body) = get_json(&state, "/api/v2/drives").await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    assert_error(&body, 404, "not_found");
}

#[tokio::test]
async fn bad_queries_are_json_400s() {
    let state = state_after(10);
    for uri in [
        "/api/v1/drives/1/history?seconds=abc",
        "/api/v1/drives/1/history?seconds=-1",
        "/api/v1/drives/1/history?seconds=NaN",
        "/api/v1/drives/1/history?seconds=1e9",
        "/api/v1/drives/1/history?secs=1",
        "/api/v1/events?drive=0",
        "/api/v1/events?after_id=-3",
    ] {
        let (status, body) = get_json(&state, uri).await;
        assert_eq!(status, StatusCode::BAD_REQUEST, "{uri}");
        assert_error(&body, 400, "bad_query");
    }
}

#[tokio::test]
async fn history_returns_the_window_of_stream_time() {
    let state = state_after(2000); // 0.25 s of stream time, a point per 10 ms
    let (status, body) = get_json(&state, "/api/v1/drives/1/history?seconds=0.1").await;
    assert_eq!(status, StatusCode::OK);
    let points = body["points"].as_array().unwrap();
    assert!((10..=12).contains(&points.len()), "{} points", points.len());
    let newest = points.last().unwrap()["time_s"].as_f64().unwrap();
    assert!(points
        .iter()
        .all(|p| p["time_s"].as_f64().unwrap() >= newest - 0.1));
    let (_, all) = get_json(&state, "/api/v1/drives/1/history").await;
    assert_eq!(all["points"].as_array().unwrap().len(), 25);
    // Drive 1 slips at 62.5-187.5 ms: the history shows it.
    assert!(all["points"]
        .as_array()
        .unwrap()
        .iter()
        .any(|p| p["slipping"] == true));
}

#[tokio::test]
async fn events_filter_by_drive_and_id() {
    let state = state_after(2000);
    let (_, body) = get_json(&state, "/api/v1/events").await;
    let events = body["events"].as_array().unwrap();
    assert_eq!(events[0]["kind"], "slip_started");
    assert_eq!(events[0]["drive"], 1);
    let (_, none) = get_json(&state, "/api/v1/events?drive=2").await;
    assert!(none["events"].as_array().unwrap().is_empty());
    let first = events[0]["id"].as_u64().unwrap();
    let (_, later) = get_json(&state, &format!("/api/v1/events?after_id={first}")).await;
    assert_eq!(later["events"].as_array().unwrap().len(), events.len() - 1);
}

#[tokio::test]
async fn probes_status_and_docs() {
    let state = AppState::new(ServiceConfig::default()).unwrap();
    let (status, body) = get_json(&state, "/healthz").await;
    assert_eq!(
        (status, body["status"].as_str()),
        (StatusCode::OK, Some("ok"))
    );
    // No ingest thread ran: the drive stream never delivered, so the service is not ready.
    let (status, body) = get_json(&state, "/readyz").await;
    assert_eq!(status, StatusCode::SERVICE_UNAVAILABLE);
    assert_eq!(body["streams"][0]["stream"], "drive");
    assert_eq!(body["streams"][0]["fresh"], false);
    let (status, body) = get_json(&state, "/api/v1/status").await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(body["streams"][0]["samples_received"], 0);
    let (status, api) = get_json(&state, "/openapi.json").await;
    assert_eq!(status, StatusCode::OK);
    for path in [
        "/api/v1/drives",
        "/api/v1/drives/{id}/history",
        "/api/v1/status",
        "/readyz",
    ] {
        assert!(
            api["paths"][path].is_object(),
            "{path} missing from the OpenAPI document"
        );
    }
    let (status, content_type, html) = get(&state, "/docs").await;
    assert_eq!(status, StatusCode::OK);
    assert!(content_type.starts_with("text/html") && html.contains("swagger-ui-bundle.js"));
    let (status, _, js) = get(&state, "/docs/swagger-ui-bundle.js").await;
    assert_eq!(status, StatusCode::OK);
    assert!(js.len() > 100_000);
}

#[tokio::test]
async fn every_metric_the_dashboard_queries_is_exported() {
    let state = state_after(10);
    let (_, _, metrics) = get(&state, "/metrics").await;
    let dashboard = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../dashboards/railmon.json"),
    )
    .unwrap();
    let mut names: Vec<&str> = dashboard
        .split(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
        .filter(|w| w.starts_with("railmon_") && w.len() > "railmon_".len())
        .collect();
    names.sort();
    names.dedup();
    assert!(names.len() > 10, "{names:?}");
    for name in names {
        assert!(
            metrics.lines().any(|l| l.starts_with(name)),
            "the dashboard queries {name}, which /metrics does not export"
        );
    }
}
