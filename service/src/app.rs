//! The HTTP API assembled (axum): versioned JSON under `/api/v1`, one router per stream (its
//! view, its history, its events) beside the service's own endpoints ([`crate::http::system`]),
//! the identity middleware, the limits, and the OpenAPI document served at `/openapi.json`.
//! Apart from the routes' toolkit ([`crate::http`]) so that no route module imports the
//! assembly that imports it.

use axum::routing::get;
use axum::{Json, Router};
use utoipa::OpenApi;

use crate::http::{events, server, system, AppError, ErrorBody, ErrorDetail};
use crate::AppState;

#[derive(OpenApi)]
#[openapi(
    info(
        title = "railmon",
        description = "Onboard condition monitoring of a rail vehicle: wheel slip of traction drives, damper health of bogies, fuel use and driving regime."
    ),
    paths(
        events::all_events,
        events::alarms,
        system::status,
        system::healthz,
        system::readyz,
        system::metrics
    ),
    components(schemas(
        events::EventsPage,
        events::AlarmsView,
        crate::store::EventView,
        crate::store::ActiveAlarm,
        crate::store::StoreStatus,
        crate::uplink::UplinkStatus,
        system::StatusView,
        crate::ingest::StreamStatusView,
        crate::ingest::RejectionRecord,
        crate::ingest::ReadinessReason,
        system::Readiness,
        system::StreamReadiness,
        system::Health,
        ErrorBody,
        ErrorDetail
    )),
    tags(
        (name = "drives", description = "Wheel slip of the traction drives"),
        (name = "bogies", description = "Damper health of the bogies"),
        (name = "vehicle", description = "Fuel use and driving regime"),
        (name = "service", description = "Status, probes and metrics of the service")
    )
)]
struct ServiceApi;

/// The OpenAPI document: the service's endpoints and every stream's.
pub fn api_doc() -> utoipa::openapi::OpenApi {
    let mut doc = ServiceApi::openapi()
        .merge_from(crate::drive::DriveApi::openapi())
        .merge_from(crate::bogie::BogieApi::openapi())
        .merge_from(crate::vehicle::VehicleApi::openapi());
    only_own_event_filters(&mut doc);
    named_response_bodies(&mut doc);
    real_examples(&mut doc);
    doc
}

/// Answers of this service captured from a live run of the three demo scenarios (drive seed,
/// damper fault, fuel cycles), arrays cut to a few items, keyed by path template, followed by
/// the status code when it is not 200 (`/readyz 503`: the replays have ended). The system test
/// `schemathesis_finds_no_failure` checks every live answer against them and rewrites the file
/// under `RAILMON_UPDATE_GOLDEN=1` (`scripts/regen-golden`); `service/tests/openapi.rs` checks
/// that every `GET` has one and that each is valid against its schema.
pub const API_EXAMPLES_JSON: &str = include_str!("../assets/api-examples.json");

/// Puts each captured answer ([`API_EXAMPLES_JSON`]) as the example of its `GET`'s JSON body
/// for its status code, so the docs show what the server really sends.
fn real_examples(doc: &mut utoipa::openapi::OpenApi) {
    use utoipa::openapi::RefOr;
    let examples: serde_json::Map<String, serde_json::Value> =
        serde_json::from_str(API_EXAMPLES_JSON).expect("service/assets/api-examples.json");
    for (key, example) in examples {
        let (path, status) = key.split_once(' ').unwrap_or((&key, "200"));
        let Some(get) = doc
            .paths
            .paths
            .get_mut(path)
            .and_then(|item| item.get.as_mut())
        else {
            continue;
        };
        let Some(RefOr::T(response)) = get.responses.responses.get_mut(status) else {
            continue;
        };
        if let Some(RefOr::T(json)) = response.content.get_mut("application/json") {
            json.example = Some(example);
        }
    }
}

/// [`identify`] puts `vehicle_id` and `fleet` first in every JSON object the routes answer;
/// the derived schemas cannot know, so each response body's schema gets them here. Not
/// `required`: the answers of the outer `server::limits` layer (timeouts, oversized headers)
/// do not pass through `identify`.
fn named_response_bodies(doc: &mut utoipa::openapi::OpenApi) {
    use utoipa::openapi::schema::{ObjectBuilder, Type};
    use utoipa::openapi::{RefOr, Schema};
    const COMPONENT: &str = "#/components/schemas/";
    let mut bodies = std::collections::BTreeSet::new();
    for item in doc.paths.paths.values() {
        let operations = [&item.get, &item.post, &item.put, &item.delete, &item.patch];
        for operation in operations.into_iter().flatten() {
            for response in operation.responses.responses.values() {
                let RefOr::T(response) = response else {
                    continue;
                };
                for content in response.content.values() {
                    let RefOr::T(content) = content else {
                        continue;
                    };
                    if let Some(RefOr::Ref(body)) = &content.schema {
                        if let Some(name) = body.ref_location.strip_prefix(COMPONENT) {
                            bodies.insert(name.to_owned());
                        }
                    }
                }
            }
        }
    }
    let Some(components) = doc.components.as_mut() else {
        return;
    };
    let fields = [
        (
            "vehicle_id",
            "The vehicle this service monitors (`[identity] vehicle_id`, else the host name).",
            "unit-4711",
        ),
        (
            "fleet",
            "The fleet it belongs to (`[identity] fleet`; may be empty).",
            "regional-north",
        ),
    ];
    for name in bodies {
        let Some(RefOr::T(Schema::Object(body))) = components.schemas.get_mut(&name) else {
            continue;
        };
        for (field, description, example) in fields {
            let schema = ObjectBuilder::new()
                .schema_type(Type::String)
                .description(Some(description))
                .pattern(Some("^[A-Za-z0-9._-]{0,64}$"))
                .examples([example]);
            body.properties.insert(field.into(), schema.into());
        }
    }
}

/// The events endpoints share one query type ([`events::EventsQuery`]), whose `stream`,
/// `drive` and `bogie` filters each belong to one endpoint (elsewhere they are a `bad_query`):
/// each endpoint's document lists only its own.
fn only_own_event_filters(doc: &mut utoipa::openapi::OpenApi) {
    const FILTERS: [&str; 3] = ["stream", "drive", "bogie"];
    for (path, own) in [
        ("/api/v1/events", "stream"),
        ("/api/v1/drives/events", "drive"),
        ("/api/v1/bogies/events", "bogie"),
        ("/api/v1/vehicle/events", ""),
    ] {
        let Some(item) = doc.paths.paths.get_mut(path) else {
            continue;
        };
        if let Some(params) = item.get.as_mut().and_then(|op| op.parameters.as_mut()) {
            params.retain(|p| match p {
                utoipa::openapi::RefOr::T(p) => {
                    p.name == own || !FILTERS.contains(&p.name.as_str())
                }
                utoipa::openapi::RefOr::Ref(_) => true,
            });
        }
    }
}

/// The router; `state` carries everything the handlers read.
pub fn app(state: AppState) -> Router {
    // Built once: it only changes with the code.
    let document = api_doc();
    Router::new()
        .merge(crate::drive::routes())
        .merge(crate::bogie::routes())
        .merge(crate::vehicle::routes())
        .route("/api/v1/events", get(events::all_events))
        .route("/api/v1/alarms", get(events::alarms))
        .route("/api/v1/status", get(system::status))
        .route("/healthz", get(system::healthz))
        .route("/readyz", get(system::readyz))
        .route("/metrics", get(system::metrics))
        .route("/", get(system::root))
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
            std::sync::Arc::new(state.identity.clone()),
            identify,
        ))
        .layer(axum::middleware::from_fn_with_state(
            std::sync::Arc::new(state.config.http.clone()),
            server::limits,
        ))
        .with_state(state)
}

/// Names the vehicle in every answer: `vehicle_id` and `fleet` first in every JSON object body
/// (estimates, history, events, status, errors alike), and as `railmon-vehicle-id` /
/// `railmon-fleet` headers on every response.
async fn identify(
    axum::extract::State(identity): axum::extract::State<std::sync::Arc<crate::config::Identity>>,
    request: axum::extract::Request,
    next: axum::middleware::Next,
) -> axum::response::Response {
    use axum::http::header::{HeaderValue, CONTENT_LENGTH, CONTENT_TYPE};
    // The OpenAPI document is about the API, not an answer of this vehicle.
    let document = request.uri().path() == "/openapi.json";
    let response = next.run(request).await;
    let (mut parts, body) = response.into_parts();
    let json = parts
        .headers
        .get(CONTENT_TYPE)
        .is_some_and(|v| v.as_bytes().starts_with(b"application/json"))
        && !document;
    let body = match json {
        false => body,
        true => match axum::body::to_bytes(body, usize::MAX).await {
            Ok(bytes) => match serde_json::from_slice::<serde_json::Value>(&bytes) {
                Ok(serde_json::Value::Object(fields)) => {
                    let mut named = serde_json::Map::with_capacity(fields.len() + 2);
                    named.insert("vehicle_id".into(), identity.vehicle_id.clone().into());
                    named.insert("fleet".into(), identity.fleet.clone().into());
                    named.extend(fields);
                    parts.headers.remove(CONTENT_LENGTH);
                    axum::body::Body::from(serde_json::Value::Object(named).to_string())
                }
                _ => axum::body::Body::from(bytes),
            },
            Err(_) => axum::body::Body::empty(),
        },
    };
    for (name, value) in [
        ("railmon-vehicle-id", &identity.vehicle_id),
        ("railmon-fleet", &identity.fleet),
    ] {
        if let Ok(value) = HeaderValue::from_str(value) {
            parts.headers.insert(name, value);
        }
    }
    axum::response::Response::from_parts(parts, body)
}
