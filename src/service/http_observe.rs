//! The outermost HTTP middleware: every request gets its id (the client's `x-request-id`
//! when sane), a span that every handler, blocking worker and log line of the request runs
//! in, the id back in the response's `x-request-id` (errors, 404s, 413s and health checks
//! included) and one access-log line.

use super::access_log::{request_span, Access};
use crate::telemetry::request_id::{RequestId, HEADER};
use axum::extract::{ConnectInfo, Request};
use axum::http::header;
use axum::middleware::Next;
use axum::response::Response;
use http_body::Body as _;
use std::net::SocketAddr;
use tracing::Instrument;

/// The client's address, for both listeners (axum's own `SocketAddr` connect info only
/// covers its TCP listener, not ours with TLS).
#[derive(Clone, Copy, Debug)]
pub struct Peer(pub SocketAddr);

macro_rules! peer_of {
    ($listener:ty) => {
        impl axum::extract::connect_info::Connected<axum::serve::IncomingStream<'_, $listener>> for Peer {
            fn connect_info(stream: axum::serve::IncomingStream<'_, $listener>) -> Self {
                Peer(*stream.remote_addr())
            }
        }
    };
}
peer_of!(tokio::net::TcpListener);
peer_of!(super::tls::TlsListener);

pub async fn observe(mut req: Request, next: Next) -> Response {
    let id = RequestId::from_client(req.headers().get(HEADER).map(|v| v.as_bytes()));
    let peer = req.extensions().get::<ConnectInfo<Peer>>().map(|c| c.0 .0);
    // The route template is only known after routing: `guard` records it.
    let span = request_span(&id, "http", req.method().as_str(), None, peer);
    let request_bytes = req.headers().get(header::CONTENT_LENGTH).and_then(|v| v.to_str().ok()).and_then(|v| v.parse().ok());
    let path = req.uri().path();
    // Object ids and typos, nothing secret; bounded so a long URI cannot bloat the log.
    span.record("path", &path[..path.floor_char_boundary(120)]);
    let mut access = Access::new(span.clone(), path);
    req.extensions_mut().insert(id.clone());
    let mut resp = next.run(req).instrument(span).await;
    resp.headers_mut().insert(HEADER, id.header_value());
    access.finish(resp.status().as_str(), request_bytes, resp.body().size_hint().exact());
    resp
}
