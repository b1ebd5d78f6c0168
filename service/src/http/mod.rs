//! The HTTP toolkit every route uses (errors, typed queries, the events endpoints' query, the
//! server with its limits) and the service's own endpoints (status, probes, metrics, Swagger
//! UI); the router and the OpenAPI document are assembled in [`crate::app`]. Handlers only read
//! atomics, `arc-swap` snapshots and the history/event rings.

mod error;
pub mod events;
mod query;
pub mod server;
pub mod system;

use railmon_bus::StreamKind;

pub use error::{AppError, ErrorBody, ErrorDetail};
pub use query::{ApiPath, ApiQuery, HistoryQuery, MAX_HISTORY_SECONDS};

use crate::AppState;

/// `Ok(())` if `kind` is enabled, else the `stream_disabled` error every stream's endpoints give.
pub fn require_stream(state: &AppState, kind: StreamKind) -> Result<(), AppError> {
    match state.stream(kind) {
        Some(_) => Ok(()),
        None => Err(AppError::StreamDisabled(kind)),
    }
}
