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
}

impl ServiceError {
    pub fn new(kind: ErrorKind, message: impl Into<String>) -> Self {
        Self { kind, message: message.into() }
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
