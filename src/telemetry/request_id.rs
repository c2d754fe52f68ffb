//! Request ids: the client's `x-request-id` when it is sane, a fresh random one otherwise.
//! Every response carries it back and every log line of the request has it.

/// The header (and gRPC metadata key) both ways.
pub const HEADER: &str = "x-request-id";

/// Longest client id taken as it is.
const MAX_LEN: usize = 64;

#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RequestId(String);

impl RequestId {
    /// The client's id if it is 1–64 characters of `[A-Za-z0-9._:-]` (safe in a header, a
    /// log line and a file name), else a new one.
    pub fn from_client(value: Option<&[u8]>) -> Self {
        match value {
            Some(v) if Self::sane(v) => Self(String::from_utf8_lossy(v).into_owned()),
            _ => Self::generate(),
        }
    }

    fn sane(v: &[u8]) -> bool {
        !v.is_empty() && v.len() <= MAX_LEN && v.iter().all(|&c| c.is_ascii_alphanumeric() || matches!(c, b'.' | b'_' | b':' | b'-'))
    }

    /// 128 random bits in hex. Without an OS random source (never on Linux) the clock and a
    /// counter still keep ids of one process apart.
    pub fn generate() -> Self {
        let mut bytes = [0u8; 16];
        if getrandom::fill(&mut bytes).is_err() {
            static COUNTER: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
            let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos() as u64);
            bytes[..8].copy_from_slice(&nanos.to_le_bytes());
            bytes[8..].copy_from_slice(&COUNTER.fetch_add(1, std::sync::atomic::Ordering::Relaxed).to_le_bytes());
        }
        Self(bytes.iter().map(|b| format!("{b:02x}")).collect())
    }

    pub fn as_str(&self) -> &str {
        &self.0
    }

    /// As a header value (always valid: the characters are checked or generated).
    pub fn header_value(&self) -> http::HeaderValue {
        http::HeaderValue::from_str(&self.0).expect("request ids are header-safe")
    }
}

impl std::fmt::Display for RequestId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sane_client_ids_are_kept_others_replaced() {
        assert_eq!(RequestId::from_client(Some(b"trace-01:abc_D.e")).as_str(), "trace-01:abc_D.e");
        let long = "a".repeat(64);
        assert_eq!(RequestId::from_client(Some(long.as_bytes())).as_str(), long);
        for bad in [&b""[..], b"has space", b"new\nline", "é".as_bytes(), "a".repeat(65).as_bytes(), b"{\"x\":1}"] {
            let id = RequestId::from_client(Some(bad));
            assert_eq!(id.as_str().len(), 32, "{bad:?} → {id}");
            assert!(id.as_str().bytes().all(|c| c.is_ascii_hexdigit()));
        }
        assert_ne!(RequestId::generate(), RequestId::generate());
    }
}
