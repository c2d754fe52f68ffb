//! The core's tracking calls: open a session, run one frame through it, read or close it.
//! Blocking (a frame may need a full estimate to start or re-initialise a track); the
//! adapters call these on blocking threads. Objects come from the same cache as estimates.

use super::core::Core;
use super::error::{ErrorKind, ServiceError};
use super::track_requests::{TrackFrameRequest, TrackFrameResponse, TrackSessionInfo, TrackSessionOptions, TrackedObject};
use super::track_sessions::SessionEntry;
use crate::detect::confirm::{candidate_options, candidates_tried};
use crate::masks::BoxMask;
use crate::track::{FrameDetection, SessionError, TrackSession};
use std::time::Instant;

impl Core {
    /// Opens a session (`streamed`: owned by a gRPC stream, which closes it).
    pub fn open_track(&self, options: &TrackSessionOptions, streamed: bool) -> Result<TrackSessionInfo, ServiceError> {
        let config = options.config()?;
        let entry = self.tracks.open(TrackSession::new(self.pool.clone(), config), streamed)?;
        Ok(self.session_info(&entry))
    }

    pub fn track_info(&self, id: &str) -> Result<TrackSessionInfo, ServiceError> {
        let entry = self.tracks.get(id)?;
        Ok(self.session_info(&entry))
    }

    pub fn list_tracks(&self) -> Vec<TrackSessionInfo> {
        self.tracks.list().iter().map(|e| self.session_info(e)).collect()
    }

    pub fn close_track(&self, id: &str) -> Result<(), ServiceError> {
        self.tracks.close(id)
    }

    /// Closes idle sessions; returns how many.
    pub fn expire_tracks(&self) -> usize {
        self.tracks.sweep()
    }

    pub fn track_sessions_open(&self) -> usize {
        self.tracks.count()
    }

    fn session_info(&self, e: &SessionEntry) -> TrackSessionInfo {
        let s = e.session.lock().expect("session lock");
        TrackSessionInfo {
            id: e.id.clone(),
            frames: s.frames(),
            last_frame: s.last_frame(),
            tracks: s.tracks(),
            max_tracks: s.config.max_tracks,
            idle_s: e.idle().as_secs_f64(),
            idle_timeout_s: self.tracks.idle_timeout.as_secs_f64(),
        }
    }

    /// Runs one frame through session `id`. Refused while another frame of the session is
    /// being processed; a refused or malformed frame leaves the session as it was.
    pub fn track_frame(&self, id: &str, req: &TrackFrameRequest) -> Result<TrackFrameResponse, ServiceError> {
        let t0 = Instant::now();
        let span = tracing::info_span!("frame", session = id, index = tracing::field::Empty);
        let _entered = span.enter();
        let turn = self.tracks.turn(id)?;
        let k = req.intrinsics.decode()?;
        let image = tracing::info_span!("decode").in_scope(|| req.image.decode())?;
        if image.dimensions() != (k.width, k.height) {
            return Err(ServiceError::invalid(format!("image is {}×{} but intrinsics say {}×{}", image.width(), image.height(), k.width, k.height)));
        }
        let depth = req.depth.as_ref().map(|d| d.decode(k.width, k.height)).transpose()?;
        // Order first: a late frame is refused before its masks are decoded or segmented.
        let mut session = turn.entry().session.lock().expect("session lock");
        let index = session.check_order(req.frame_index).map_err(|e| ServiceError::invalid(e.to_string()))?;
        span.record("index", index);
        if !req.detections.is_empty() && !req.objects.is_empty() {
            return Err(ServiceError::invalid("give detections or objects, not both"));
        }
        super::detect_requests::check_objects(&req.objects)?;
        let mut detections = Vec::with_capacity(req.detections.len());
        // Objects to find: those named that no track followed into the last frame.
        let followed: std::collections::BTreeSet<String> = session.tracks().into_iter().filter(|t| t.lost_frames == 0).map(|t| t.object_id).collect();
        let wanted: Vec<String> = req.objects.iter().filter(|id| !followed.contains(*id)).cloned().collect();
        if !wanted.is_empty() {
            // Candidates below the caller's threshold, a few per object: a track starts
            // from the first one confirmed at its estimated pose (`detect::confirm`).
            let report = self.run_detector((&image, depth.as_ref()), &k, &wanted, &candidate_options(&req.detect), None)?;
            let mut per_object = std::collections::BTreeMap::<String, usize>::new();
            for d in report.detections {
                let n = per_object.entry(d.object_id.clone()).or_default();
                *n += 1;
                if *n <= candidates_tried(1) {
                    detections.push(FrameDetection::candidate(d.object_id, d.mask, d.score, req.detect.min_score, depth.is_some()));
                }
            }
        }
        for (i, d) in req.detections.iter().enumerate() {
            if !d.score.is_finite() {
                return Err(ServiceError::invalid(format!("detections[{i}].score is not a finite number")));
            }
            crate::store::validate_id(&d.object_id).map_err(|e| ServiceError::invalid(format!("detections[{i}].object_id: {e}")))?;
            detections.push(FrameDetection::given(d.object_id.clone(), d.mask(i, &image, BoxMask::Segment)?, d.score));
        }
        // Every named object must exist before any work starts (NOT_FOUND names it).
        let mut models = std::collections::BTreeMap::new();
        for d in &detections {
            if !models.contains_key(&d.object_id) {
                models.insert(d.object_id.clone(), self.load_to_render(&d.object_id)?);
            }
        }
        let resolve = |object_id: &str| models.get(object_id).cloned().ok_or_else(|| format!("object {object_id:?} was not loaded"));
        let (frame_index, outcomes) = session.frame(req.frame_index, &image, depth.as_ref(), &k, detections, &resolve, &self.estimator).map_err(|e| match e {
            SessionError::OutOfOrder { .. } | SessionError::BadFrame(_) => ServiceError::invalid(e.to_string()),
            SessionError::Object { .. } | SessionError::Internal(_) => ServiceError::new(ErrorKind::Internal, e.to_string()),
        })?;
        Ok(TrackFrameResponse { frame_index, objects: outcomes.into_iter().map(TrackedObject::from).collect(), total_ms: t0.elapsed().as_secs_f64() * 1e3 })
    }
}
