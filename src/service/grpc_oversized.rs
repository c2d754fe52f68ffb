//! tonic answers a request message over the size limit with OUT_OF_RANGE ("decoded
//! message length too large"); the API promises INVALID_ARGUMENT for every oversized
//! request (413 over HTTP). The status travels in the response headers (trailers-only
//! answers) or in the body's trailers, so both are rewritten on the way out. The message
//! is percent-encoded on the wire.

use super::grpc_trailers::TrailersHook;
use http::{HeaderMap, HeaderValue};

fn rewrite(headers: &mut HeaderMap) {
    let out_of_range = headers.get("grpc-status").is_some_and(|v| v.as_bytes() == b"11");
    let too_large = headers.get("grpc-message").and_then(|v| v.to_str().ok()).is_some_and(|m| m.contains("too large") || m.contains("too%20large"));
    if out_of_range && too_large {
        headers.insert("grpc-status", HeaderValue::from_static("3"));
    }
}

/// A response whose trailers pass through a header rewrite.
pub type RewrittenTrailers<B> = http::Response<TrailersHook<B, fn(&mut HeaderMap)>>;

pub fn oversized_to_invalid_argument<B>(resp: http::Response<B>) -> RewrittenTrailers<B> {
    let (mut parts, body) = resp.into_parts();
    rewrite(&mut parts.headers);
    http::Response::from_parts(parts, TrailersHook::new(body, rewrite))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_the_too_large_out_of_range_changes() {
        let mut h = HeaderMap::new();
        h.insert("grpc-status", HeaderValue::from_static("11"));
        h.insert("grpc-message", HeaderValue::from_static("Error,%20decoded%20message%20length%20too%20large:%20found%204%20bytes"));
        rewrite(&mut h);
        assert_eq!(h["grpc-status"], "3");
        let mut other = HeaderMap::new();
        other.insert("grpc-status", HeaderValue::from_static("11"));
        other.insert("grpc-message", HeaderValue::from_static("index out of range"));
        rewrite(&mut other);
        assert_eq!(other["grpc-status"], "11");
    }
}
