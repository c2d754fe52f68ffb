//! The calls both adapters make, in async form: each takes its slot (estimates wait for
//! one in line, estimate_queue.rs), runs the blocking core work off the async threads
//! under the request's deadline, and records metrics. HTTP and gRPC differ only in how they parse requests and
//! write answers, so they answer the same request the same way.

use super::auth::ApiKeys;
use super::core::Core;
use super::detect_requests::{DetectRequest, DetectResponse};
use super::error::ServiceError;
use super::metrics::{Gauges, Metrics};
use super::operations::OperationStatus;
use super::rate_limit::RateLimiter;
use super::requests::{EstimateRequest, EstimateResponse, OnboardRequest};
use super::track_requests::{TrackFrameRequest, TrackFrameResponse, TrackSessionInfo, TrackSessionOptions};
use crate::store::ObjectInfo;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

#[derive(Clone)]
pub struct Api {
    pub core: Arc<Core>,
    /// Set once the store is open, the backbone loaded and warmed up, the pool up.
    pub ready: Arc<AtomicBool>,
    pub metrics: Arc<Metrics>,
    pub keys: ApiKeys,
    /// Per-client rate limit (access.rs); `None`: off.
    pub rate: Option<Arc<RateLimiter>>,
    /// Longest an estimate may take on the server (a client's shorter deadline wins).
    pub request_timeout: Option<Duration>,
}

/// Runs blocking core work off the async threads, inside the caller's span (the
/// request's), so the work's stages and log lines belong to the request.
pub async fn blocking<T: Send + 'static>(f: impl FnOnce() -> Result<T, ServiceError> + Send + 'static) -> Result<T, ServiceError> {
    let span = tracing::Span::current();
    tokio::task::spawn_blocking(move || span.in_scope(f)).await.map_err(|e| ServiceError::internal(format!("worker failed: {e}")))?
}

impl Api {
    pub fn is_ready(&self) -> bool {
        self.ready.load(Ordering::Acquire)
    }

    pub fn gauges(&self) -> Gauges {
        let c = self.core.cache_stats();
        let q = &self.core.estimates;
        Gauges {
            estimates_running: q.running(),
            estimates_waiting: q.waiting(),
            estimate_service_seconds: q.service_time().map(|d| d.as_secs_f64()),
            onboardings_running: self.core.onboardings_running(),
            objects_loaded: c.objects,
            cache_bytes: c.bytes,
            cache_stale: c.stale,
            ready: self.is_ready(),
            queue: self.core.queue_stats(),
            track_sessions: self.core.track_sessions_open(),
            render_mesh_uploads: self.core.render_mesh_uploads(),
            thumbnails_drawn: self.core.thumbnails.drawn(),
        }
    }

    /// The time this request may take: the server's limit or the client's deadline,
    /// whichever is shorter.
    pub fn budget(&self, client: Option<Duration>) -> Option<Duration> {
        match (self.request_timeout, client) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// Estimates within `budget` (see `heavy`).
    pub async fn estimate(&self, req: EstimateRequest, budget: Option<Duration>) -> Result<EstimateResponse, ServiceError> {
        let detections = req.detections.len();
        let resp = self.heavy(budget, move |core, deadline| core.estimate(&req, deadline)).await?;
        for r in &resp.results {
            self.metrics.stages(&r.timings_ms, detections.max(resp.detections.len()));
        }
        Ok(resp)
    }

    /// Detects within `budget`, in an estimate's slot (see `heavy`).
    pub async fn detect(&self, req: DetectRequest, budget: Option<Duration>) -> Result<DetectResponse, ServiceError> {
        let resp = self.heavy(budget, move |core, deadline| core.detect(&req, deadline)).await?;
        self.metrics.detected(&resp.timings_ms, resp.detections.len());
        Ok(resp)
    }

    /// Runs the server's heavy work (an estimate or a detection: one limit for both) in a
    /// slot, after waiting in line for one, all within `budget`. Past it the caller gets
    /// DEADLINE_EXCEEDED at once; the worker stops at its next check and only then frees
    /// its slot, so the concurrency limit stays true.
    async fn heavy<T: Send + 'static>(&self, budget: Option<Duration>, work: impl FnOnce(&Core, Option<Instant>) -> Result<T, ServiceError> + Send + 'static) -> Result<T, ServiceError> {
        let deadline = budget.map(|b| Instant::now() + b);
        let turn = self.core.estimates.enter(budget).await.map_err(|(why, e)| {
            self.metrics.queue_refused(why.name());
            e
        })?;
        self.metrics.queue_wait(turn.waited.as_secs_f64());
        let core = self.core.clone();
        let work = blocking(move || {
            let _turn = turn;
            work(&core, deadline)
        });
        match deadline {
            Some(d) => tokio::time::timeout_at(d.into(), work).await.map_err(|_| super::error::deadline_exceeded(budget.unwrap_or_default()))?,
            None => work.await,
        }
    }

    /// `request_id`: the starting request's, for the onboarding's own log lines.
    pub async fn onboard(&self, req: OnboardRequest, request_id: Option<crate::telemetry::RequestId>) -> Result<OperationStatus, ServiceError> {
        let core = self.core.clone();
        blocking(move || core.start_onboard(req, request_id.as_ref())).await
    }

    pub async fn list_objects(&self) -> Result<Vec<ObjectInfo>, ServiceError> {
        let core = self.core.clone();
        blocking(move || core.list_objects()).await
    }

    pub async fn get_object(&self, id: String) -> Result<ObjectInfo, ServiceError> {
        let core = self.core.clone();
        blocking(move || core.get_object(&id)).await
    }

    pub async fn delete_object(&self, id: String) -> Result<(), ServiceError> {
        let core = self.core.clone();
        blocking(move || core.delete_object(&id)).await
    }
}

/// Tracking sessions over HTTP (the gRPC stream drives the core itself, grpc_track.rs).
impl Api {
    pub async fn open_track(&self, options: TrackSessionOptions) -> Result<TrackSessionInfo, ServiceError> {
        let core = self.core.clone();
        blocking(move || core.open_track(&options, false)).await
    }

    /// One frame of session `id`, counted in the tracking metrics.
    pub async fn track_frame(&self, id: String, req: TrackFrameRequest) -> Result<TrackFrameResponse, ServiceError> {
        let core = self.core.clone();
        let resp = blocking(move || core.track_frame(&id, &req)).await?;
        self.metrics.track_frame(resp.objects.iter().map(|o| o.mode.as_str()));
        Ok(resp)
    }
}
