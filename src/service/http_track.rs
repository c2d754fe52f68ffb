//! HTTP routes of the tracking sessions: `POST /v1/tracks` opens one (optional JSON body of
//! options), `POST /v1/tracks/{id}/frames` runs a frame through it, `GET` reads one or all,
//! `DELETE` closes one. The gRPC `Track` stream is the same session over one call.

use super::api::{blocking, Api};
use super::error::ServiceError;
use super::track_requests::{OpenTrackRequest, TrackFrameRequest};
use axum::body::Bytes;
use axum::extract::rejection::JsonRejection;
use axum::extract::{Path, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};

async fn open(State(s): State<Api>, body: Bytes) -> Result<Response, ServiceError> {
    // An empty body is an empty set of options.
    let req: OpenTrackRequest =
        if body.iter().all(u8::is_ascii_whitespace) { OpenTrackRequest::default() } else { serde_json::from_slice(&body).map_err(|e| ServiceError::invalid(format!("request body: {e}")))? };
    Ok((StatusCode::CREATED, Json(s.open_track(req.options).await?)).into_response())
}

// Reading a session waits for a frame it is processing, so it runs off the async threads.
async fn list(State(s): State<Api>) -> Result<Response, ServiceError> {
    let sessions = blocking(move || Ok(s.core.list_tracks())).await?;
    Ok(Json(serde_json::json!({ "sessions": sessions })).into_response())
}

async fn info(State(s): State<Api>, Path(id): Path<String>) -> Result<Response, ServiceError> {
    Ok(Json(blocking(move || s.core.track_info(&id)).await?).into_response())
}

async fn close(State(s): State<Api>, Path(id): Path<String>) -> Result<Response, ServiceError> {
    s.core.close_track(&id)?;
    Ok(StatusCode::NO_CONTENT.into_response())
}

async fn frame(State(s): State<Api>, Path(id): Path<String>, b: Result<Json<TrackFrameRequest>, JsonRejection>) -> Result<Response, ServiceError> {
    let req = super::http_json::body(b)?;
    Ok(Json(s.track_frame(id, req).await?).into_response())
}

pub fn routes() -> Router<Api> {
    Router::new().route("/v1/tracks", get(list).post(open)).route("/v1/tracks/{id}", get(info).delete(close)).route("/v1/tracks/{id}/frames", post(frame))
}
