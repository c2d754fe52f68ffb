//! tonic answers a request message over the size limit with OUT_OF_RANGE ("decoded
//! message length too large"); the API promises INVALID_ARGUMENT for every oversized
//! request (413 over HTTP). The status travels in the response headers (trailers-only
//! answers) or in the body's trailers, so both are rewritten on the way out. The message
//! is percent-encoded on the wire.

use http::{HeaderMap, HeaderValue};
use http_body::{Body, Frame};
use std::pin::Pin;
use std::task::{Context, Poll};

fn rewrite(headers: &mut HeaderMap) {
    let out_of_range = headers.get("grpc-status").is_some_and(|v| v.as_bytes() == b"11");
    let too_large = headers.get("grpc-message").and_then(|v| v.to_str().ok()).is_some_and(|m| m.contains("too large") || m.contains("too%20large"));
    if out_of_range && too_large {
        headers.insert("grpc-status", HeaderValue::from_static("3"));
    }
}

/// A response body whose trailers get the rewrite.
pub struct RewrittenBody<B>(B);

impl<B: Body + Unpin> Body for RewrittenBody<B> {
    type Data = B::Data;
    type Error = B::Error;

    fn poll_frame(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Result<Frame<Self::Data>, Self::Error>>> {
        match Pin::new(&mut self.0).poll_frame(cx) {
            Poll::Ready(Some(Ok(frame))) => Poll::Ready(Some(Ok(match frame.into_trailers() {
                Ok(mut trailers) => {
                    rewrite(&mut trailers);
                    Frame::trailers(trailers)
                }
                Err(frame) => frame,
            }))),
            other => other,
        }
    }

    fn is_end_stream(&self) -> bool {
        self.0.is_end_stream()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        self.0.size_hint()
    }
}

pub fn oversized_to_invalid_argument<B>(resp: http::Response<B>) -> http::Response<RewrittenBody<B>> {
    let (mut parts, body) = resp.into_parts();
    rewrite(&mut parts.headers);
    http::Response::from_parts(parts, RewrittenBody(body))
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
