//! The gRPC `Track` stream: one tracking session per stream, frames processed in order, one
//! answer per frame. A bad frame is answered with `error` set and the stream goes on; a
//! frame that cannot even be read (over the message size limit), the session limit and an
//! idle client end the stream with a status. Frames are read one at a time and only after
//! the last answer was queued, and the answer queue is short: a client that stops reading
//! answers stops the server reading frames (HTTP/2 flow control), so nothing piles up.

use super::api::{blocking, Api};
use super::error::ServiceError;
use super::grpc_codes::{code_name, code_of};
use super::grpc_convert as convert;
use super::proto as pb;
use super::track_requests::{TrackFrameRequest, TrackFrameResponse, TrackSessionOptions, TrackedObject};
use std::time::Instant;
use tokio::sync::mpsc::Sender;
use tonic::{Status, Streaming};

/// Answers waiting to be read by the client before the server stops reading frames.
const ANSWERS_QUEUED: usize = 4;
const RPC: &str = "/b2tfpose.v1.PoseService/Track";

pub type TrackStream = tokio_stream::wrappers::ReceiverStream<Result<pb::TrackFrameResult, Status>>;

fn options(o: Option<pb::TrackOptions>) -> TrackSessionOptions {
    let o = o.unwrap_or_default();
    let set = |v: u32| (v > 0).then_some(v as usize);
    TrackSessionOptions { max_tracks: set(o.max_tracks), drop_after_lost: set(o.drop_after_lost), lost_below: o.lost_below }
}

fn frame_request(f: pb::TrackFrame) -> Result<TrackFrameRequest, ServiceError> {
    let image = convert::image(convert::required(f.image, "image")?);
    let intrinsics = convert::intrinsics(convert::required(f.intrinsics, "intrinsics")?);
    Ok(TrackFrameRequest {
        image,
        intrinsics,
        detections: convert::detections(f.detections),
        objects: f.objects,
        detect: convert::detect_options(f.detect),
        frame_index: f.frame_index,
        depth: f.depth.map(convert::depth),
    })
}

fn tracked_object(o: TrackedObject) -> pb::TrackedObject {
    use pb::tracked_object::Mode;
    let mode = match o.mode.as_str() {
        "estimated" => Mode::Estimated,
        "tracked" => Mode::Tracked,
        "reinitialised" => Mode::Reinitialised,
        "lost" => Mode::Lost,
        "dropped" => Mode::Dropped,
        "refused" => Mode::Refused,
        _ => Mode::Unspecified,
    };
    pb::TrackedObject {
        track_id: o.track_id,
        object_id: o.object_id,
        pose: o.pose.map(convert::pose),
        quality: o.quality,
        mode: mode as i32,
        detection_index: o.detection_index.map_or(-1, |d| d as i32),
        ms: o.ms,
        reason: o.reason.unwrap_or_default(),
        depth_fit: o.depth_fit.map(|f| pb::DepthFit {
            points: f.points as u32,
            measured_share: f.measured_share,
            inlier_share: f.inlier_share,
            free_space_share: f.free_space_share,
            occluded_share: f.occluded_share,
            rms_mm: f.rms_mm.unwrap_or(f64::NAN),
            tolerance_mm: f.tolerance_mm,
            moved_mm: f.moved_mm,
        }),
        timings_ms: o.timings_ms.into_iter().collect(),
    }
}

fn answer(session_id: &str, r: Result<TrackFrameResponse, ServiceError>) -> pb::TrackFrameResult {
    match r {
        Ok(r) => pb::TrackFrameResult { frame_index: r.frame_index, objects: r.objects.into_iter().map(tracked_object).collect(), total_ms: r.total_ms, error: None, session_id: session_id.into() },
        Err(e) => pb::TrackFrameResult { error: Some(pb::FrameError { code: code_name(code_of(&e.kind)), message: e.message }), session_id: session_id.into(), ..Default::default() },
    }
}

/// Closes the stream's session however the stream ends.
struct SessionGuard(Api, String);

impl Drop for SessionGuard {
    fn drop(&mut self) {
        let _ = self.0.core.close_track(&self.1);
    }
}

/// Starts serving one stream; the answers come through the returned stream.
pub fn serve(api: Api, inbound: Streaming<pb::TrackFrame>) -> TrackStream {
    let (tx, rx) = tokio::sync::mpsc::channel(ANSWERS_QUEUED);
    // The stream's frames are served in the call's span: one request id for the stream.
    tokio::spawn(tracing::Instrument::in_current_span(run(api, inbound, tx)));
    TrackStream::new(rx)
}

async fn run(api: Api, mut inbound: Streaming<pb::TrackFrame>, tx: Sender<Result<pb::TrackFrameResult, Status>>) {
    let idle = api.core.config.track_idle_timeout;
    let mut session: Option<SessionGuard> = None;
    loop {
        let frame = match tokio::time::timeout(idle, inbound.message()).await {
            Err(_) => {
                let _ = tx.send(Err(Status::deadline_exceeded(format!("no frame for {} s: the tracking stream is closed", idle.as_secs_f64())))).await;
                return;
            }
            Ok(Ok(None)) => return, // the client finished sending
            Ok(Err(status)) => {
                // An unreadable message (e.g. over the size limit) ends the stream.
                let _ = tx.send(Err(status)).await;
                return;
            }
            Ok(Ok(Some(frame))) => frame,
        };
        let started = Instant::now();
        if session.is_none() {
            let opened = api.core.open_track(&options(frame.options), true);
            match opened {
                Ok(info) => session = Some(SessionGuard(api.clone(), info.id)),
                Err(e) => {
                    api.metrics.request("grpc", RPC, &code_name(code_of(&e.kind)), started.elapsed().as_secs_f64());
                    let _ = tx.send(Err(Status::from(e))).await;
                    return;
                }
            }
        }
        let id = session.as_ref().map(|s| s.1.clone()).unwrap_or_default();
        let result = match frame_request(frame) {
            Ok(req) => {
                let (core, id) = (api.core.clone(), id.clone());
                blocking(move || core.track_frame(&id, &req)).await
            }
            Err(e) => Err(e),
        };
        let code = result.as_ref().map_or_else(|e| code_name(code_of(&e.kind)), |_| "OK".to_string());
        tracing::debug!(code, frame = result.as_ref().ok().map(|r| r.frame_index), ms = started.elapsed().as_secs_f64() * 1e3, "frame answered");
        api.metrics.request("grpc", RPC, &code, started.elapsed().as_secs_f64());
        if let Ok(r) = &result {
            api.metrics.track_frame(r.objects.iter().map(|o| o.mode.as_str()));
        }
        if tx.send(Ok(answer(&id, result))).await.is_err() {
            return; // the client went away
        }
    }
}
