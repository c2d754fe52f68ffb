//! The network service: one core (`core.rs`: store, cache, backbone, render pool,
//! estimator, onboarding operations) and the async calls over it (`api.rs`), behind thin
//! adapters that parse, validate, call and map errors: HTTP/JSON (`http.rs`, axum) and
//! gRPC (`grpc.rs`, tonic, API in `proto/`). `server.rs` runs both listeners. No pipeline
//! logic lives here.

pub mod access;
pub mod access_log;
pub mod api;
pub mod auth;
pub mod base64_bytes;
pub mod client;
pub mod client_ca;
pub mod console;
pub mod core;
pub mod core_detect;
pub mod core_thumbnail;
pub mod core_track;
pub mod depth_input;
pub mod detect_requests;
pub mod error;
pub mod estimate_queue;
pub mod grpc;
pub mod grpc_codes;
pub mod grpc_convert;
pub mod grpc_observe;
pub mod grpc_oversized;
pub mod grpc_track;
pub mod grpc_trailers;
pub mod http;
pub mod http_json;
pub mod http_observe;
pub mod http_track;
pub mod metrics;
pub mod multipart;
pub mod operations;
pub mod proto;
pub mod rate_limit;
pub mod requests;
pub mod scopes;
pub mod server;
pub mod thumbnails;
pub mod tls;
pub mod track_requests;
pub mod track_sessions;
pub mod wire;

pub use self::core::{Core, CoreConfig};
pub use api::Api;
pub use error::{ErrorKind, ServiceError};
