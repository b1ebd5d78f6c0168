//! The one error type of the HTTP API and its JSON body (axum's error pattern: handlers return
//! `Result<Json<T>, AppError>`).

use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::Json;
use railmon_bus::StreamKind;
use serde::Serialize;
use utoipa::ToSchema;

/// Every error body: `{"error": {"status": 404, "code": "unknown_drive", "message": "..."}}`.
#[derive(Debug, Serialize, ToSchema)]
pub struct ErrorBody {
    pub error: ErrorDetail,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct ErrorDetail {
    pub status: u16,
    /// Stable machine-readable code: `unknown_drive`, `unknown_bogie`, `stream_disabled`,
    /// `bad_query`, `bad_path`, `not_found`, `method_not_allowed`, `uri_too_long`,
    /// `headers_too_large`, `timeout`, `internal`; `railmon fleet` also `unavailable`.
    pub code: String,
    pub message: String,
}

#[derive(Debug, thiserror::Error)]
pub enum AppError {
    #[error("drive {id} is not known ({known} drives)")]
    UnknownDrive { id: String, known: usize },
    #[error("bogie {id} is not known (bogies {known:?})")]
    UnknownBogie { id: String, known: Vec<u32> },
    #[error("the {0} stream is not enabled ({0}.enabled = false)")]
    StreamDisabled(StreamKind),
    #[error("{0}")]
    BadQuery(String),
    #[error("{0}")]
    BadPath(String),
    #[error("no such resource: {0}")]
    NotFound(String),
    #[error("method {0} is not allowed here (the API is read-only: GET)")]
    MethodNotAllowed(String),
    #[error("request target of {bytes} bytes, at most {max}")]
    UriTooLong { bytes: usize, max: usize },
    #[error("request headers of {bytes} bytes, at most {max}")]
    HeadersTooLarge { bytes: usize, max: usize },
    #[error("the request took longer than {0:?}")]
    Timeout(std::time::Duration),
    /// `railmon fleet`: its NATS stream cannot be read now (logged by the caller).
    #[error("the fleet's event stream cannot be read now")]
    Unavailable,
    /// The detail is logged by the caller; the client gets a short message.
    #[error("internal error")]
    Internal,
}

impl AppError {
    fn status_and_code(&self) -> (StatusCode, &'static str) {
        match self {
            AppError::UnknownDrive { .. } => (StatusCode::NOT_FOUND, "unknown_drive"),
            AppError::UnknownBogie { .. } => (StatusCode::NOT_FOUND, "unknown_bogie"),
            AppError::StreamDisabled(_) => (StatusCode::NOT_FOUND, "stream_disabled"),
            AppError::BadQuery(_) => (StatusCode::BAD_REQUEST, "bad_query"),
            AppError::BadPath(_) => (StatusCode::BAD_REQUEST, "bad_path"),
            AppError::NotFound(_) => (StatusCode::NOT_FOUND, "not_found"),
            AppError::MethodNotAllowed(_) => (StatusCode::METHOD_NOT_ALLOWED, "method_not_allowed"),
            AppError::UriTooLong { .. } => (StatusCode::URI_TOO_LONG, "uri_too_long"),
            AppError::HeadersTooLarge { .. } => (
                StatusCode::REQUEST_HEADER_FIELDS_TOO_LARGE,
                "headers_too_large",
            ),
            AppError::Timeout(_) => (StatusCode::SERVICE_UNAVAILABLE, "timeout"),
            AppError::Unavailable => (StatusCode::SERVICE_UNAVAILABLE, "unavailable"),
            AppError::Internal => (StatusCode::INTERNAL_SERVER_ERROR, "internal"),
        }
    }
}

impl IntoResponse for AppError {
    fn into_response(self) -> Response {
        let (status, code) = self.status_and_code();
        let body = ErrorBody {
            error: ErrorDetail {
                status: status.as_u16(),
                code: code.into(),
                message: self.to_string(),
            },
        };
        (status, Json(body)).into_response()
    }
}
