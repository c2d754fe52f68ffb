//! HTTP/JSON adapter (axum): routes, body limits, JSON errors. Each handler parses, calls
//! the core (blocking work on the blocking pool, after taking a slot) and maps
//! `ServiceError` to a status with a JSON body `{"error": {"kind", "message"}}`.

use super::core::Core;
use super::error::{ErrorKind, ServiceError};
use super::requests::{EstimateRequest, OnboardRequest};
use axum::extract::rejection::JsonRejection;
use axum::extract::{DefaultBodyLimit, Path, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

#[derive(Clone)]
pub struct AppState {
    pub core: Arc<Core>,
    /// Set once the store is open, the backbone loaded and warmed up, the pool up.
    pub ready: Arc<AtomicBool>,
}

pub fn status_of(kind: &ErrorKind) -> StatusCode {
    match kind {
        ErrorKind::InvalidArgument => StatusCode::BAD_REQUEST,
        ErrorKind::Unauthenticated => StatusCode::UNAUTHORIZED,
        ErrorKind::NotFound => StatusCode::NOT_FOUND,
        ErrorKind::AlreadyExists => StatusCode::CONFLICT,
        ErrorKind::TooLarge => StatusCode::PAYLOAD_TOO_LARGE,
        ErrorKind::ResourceExhausted => StatusCode::TOO_MANY_REQUESTS,
        ErrorKind::Unavailable => StatusCode::SERVICE_UNAVAILABLE,
        ErrorKind::DeadlineExceeded => StatusCode::GATEWAY_TIMEOUT,
        ErrorKind::Internal => StatusCode::INTERNAL_SERVER_ERROR,
    }
}

impl IntoResponse for ServiceError {
    fn into_response(self) -> Response {
        (status_of(&self.kind), Json(serde_json::json!({ "error": self }))).into_response()
    }
}

/// A JSON body, or the reason it is not one (too large → 413, anything else → 400).
fn body<T>(b: Result<Json<T>, JsonRejection>) -> Result<T, ServiceError> {
    match b {
        Ok(Json(v)) => Ok(v),
        Err(e) if e.status() == StatusCode::PAYLOAD_TOO_LARGE => Err(ServiceError::new(ErrorKind::TooLarge, format!("request body too large: {}", e.body_text()))),
        Err(e) => Err(ServiceError::invalid(format!("request body: {}", e.body_text()))),
    }
}

/// Runs blocking core work off the async threads.
async fn blocking<T: Send + 'static>(f: impl FnOnce() -> Result<T, ServiceError> + Send + 'static) -> Result<T, ServiceError> {
    tokio::task::spawn_blocking(f).await.map_err(|e| ServiceError::internal(format!("worker failed: {e}")))?
}

async fn healthz() -> &'static str {
    "ok"
}

async fn readyz(State(s): State<AppState>) -> Response {
    if s.ready.load(Ordering::Acquire) {
        (StatusCode::OK, "ready").into_response()
    } else {
        ServiceError::new(ErrorKind::Unavailable, "warming up").into_response()
    }
}

async fn list_objects(State(s): State<AppState>) -> Result<Response, ServiceError> {
    let core = s.core.clone();
    let list = blocking(move || core.list_objects()).await?;
    Ok(Json(serde_json::json!({ "objects": list })).into_response())
}

async fn get_object(State(s): State<AppState>, Path(id): Path<String>) -> Result<Response, ServiceError> {
    let core = s.core.clone();
    Ok(Json(blocking(move || core.get_object(&id)).await?).into_response())
}

async fn delete_object(State(s): State<AppState>, Path(id): Path<String>) -> Result<Response, ServiceError> {
    let core = s.core.clone();
    blocking(move || core.delete_object(&id)).await?;
    Ok(StatusCode::NO_CONTENT.into_response())
}

async fn onboard(State(s): State<AppState>, b: Result<Json<OnboardRequest>, JsonRejection>) -> Result<Response, ServiceError> {
    let req = body(b)?;
    let core = s.core.clone();
    let op = blocking(move || core.start_onboard(req)).await?;
    Ok((StatusCode::ACCEPTED, Json(op)).into_response())
}

async fn get_operation(State(s): State<AppState>, Path(id): Path<String>) -> Result<Response, ServiceError> {
    Ok(Json(s.core.operation(&id)?).into_response())
}

async fn cancel_operation(State(s): State<AppState>, Path(id): Path<String>) -> Result<Response, ServiceError> {
    Ok(Json(s.core.cancel_operation(&id)?).into_response())
}

async fn estimate(State(s): State<AppState>, b: Result<Json<EstimateRequest>, JsonRejection>) -> Result<Response, ServiceError> {
    let req = body(b)?;
    // Over the limit the request is refused now, not queued.
    let slot = s.core.estimate_slot().ok_or_else(|| ServiceError::new(ErrorKind::ResourceExhausted, format!("{} estimates already running; retry later", s.core.config.max_estimates)))?;
    let core = s.core.clone();
    let resp = blocking(move || {
        let _slot = slot;
        core.estimate(&req)
    })
    .await?;
    Ok(Json(resp).into_response())
}

pub fn router(state: AppState, max_body_bytes: usize) -> Router {
    Router::new()
        .route("/healthz", get(healthz))
        .route("/readyz", get(readyz))
        .route("/v1/objects", get(list_objects).post(onboard))
        .route("/v1/objects/{id}", get(get_object).delete(delete_object))
        .route("/v1/operations/{id}", get(get_operation))
        .route("/v1/operations/{id}/cancel", post(cancel_operation))
        .route("/v1/estimate", post(estimate))
        .layer(DefaultBodyLimit::max(max_body_bytes))
        .with_state(state)
}
