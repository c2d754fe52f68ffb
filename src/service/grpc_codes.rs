//! How the service's errors read in gRPC: the status code of each error kind, the
//! metadata a refusal carries (retry-after), and the codes' names for metrics and
//! per-frame errors. Shared by the unary RPCs (`grpc`) and the tracking stream
//! (`grpc_track`).

use super::error::{ErrorKind, ServiceError};
use tonic::{Code, Status};

pub fn code_of(kind: &ErrorKind) -> Code {
    match kind {
        ErrorKind::InvalidArgument | ErrorKind::TooLarge => Code::InvalidArgument,
        ErrorKind::Unauthenticated => Code::Unauthenticated,
        ErrorKind::PermissionDenied => Code::PermissionDenied,
        ErrorKind::NotFound => Code::NotFound,
        ErrorKind::AlreadyExists => Code::AlreadyExists,
        ErrorKind::ResourceExhausted => Code::ResourceExhausted,
        ErrorKind::Unavailable => Code::Unavailable,
        ErrorKind::DeadlineExceeded => Code::DeadlineExceeded,
        ErrorKind::Internal => Code::Internal,
    }
}

impl From<ServiceError> for Status {
    fn from(e: ServiceError) -> Self {
        let mut meta = tonic::metadata::MetadataMap::new();
        if let (Some(ms), Some(secs)) = (e.retry_after_ms, e.retry_after_secs()) {
            meta.insert("retry-after", secs.into());
            meta.insert("retry-after-ms", ms.into());
        }
        Status::with_metadata(code_of(&e.kind), e.message, meta)
    }
}

/// The canonical upper-snake name of a code, as gRPC's documentation spells it.
pub fn code_name(code: Code) -> String {
    let mut out = String::new();
    for (i, ch) in format!("{code:?}").chars().enumerate() {
        if ch.is_uppercase() && i > 0 {
            out.push('_');
        }
        out.push(ch.to_ascii_uppercase());
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn code_names_and_statuses() {
        assert_eq!(code_name(Code::Ok), "OK");
        assert_eq!(code_name(Code::InvalidArgument), "INVALID_ARGUMENT");
        assert_eq!(code_name(Code::ResourceExhausted), "RESOURCE_EXHAUSTED");
        let e: Status = ServiceError::new(ErrorKind::TooLarge, "big").into();
        assert_eq!(e.code(), Code::InvalidArgument);
        assert!(e.metadata().get("retry-after-ms").is_none());
    }
}
