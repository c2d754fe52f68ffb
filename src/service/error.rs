//! The errors a request can end in, one kind per status: the HTTP and gRPC adapters map
//! each kind to their own code, so both report the same failure the same way.

#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ErrorKind {
    /// 400 / INVALID_ARGUMENT
    InvalidArgument,
    /// 401 / UNAUTHENTICATED
    Unauthenticated,
    /// 403 / PERMISSION_DENIED
    PermissionDenied,
    /// 404 / NOT_FOUND
    NotFound,
    /// 409 / ALREADY_EXISTS
    AlreadyExists,
    /// 413 / INVALID_ARGUMENT (too large)
    TooLarge,
    /// 429 / RESOURCE_EXHAUSTED
    ResourceExhausted,
    /// 503 / UNAVAILABLE
    Unavailable,
    /// 504 / DEADLINE_EXCEEDED
    DeadlineExceeded,
    /// 500 / INTERNAL
    Internal,
}

#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, thiserror::Error)]
#[error("{message}")]
pub struct ServiceError {
    pub kind: ErrorKind,
    pub message: String,
    /// For a refusal that will pass (a rate limit, a full estimate queue): when to come
    /// back, in ms. HTTP sends it as `Retry-After` (whole seconds) and `retry-after-ms`,
    /// gRPC as `retry-after` / `retry-after-ms` metadata, and the JSON error body has it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub retry_after_ms: Option<u64>,
}

impl ServiceError {
    pub fn new(kind: ErrorKind, message: impl Into<String>) -> Self {
        Self { kind, message: message.into(), retry_after_ms: None }
    }
    /// A 429 / RESOURCE_EXHAUSTED that says when to retry.
    pub fn exhausted(message: impl Into<String>, retry_after: std::time::Duration) -> Self {
        let ms = u64::try_from(retry_after.as_millis()).unwrap_or(u64::MAX).max(1);
        Self { kind: ErrorKind::ResourceExhausted, message: message.into(), retry_after_ms: Some(ms) }
    }
    /// The `Retry-After` header's whole seconds (rounded up, at least 1).
    pub fn retry_after_secs(&self) -> Option<u64> {
        self.retry_after_ms.map(|ms| ms.div_ceil(1000).max(1))
    }
    pub fn invalid(message: impl Into<String>) -> Self {
        Self::new(ErrorKind::InvalidArgument, message)
    }
    pub fn not_found(message: impl Into<String>) -> Self {
        Self::new(ErrorKind::NotFound, message)
    }
    pub fn internal(message: impl Into<String>) -> Self {
        Self::new(ErrorKind::Internal, message)
    }
}

impl From<crate::store::StoreError> for ServiceError {
    fn from(e: crate::store::StoreError) -> Self {
        use crate::store::StoreError as S;
        let kind = match &e {
            S::BadId(_) => ErrorKind::InvalidArgument,
            S::NotFound(_) => ErrorKind::NotFound,
            S::AlreadyExists(_) => ErrorKind::AlreadyExists,
            S::ReadOnly(_) => ErrorKind::PermissionDenied,
            // The store's server is down or refuses us: worth retrying, not a bug here.
            S::Remote { .. } => ErrorKind::Unavailable,
            _ => ErrorKind::Internal,
        };
        Self::new(kind, e.to_string())
    }
}

impl From<crate::estimate::EstimateError> for ServiceError {
    fn from(e: crate::estimate::EstimateError) -> Self {
        use crate::estimate::EstimateError as E;
        let kind = match &e {
            E::BadInput(_) | E::BackboneMismatch { .. } => ErrorKind::InvalidArgument,
            _ => ErrorKind::Internal,
        };
        Self::new(kind, e.to_string())
    }
}

/// The answer to a request that ran past its deadline (`budget`).
pub fn deadline_exceeded(budget: std::time::Duration) -> ServiceError {
    ServiceError::new(ErrorKind::DeadlineExceeded, format!("the request did not finish within its deadline of {} ms", budget.as_millis()))
}
