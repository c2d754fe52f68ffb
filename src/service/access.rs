//! Admission, the one check both adapters make before any work: the API key (401 /
//! UNAUTHENTICATED), its scope for the endpoint (403 / PERMISSION_DENIED, naming the scope,
//! never the key), then the caller's rate limit (429 / RESOURCE_EXHAUSTED with the wait).
//! Health checks skip all three. The rate limit is per key identity, or per client address
//! when no keys are configured.

use super::api::Api;
use super::auth::Caller;
use super::error::{ErrorKind, ServiceError};
use super::rate_limit::{peer_client, retry_after_secs};
use super::scopes::Needs;
use std::net::IpAddr;

/// Why a request is turned away, and for a rate limit when to come back (seconds).
#[derive(Debug)]
pub struct Refused {
    pub error: ServiceError,
    pub retry_after: Option<u64>,
}

impl From<ServiceError> for Refused {
    fn from(error: ServiceError) -> Self {
        Self { error, retry_after: None }
    }
}

pub struct Request<'a> {
    pub needs: Needs,
    /// The `Authorization` header or metadata value.
    pub authorization: Option<&'a str>,
    pub peer: Option<IpAddr>,
    /// The endpoint in messages: "POST /v1/objects", "/b2tfpose.v1.PoseService/Onboard".
    pub endpoint: &'a str,
    /// How to send a key, for the 401 message of this protocol.
    pub key_hint: &'a str,
}

/// The caller (when keys are configured) if the request may go on.
pub fn admit(api: &Api, r: &Request) -> Result<Option<Caller>, Refused> {
    if r.needs == Needs::Nothing {
        return Ok(None);
    }
    let caller = if api.keys.enabled() {
        let c = api.keys.authenticate(r.authorization).ok_or_else(|| ServiceError::new(ErrorKind::Unauthenticated, format!("missing or unknown API key ({})", r.key_hint)))?;
        if let Needs::Scope(s) = r.needs {
            if !c.scopes.has(s) {
                tracing::debug!(endpoint = r.endpoint, key = %c.identity, scope = s.name(), "refused: the key lacks the scope");
                return Err(ServiceError::new(ErrorKind::PermissionDenied, format!("this API key lacks the `{}` scope, which {} needs", s.name(), r.endpoint)).into());
            }
        }
        Some(c)
    } else {
        None
    };
    if let Some(limiter) = &api.rate {
        let (client, label, whose) = match (&caller, r.peer) {
            (Some(c), _) => (format!("key:{}", c.identity), &*c.identity, "this API key"),
            (None, Some(ip)) => (peer_client(ip), "address", "this client address"),
            (None, None) => ("unknown".to_string(), "address", "this client"),
        };
        if let Err(wait) = limiter.check(&client) {
            api.metrics.rate_limited(label);
            let secs = retry_after_secs(wait);
            let spec = limiter.spec();
            let msg = format!("rate limit of {} requests/s (burst {}) reached for {whose}; retry in {secs} s", spec.rate, spec.burst);
            return Err(Refused { error: ServiceError::new(ErrorKind::ResourceExhausted, msg), retry_after: Some(secs) });
        }
    }
    if let Some(c) = &caller {
        api.metrics.key_request(&c.identity);
    }
    Ok(caller)
}
