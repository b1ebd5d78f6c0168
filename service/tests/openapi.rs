//! The OpenAPI document is valid (`openapi-spec-validator`, from the Python environment of
//! `scripts/install-test-deps`: `target-venv`, or `$RAILMON_TEST_VENV`) and usable: every
//! operation has a summary, a tag of its stream, and a description for every response; every
//! `f64` that the server may send as `null` is nullable; the history bound is the server's.
//! `GET /` leads to the docs; every JSON answer has a real example, valid against its schema. The server's answers against the document: `tests/tests/schemathesis.rs`.

mod common;

use axum::body::{to_bytes, Body};
use axum::http::{Request, StatusCode};
use common::test_config;
use railmon_service::{app, AppState};
use serde_json::Value;
use tower::ServiceExt;

async fn get(state: &AppState, uri: &str) -> (StatusCode, Option<String>, String) {
    let response = app(state.clone())
        .oneshot(Request::get(uri).body(Body::empty()).unwrap())
        .await
        .unwrap();
    let status = response.status();
    let location = response
        .headers()
        .get("location")
        .map(|v| v.to_str().unwrap().to_string());
    let body = to_bytes(response.into_body(), 16 << 20).await.unwrap();
    (
        status,
        location,
        String::from_utf8_lossy(&body).into_owned(),
    )
}

async fn document() -> Value {
    let state = AppState::new(test_config()).unwrap();
    let (status, _, body) = get(&state, "/openapi.json").await;
    assert_eq!(status, StatusCode::OK);
    serde_json::from_str(&body).unwrap()
}

/// Runs `tool` of the test Python environment on the document (written to a file, whose path
/// is the last argument) and panics with its output unless it succeeds.
async fn check_document_with(tool: &str, args: &[&str]) {
    check_with(tool, args, document().await).await;
}

/// [`check_document_with`] on `document`.
async fn check_with(tool: &str, args: &[&str], document: Value) {
    let venv = std::env::var("RAILMON_TEST_VENV")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|_| {
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../target-venv")
        });
    let tool = venv.join("bin").join(tool);
    assert!(
        tool.exists(),
        "{} missing: run scripts/install-test-deps",
        tool.display()
    );
    static N: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let file = std::env::temp_dir().join(format!(
        "railmon-openapi-{}-{}.json",
        std::process::id(),
        N.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
    ));
    std::fs::write(&file, document.to_string()).unwrap();
    let out = std::process::Command::new(&tool)
        .args(args)
        .arg(&file)
        .output()
        .unwrap();
    let _ = std::fs::remove_file(&file);
    assert!(
        out.status.success(),
        "{}:\n{}{}",
        tool.display(),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

#[tokio::test]
async fn the_document_passes_the_openapi_validator() {
    check_document_with("openapi-spec-validator", &[]).await;
}

/// `railmon fleet`'s document too (its answers: tests/tests/fleet.rs).
#[tokio::test]
async fn the_fleet_document_passes_the_openapi_validator() {
    let document = serde_json::to_value(railmon_service::fleet::routes::api_doc()).unwrap();
    for path in [
        "/api/v1/vehicles",
        "/api/v1/vehicles/{vehicle_id}/events",
        "/api/v1/vehicles/{vehicle_id}/health",
        "/api/v1/alarms",
    ] {
        assert!(document["paths"][path]["get"].is_object(), "{path}");
    }
    check_with("openapi-spec-validator", &[], document).await;
}

/// Checks that each `GET` has an example on one of its JSON answers, and each example against
/// its answer's schema (OpenAPI 3.1 dialect, `$ref`s resolved in the document); argument: the
/// document's file.
const VALIDATE_EXAMPLES_PY: &str = r#"
import json, sys
import openapi_schema_validator as v
doc = json.load(open(sys.argv[1]))
bad = []
for path, item in doc["paths"].items():
    examples, json_answers = 0, 0
    for status, response in item.get("get", {}).get("responses", {}).items():
        body = response.get("content", {}).get("application/json")
        json_answers += body is not None
        if body is None or "example" not in body:
            continue
        examples += 1
        schema = dict(body["schema"], components=doc["components"])
        try:
            v.validate(body["example"], schema, cls=v.OAS31Validator)
        except v.ValidationError as e:
            bad.append(f"{path} {status}: {e.message} at {list(e.absolute_path)}")
    if json_answers and not examples:
        bad.append(f"{path}: no example")
print("\n".join(bad))
sys.exit(1 if bad else 0)
"#;

/// Every JSON answer of a `GET` has an example (a real answer, captured by the system test
/// `schemathesis_finds_no_failure`), and the example is valid against the answer's schema.
#[tokio::test]
async fn every_answer_has_an_example_valid_against_its_schema() {
    check_document_with("python", &["-c", VALIDATE_EXAMPLES_PY]).await;
}

#[tokio::test]
async fn every_operation_has_a_summary_a_stream_tag_and_described_responses() {
    let api = document().await;
    let tags: Vec<&str> = api["tags"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["name"].as_str().unwrap())
        .collect();
    let mut operations = 0;
    for (path, item) in api["paths"].as_object().unwrap() {
        for (method, op) in item.as_object().unwrap() {
            operations += 1;
            let name = format!("{method} {path}");
            assert!(
                op["summary"].as_str().is_some_and(|s| !s.is_empty()),
                "{name}: no summary"
            );
            let op_tags = op["tags"]
                .as_array()
                .unwrap_or_else(|| panic!("{name}: no tag"));
            assert!(
                op_tags.iter().all(|t| tags.contains(&t.as_str().unwrap())),
                "{name}: {op_tags:?}"
            );
            let stream = ["drives", "bogies", "vehicle"]
                .into_iter()
                .find(|s| path.starts_with(&format!("/api/v1/{s}")));
            if let Some(stream) = stream {
                assert_eq!(op_tags, &[Value::from(stream)], "{name}");
            }
            for (code, response) in op["responses"].as_object().unwrap() {
                assert!(
                    response["description"]
                        .as_str()
                        .is_some_and(|d| !d.is_empty()),
                    "{name} {code}: no description"
                );
            }
        }
    }
    assert!(operations >= 15, "{operations}");
}

#[tokio::test]
async fn the_root_leads_to_the_docs() {
    let state = AppState::new(test_config()).unwrap();
    let (status, location, _) = get(&state, "/").await;
    assert_eq!(
        (status, location.as_deref()),
        (StatusCode::TEMPORARY_REDIRECT, Some("/docs"))
    );
}

/// The bounds the document states are the ones the server enforces.
#[tokio::test]
async fn parameter_bounds_are_the_servers() {
    let api = document().await;
    let param = |path: &str, name: &str| -> Value {
        api["paths"][path]["get"]["parameters"]
            .as_array()
            .unwrap()
            .iter()
            .find(|p| p["name"] == name)
            .unwrap_or_else(|| panic!("{path}: no parameter {name}"))["schema"]
            .clone()
    };
    let limit = param("/api/v1/events", "limit");
    assert_eq!(
        (limit["minimum"].as_u64(), limit["maximum"].as_u64()),
        (
            Some(1),
            Some(railmon_service::http::events::MAX_PAGE as u64)
        )
    );
    let drive = param("/api/v1/drives/events", "drive");
    assert_eq!(
        drive["maximum"].as_u64(),
        Some(railmon_bus::MAX_DRIVES as u64)
    );
    let seconds = param("/api/v1/drives/{id}/history", "seconds");
    assert_eq!(
        seconds["maximum"].as_f64(),
        Some(railmon_service::http::MAX_HISTORY_SECONDS)
    );
    assert_eq!(seconds["exclusiveMinimum"].as_f64(), Some(0.0));
    // Each events endpoint lists only its own subject filter.
    let names = |path: &str| -> Vec<String> {
        api["paths"][path]["get"]["parameters"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| p["name"].as_str().unwrap().to_string())
            .collect()
    };
    assert!(names("/api/v1/drives/events").contains(&"drive".to_string()));
    assert!(!names("/api/v1/drives/events").contains(&"bogie".to_string()));
    assert!(!names("/api/v1/vehicle/events")
        .iter()
        .any(|n| ["drive", "bogie", "stream"].contains(&n.as_str())));
    // Where the server sends null before the first estimate, the schema allows it.
    let damper = &api["components"]["schemas"]["DamperView"]["properties"]["health_ratio"];
    assert!(damper.to_string().contains("null"), "{damper}");
    for field in [
        "effective_sample_size",
        "nis_window_mean",
        "noise_std_ratio",
    ] {
        let bogie = &api["components"]["schemas"]["BogieView"]["properties"][field];
        assert!(bogie.to_string().contains("null"), "{field}: {bogie}");
    }
}

/// Every key of a live answer is in its schema: the `vehicle_id` and `fleet` that every JSON
/// answer starts with included (issue 13).
#[tokio::test]
async fn answers_name_their_vehicle_in_the_schema_too() {
    let api = document().await;
    let state = AppState::new(test_config()).unwrap();
    for (uri, schema) in [
        ("/api/v1/status", "StatusView"),
        ("/api/v1/events", "EventsPage"),
        ("/api/v1/nowhere", "ErrorBody"),
    ] {
        let (_, _, body) = get(&state, uri).await;
        let body: Value = serde_json::from_str(&body).unwrap();
        let properties = api["components"]["schemas"][schema]["properties"]
            .as_object()
            .unwrap_or_else(|| panic!("{schema}: no properties"));
        for key in body.as_object().unwrap().keys() {
            assert!(
                properties.contains_key(key),
                "{uri}: `{key}` not in {schema}"
            );
        }
        for key in ["vehicle_id", "fleet"] {
            assert!(body.get(key).is_some(), "{uri}: no `{key}`");
        }
    }
}
