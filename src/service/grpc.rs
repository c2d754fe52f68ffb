//! gRPC adapter (tonic): `b2tfpose.v1.PoseService` over the same `Api` as HTTP, plus the
//! standard health service (SERVING once warmed up) and server reflection. API keys come
//! from the `authorization` metadata (`Bearer <key>`); health and reflection stay open.
//! Deadlines: the client's `grpc-timeout` and the server's request timeout, whichever is
//! shorter, bound an estimate (DEADLINE_EXCEEDED).

use super::access;
use super::api::Api;
use super::error::ServiceError;
use super::grpc_codes::{code_name, code_of};
use super::grpc_convert as convert;
use super::proto::pose_service_server::{PoseService, PoseServiceServer};
use super::proto::{self as pb};
use super::scopes;
use std::time::{Duration, Instant};
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Code, Request, Response, Status};

/// The client's deadline from `grpc-timeout` ("<digits><H|M|S|m|u|n>"), less a margin
/// so this server answers DEADLINE_EXCEEDED itself before the transport's own timer
/// (which would answer CANCELLED) fires.
fn client_deadline<T>(req: &Request<T>) -> Option<Duration> {
    let v = req.metadata().get("grpc-timeout")?.to_str().ok()?;
    let (digits, unit) = v.split_at(v.len().checked_sub(1)?);
    let n: u64 = digits.parse().ok()?;
    let d = match unit {
        "H" => Duration::from_secs(n.saturating_mul(3600)),
        "M" => Duration::from_secs(n.saturating_mul(60)),
        "S" => Duration::from_secs(n),
        "m" => Duration::from_millis(n),
        "u" => Duration::from_micros(n),
        "n" => Duration::from_nanos(n),
        _ => return None,
    };
    Some(d.saturating_sub((d / 20).min(Duration::from_millis(50))))
}

pub struct GrpcService {
    api: Api,
}

impl GrpcService {
    pub fn new(api: Api) -> Self {
        Self { api }
    }

    /// Runs one call, counting it in the metrics under its RPC name and status code.
    async fn observed<T>(&self, rpc: &str, work: impl std::future::Future<Output = Result<T, ServiceError>>) -> Result<T, Status> {
        let started = Instant::now();
        let result = work.await;
        let code = match &result {
            Ok(_) => Code::Ok,
            Err(e) => code_of(&e.kind),
        };
        self.api.metrics.request("grpc", &format!("/b2tfpose.v1.PoseService/{rpc}"), &code_name(code), started.elapsed().as_secs_f64());
        result.map_err(Status::from)
    }
}

#[tonic::async_trait]
impl PoseService for GrpcService {
    async fn onboard(&self, req: Request<pb::OnboardRequest>) -> Result<Response<pb::Operation>, Status> {
        let request_id = req.extensions().get::<crate::telemetry::RequestId>().cloned();
        let op = self.observed("Onboard", async { self.api.onboard(convert::onboard_request(req.into_inner())?, request_id).await }).await?;
        Ok(Response::new(convert::operation(op)))
    }

    async fn get_operation(&self, req: Request<pb::GetOperationRequest>) -> Result<Response<pb::Operation>, Status> {
        let op = self.observed("GetOperation", async { self.api.core.operation(&req.into_inner().id) }).await?;
        Ok(Response::new(convert::operation(op)))
    }

    type WatchOperationStream = ReceiverStream<Result<pb::Operation, Status>>;

    async fn watch_operation(&self, req: Request<pb::GetOperationRequest>) -> Result<Response<Self::WatchOperationStream>, Status> {
        let id = req.into_inner().id;
        let mut last = self.observed("WatchOperation", async { self.api.core.operation(&id) }).await?;
        let (tx, rx) = tokio::sync::mpsc::channel(8);
        let core = self.api.core.clone();
        tokio::spawn(tracing::Instrument::in_current_span(async move {
            // Operations keep no subscriber list; polling a few atomics is cheap.
            let mut interval = tokio::time::interval(Duration::from_millis(100));
            if tx.send(Ok(convert::operation(last.clone()))).await.is_err() {
                return;
            }
            while last.state == super::operations::OperationState::Running {
                interval.tick().await;
                let Ok(now) = core.operation(&id) else { break };
                if now.state != last.state || now.templates_done != last.templates_done {
                    if tx.send(Ok(convert::operation(now.clone()))).await.is_err() {
                        return; // the client went away
                    }
                    last = now;
                }
            }
        }));
        Ok(Response::new(ReceiverStream::new(rx)))
    }

    async fn cancel_operation(&self, req: Request<pb::GetOperationRequest>) -> Result<Response<pb::Operation>, Status> {
        let op = self.observed("CancelOperation", async { self.api.core.cancel_operation(&req.into_inner().id) }).await?;
        Ok(Response::new(convert::operation(op)))
    }

    async fn estimate(&self, req: Request<pb::EstimateRequest>) -> Result<Response<pb::EstimateResponse>, Status> {
        let budget = self.api.budget(client_deadline(&req));
        let resp = self.observed("Estimate", async { self.api.estimate(convert::estimate_request(req.into_inner())?, budget).await }).await?;
        Ok(Response::new(convert::estimate_response(resp)))
    }

    async fn detect(&self, req: Request<pb::DetectRequest>) -> Result<Response<pb::DetectResponse>, Status> {
        let budget = self.api.budget(client_deadline(&req));
        let resp = self.observed("Detect", async { self.api.detect(convert::detect_request(req.into_inner())?, budget).await }).await?;
        Ok(Response::new(convert::detect_response(resp)))
    }

    async fn list_objects(&self, _req: Request<pb::ListObjectsRequest>) -> Result<Response<pb::ListObjectsResponse>, Status> {
        let objects = self.observed("ListObjects", self.api.list_objects()).await?;
        Ok(Response::new(pb::ListObjectsResponse { objects: objects.into_iter().map(convert::object_info).collect() }))
    }

    async fn get_object(&self, req: Request<pb::GetObjectRequest>) -> Result<Response<pb::ObjectInfo>, Status> {
        let info = self.observed("GetObject", self.api.get_object(req.into_inner().object_id)).await?;
        Ok(Response::new(convert::object_info(info)))
    }

    type TrackStream = super::grpc_track::TrackStream;

    async fn track(&self, req: Request<tonic::Streaming<pb::TrackFrame>>) -> Result<Response<Self::TrackStream>, Status> {
        Ok(Response::new(super::grpc_track::serve(self.api.clone(), req.into_inner())))
    }

    async fn delete_object(&self, req: Request<pb::GetObjectRequest>) -> Result<Response<pb::DeleteObjectResponse>, Status> {
        self.observed("DeleteObject", self.api.delete_object(req.into_inner().object_id)).await?;
        Ok(Response::new(pb::DeleteObjectResponse {}))
    }
}

/// The request path ("/b2tfpose.v1.PoseService/Estimate"): an interceptor sees only
/// metadata and extensions, and tonic names the method (`GrpcMethod`) only later, inside
/// the generated service.
#[derive(Clone)]
struct RpcPath(String);

/// Puts the `RpcPath` in the extensions, then calls the service.
#[derive(Clone)]
pub struct WithRpcPath<S>(S);

impl<S: tonic::server::NamedService> tonic::server::NamedService for WithRpcPath<S> {
    const NAME: &'static str = S::NAME;
}

impl<S: tower::Service<http::Request<B>>, B> tower::Service<http::Request<B>> for WithRpcPath<S> {
    type Response = S::Response;
    type Error = S::Error;
    type Future = S::Future;

    fn poll_ready(&mut self, cx: &mut std::task::Context<'_>) -> std::task::Poll<Result<(), Self::Error>> {
        self.0.poll_ready(cx)
    }

    fn call(&mut self, mut req: http::Request<B>) -> Self::Future {
        let path = RpcPath(req.uri().path().to_string());
        req.extensions_mut().insert(path);
        self.0.call(req)
    }
}

/// The PoseService with its message size limit and admission (API key, scope, rate limit:
/// access.rs) in front. It runs on the call's headers, before any message is read, for
/// streams (Track, WatchOperation) once when they open. The caller goes on in the
/// request's extensions.
pub fn pose_service(api: Api, max_message_bytes: usize) -> WithRpcPath<tonic::service::interceptor::InterceptedService<PoseServiceServer<GrpcService>, impl tonic::service::Interceptor + Clone>> {
    let admission = api.clone();
    let server = PoseServiceServer::new(GrpcService::new(api)).max_decoding_message_size(max_message_bytes);
    let check = move |mut req: Request<()>| -> Result<Request<()>, Status> {
        let rpc = req.extensions().get::<RpcPath>().map_or_else(|| "unknown".to_string(), |p| p.0.clone());
        let method = rpc.rsplit('/').next().unwrap_or_default();
        let admitted = access::admit(
            &admission,
            &access::Request {
                needs: scopes::grpc(method),
                authorization: req.metadata().get("authorization").and_then(|v| v.to_str().ok()),
                peer: req.remote_addr().map(|a| a.ip()),
                endpoint: &rpc,
                key_hint: "send authorization: Bearer <key> metadata",
            },
        );
        match admitted {
            Ok(caller) => {
                if let Some(c) = caller {
                    // The interceptor runs inside the call's span (grpc_observe.rs).
                    tracing::Span::current().record("api_key", &*c.identity);
                    req.extensions_mut().insert(c);
                }
                Ok(req)
            }
            Err(refused) => {
                admission.metrics.request("grpc", &rpc, &code_name(code_of(&refused.kind)), 0.0);
                Err(refused.into())
            }
        }
    };
    WithRpcPath(tonic::service::interceptor::InterceptedService::new(server, check))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deadline_header() {
        let mut r = Request::new(());
        assert_eq!(client_deadline(&r), None);
        r.metadata_mut().insert("grpc-timeout", "2S".parse().unwrap());
        assert_eq!(client_deadline(&r), Some(Duration::from_millis(1950)));
        r.metadata_mut().insert("grpc-timeout", "200m".parse().unwrap());
        assert_eq!(client_deadline(&r), Some(Duration::from_millis(190)));
        r.metadata_mut().insert("grpc-timeout", "x".parse().unwrap());
        assert_eq!(client_deadline(&r), None);
    }

    #[test]
    fn a_refusal_says_when_to_retry_in_its_metadata() {
        let e: Status = ServiceError::exhausted("queue full", Duration::from_millis(2300)).into();
        assert_eq!((e.code(), e.message()), (Code::ResourceExhausted, "queue full"));
        assert_eq!(e.metadata().get("retry-after-ms").unwrap(), "2300");
        assert_eq!(e.metadata().get("retry-after").unwrap(), "3");
    }
}
