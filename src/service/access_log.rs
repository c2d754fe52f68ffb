//! What both adapters record of every request: its span (`request`, with the request id,
//! so every line logged while serving it has the id) and one access-log line when it ends
//! (target `b2tfpose::access`). Neither holds bodies, headers or keys: only the method,
//! route, peer, status, duration and sizes.

use crate::telemetry::RequestId;
use std::net::SocketAddr;
use std::time::Instant;
use tracing::field::Empty;
use tracing::Span;

/// The span of one request. `route`: the route template or RPC path when known now (HTTP
/// records it after routing, and the raw `path` too). `api_key`: the identity of the key
/// that admitted the request (its `name=` or digest prefix, never the key), recorded by
/// the admission check.
pub fn request_span(id: &RequestId, proto: &'static str, method: &str, route: Option<&str>, peer: Option<SocketAddr>) -> Span {
    tracing::info_span!("request", request_id = %id, proto, method, route, peer = peer.map(tracing::field::display), path = Empty, api_key = Empty, status = Empty, ms = Empty)
}

/// Probes and scrapes come every few seconds; at info they would drown the requests.
fn routine(route: &str) -> bool {
    matches!(route, "/healthz" | "/readyz" | "/metrics") || route.starts_with("/grpc.health.v1.") || route.starts_with("/grpc.reflection.")
}

/// The access-log line of one request, written once by `finish` (or, for a call whose
/// answer was never finished, when dropped: the client went away).
pub struct Access {
    span: Span,
    started: Instant,
    routine: bool,
    done: bool,
}

impl Access {
    pub fn new(span: Span, route: &str) -> Self {
        Self { span, started: Instant::now(), routine: routine(route), done: false }
    }

    /// Writes the line; `status`: the HTTP code or the gRPC code's name. The status and
    /// duration also become fields of the span (for the exported trace).
    pub fn finish(&mut self, status: &str, request_bytes: Option<u64>, response_bytes: Option<u64>) {
        if std::mem::replace(&mut self.done, true) {
            return;
        }
        let ms = (self.started.elapsed().as_secs_f64() * 1e4).round() / 10.0;
        self.span.in_scope(|| {
            if self.routine {
                tracing::debug!(target: "b2tfpose::access", status, ms, request_bytes, response_bytes, "request finished");
            } else {
                tracing::info!(target: "b2tfpose::access", status, ms, request_bytes, response_bytes, "request finished");
            }
        });
        self.span.record("status", status);
        self.span.record("ms", ms);
    }
}

impl Drop for Access {
    fn drop(&mut self) {
        self.finish("CANCELLED", None, None);
    }
}
