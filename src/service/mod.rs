//! The network service: one core (`core.rs`: store, cache, backbone, render pool,
//! estimator, onboarding operations) behind thin adapters that parse, validate, call the
//! core and map errors (`http.rs`; gRPC to follow). No pipeline logic lives here.

pub mod auth;
pub mod core;
pub mod error;
pub mod http;
pub mod metrics;
pub mod operations;
pub mod requests;

pub use self::core::{Core, CoreConfig};
pub use error::{ErrorKind, ServiceError};
