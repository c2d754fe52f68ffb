//! A gRPC response body whose trailers pass through a function on the way out: the status
//! of a successful or streamed call travels there, not in the response headers.

use http::HeaderMap;
use http_body::{Body, Frame};
use std::pin::Pin;
use std::task::{Context, Poll};

pub struct TrailersHook<B, F> {
    body: B,
    hook: F,
}

impl<B, F: FnMut(&mut HeaderMap)> TrailersHook<B, F> {
    pub fn new(body: B, hook: F) -> Self {
        Self { body, hook }
    }
}

impl<B: Body + Unpin, F: FnMut(&mut HeaderMap) + Unpin> Body for TrailersHook<B, F> {
    type Data = B::Data;
    type Error = B::Error;

    fn poll_frame(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Result<Frame<Self::Data>, Self::Error>>> {
        let this = &mut *self;
        match Pin::new(&mut this.body).poll_frame(cx) {
            Poll::Ready(Some(Ok(frame))) => Poll::Ready(Some(Ok(match frame.into_trailers() {
                Ok(mut trailers) => {
                    (this.hook)(&mut trailers);
                    Frame::trailers(trailers)
                }
                Err(frame) => frame,
            }))),
            other => other,
        }
    }

    fn is_end_stream(&self) -> bool {
        self.body.is_end_stream()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        self.body.size_hint()
    }
}
