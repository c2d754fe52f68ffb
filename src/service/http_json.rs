//! A route's JSON body as the service's own error when it is not one: shared by the
//! routes of `http` and of `http_track`.

use super::error::{ErrorKind, ServiceError};
use axum::extract::rejection::JsonRejection;
use axum::http::StatusCode;
use axum::Json;

/// A JSON body, or the reason it is not one (too large → 413, anything else → 400).
pub fn body<T>(b: Result<Json<T>, JsonRejection>) -> Result<T, ServiceError> {
    match b {
        Ok(Json(v)) => Ok(v),
        Err(e) if e.status() == StatusCode::PAYLOAD_TOO_LARGE => Err(ServiceError::new(ErrorKind::TooLarge, format!("request body too large: {}", e.body_text()))),
        Err(e) => Err(ServiceError::invalid(format!("request body: {}", e.body_text()))),
    }
}
