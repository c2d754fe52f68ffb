//! HTTP/JSON adapter (axum): routes, body limits, JSON errors. Each handler parses, calls
//! the core (blocking work on the blocking pool, after taking a slot) and maps
//! `ServiceError` to a status with a JSON body `{"error": {"kind", "message"}}`.

use super::access;
use super::api::Api;
use super::detect_requests::DetectRequest;
use super::error::{ErrorKind, ServiceError};
use super::http_json::body;
use super::requests::{EstimateRequest, OnboardRequest};
use super::scopes;
use axum::extract::rejection::JsonRejection;
use axum::extract::{ConnectInfo, DefaultBodyLimit, FromRequest, MatchedPath, Multipart, Path, Request, State};
use axum::http::{header, StatusCode};
use axum::middleware::{from_fn_with_state, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};

/// The OpenAPI 3 description of these routes, served at `/openapi.json`.
pub const OPENAPI: &str = include_str!("openapi.json");

pub fn status_of(kind: &ErrorKind) -> StatusCode {
    match kind {
        ErrorKind::InvalidArgument => StatusCode::BAD_REQUEST,
        ErrorKind::Unauthenticated => StatusCode::UNAUTHORIZED,
        ErrorKind::PermissionDenied => StatusCode::FORBIDDEN,
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
        let retry = self.retry_after_ms.zip(self.retry_after_secs());
        let mut resp = (status_of(&self.kind), Json(serde_json::json!({ "error": self }))).into_response();
        if let Some((ms, secs)) = retry {
            resp.headers_mut().insert(header::RETRY_AFTER, secs.into());
            resp.headers_mut().insert(RETRY_AFTER_MS, ms.into());
        }
        resp
    }
}

/// The wait a refusal asks for in milliseconds: `Retry-After` has only whole seconds.
const RETRY_AFTER_MS: header::HeaderName = header::HeaderName::from_static("retry-after-ms");

/// Admission (API key, scope, rate limit: access.rs) and request metrics, after routing so
/// the route template (not the raw path with ids) picks the scope and labels the metrics.
/// The caller goes on in the request's extensions.
async fn guard(State(s): State<Api>, mut req: Request, next: Next) -> Response {
    let method = req.method().to_string();
    let route = req.extensions().get::<MatchedPath>().map_or_else(|| "unmatched".to_string(), |m| m.as_str().to_string());
    tracing::Span::current().record("route", route.as_str());
    let t = std::time::Instant::now();
    let endpoint = format!("{method} {route}");
    let admitted = access::admit(
        &s,
        &access::Request {
            needs: scopes::http(&method, &route),
            authorization: req.headers().get(header::AUTHORIZATION).and_then(|v| v.to_str().ok()),
            peer: req.extensions().get::<ConnectInfo<super::http_observe::Peer>>().map(|c| c.0 .0.ip()),
            endpoint: &endpoint,
            key_hint: "send Authorization: Bearer <key>",
        },
    );
    let resp = match admitted {
        Ok(caller) => {
            if let Some(c) = caller {
                tracing::Span::current().record("api_key", &*c.identity);
                req.extensions_mut().insert(c);
            }
            next.run(req).await
        }
        Err(refused) => refused.into_response(),
    };
    s.metrics.request(&method, &route, resp.status().as_str(), t.elapsed().as_secs_f64());
    resp
}

/// Refuses a body whose announced length is over the limit before reading any of it (the
/// extractors' own limit only trips after reading that much).
async fn announced_size(State(max): State<usize>, req: Request, next: Next) -> Response {
    let announced = req.headers().get(header::CONTENT_LENGTH).and_then(|v| v.to_str().ok()).and_then(|v| v.parse::<u64>().ok());
    match announced {
        Some(n) if n > max as u64 => ServiceError::new(ErrorKind::TooLarge, format!("request body of {n} bytes is over the limit of {max}")).into_response(),
        _ => next.run(req).await,
    }
}

async fn metrics(State(s): State<Api>) -> Response {
    ([(header::CONTENT_TYPE, "text/plain; version=0.0.4")], s.metrics.render(&s.gauges())).into_response()
}

async fn openapi() -> Response {
    ([(header::CONTENT_TYPE, "application/json")], OPENAPI).into_response()
}

async fn healthz() -> &'static str {
    "ok"
}

async fn readyz(State(s): State<Api>) -> Response {
    if s.is_ready() {
        (StatusCode::OK, "ready").into_response()
    } else {
        ServiceError::new(ErrorKind::Unavailable, "warming up").into_response()
    }
}

async fn list_objects(State(s): State<Api>) -> Result<Response, ServiceError> {
    Ok(Json(serde_json::json!({ "objects": s.list_objects().await? })).into_response())
}

async fn get_object(State(s): State<Api>, Path(id): Path<String>) -> Result<Response, ServiceError> {
    Ok(Json(s.get_object(id).await?).into_response())
}

async fn delete_object(State(s): State<Api>, Path(id): Path<String>) -> Result<Response, ServiceError> {
    s.delete_object(id).await?;
    Ok(StatusCode::NO_CONTENT.into_response())
}

/// JSON with base64 files, or multipart/form-data with the files as they are.
async fn onboard(State(s): State<Api>, req: Request) -> Result<Response, ServiceError> {
    let request_id = req.extensions().get::<crate::telemetry::RequestId>().cloned();
    let multipart = req.headers().get(header::CONTENT_TYPE).and_then(|v| v.to_str().ok()).is_some_and(|v| v.starts_with("multipart/form-data"));
    let parsed: OnboardRequest = if multipart {
        let form = Multipart::from_request(req, &()).await.map_err(|e| ServiceError::invalid(format!("multipart body: {}", e.body_text())))?;
        super::multipart::onboard_request(form).await?
    } else {
        body(Json::from_request(req, &()).await)?
    };
    let op = s.onboard(parsed, request_id).await?;
    Ok((StatusCode::ACCEPTED, Json(op)).into_response())
}

async fn get_operation(State(s): State<Api>, Path(id): Path<String>) -> Result<Response, ServiceError> {
    Ok(Json(s.core.operation(&id)?).into_response())
}

async fn cancel_operation(State(s): State<Api>, Path(id): Path<String>) -> Result<Response, ServiceError> {
    Ok(Json(s.core.cancel_operation(&id)?).into_response())
}

/// Who the request's key is and what it may do, so a client (the console) can offer only
/// what will be allowed. Without keys configured: everyone may do everything.
async fn caller(State(s): State<Api>, req: Request) -> Response {
    let caller = req.extensions().get::<super::auth::Caller>();
    let scopes = caller.map_or_else(scopes::Scopes::all, |c| c.scopes);
    let names: Vec<&str> = scopes::Scope::ALL.into_iter().filter(|x| scopes.has(*x)).map(scopes::Scope::name).collect();
    Json(serde_json::json!({ "keys_required": s.keys.enabled(), "identity": caller.map(|c| &*c.identity), "scopes": names, "read_only": s.core.config.read_only })).into_response()
}

#[derive(serde::Deserialize)]
struct ThumbnailQuery {
    size: Option<u32>,
}

/// A PNG of the object drawn from a fixed three-quarter view (`?size=` pixels, square).
async fn thumbnail(State(s): State<Api>, Path(id): Path<String>, q: Result<axum::extract::Query<ThumbnailQuery>, axum::extract::rejection::QueryRejection>) -> Result<Response, ServiceError> {
    let size = q.map_err(|e| ServiceError::invalid(format!("query: {}", e.body_text())))?.size.unwrap_or(super::thumbnails::DEFAULT_SIZE);
    let core = s.core.clone();
    let png = super::api::blocking(move || core.thumbnail(&id, size)).await?;
    Ok(([(header::CONTENT_TYPE, "image/png"), (header::CACHE_CONTROL, "private, max-age=300")], png.to_vec()).into_response())
}

async fn estimate(State(s): State<Api>, b: Result<Json<EstimateRequest>, JsonRejection>) -> Result<Response, ServiceError> {
    let req = body(b)?;
    let budget = s.budget(None);
    Ok(Json(s.estimate(req, budget).await?).into_response())
}

async fn detect(State(s): State<Api>, b: Result<Json<DetectRequest>, JsonRejection>) -> Result<Response, ServiceError> {
    let req = body(b)?;
    let budget = s.budget(None);
    Ok(Json(s.detect(req, budget).await?).into_response())
}

/// The API's routes, and the web console's unless `console` is false.
pub fn router(state: Api, max_body_bytes: usize, console: bool) -> Router {
    let api = Router::new()
        .route("/healthz", get(healthz))
        .route("/readyz", get(readyz))
        .route("/v1/objects", get(list_objects).post(onboard))
        .route("/v1/objects/{id}", get(get_object).delete(delete_object))
        .route("/v1/objects/{id}/thumbnail", get(thumbnail))
        .route("/v1/caller", get(caller))
        .route("/v1/operations/{id}", get(get_operation))
        .route("/v1/operations/{id}/cancel", post(cancel_operation))
        .route("/v1/estimate", post(estimate))
        .route("/v1/detect", post(detect))
        .merge(super::http_track::routes())
        .route("/metrics", get(metrics))
        .route("/openapi.json", get(openapi));
    let routes = if console { api.merge(super::console::routes()) } else { api };
    routes
        .route_layer(from_fn_with_state(state.clone(), guard))
        .layer(DefaultBodyLimit::max(max_body_bytes))
        .layer(from_fn_with_state(max_body_bytes, announced_size))
        .layer(axum::middleware::from_fn(super::http_observe::observe))
        .with_state(state)
}
