//! The outermost gRPC layer (every service: PoseService, health, reflection): each call
//! gets its id (the client's `x-request-id` metadata when sane), a span the handler runs
//! in, the id back in the response headers and, for answers whose status comes at the end
//! (successes, streams), in the trailers too, so a client's error `Status` carries it
//! whichever way it came. The access-log line is written when the status is known: in the
//! headers of an immediate error, else in the trailers, so a stream's line comes at its end.

use super::access_log::{request_span, Access};
use super::grpc_codes::code_name;
use super::grpc_trailers::TrailersHook;
use crate::telemetry::request_id::{RequestId, HEADER};
use http::{HeaderMap, Request, Response};
use std::future::Future;
use std::net::SocketAddr;
use std::pin::Pin;
use std::task::{Context, Poll};
use tonic::transport::server::{TcpConnectInfo, TlsConnectInfo};
use tracing::Instrument;

#[derive(Clone, Copy, Default)]
pub struct ObserveLayer;

impl<S> tower::Layer<S> for ObserveLayer {
    type Service = Observe<S>;
    fn layer(&self, inner: S) -> Observe<S> {
        Observe(inner)
    }
}

#[derive(Clone)]
pub struct Observe<S>(S);

/// What the trailers hook does: the id in, the status out to the access log.
pub type Hook = Box<dyn FnMut(&mut HeaderMap) + Send + Sync>;

fn peer<B>(req: &Request<B>) -> Option<SocketAddr> {
    let ext = req.extensions();
    ext.get::<TcpConnectInfo>().and_then(TcpConnectInfo::remote_addr).or_else(|| ext.get::<TlsConnectInfo<TcpConnectInfo>>().and_then(|t| t.get_ref().remote_addr()))
}

/// The status's code name ("OK", "NOT_FOUND"), if these headers hold one.
fn status_of(headers: &HeaderMap) -> Option<String> {
    let n: i32 = headers.get("grpc-status")?.to_str().ok()?.parse().ok()?;
    Some(code_name(tonic::Code::from_i32(n)))
}

impl<S, B, R> tower::Service<Request<B>> for Observe<S>
where
    S: tower::Service<Request<B>, Response = Response<R>>,
    S::Future: Send + 'static,
{
    type Response = Response<TrailersHook<R, Hook>>;
    type Error = S::Error;
    type Future = Pin<Box<dyn Future<Output = Result<Self::Response, S::Error>> + Send>>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), S::Error>> {
        self.0.poll_ready(cx)
    }

    fn call(&mut self, mut req: Request<B>) -> Self::Future {
        let id = RequestId::from_client(req.headers().get(HEADER).map(|v| v.as_bytes()));
        let rpc = req.uri().path().to_string();
        let span = request_span(&id, "grpc", "grpc", Some(&rpc), peer(&req));
        let mut access = Access::new(span.clone(), &rpc);
        req.extensions_mut().insert(id.clone());
        let call = span.in_scope(|| self.0.call(req)).instrument(span);
        Box::pin(async move {
            let (mut parts, body) = call.await?.into_parts();
            parts.headers.insert(HEADER, id.header_value());
            // A trailers-only answer (an immediate error) has its status here.
            if let Some(status) = status_of(&parts.headers) {
                access.finish(&status, None, None);
            }
            let hook: Hook = Box::new(move |trailers: &mut HeaderMap| {
                trailers.insert(HEADER, id.header_value());
                if let Some(status) = status_of(trailers) {
                    access.finish(&status, None, None);
                }
            });
            Ok(Response::from_parts(parts, TrailersHook::new(body, hook)))
        })
    }
}
