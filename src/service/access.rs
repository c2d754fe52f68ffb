//! Admission, the one check both adapters make before any work: the API key (401 /
//! UNAUTHENTICATED), its scope for the endpoint (403 / PERMISSION_DENIED, naming the scope,
//! never the key), then the caller's rate limit (429 / RESOURCE_EXHAUSTED with the wait).
//! Health checks skip all three. The rate limit is per key identity, or per client address
//! when no keys are configured.

use super::api::Api;
use super::auth::Caller;
use super::error::{ErrorKind, ServiceError};
use super::rate_limit::peer_client;
use super::scopes::Needs;
use std::net::IpAddr;

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

/// The caller (when keys are configured) if the request may go on; a rate limit's
/// refusal says when to come back (`ServiceError::retry_after_ms`).
pub fn admit(api: &Api, r: &Request) -> Result<Option<Caller>, ServiceError> {
    if r.needs == Needs::Nothing {
        return Ok(None);
    }
    let caller = if api.keys.enabled() {
        let c = api.keys.authenticate(r.authorization).ok_or_else(|| ServiceError::new(ErrorKind::Unauthenticated, format!("missing or unknown API key ({})", r.key_hint)))?;
        if let Needs::Scope(s) = r.needs {
            if !c.scopes.has(s) {
                tracing::debug!(endpoint = r.endpoint, key = %c.identity, scope = s.name(), "refused: the key lacks the scope");
                return Err(ServiceError::new(ErrorKind::PermissionDenied, format!("this API key lacks the `{}` scope, which {} needs", s.name(), r.endpoint)));
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
            let spec = limiter.spec();
            let mut refused = ServiceError::exhausted("", wait);
            let secs = refused.retry_after_secs().unwrap_or(1);
            refused.message = format!("rate limit of {} requests/s (burst {}) reached for {whose}; retry in {secs} s", spec.rate, spec.burst);
            return Err(refused);
        }
    }
    if let Some(c) = &caller {
        api.metrics.key_request(&c.identity);
    }
    Ok(caller)
}
