//! The HTTP API through `tower::ServiceExt::oneshot`, over state fed by the drive pipeline.

mod common;

use axum::body::{to_bytes, Body};
use axum::http::{Request, StatusCode};
use common::vehicle::{vehicle_config, VehicleHarness};
use common::{test_config, Harness};
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
    let state = AppState::new(test_config()).unwrap();
    let mut harness = Harness::with(state.drive.clone(), state.metrics.clone());
    for _ in 0..steps {
        harness.advance().unwrap();
    }
    harness.view();
    state
}

/// State with the vehicle stream enabled after `steps` simulated seconds of `fuel-cycles`
/// (and 10 drive frames).
fn vehicle_state_after(steps: usize) -> AppState {
    let config = ServiceConfig {
        vehicle: vehicle_config(),
        ..test_config()
    };
    let state = AppState::new(config.clone()).unwrap();
    let mut drives = Harness::with(state.drive.clone(), state.metrics.clone());
    for _ in 0..10 {
        drives.advance().unwrap();
    }
    drives.view();
    let mut harness =
        VehicleHarness::with(config.vehicle, state.vehicle.clone(), state.metrics.clone());
    for _ in 0..steps {
        harness.advance().unwrap();
    }
    harness.view();
    state
}

/// A metrics text line without the identity labels every series carries (`vehicle_id`,
/// `fleet`), so that tests name series by their own labels.
fn without_identity_labels(line: &str) -> String {
    let (Some(open), Some(close)) = (line.find('{'), line.find('}')) else {
        return line.to_string();
    };
    let kept: Vec<&str> = line[open + 1..close]
        .split(',')
        .filter(|l| !l.starts_with("vehicle_id=") && !l.starts_with("fleet="))
        .collect();
    match kept.is_empty() {
        true => format!("{}{}", &line[..open], &line[close + 1..]),
        false => format!(
            "{}{{{}}}{}",
            &line[..open],
            kept.join(","),
            &line[close + 1..]
        ),
    }
}

/// The value of the series `name{labels}` in the metrics text.
fn series(text: &str, name: &str) -> f64 {
    let prefix = format!("{name} ");
    text.lines()
        .find_map(|l| {
            without_identity_labels(l)
                .strip_prefix(&prefix)
                .map(str::to_string)
        })
        .unwrap_or_else(|| panic!("no {name} in metrics"))
        .parse()
        .unwrap()
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
            .find_map(|l| {
                without_identity_labels(l)
                    .strip_prefix(&line)
                    .map(str::to_string)
            })
            .unwrap_or_else(|| panic!("no {line} in metrics"))
            .parse()
            .unwrap();
        assert_eq!(value, d["slip_probability"].as_f64().unwrap());
    }
    // Time flagged slipping, as a counter: a slip shorter than a scrape interval still shows
    // in its rate. Drive 1 slips from about step 480 of these 1000 (125 us each).
    let slip_s = |drive: u64| {
        series(
            &text,
            &format!("railmon_drive_slip_seconds_total{{drive=\"{drive}\"}}"),
        )
    };
    assert!((0.03..0.07).contains(&slip_s(1)), "{}", slip_s(1));
    assert_eq!((slip_s(2), slip_s(3)), (0.0, 0.0));
    assert!(text.contains("\nprocess_resident_memory_bytes"));
    assert!(text.lines().any(|l| without_identity_labels(l)
        .starts_with("railmon_stream_samples_received_total{stream=\"drive\"} ")));
}

#[tokio::test]
async fn every_answer_and_series_names_the_vehicle() {
    let mut config = test_config();
    config.identity.vehicle_id = "unit-4711".into();
    config.identity.fleet = "north".into();
    let state = AppState::new(config).unwrap();
    for uri in [
        "/api/v1/drives",
        "/api/v1/status",
        "/readyz",
        "/api/v1/drives/9",
    ] {
        let (_, body) = get_json(&state, uri).await;
        assert_eq!(body["vehicle_id"], "unit-4711", "{uri}: {body}");
        assert_eq!(body["fleet"], "north", "{uri}: {body}");
    }
    let (_, _, text) = get(&state, "/metrics").await;
    let series: Vec<&str> = text.lines().filter(|l| !l.starts_with('#')).collect();
    assert!(!series.is_empty());
    for line in series {
        assert!(
            line.contains("vehicle_id=\"unit-4711\"") && line.contains("fleet=\"north\""),
            "{line}"
        );
    }
    let bad = ServiceConfig::load(
        None,
        [(
            "RAILMON_IDENTITY__VEHICLE_ID".to_string(),
            "unit 4711/x".to_string(),
        )],
    )
    .unwrap_err()
    .to_string();
    assert!(bad.contains("identity.vehicle_id"), "{bad}");
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
        "/api/v1/drives/events?drive=0",
        "/api/v1/drives/events?after_id=-3",
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
    // A point per 10 ms of the steps published: 0 ..= 1,999 - FIXED_LAG_STEPS, 125 us each.
    let last_ms = (1_999 - railmon_slip::fixed_lag::FIXED_LAG_STEPS) as f64 * 0.125;
    let want = (last_ms / 10.0).floor() as usize + 1;
    assert_eq!(all["points"].as_array().unwrap().len(), want);
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
    let (_, body) = get_json(&state, "/api/v1/drives/events").await;
    let events = body["events"].as_array().unwrap();
    assert_eq!(events[0]["kind"], "slip_started");
    assert_eq!(events[0]["drive"], 1);
    let (_, none) = get_json(&state, "/api/v1/drives/events?drive=2").await;
    assert!(none["events"].as_array().unwrap().is_empty());
    let first = events[0]["id"].as_u64().unwrap();
    let (_, later) = get_json(&state, &format!("/api/v1/drives/events?after_id={first}")).await;
    assert_eq!(later["events"].as_array().unwrap().len(), events.len() - 1);
}

#[tokio::test]
async fn probes_status_and_docs() {
    let state = AppState::new(test_config()).unwrap();
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
        "/api/v1/vehicle",
        "/api/v1/vehicle/history",
        "/api/v1/vehicle/events",
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
    let state = vehicle_state_after(10);
    // Estimates have no series before the first (the bogie's here): the declared families.
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
            state.metrics.exports(name),
            "the dashboard queries {name}, which /metrics does not export"
        );
    }
}

#[tokio::test]
async fn vehicle_reports_fuel_forecast_regime_and_metrics_in_base_units() {
    let state = vehicle_state_after(400);
    let (status, v) = get_json(&state, "/api/v1/vehicle").await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(
        (v["samples"].as_u64(), v["initialising"].as_bool()),
        (Some(400), Some(false))
    );
    assert_eq!(v["time_s"], 399.0);
    for field in [
        "fuel_rate_cm3_s",
        "virtual_sensor_cm3_s",
        "zero_step_cm3_s",
        "one_step_forecast_cm3_s",
        "cumulative_fuel_cm3",
        "cumulative_virtual_fuel_cm3",
        "forecast_error_cm3_s",
        "forecast_rmse_cm3_s",
        "speed_m_s",
    ] {
        assert!(
            v[field].as_f64().is_some_and(f64::is_finite),
            "{field}: {v}"
        );
    }
    let forecast = v["forecast_cm3_s"].as_array().unwrap();
    assert_eq!(
        (forecast.len(), v["forecast_step_s"].as_f64()),
        (10, Some(1.0))
    );
    let probabilities = v["regime_probabilities"].as_array().unwrap();
    assert_eq!(probabilities.len(), 3);
    // `most_probable_regime` is this sample's argmax; `regime` is the confirmed one (it held
    // the argmax for `regime_confirm_samples` samples), which may lag it by design.
    let most_probable = v["most_probable_regime"].as_u64().unwrap() as usize;
    let best = probabilities[most_probable].as_f64().unwrap();
    assert!(probabilities.iter().all(|p| p.as_f64().unwrap() <= best));
    let regime = v["regime"].as_u64().unwrap() as usize;
    assert!(regime < probabilities.len());

    let (_, _, text) = get(&state, "/metrics").await;
    let m3 = |cm3: &Value| cm3.as_f64().unwrap() * 1e-6;
    for (kind, field) in [
        ("measured", "fuel_rate_cm3_s"),
        ("virtual_sensor", "virtual_sensor_cm3_s"),
        ("one_step_forecast", "one_step_forecast_cm3_s"),
    ] {
        let name = format!("railmon_vehicle_fuel_rate_cubic_meters_per_second{{kind=\"{kind}\"}}");
        assert_eq!(series(&text, &name), m3(&v[field]), "{name}");
    }
    for (h, f) in forecast.iter().enumerate() {
        let name = format!(
            "railmon_vehicle_fuel_forecast_cubic_meters_per_second{{horizon_s=\"{}\"}}",
            h + 1
        );
        assert_eq!(series(&text, &name), m3(f), "{name}");
    }
    let name = "railmon_vehicle_fuel_consumed_cubic_meters{kind=\"measured\"}";
    assert_eq!(series(&text, name), m3(&v["cumulative_fuel_cm3"]));
    for (i, p) in probabilities.iter().enumerate() {
        let name = format!("railmon_vehicle_regime_probability_ratio{{regime=\"{i}\"}}");
        assert_eq!(series(&text, &name), p.as_f64().unwrap(), "{name}");
    }
    assert_eq!(
        series(&text, "railmon_vehicle_regime_active"),
        regime as f64
    );
    assert_eq!(
        series(
            &text,
            "railmon_vehicle_fuel_forecast_error_cubic_meters_per_second"
        ),
        m3(&v["forecast_error_cm3_s"])
    );
    assert_eq!(
        series(&text, "railmon_vehicle_regime_changes_total"),
        v["regime_changes"].as_f64().unwrap()
    );
    // 400 samples, 150 of them initialisation: 250 honest 1-step forecasts scored.
    assert_eq!(
        series(
            &text,
            "railmon_vehicle_fuel_forecast_absolute_error_cubic_meters_per_second_count"
        ),
        250.0
    );
    for reason in [
        "not_finite",
        "unknown_category",
        "missing_channel",
        "acceleration_out_of_range",
    ] {
        let name = format!(
            "railmon_stream_samples_rejected_total{{reason=\"{reason}\",stream=\"vehicle\"}}"
        );
        assert_eq!(series(&text, &name), 0.0, "{name}");
    }
}

/// Every key of the vehicle stream's live answers is in its schema, nested intervals and the
/// regime-change event's fields included (issue 14: names and 90 % intervals).
#[tokio::test]
async fn vehicle_answers_keys_are_in_their_schemas() {
    let state = vehicle_state_after(1500);
    let (_, api) = get_json(&state, "/openapi.json").await;
    let schemas = &api["components"]["schemas"];
    let check = |what: &str, body: &Value, schema: &str| {
        let properties = schemas[schema]["properties"]
            .as_object()
            .unwrap_or_else(|| panic!("{schema}: no properties"));
        for key in body.as_object().unwrap().keys() {
            assert!(
                properties.contains_key(key),
                "{what}: `{key}` not in {schema}"
            );
        }
        for key in properties.keys() {
            assert!(
                body.get(key).is_some(),
                "{what}: {schema}'s `{key}` not sent"
            );
        }
    };
    let (_, view) = get_json(&state, "/api/v1/vehicle").await;
    check("/api/v1/vehicle", &view, "VehicleView");
    let interval = &view["virtual_sensor_interval_cm3_s"];
    check("virtual sensor interval", interval, "IntervalView");
    check(
        "forecast interval",
        &view["forecast_interval_cm3_s"][9],
        "IntervalView",
    );
    assert_eq!(
        view["forecast_interval_cm3_s"].as_array().unwrap().len(),
        10
    );
    let names = view["regime_names"].as_array().unwrap();
    assert_eq!(names.len(), 3);
    let regime = view["regime"].as_u64().unwrap() as usize;
    assert_eq!(view["regime_name"], names[regime]);
    let (_, history) = get_json(&state, "/api/v1/vehicle/history?seconds=3").await;
    check(
        "history point",
        &history["points"][0],
        "VehicleHistoryPoint",
    );
    let (_, events) = get_json(&state, "/api/v1/vehicle/events").await;
    let event = &events["events"][0];
    assert!(event.is_object(), "{events}");
    let mut detail = event.as_object().unwrap().clone();
    // EventView is allOf [the stream's fields, the common fields]: remove the common ones.
    let common = schemas["EventView"]["allOf"][1]["properties"]
        .as_object()
        .unwrap()
        .clone();
    for key in common.keys() {
        detail.remove(key);
    }
    check(
        "regime_changed detail",
        &Value::Object(detail),
        "RegimeEventDetail",
    );
}

#[tokio::test]
async fn vehicle_history_and_events() {
    let state = vehicle_state_after(1500);
    let (status, body) = get_json(&state, "/api/v1/vehicle/history?seconds=10").await;
    assert_eq!(status, StatusCode::OK);
    let points = body["points"].as_array().unwrap();
    assert_eq!(points.len(), 11, "{body}");
    assert_eq!(points[10]["time_s"], 1499.0);
    assert_eq!(body["interval_s"], 1.0);
    let (_, all) = get_json(&state, "/api/v1/vehicle/history").await;
    assert_eq!(all["points"].as_array().unwrap().len(), 601);
    let (_, current) = get_json(&state, "/api/v1/vehicle").await;
    let (_, body) = get_json(&state, "/api/v1/vehicle/events").await;
    let events = body["events"].as_array().unwrap();
    assert_eq!(
        events.len() as u64,
        current["regime_changes"].as_u64().unwrap()
    );
    assert!(!events.is_empty());
    assert_eq!(events[0]["kind"], "regime_changed");
    assert_eq!(events.last().unwrap()["to_regime"], current["regime"]);
    let first = events[0]["id"].as_u64().unwrap();
    let (_, later) = get_json(&state, &format!("/api/v1/vehicle/events?after_id={first}")).await;
    assert_eq!(later["events"].as_array().unwrap().len(), events.len() - 1);
    for uri in [
        "/api/v1/vehicle/history?seconds=0",
        "/api/v1/vehicle/history?window=3",
        "/api/v1/vehicle/events?after_id=x",
        "/api/v1/vehicle/events?drive=1",
    ] {
        let (status, body) = get_json(&state, uri).await;
        assert_eq!(status, StatusCode::BAD_REQUEST, "{uri}");
        assert_error(&body, 400, "bad_query");
    }
    let (_, ready) = get_json(&state, "/readyz").await;
    assert_eq!(ready["streams"][1]["stream"], "vehicle");
}

#[tokio::test]
async fn disabled_streams_are_json_404s_alike() {
    let state = state_after(10);
    let no_drives = AppState::new(ServiceConfig {
        drive: railmon_service::config::DriveConfig {
            enabled: false,
            ..Default::default()
        },
        ..test_config()
    })
    .unwrap();
    for uri in [
        "/api/v1/drives",
        "/api/v1/drives/1",
        "/api/v1/drives/1/history",
        "/api/v1/drives/events",
    ] {
        let (status, body) = get_json(&no_drives, uri).await;
        assert_eq!(status, StatusCode::NOT_FOUND, "{uri}");
        assert_error(&body, 404, "stream_disabled");
    }
    for uri in [
        "/api/v1/vehicle",
        "/api/v1/vehicle/history",
        "/api/v1/vehicle/events",
        "/api/v1/bogies",
        "/api/v1/bogies/1",
        "/api/v1/bogies/1/history",
        "/api/v1/bogies/events",
    ] {
        let (status, body) = get_json(&state, uri).await;
        assert_eq!(status, StatusCode::NOT_FOUND, "{uri}");
        assert_error(&body, 404, "stream_disabled");
    }
}

#[tokio::test]
async fn unknown_bogies_and_bad_bogie_queries_are_json_errors() {
    let config = ServiceConfig {
        bogie: railmon_service::config::BogieConfig {
            enabled: true,
            ..Default::default()
        },
        ..test_config()
    };
    let state = AppState::new(config).unwrap();
    for uri in [
        "/api/v1/bogies/9",
        "/api/v1/bogies/x/history",
        "/api/v1/bogies/events?bogie=3",
    ] {
        let (status, body) = get_json(&state, uri).await;
        assert_eq!(status, StatusCode::NOT_FOUND, "{uri}");
        assert_error(&body, 404, "unknown_bogie");
        assert!(
            body["error"]["message"]
                .as_str()
                .unwrap()
                .contains("[1, 2]"),
            "{body}"
        );
    }
    for uri in [
        "/api/v1/bogies/1/history?seconds=-1",
        "/api/v1/bogies/events?after=3",
    ] {
        let (status, body) = get_json(&state, uri).await;
        assert_eq!(status, StatusCode::BAD_REQUEST, "{uri}");
        assert_error(&body, 400, "bad_query");
    }
    let (status, _) = get_json(&state, "/api/v1/bogies/2").await;
    assert_eq!(status, StatusCode::OK);
}

#[tokio::test]
async fn wrong_method_long_target_and_large_headers_are_json_errors() {
    let state = state_after(10);
    let send = |request: Request<Body>| {
        let state = state.clone();
        async move {
            let response = app(state).oneshot(request).await.unwrap();
            let status = response.status();
            let body = to_bytes(response.into_body(), 1 << 20).await.unwrap();
            (status, serde_json::from_slice::<Value>(&body).unwrap())
        }
    };
    let (status, body) = send(Request::post("/api/v1/drives").body(Body::empty()).unwrap()).await;
    assert_eq!(status, StatusCode::METHOD_NOT_ALLOWED);
    assert_error(&body, 405, "method_not_allowed");
    let long = format!("/api/v1/drives?x={}", "a".repeat(9000));
    let (status, body) = send(Request::get(long).body(Body::empty()).unwrap()).await;
    assert_eq!(status, StatusCode::URI_TOO_LONG);
    assert_error(&body, 414, "uri_too_long");
    let (status, body) = send(
        Request::get("/healthz")
            .header("x-big", "b".repeat(20_000))
            .body(Body::empty())
            .unwrap(),
    )
    .await;
    assert_eq!(status, StatusCode::REQUEST_HEADER_FIELDS_TOO_LARGE);
    assert_error(&body, 431, "headers_too_large");
    let (status, body) = send(
        Request::get("/api/v1/drives/%FF/history")
            .body(Body::empty())
            .unwrap(),
    )
    .await;
    assert!(status.is_client_error(), "{status}");
    assert!(body["error"]["code"].is_string(), "{body}");
}

/// A stored row whose `detail` is not JSON (written by hand, a bug, a bit flip) is skipped and
/// counted, never a 500: the rest of the page is served and the cursor moves past it.
#[tokio::test]
async fn a_row_that_cannot_be_read_is_skipped_not_a_500() {
    use railmon_bus::StreamKind;
    use railmon_service::store::{EventStore, NewEvent};
    let dir = std::env::temp_dir().join(format!("railmon-http-bad-row-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut config = test_config();
    config.storage.data_dir = dir.display().to_string();
    {
        let identity = config.identity.resolve();
        let (store, thread) = EventStore::open(&config.storage, &identity).unwrap();
        store.append(
            (1..=3)
                .map(|k| NewEvent {
                    stream: StreamKind::Drive,
                    kind: "slip_started".into(),
                    subject: k.to_string(),
                    time_utc_ns: 1_795_000_000_000_000_000,
                    time_s: 0.0,
                    run: 0,
                    run_time_s: 0.0,
                    detail: serde_json::Map::new(),
                    alarm: None,
                })
                .collect(),
        );
        assert_eq!(store.close(), 0);
        thread.join().unwrap();
    }
    let db = rusqlite::Connection::open(dir.join("events.sqlite3")).unwrap();
    db.execute("UPDATE events SET detail = '{oops' WHERE id = 2", [])
        .unwrap();
    drop(db);
    let state = AppState::new(config).unwrap();
    let (status, page) = get_json(&state, "/api/v1/events").await;
    assert_eq!(status, StatusCode::OK, "{page}");
    let ids: Vec<u64> = page["events"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["id"].as_u64().unwrap())
        .collect();
    assert_eq!(ids, vec![1, 3]);
    let (status, page) = get_json(&state, "/api/v1/events?after_id=1&limit=1").await;
    assert_eq!(status, StatusCode::OK, "{page}");
    assert_eq!(page["events"], serde_json::json!([]));
    assert_eq!(page["next_after_id"], 2, "past the skipped row");
    let (_, status_view) = get_json(&state, "/api/v1/status").await;
    assert_eq!(
        status_view["events"]["events_unreadable"], 1,
        "{status_view}"
    );
    let (_, _, metrics) = get(&state, "/metrics").await;
    assert!(
        metrics
            .lines()
            .any(|l| l.starts_with("railmon_events_unreadable_total") && l.ends_with(" 1")),
        "{metrics}"
    );
    state.close_store();
    let _ = std::fs::remove_dir_all(&dir);
}
