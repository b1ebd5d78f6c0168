//! Typed query and path extractors whose rejections are [`AppError`]s (JSON bodies), and the
//! query parameters the endpoints share.

use axum::extract::{FromRequestParts, Path};
use axum::http::request::Parts;
use serde::de::DeserializeOwned;
use serde::Deserialize;
use utoipa::IntoParams;

use super::AppError;

/// `axum::extract::Query` with a JSON `bad_query` rejection. Use it with a struct that denies
/// unknown fields, so a misspelt parameter is an error rather than silently ignored.
pub struct ApiQuery<T>(pub T);

impl<T: DeserializeOwned, S: Send + Sync> FromRequestParts<S> for ApiQuery<T> {
    type Rejection = AppError;

    async fn from_request_parts(parts: &mut Parts, _state: &S) -> Result<Self, AppError> {
        let query = parts.uri.query().unwrap_or_default();
        serde_urlencoded::from_str(query)
            .map(ApiQuery)
            .map_err(|e| AppError::BadQuery(format!("query `{query}`: {e}")))
    }
}

/// `axum::extract::Path` of one segment, kept as text so that the handler names it in a
/// domain error (`unknown_drive`, `unknown_bogie`) instead of a generic rejection.
pub struct ApiPath(pub String);

impl<S: Send + Sync> FromRequestParts<S> for ApiPath {
    type Rejection = AppError;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, AppError> {
        Path::<String>::from_request_parts(parts, state)
            .await
            .map(|Path(id)| ApiPath(id))
            .map_err(|e| AppError::BadPath(e.body_text()))
    }
}

/// The longest history window a request may ask for, s.
pub const MAX_HISTORY_SECONDS: f64 = 86_400.0;

/// `?seconds=N` of a history endpoint.
#[derive(Debug, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct HistoryQuery {
    /// Window of stream time before the newest point, s (at most 86400).
    #[param(exclusive_minimum = 0.0, maximum = 86400.0, example = 60.0)]
    pub seconds: Option<f64>,
}

impl HistoryQuery {
    /// The window, `default` when not given; a bad value is a `bad_query`.
    pub fn seconds_or(&self, default: f64) -> Result<f64, AppError> {
        match self.seconds {
            None => Ok(default),
            Some(s) if s.is_finite() && s > 0.0 && s <= MAX_HISTORY_SECONDS => Ok(s),
            Some(s) => Err(AppError::BadQuery(format!(
                "`seconds={s}`: expected a number of seconds in (0, {MAX_HISTORY_SECONDS}]"
            ))),
        }
    }
}
