//! Events of every stream from the event store: `/api/v1/events` (all streams), each stream's
//! `/events` (the same page, one stream), and `/api/v1/alarms` (the alarms active now).

use axum::extract::State;
use axum::Json;
use railmon_bus::StreamKind;
use serde::{Deserialize, Serialize};
use utoipa::{IntoParams, ToSchema};

use super::{require_stream, ApiQuery, AppError};
use crate::store::{ActiveAlarm, EventQuery, EventView};
use crate::AppState;

/// The most events one page holds.
pub const MAX_PAGE: usize = 1000;
/// Events in a page when `limit` is not given.
pub const DEFAULT_PAGE: usize = 100;

/// A page of events, oldest first.
#[derive(Debug, Serialize, ToSchema)]
pub struct EventsPage {
    pub events: Vec<EventView>,
    /// Pass as `after_id` for the next page (the last id read for this one, also of a stored row
    /// skipped because it could not be read; else the `after_id` given).
    pub next_after_id: u64,
}

/// The alarms active now, with the event that raised each.
#[derive(Debug, Serialize, ToSchema)]
pub struct AlarmsView {
    pub alarms: Vec<ActiveAlarm>,
}

#[derive(Debug, Default, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct EventsQuery {
    /// Only events with a larger id (ids increase over the life of the database; SQLite
    /// holds them as i64).
    #[param(maximum = 9223372036854775807_i64, example = 0)]
    pub after_id: Option<u64>,
    /// Only events acquired at or after this time (RFC 3339, e.g. 2026-11-22T08:00:00Z).
    /// The pattern is what the server parses: RFC 3339 with `T`, `t` or a space, optional
    /// fractions, `Z` or an offset within a day, dates that exist (29 February of leap years
    /// only), years 1678-2261 (nanoseconds since 1970 in an i64).
    #[param(
        pattern = r"^((1(6(7[89]|[89][0-9])|[7-9][0-9]{2})|2([01][0-9]{2}|2([0-5][0-9]|6[01])))-((0[13578]|1[02])-(0[1-9]|[12][0-9]|3[01])|(0[469]|11)-(0[1-9]|[12][0-9]|30)|02-(0[1-9]|1[0-9]|2[0-8]))|(16(8[048]|9[26])|1[7-9](0[48]|[2468][048]|[13579][26])|2000|2[01](0[48]|[2468][048]|[13579][26])|22(0[48]|[24][048]|[135][26]|60))-02-29)[Tt ]([01][0-9]|2[0-3]):[0-5][0-9]:([0-5][0-9]|60)(\.[0-9]+)?([Zz]|[+-]([01][0-9]|2[0-3]):[0-5][0-9])$",
        example = "2026-11-22T08:00:00Z"
    )]
    pub since: Option<String>,
    /// Only events of this kind (`slip_started`, `damper_degraded`, `regime_changed`, ...).
    pub kind: Option<String>,
    /// Events per page, 1..=1000 (default 100).
    #[param(minimum = 1, maximum = 1000, example = 100)]
    pub limit: Option<usize>,
    /// Only this vehicle (this service's `vehicle_id`; another gives an empty page).
    pub vehicle: Option<String>,
    /// `/api/v1/events` only: one stream (`drive`, `bogie`, `vehicle`).
    #[param(pattern = "^(drive|bogie|vehicle)$", example = "bogie")]
    pub stream: Option<String>,
    /// `/api/v1/drives/events` only: one drive (1-based).
    #[param(minimum = 1, maximum = 32, example = 1)]
    pub drive: Option<usize>,
    /// `/api/v1/bogies/events` only: one bogie.
    pub bogie: Option<u32>,
}

/// Which endpoint a page is for: all streams, or one (with the subject filter it allows).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scope {
    All,
    Stream(StreamKind),
}

fn bad(message: String) -> AppError {
    AppError::BadQuery(message)
}

/// The store query of `q` on `scope`, or why not.
fn store_query(state: &AppState, scope: Scope, q: &EventsQuery) -> Result<EventQuery, AppError> {
    let allowed = |name: &str, given: bool, ok: bool| match given && !ok {
        true => Err(bad(format!("`{name}` is not a parameter of this endpoint"))),
        false => Ok(()),
    };
    allowed("stream", q.stream.is_some(), scope == Scope::All)?;
    allowed(
        "drive",
        q.drive.is_some(),
        scope == Scope::Stream(StreamKind::Drive),
    )?;
    allowed(
        "bogie",
        q.bogie.is_some(),
        scope == Scope::Stream(StreamKind::Bogie),
    )?;
    let stream = match (scope, &q.stream) {
        (Scope::Stream(kind), _) => Some(kind),
        (Scope::All, None) => None,
        (Scope::All, Some(name)) => Some(
            StreamKind::ALL
                .into_iter()
                .find(|k| k.name() == name)
                .ok_or_else(|| bad(format!("`stream={name}`: expected drive, bogie or vehicle")))?,
        ),
    };
    if let Some(after_id) = q.after_id.filter(|&id| i64::try_from(id).is_err()) {
        return Err(bad(format!(
            "`after_id={after_id}`: expected at most {}",
            i64::MAX
        )));
    }
    let limit = q.limit.unwrap_or(DEFAULT_PAGE);
    if !(1..=MAX_PAGE).contains(&limit) {
        return Err(bad(format!("`limit={limit}`: expected 1..={MAX_PAGE}")));
    }
    let since_utc_ns = match &q.since {
        None => None,
        Some(text) => Some(railmon_bus::utc::parse_rfc3339(text).map_err(bad)?),
    };
    let subject = match (q.drive, q.bogie) {
        (Some(drive), _) if !(1..=railmon_bus::MAX_DRIVES).contains(&drive) => {
            return Err(bad(format!(
                "`drive={drive}`: drives are numbered 1..={}",
                railmon_bus::MAX_DRIVES
            )))
        }
        (Some(drive), _) => Some(drive.to_string()),
        (_, Some(bogie)) => {
            if !state.config.bogie.bogies.contains(&bogie) {
                return Err(AppError::UnknownBogie {
                    id: bogie.to_string(),
                    known: state.config.bogie.bogies.clone(),
                });
            }
            None // matched on the prefix below
        }
        _ => None,
    };
    Ok(EventQuery {
        after_id: q.after_id.unwrap_or(0),
        since_utc_ns,
        stream,
        kind: q.kind.clone(),
        subject,
        subject_prefix: q.bogie.map(|b| format!("{b}/")),
        limit,
    })
}

/// A page of `scope`'s events.
pub async fn page(
    state: AppState,
    scope: Scope,
    q: EventsQuery,
) -> Result<Json<EventsPage>, AppError> {
    if let Scope::Stream(kind) = scope {
        require_stream(&state, kind)?;
    }
    let query = store_query(&state, scope, &q)?;
    let after_id = query.after_id;
    let other_vehicle = q
        .vehicle
        .as_ref()
        .is_some_and(|v| *v != state.identity.vehicle_id);
    let page = match other_vehicle {
        true => crate::store::ReadPage::default(),
        false => {
            let store = state.store.clone();
            tokio::task::spawn_blocking(move || store.read_page(&query))
                .await
                .map_err(|e| {
                    tracing::error!("event page task: {e}");
                    AppError::Internal
                })?
                .map_err(|e| {
                    tracing::error!("event page: {e}");
                    AppError::Internal
                })?
        }
    };
    // Past the last row read, also one skipped as unreadable: a cursor never sticks on it.
    let next_after_id = page.last_read_id.map_or(after_id, |id| id.max(after_id));
    Ok(Json(EventsPage {
        events: page.events,
        next_after_id,
    }))
}

/// Events of every stream, oldest first, in pages.
#[utoipa::path(get, path = "/api/v1/events", tag = "service",
    params(EventsQuery),
    responses((status = 200, description = "A page of events, oldest first", body = EventsPage),
              (status = 400, description = "Bad query", body = super::ErrorBody)))]
pub async fn all_events(
    State(state): State<AppState>,
    ApiQuery(q): ApiQuery<EventsQuery>,
) -> Result<Json<EventsPage>, AppError> {
    page(state, Scope::All, q).await
}

/// The alarms active now (slipping drives, degraded dampers), restored at a restart.
#[utoipa::path(get, path = "/api/v1/alarms", tag = "service",
    responses((status = 200, description = "The active alarms", body = AlarmsView)))]
pub async fn alarms(State(state): State<AppState>) -> Result<Json<AlarmsView>, AppError> {
    let store = state.store.clone();
    let alarms = tokio::task::spawn_blocking(move || store.active_alarms())
        .await
        .map_err(|e| {
            tracing::error!("alarms task: {e}");
            AppError::Internal
        })?
        .map_err(|e| {
            tracing::error!("alarms: {e}");
            AppError::Internal
        })?;
    Ok(Json(AlarmsView { alarms }))
}
