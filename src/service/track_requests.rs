//! The tracking API's messages as plain serde types (HTTP bodies; the gRPC stream maps its
//! protobuf messages onto the same): opening a session, one frame in, one pose per tracked
//! object out, and a session's state.

use super::error::ServiceError;
use super::requests::{DetectionInput, ImageInput, IntrinsicsInput, PoseOutput};
use crate::estimate::depth_fit::DepthFit;
use crate::track::{SessionConfig, TrackOutcome};

/// Options of a new session; every field optional.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrackSessionOptions {
    /// Objects tracked at once (1–32; default 8).
    pub max_tracks: Option<usize>,
    /// Consecutive lost frames before a track is dropped (default 30).
    pub drop_after_lost: Option<usize>,
    /// Outline agreement (0–1) under which a frame is lost (default 0.3).
    pub lost_below: Option<f64>,
}

pub const MAX_TRACKS_PER_SESSION: usize = 32;

impl TrackSessionOptions {
    pub fn config(&self) -> Result<SessionConfig, ServiceError> {
        let mut c = SessionConfig::default();
        if let Some(n) = self.max_tracks {
            if n == 0 || n > MAX_TRACKS_PER_SESSION {
                return Err(ServiceError::invalid(format!("options.max_tracks must be 1–{MAX_TRACKS_PER_SESSION}, not {n}")));
            }
            c.max_tracks = n;
        }
        if let Some(n) = self.drop_after_lost {
            if n == 0 {
                return Err(ServiceError::invalid("options.drop_after_lost must be at least 1"));
            }
            c.drop_after_lost = n;
        }
        if let Some(q) = self.lost_below {
            if !(0.0..=1.0).contains(&q) {
                return Err(ServiceError::invalid(format!("options.lost_below must be in [0, 1], not {q}")));
            }
            c.tracker.lost_below = q;
        }
        Ok(c)
    }
}

#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct OpenTrackRequest {
    pub options: TrackSessionOptions,
}

/// One video frame.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct TrackFrameRequest {
    pub image: ImageInput,
    pub intrinsics: IntrinsicsInput,
    /// Detections in this frame: one that no track explains starts a track; one over a
    /// lost track re-initialises it. None needed while tracking goes well.
    #[serde(default)]
    pub detections: Vec<DetectionInput>,
    /// Instead of detections: objects the server's detector looks for in this frame, each
    /// only while the session has no track of it that was followed in the last frame (so
    /// a tracked object costs no search; a new or lost one is found and started or
    /// re-initialised).
    #[serde(default, deserialize_with = "crate::limits::bounded_vec::<_, _, { crate::limits::MAX_DETECT_OBJECTS }>")]
    pub objects: Vec<String>,
    /// The detector's settings for `objects`.
    #[serde(default)]
    pub detect: crate::detect::DetectOptions,
    /// The frame's number; when given it must be above the last one (else the next).
    #[serde(default)]
    pub frame_index: Option<u64>,
    /// The depth camera's frame registered to `image` (RGB-D, as in an estimate): tracks
    /// are then fitted to the measured surface and lost where it refutes them.
    #[serde(default)]
    pub depth: Option<super::depth_input::DepthInput>,
}

/// One object in one frame.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct TrackedObject {
    /// The track's number in the session (absent for a refused detection).
    pub track_id: Option<u32>,
    pub object_id: String,
    pub pose: Option<PoseOutput>,
    pub quality: f64,
    /// estimated | tracked | reinitialised | lost | dropped | refused
    pub mode: String,
    /// Index into this frame's detections of the one used, if any.
    pub detection_index: Option<usize>,
    pub ms: f64,
    pub reason: Option<String>,
    /// How the pose lies on the measured surface, on frames tracked with depth.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth_fit: Option<DepthFitOutput>,
    /// The tracking step's stage times, ms (colours, contour, photometric, depth, relearn,
    /// total), on frames the track was followed from the last one; empty for a new track
    /// or a refused detection.
    #[serde(default)]
    pub timings_ms: std::collections::BTreeMap<String, f64>,
}

/// `estimate::depth_fit::DepthFit` as answers carry it.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct DepthFitOutput {
    pub points: usize,
    pub measured_share: f64,
    pub inlier_share: f64,
    pub free_space_share: f64,
    pub occluded_share: f64,
    /// NaN (null) without inliers.
    pub rms_mm: Option<f64>,
    pub tolerance_mm: f64,
    pub moved_mm: f64,
}

impl From<&DepthFit> for DepthFitOutput {
    fn from(f: &DepthFit) -> Self {
        Self {
            points: f.points,
            measured_share: f.measured_share,
            inlier_share: f.inlier_share,
            free_space_share: f.free_space_share,
            occluded_share: f.occluded_share,
            rms_mm: f.rms_mm.is_finite().then_some(f.rms_mm),
            tolerance_mm: f.tolerance_mm,
            moved_mm: f.moved_mm,
        }
    }
}

impl From<TrackOutcome> for TrackedObject {
    fn from(o: TrackOutcome) -> Self {
        Self {
            track_id: o.track_id,
            object_id: o.object_id,
            pose: o.pose.as_ref().map(PoseOutput::from),
            quality: o.quality,
            mode: o.mode.as_str().to_string(),
            detection_index: o.detection_index,
            ms: o.ms,
            reason: o.reason,
            depth_fit: o.depth_fit.as_ref().map(DepthFitOutput::from),
            timings_ms: o.timings.map(|t| t.by_stage()).unwrap_or_default(),
        }
    }
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct TrackFrameResponse {
    pub frame_index: u64,
    pub objects: Vec<TrackedObject>,
    /// The whole frame on the server, decoding included, milliseconds.
    pub total_ms: f64,
}

/// A session's state.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TrackSessionInfo {
    pub id: String,
    pub frames: u64,
    pub last_frame: Option<u64>,
    pub tracks: Vec<crate::track::session::TrackSummary>,
    pub max_tracks: usize,
    pub idle_s: f64,
    /// Idle this long, the session is closed (streams: the stream is ended).
    pub idle_timeout_s: f64,
}
