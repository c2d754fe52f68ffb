//! Several tracked objects in one video stream: a detection that no track explains starts
//! a track with a full estimate; every frame then tracks each object from its last pose
//! (milliseconds, no retrieval); a lost track is re-initialised by a full estimate from the
//! caller's detection for that frame when one overlaps it, else from the object found by
//! the colours its track learnt (around its last pose, else anywhere in the frame:
//! search.rs), and is dropped after too many lost frames. Frames
//! are numbered and must come in order. The CLI, the gRPC stream and the HTTP sessions all
//! run this, so they track alike.

use super::colour::Window;
use super::{Tracker, TrackerConfig};
use crate::depth::DepthImage;
use crate::detect::confirm::{confirm, confirmation_needed};
use crate::estimate::depth_fit::DepthFit;
use crate::estimate::{Detection, EstimateConfig, Estimator};
use crate::geometry::{Intrinsics, Pose};
use crate::onboard::ObjectModel;
use crate::render::RenderPool;
use crate::telemetry::ms_since;
use image::{GrayImage, RgbImage};
use std::sync::Arc;
use std::time::Instant;

#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct SessionConfig {
    pub tracker: TrackerConfig,
    /// Objects tracked at once; detections beyond are answered `refused`.
    pub max_tracks: usize,
    /// Consecutive lost frames after which a track is dropped.
    pub drop_after_lost: usize,
    /// Half-side of the box searched first for a lost object, in object radii around its
    /// last pose (the whole frame is searched when nothing is found there).
    pub search_radii: f64,
    /// A re-initialising estimate must explain the mask it came from: its rendered
    /// silhouette needs at least this IoU with it. A segmentation that caught clutter, or
    /// an estimate that put the object at the wrong depth, would otherwise restart the
    /// track on a wrong pose that the outline then follows with middling agreement.
    pub min_reinit_iou: f64,
}

impl Default for SessionConfig {
    fn default() -> Self {
        Self { tracker: TrackerConfig::default(), max_tracks: 8, drop_after_lost: 30, search_radii: 1.2, min_reinit_iou: 0.5 }
    }
}

/// How a track's pose in a frame came about.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrackMode {
    /// A new track, from a full estimate of a detection.
    Estimated,
    /// Followed from the last frame.
    Tracked,
    /// Lost, then found again by a full estimate.
    Reinitialised,
    /// Not found in this frame; the pose is absent.
    Lost,
    /// Lost for too long: this track ends here.
    Dropped,
    /// A detection that started no track (no pose from it, or too many tracks).
    Refused,
}

impl TrackMode {
    pub fn as_str(&self) -> &'static str {
        match self {
            TrackMode::Estimated => "estimated",
            TrackMode::Tracked => "tracked",
            TrackMode::Reinitialised => "reinitialised",
            TrackMode::Lost => "lost",
            TrackMode::Dropped => "dropped",
            TrackMode::Refused => "refused",
        }
    }
}

/// One object in one frame.
#[derive(Clone, Debug)]
pub struct TrackOutcome {
    /// The track's number in this session (None for a refused detection).
    pub track_id: Option<u32>,
    pub object_id: String,
    pub pose: Option<Pose>,
    /// Outline agreement 0–1 (1 for a pose fresh from a full estimate).
    pub quality: f64,
    pub mode: TrackMode,
    /// Index of the frame's detection this came from, when one was used.
    pub detection_index: Option<usize>,
    pub ms: f64,
    /// Why there is no pose, when there is none.
    pub reason: Option<String>,
    /// How the pose lies on the measured surface, on frames tracked with depth (and lost
    /// ones the depth refused).
    pub depth_fit: Option<DepthFit>,
    /// The tracking step's stage times, on frames the track was followed from the last
    /// one (tracked, lost, dropped, re-initialised: the full estimate is in `ms` only);
    /// none for a new track or a refused detection.
    pub timings: Option<super::TrackTimings>,
}

/// A detection of one object in a frame (a mask; boxes are segmented by the caller).
pub struct FrameDetection {
    pub object_id: String,
    pub mask: GrayImage,
    pub score: f32,
    /// A candidate of the detector rather than the caller's detection: a track starts from
    /// it only when its estimate is confirmed at this score or more (`detect::confirm`),
    /// and only the first of an object's candidates so confirmed starts one.
    pub min_confirmation: Option<f32>,
}

impl FrameDetection {
    /// The caller's detection, taken as it is.
    pub fn given(object_id: String, mask: GrayImage, score: f32) -> Self {
        Self { object_id, mask, score, min_confirmation: None }
    }

    /// A candidate of the detector, for a caller whose threshold is `min_score`: its
    /// estimate must be confirmed at `confirmation_needed(min_score, with_depth)`, as
    /// answers are (less with the depth detector's candidates, confirmed with depth).
    pub fn candidate(object_id: String, mask: GrayImage, score: f32, min_score: f32, with_depth: bool) -> Self {
        Self { object_id, mask, score, min_confirmation: Some(confirmation_needed(min_score, with_depth)) }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    #[error("frame_index {given} is not after the last frame ({last}): frames must come in order")]
    OutOfOrder { given: u64, last: u64 },
    #[error("{0}")]
    BadFrame(String),
    /// The model of an object could not be had (unknown id, store error).
    #[error("{object_id}: {message}")]
    Object { object_id: String, message: String },
    #[error("{0}")]
    Internal(String),
}

struct Track {
    id: u32,
    object_id: String,
    model: Arc<ObjectModel>,
    tracker: Tracker,
    lost_frames: usize,
}

pub struct TrackSession {
    pub config: SessionConfig,
    renderer: Arc<RenderPool>,
    tracks: Vec<Track>,
    next_track: u32,
    last_frame: Option<u64>,
    frames: u64,
}

/// A track's state as a caller may list it.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TrackSummary {
    pub track_id: u32,
    pub object_id: String,
    pub lost_frames: usize,
}

impl TrackSession {
    pub fn new(renderer: Arc<RenderPool>, config: SessionConfig) -> Self {
        Self { config, renderer, tracks: Vec::new(), next_track: 0, last_frame: None, frames: 0 }
    }

    /// Frames processed so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    pub fn last_frame(&self) -> Option<u64> {
        self.last_frame
    }

    pub fn tracks(&self) -> Vec<TrackSummary> {
        self.tracks.iter().map(|t| TrackSummary { track_id: t.id, object_id: t.object_id.clone(), lost_frames: t.lost_frames }).collect()
    }

    /// The number the next frame gets: `given` when it is after the last one, else the next.
    pub fn check_order(&self, given: Option<u64>) -> Result<u64, SessionError> {
        frame_number(given, self.last_frame)
    }

    /// Tracks every object into this frame and starts tracks for the detections no track
    /// explains. `models` gives an object's model by id; every detection's object must
    /// resolve before any work starts. With the frame's registered `depth`, tracking and
    /// the full estimates use it too.
    #[allow(clippy::too_many_arguments)]
    pub fn frame(
        &mut self,
        index: Option<u64>,
        image: &RgbImage,
        depth: Option<&DepthImage>,
        k: &Intrinsics,
        detections: Vec<FrameDetection>,
        models: &dyn Fn(&str) -> Result<Arc<ObjectModel>, String>,
        estimator: &Estimator,
    ) -> Result<(u64, Vec<TrackOutcome>), SessionError> {
        let index = self.check_order(index)?;
        if image.dimensions() != (k.width, k.height) {
            return Err(SessionError::BadFrame(format!("image is {}×{} but intrinsics say {}×{}", image.width(), image.height(), k.width, k.height)));
        }
        if let Some(d) = depth.filter(|d| (d.width(), d.height()) != (k.width, k.height)) {
            return Err(SessionError::BadFrame(format!("depth is {}×{} but the frame is {}×{}", d.width(), d.height(), k.width, k.height)));
        }
        let frame = Frame { image, depth };
        if let Some(d) = detections.iter().find(|d| d.mask.dimensions() != (k.width, k.height)) {
            return Err(SessionError::BadFrame(format!("a mask of {} is {}×{}, not the frame's {}×{}", d.object_id, d.mask.width(), d.mask.height(), k.width, k.height)));
        }
        let mut new_models = std::collections::BTreeMap::new();
        for d in &detections {
            if !new_models.contains_key(d.object_id.as_str()) {
                let m = models(&d.object_id).map_err(|message| SessionError::Object { object_id: d.object_id.clone(), message })?;
                new_models.insert(d.object_id.as_str(), m);
            }
        }
        // Every track is followed first; detections are then matched against where the
        // tracks are now, so a lost track can take a detection wherever it is.
        let mut steps = Vec::with_capacity(self.tracks.len());
        for track in &mut self.tracks {
            let t = Instant::now();
            let _span = tracing::info_span!("track", track = track.id).entered();
            steps.push((track.tracker.track(image, depth, k).map_err(SessionError::Internal)?, t));
        }
        let lost: Vec<bool> = steps.iter().map(|(s, _)| s.lost).collect();
        let claimed = self.associate(k, &detections, &lost);
        let mut out = Vec::new();
        for (ti, (track, (step, t))) in self.tracks.iter_mut().zip(steps).enumerate() {
            let detection = claimed.iter().position(|c| *c == Some(ti)).map(|d| (d, &detections[d]));
            out.push(finish_track(track, step, t, &frame, k, detection, estimator, &self.config)?);
        }
        let dropped: Vec<u32> = out.iter().filter(|o| o.mode == TrackMode::Dropped).filter_map(|o| o.track_id).collect();
        self.tracks.retain(|t| !dropped.contains(&t.id));
        // Objects a confirmed candidate started a track of: their later candidates are not tried.
        let mut started = std::collections::BTreeSet::new();
        for (di, d) in detections.iter().enumerate().filter(|(di, _)| claimed[*di].is_none()) {
            let candidate = d.min_confirmation.is_some();
            if candidate && started.contains(d.object_id.as_str()) {
                continue;
            }
            let outcome = self.start_track(di, d, new_models[d.object_id.as_str()].clone(), &frame, k, estimator)?;
            if candidate && outcome.track_id.is_some() {
                started.insert(d.object_id.as_str());
            }
            out.push(outcome);
        }
        self.last_frame = Some(index);
        self.frames += 1;
        Ok((index, out))
    }

    /// For each detection, the track it belongs to, best-scoring detections first, each
    /// track taking at most one: a track of the same object whose box at its current pose
    /// overlaps the detection's box most (at least a third of the smaller box); then a
    /// lost track of the same object takes a detection that overlaps none, wherever it is.
    /// A detection that no track takes starts a new one.
    fn associate(&self, k: &Intrinsics, detections: &[FrameDetection], lost: &[bool]) -> Vec<Option<usize>> {
        let mut claimed = vec![None; detections.len()];
        let mut order: Vec<usize> = (0..detections.len()).collect();
        order.sort_by(|&a, &b| detections[b].score.total_cmp(&detections[a].score));
        let boxes: Vec<Option<[u32; 4]>> = detections.iter().map(|d| mask_box(&d.mask)).collect();
        let mut taken = vec![false; self.tracks.len()];
        for &di in &order {
            let Some(db) = boxes[di] else { continue };
            let best = self
                .tracks
                .iter()
                .enumerate()
                .filter(|(ti, t)| !taken[*ti] && t.object_id == detections[di].object_id)
                .filter_map(|(ti, t)| {
                    let w = t.tracker.window(k, &t.tracker.pose(), 1.0)?;
                    Some((ti, overlap(db, [w.x0, w.y0, w.x1, w.y1])))
                })
                .filter(|(_, o)| *o >= 1.0 / 3.0)
                .max_by(|a, b| a.1.total_cmp(&b.1));
            if let Some((ti, _)) = best {
                taken[ti] = true;
                claimed[di] = Some(ti);
            }
        }
        for &di in &order {
            if claimed[di].is_some() {
                continue;
            }
            if let Some(ti) = (0..self.tracks.len()).find(|&ti| !taken[ti] && lost[ti] && self.tracks[ti].object_id == detections[di].object_id) {
                taken[ti] = true;
                claimed[di] = Some(ti);
            }
        }
        claimed
    }

    fn start_track(&mut self, di: usize, d: &FrameDetection, model: Arc<ObjectModel>, frame: &Frame<'_>, k: &Intrinsics, estimator: &Estimator) -> Result<TrackOutcome, SessionError> {
        let t = Instant::now();
        let image = frame.image;
        let refused = |reason: String, t: Instant| TrackOutcome {
            track_id: None,
            object_id: d.object_id.clone(),
            pose: None,
            quality: 0.0,
            mode: TrackMode::Refused,
            detection_index: Some(di),
            ms: ms_since(t),
            reason: Some(reason),
            depth_fit: None,
            timings: None,
        };
        if self.tracks.len() >= self.config.max_tracks {
            return Ok(refused(format!("this session already tracks {} objects (its limit)", self.tracks.len()), t));
        }
        let pose = match full_estimate(estimator, &model, frame, k, d.mask.clone(), d.score)? {
            Ok((p, _)) => p,
            Err(reason) => return Ok(refused(reason, t)),
        };
        if let Some(min) = d.min_confirmation {
            let c = confirm(image, frame.depth, k, &model.mesh, &d.mask, &pose, &self.renderer).map_err(|e| SessionError::Internal(format!("{}: confirming: {e}", d.object_id)))?;
            if c < min {
                return Ok(refused(format!("the detector's candidate was not confirmed at its estimated pose (score {c:.3}, under {min:.3})"), t));
            }
        }
        let tracker = match Tracker::new(model.clone(), self.renderer.clone(), image, k, pose, self.config.tracker.clone()) {
            Ok(t) => t,
            Err(reason) => return Ok(refused(format!("the estimated pose cannot start a track: {reason}"), t)),
        };
        let id = self.next_track;
        self.next_track += 1;
        self.tracks.push(Track { id, object_id: d.object_id.clone(), model, tracker, lost_frames: 0 });
        Ok(TrackOutcome {
            track_id: Some(id),
            object_id: d.object_id.clone(),
            pose: Some(pose),
            quality: 1.0,
            mode: TrackMode::Estimated,
            detection_index: Some(di),
            ms: ms_since(t),
            reason: None,
            depth_fit: None,
            timings: None,
        })
    }
}

/// A track's frame after its tracking step: kept when tracked, else re-initialised from
/// the detection it took (or the object found by its colours), else lost or dropped.
#[allow(clippy::too_many_arguments)]
fn finish_track(
    track: &mut Track,
    step: super::TrackStep,
    t: Instant,
    frame: &Frame<'_>,
    k: &Intrinsics,
    detection: Option<(usize, &FrameDetection)>,
    estimator: &Estimator,
    config: &SessionConfig,
) -> Result<TrackOutcome, SessionError> {
    let image = frame.image;
    let depth_fit = step.report.depth_fit.clone();
    let outcome = |pose: Option<Pose>, quality: f64, mode: TrackMode, detection_index: Option<usize>, reason: Option<String>| TrackOutcome {
        track_id: Some(track.id),
        object_id: track.object_id.clone(),
        pose,
        quality,
        mode,
        detection_index,
        ms: ms_since(t),
        reason,
        depth_fit: if mode == TrackMode::Reinitialised { None } else { depth_fit.clone() },
        timings: Some(step.timings),
    };
    if !step.lost {
        track.lost_frames = 0;
        return Ok(outcome(Some(step.pose), step.quality, TrackMode::Tracked, None, None));
    }
    let (mask, score, used, searched) = match detection {
        Some((di, d)) => (Some(d.mask.clone()), d.score, Some(di), None),
        None => match track.tracker.search(image, k, config.search_radii) {
            Some((mask, window)) => (Some(mask), 1.0, None, Some(window)),
            None => (None, 1.0, None, None),
        },
    };
    let mut why = step.report.note.clone().unwrap_or_else(|| format!("outline agreement {:.2} under {:.2}", step.quality, config.tracker.lost_below));
    if let Some(mask) = mask {
        match full_estimate(estimator, &track.model, frame, k, mask, score)? {
            Ok((_, iou)) if iou < config.min_reinit_iou => why = format!("{why}; re-initialising: the estimate explains its mask poorly (silhouette IoU {iou:.2} under {:.2})", config.min_reinit_iou),
            // What was found inside the searched box must be an object there: an estimate
            // centred elsewhere explains a region that took in clutter too. (Its outline
            // may reach beyond the box: the box was only where to look.)
            Ok((pose, _)) if searched.is_some_and(|w| !centred_in(k, &track.model, &pose, w)) => {
                why = format!("{why}; re-initialising: the estimate puts the object beyond the box searched around its last pose")
            }
            // The estimate explains its mask, but a mask of clutter is explained by a pose
            // whose render looks nothing like the frame.
            Ok((pose, _)) if track.tracker.appearance_at(image, k, &pose).map_err(SessionError::Internal)?.is_some_and(|a| a < config.tracker.min_appearance) => {
                why = format!("{why}; re-initialising: the estimated pose does not look like the frame")
            }
            Ok((pose, _)) => match track.tracker.restart(image, k, pose) {
                Ok(()) => {
                    track.lost_frames = 0;
                    return Ok(outcome(Some(pose), 1.0, TrackMode::Reinitialised, used, None));
                }
                Err(reason) => why = format!("{why}; re-initialising: {reason}"),
            },
            Err(reason) => why = format!("{why}; re-initialising: {reason}"),
        }
    }
    track.lost_frames += 1;
    let mode = if track.lost_frames >= config.drop_after_lost.max(1) { TrackMode::Dropped } else { TrackMode::Lost };
    Ok(outcome(None, step.quality, mode, used, Some(why)))
}

fn frame_number(given: Option<u64>, last: Option<u64>) -> Result<u64, SessionError> {
    match (given, last) {
        (Some(g), Some(last)) if g <= last => Err(SessionError::OutOfOrder { given: g, last }),
        (Some(g), _) => Ok(g),
        (None, Some(last)) => Ok(last + 1),
        (None, None) => Ok(0),
    }
}

/// One frame's images: the colour image and, from an RGB-D camera, its registered depth.
struct Frame<'a> {
    image: &'a RgbImage,
    depth: Option<&'a DepthImage>,
}

/// A full estimate from one mask: the pose and its rendered silhouette's IoU with the
/// mask, or why there is none.
fn full_estimate(estimator: &Estimator, model: &ObjectModel, frame: &Frame<'_>, k: &Intrinsics, mask: GrayImage, score: f32) -> Result<Result<(Pose, f64), String>, SessionError> {
    match estimator.estimate_rgbd(model, frame.image, frame.depth, k, &[Detection::new(mask, score)], None, &EstimateConfig::default()) {
        Ok(r) => {
            let iou = r.hypotheses.iter().find(|h| Some(h.mask_index) == r.mask_index).map_or(f64::NAN, |h| h.iou as f64);
            Ok(r.pose.map(|p| (p, iou)).ok_or_else(|| r.reason.unwrap_or_else(|| "no pose".into())))
        }
        Err(crate::estimate::EstimateError::BadInput(m)) => Ok(Err(m)),
        Err(e) => Err(SessionError::Internal(e.to_string())),
    }
}

/// Whether the object's centre at `pose` projects inside `w`.
fn centred_in(k: &Intrinsics, model: &ObjectModel, pose: &Pose, w: Window) -> bool {
    projects_inside(k, &pose.transform_point(&nalgebra::Point3::from(nalgebra::Vector3::from(model.mesh.bbox_center()))), w)
}

/// Whether camera-frame point `p` is in front of the camera and projects inside `w`.
fn projects_inside(k: &Intrinsics, p: &nalgebra::Point3<f64>, w: Window) -> bool {
    p.z > 0.0 && k.project(p).is_some_and(|uv| uv.x >= w.x0 as f64 && uv.y >= w.y0 as f64 && uv.x < w.x1 as f64 && uv.y < w.y1 as f64)
}

/// [x0, y0, x1, y1) of a mask's non-zero pixels.
fn mask_box(mask: &GrayImage) -> Option<[u32; 4]> {
    crate::features::crop::mask_bbox(mask).map(|(x0, y0, x1, y1)| [x0, y0, x1 + 1, y1 + 1])
}

/// Intersection over the smaller box's area.
fn overlap(a: [u32; 4], b: [u32; 4]) -> f64 {
    let area = |r: [u32; 4]| (r[2].saturating_sub(r[0]) as f64) * (r[3].saturating_sub(r[1]) as f64);
    let i = [a[0].max(b[0]), a[1].max(b[1]), a[2].min(b[2]), a[3].min(b[3])];
    let smaller = area(a).min(area(b));
    if smaller <= 0.0 {
        0.0
    } else {
        area(i) / smaller
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn boxes_and_overlap() {
        let mut m = GrayImage::new(10, 10);
        assert_eq!(mask_box(&m), None);
        m.put_pixel(2, 3, image::Luma([1]));
        m.put_pixel(5, 7, image::Luma([1]));
        assert_eq!(mask_box(&m), Some([2, 3, 6, 8]));
        assert_eq!(overlap([0, 0, 10, 10], [5, 5, 7, 7]), 1.0);
        assert_eq!(overlap([0, 0, 4, 4], [2, 0, 6, 4]), 0.5);
        assert_eq!(overlap([0, 0, 4, 4], [4, 4, 6, 6]), 0.0);
        assert_eq!(overlap([0, 0, 0, 4], [0, 0, 4, 4]), 0.0);
        let k = Intrinsics::new(100.0, 100.0, 150.0, 150.0, 300, 300).unwrap();
        let searched = Window { x0: 100, y0: 100, x1: 200, y1: 200 };
        let at = |x: f64, y: f64, z: f64| nalgebra::Point3::new(x, y, z);
        assert!(projects_inside(&k, &at(0.0, 0.0, 1.0), searched), "(150, 150)");
        assert!(projects_inside(&k, &at(-0.5, 0.49, 1.0), searched), "(100, 199)");
        assert!(!projects_inside(&k, &at(0.6, 0.0, 1.0), searched), "(210, 150)");
        assert!(!projects_inside(&k, &at(0.0, 0.0, -1.0), searched), "behind the camera");
    }

    #[test]
    fn detector_candidates_need_the_answers_confirmation_given_ones_none() {
        let m = GrayImage::new(4, 4);
        assert_eq!(FrameDetection::given("a".into(), m.clone(), 1.0).min_confirmation, None);
        assert_eq!(FrameDetection::candidate("a".into(), m.clone(), 0.5, 0.45, false).min_confirmation, Some(confirmation_needed(0.45, false)));
        let with_depth = FrameDetection::candidate("a".into(), m, 0.5, 0.45, true).min_confirmation.unwrap();
        assert!((with_depth - confirmation_needed(0.45, true)).abs() < 1e-6 && with_depth < confirmation_needed(0.45, false));
    }

    #[test]
    fn frames_must_come_in_order() {
        assert_eq!(frame_number(None, None).unwrap(), 0);
        assert_eq!(frame_number(Some(7), None).unwrap(), 7);
        assert_eq!(frame_number(None, Some(7)).unwrap(), 8);
        assert_eq!(frame_number(Some(9), Some(7)).unwrap(), 9);
        assert!(matches!(frame_number(Some(7), Some(7)), Err(SessionError::OutOfOrder { given: 7, last: 7 })));
        assert!(matches!(frame_number(Some(3), Some(7)), Err(SessionError::OutOfOrder { .. })));
    }
}
