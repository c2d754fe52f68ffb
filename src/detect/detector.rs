//! Finds onboarded objects in an image: the scales each object's size and the distance
//! range imply, response maps once per scale for all objects, every template of every
//! object over them, suppression of overlaps across objects and instances, then for each
//! detection the coarse pose of its template and a mask (the mesh rendered at that pose,
//! replaced by the graph-cut segmentation of its box where the two agree).

use super::colour_prior::ColourPrior;
use super::nms::{parts_of_larger, suppress};
use super::responses::ResponseMaps;
use super::scales::{distance_for_scale, rung_scale, rungs_between, scale_for_distance};
use super::search::search;
use super::templates::ShapeModel;
use super::verify::{Evidence, Window};
use crate::geometry::{Intrinsics, Pose};
use crate::masks::{mask_iou, segment_box, Method, PixelBox, SegmentConfig};
use crate::mesh::Mesh;
use crate::render::{RenderOptions, RenderPool};
use crate::telemetry::ms_since;
use image::{imageops, GrayImage, RgbImage};
use nalgebra::{Rotation3, Vector3};
use rayon::prelude::*;
use std::collections::{BTreeMap, BTreeSet};
use std::time::Instant;

/// One object to look for.
pub struct Target<'a> {
    pub id: &'a str,
    pub shape: &'a ShapeModel,
    pub mesh: &'a Mesh,
}

/// Search settings of one request.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct DetectOptions {
    /// At most this many detections, best first, over all objects.
    pub max_detections: usize,
    /// Score (`combined_score`) a detection needs.
    pub min_score: f32,
    /// Distances of the object's centre from the camera to search, metres; unset: from
    /// the object appearing `DEFAULT_MAX_SHARE` of the image's shorter side across down to
    /// `DEFAULT_MIN_DIAMETER_PX`.
    pub min_distance_m: Option<f64>,
    pub max_distance_m: Option<f64>,
    /// Replace the rendered silhouette by the graph-cut segmentation of its box where the
    /// two agree (the photo's own outline).
    pub refine_masks: bool,
}

impl Default for DetectOptions {
    fn default() -> Self {
        Self { max_detections: 20, min_score: DEFAULT_MIN_SCORE, min_distance_m: None, max_distance_m: None, refine_masks: true }
    }
}

/// Default score threshold (docs/detection.md: chosen on generated scenes and empty images).
pub const DEFAULT_MIN_SCORE: f32 = 0.45;
/// Smallest bounding-sphere diameter searched by default, pixels.
pub const DEFAULT_MIN_DIAMETER_PX: f64 = 40.0;
/// Largest, as a share of the image's shorter side.
pub const DEFAULT_MAX_SHARE: f64 = 1.0;
/// Orientations spread over this window, and the search grid's step (LINE-2D's T), pixels.
pub const SPREAD_PX: usize = 4;
pub const STRIDE_PX: usize = 4;
/// Grid positions whose template sum is below this share of the maximum are not refined.
const MIN_RAW_SCORE: f32 = 0.6;
/// Template matches scoring less above chance are not candidates.
const MIN_SHAPE_SCORE: f32 = 0.4;
/// A template's orientation spread (`ShapeModel::orientation_spread`) from which its
/// candidates rank in full; below, in proportion (docs/detection.md: false detections per
/// empty image 2.8 → 1.0 on the bench, recall unchanged).
const FULL_SPREAD: f32 = 0.6;
/// Candidates per object considered for suppression (best rank first).
const RANKED_PER_OBJECT: usize = 300;
/// Candidates per object rendered and compared with the image (about 3–5 ms each).
const VERIFIED_PER_OBJECT: usize = 12;
/// Verified candidates per object that get a second look from turned viewpoints, and the
/// turn (about half the templates' view spacing).
const VIEW_REFINED_PER_OBJECT: usize = 4;
const VIEW_STEP_DEG: f64 = 12.0;
/// A match inside a larger one of the same object whose rank (before verification) or
/// score (after) reaches this share of its own gives way to it (`nms::parts_of_larger`).
const PART_RANK_RATIO: f32 = 0.9;
const PART_SCORE_RATIO: f32 = 0.9;
/// Boxes overlapping more than this are one detection.
const NMS_IOU: f64 = 0.5;
/// Graph-cut masks must agree this well with the rendered silhouette to replace it.
const MIN_SEGMENT_AGREEMENT: f64 = 0.6;

#[derive(Debug, thiserror::Error)]
pub enum DetectError {
    #[error("{0}")]
    BadInput(String),
    #[error("object {object:?}: {message}")]
    Render { object: String, message: String },
}

/// One found object instance.
#[derive(Clone, Debug)]
pub struct Detection {
    pub object_id: String,
    /// [x, y, w, h] in pixels, around `mask`.
    pub bbox: [f64; 4],
    /// The render's evidence combined (`combined_score`), 0–1.
    pub score: f32,
    /// The template match alone: share of the best possible response.
    pub shape_score: f32,
    pub evidence: Evidence,
    /// Image-sized, 255 = object.
    pub mask: GrayImage,
    /// How the mask was made: the rendered silhouette or the graph cut of its box.
    pub mask_source: MaskSource,
    /// The matched template's pose placed where it was found (a hypothesis, ~15–20° and a
    /// few % of depth from the truth).
    pub pose: Pose,
    pub template: usize,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MaskSource {
    Silhouette,
    GraphCut,
    /// A surface of the depth image (`depth_segments`).
    DepthSegment,
}

/// What one object's search covered.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Searched {
    pub object_id: String,
    /// Nearest and farthest distance searched (sphere centre), metres.
    pub distance_m: [f64; 2],
    pub scales: usize,
    pub candidates: usize,
}

#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct DetectTimings {
    pub responses_ms: f64,
    pub search_ms: f64,
    pub verify_ms: f64,
    pub masks_ms: f64,
    pub total_ms: f64,
}

impl DetectTimings {
    /// Stage name (without `_ms`) → milliseconds: what the service answers and its metrics observe.
    pub fn by_stage(&self) -> std::collections::BTreeMap<String, f64> {
        [("responses", self.responses_ms), ("search", self.search_ms), ("verify", self.verify_ms), ("masks", self.masks_ms), ("total", self.total_ms)]
            .into_iter()
            .map(|(name, ms)| (name.to_string(), ms))
            .collect()
    }
}

#[derive(Clone, Debug)]
pub struct DetectReport {
    pub detections: Vec<Detection>,
    pub searched: Vec<Searched>,
    pub timings: DetectTimings,
    /// Why nothing was found, when nothing was.
    pub reason: Option<String>,
}

/// A placement in original image coordinates.
struct Candidate {
    target: usize,
    template: usize,
    /// Projected centre (pixels) and the resampling factor it was found at.
    u: f64,
    v: f64,
    rho: f64,
    bbox: [f64; 4],
    score: f32,
    /// What candidates are ranked by before verification.
    rank: f32,
}

pub fn check_options(o: &DetectOptions) -> Result<(), DetectError> {
    let bad = |m: String| Err(DetectError::BadInput(m));
    if !(1..=crate::limits::MAX_DETECTIONS).contains(&o.max_detections) {
        return bad(format!("max_detections must be 1–{}, got {}", crate::limits::MAX_DETECTIONS, o.max_detections));
    }
    if !(o.min_score.is_finite() && (0.0..=1.0).contains(&o.min_score)) {
        return bad(format!("min_score must be within 0–1, got {}", o.min_score));
    }
    for (name, v) in [("min_distance_m", o.min_distance_m), ("max_distance_m", o.max_distance_m)] {
        if let Some(v) = v {
            if !(v.is_finite() && (0.001..=1000.0).contains(&v)) {
                return bad(format!("{name} must be within 0.001–1000 m, got {v}"));
            }
        }
    }
    if let (Some(a), Some(b)) = (o.min_distance_m, o.max_distance_m) {
        if a >= b {
            return bad(format!("min_distance_m ({a}) must be below max_distance_m ({b})"));
        }
    }
    Ok(())
}

/// Looks for every target in `image` by LINE-2D-style shape matching and renders.
pub fn detect_in_colour(image: &RgbImage, k: &Intrinsics, targets: &[Target], opts: &DetectOptions, renderer: &RenderPool) -> Result<DetectReport, DetectError> {
    let t0 = Instant::now();
    check_input(image, k, opts)?;
    let plans: Vec<ScalePlan> = targets.iter().map(|t| scale_plan(t, k, image, opts)).collect();
    let maps = response_maps(image, targets, &plans);
    let responses_ms = ms_since(t0);

    let t1 = Instant::now();
    let (candidates, searched) = search_all(targets, &plans, &maps, opts);
    let kept = best_per_object(&candidates, targets.len(), opts);
    let search_ms = ms_since(t1);

    let t2 = Instant::now();
    let verified = verify_kept(image, k, targets, &candidates, &kept, renderer)?;
    let verify_ms = ms_since(t2);
    let passed = passed_and_apart(&candidates, &verified, opts);

    let t3 = Instant::now();
    let detections: Vec<Detection> = passed
        .par_iter()
        .map(|&(i, pose, ev, score)| {
            let c = &candidates[*i];
            finish(image, k, &targets[c.target], *pose, c, *ev, *score, opts.refine_masks, renderer)
        })
        .collect::<Result<_, _>>()?;
    let masks_ms = ms_since(t3);
    let reason = if !detections.is_empty() {
        None
    } else if plans.iter().all(|p| p.rungs.is_empty()) {
        Some("no scale to search: the distance range puts the objects outside the sizes this image can show".to_string())
    } else {
        Some(format!("no candidate scored {} or more ({} candidates checked)", opts.min_score, verified.len()))
    };
    Ok(DetectReport { detections, searched, timings: DetectTimings { responses_ms, search_ms, verify_ms, masks_ms, total_ms: ms_since(t0) }, reason })
}

fn check_input(image: &RgbImage, k: &Intrinsics, opts: &DetectOptions) -> Result<(), DetectError> {
    check_options(opts)?;
    Intrinsics::new(k.fx, k.fy, k.cx, k.cy, k.width, k.height).map_err(|e| DetectError::BadInput(e.to_string()))?;
    if (k.width, k.height) != image.dimensions() {
        return Err(DetectError::BadInput(format!("camera resolution {}×{} differs from the image's {}×{}", k.width, k.height, image.width(), image.height())));
    }
    Ok(())
}

/// The scales one object is searched at, and the distances they stand for.
struct ScalePlan {
    rungs: Vec<usize>,
    /// Nearest and farthest distance (NaN when no scale is left), metres.
    range: [f64; 2],
}

fn scale_plan(t: &Target, k: &Intrinsics, image: &RgbImage, opts: &DetectOptions) -> ScalePlan {
    let f = (k.fx * k.fy).sqrt();
    let short_side = image.width().min(image.height()) as f64;
    let (c, r) = (t.shape.config.canonical_px as f64, t.mesh.bounding_radius().max(1e-6));
    let rho_hi = match opts.min_distance_m {
        Some(z) => scale_for_distance(c, f, r, z),
        None => c / DEFAULT_MIN_DIAMETER_PX,
    };
    let rho_lo = match opts.max_distance_m {
        Some(z) => scale_for_distance(c, f, r, z),
        None => c / (DEFAULT_MAX_SHARE * short_side),
    };
    // A resampled image smaller than a template holds no whole object.
    let rho_floor = t.shape.config.template_side() as f64 / short_side;
    let rungs: Vec<usize> = rungs_between(rho_lo.max(rho_floor * 0.5), rho_hi).into_iter().filter(|&k| rung_scale(k) >= rho_floor * 0.5).collect();
    let dist = |rho: f64| distance_for_scale(c, f, r, rho);
    let range = match (rungs.first(), rungs.last()) {
        (Some(&a), Some(&b)) => [dist(rung_scale(a)), dist(rung_scale(b))],
        _ => [f64::NAN, f64::NAN],
    };
    ScalePlan { rungs, range }
}

/// The image resampled to one scale and its response maps: the factors in x and y, the
/// maps, the resampled image.
type RungMaps = (f64, f64, ResponseMaps, RgbImage);

/// Response maps once per (scale, gradient threshold) any object needs, shared by all.
fn response_maps(image: &RgbImage, targets: &[Target], plans: &[ScalePlan]) -> BTreeMap<(usize, u32), RungMaps> {
    let mut needed: BTreeSet<(usize, u32)> = BTreeSet::new();
    for (t, p) in targets.iter().zip(plans) {
        for &k in &p.rungs {
            needed.insert((k, t.shape.config.min_magnitude.to_bits()));
        }
    }
    let keys: Vec<(usize, u32)> = needed.into_iter().collect();
    keys.par_iter()
        .map(|&(k, mag)| {
            let (small, rx, ry) = resampled(image, rung_scale(k));
            let maps = ResponseMaps::compute(&small, f32::from_bits(mag), SPREAD_PX, STRIDE_PX);
            ((k, mag), (rx, ry, maps, small))
        })
        .collect()
}

/// Every template of every object over its scales' maps: the placements, and per object
/// what was searched.
fn search_all(targets: &[Target], plans: &[ScalePlan], maps: &BTreeMap<(usize, u32), RungMaps>, opts: &DetectOptions) -> (Vec<Candidate>, Vec<Searched>) {
    let mut candidates: Vec<Candidate> = Vec::new();
    let mut searched = Vec::new();
    for (ti, (t, plan)) in targets.iter().zip(plans).enumerate() {
        let before = candidates.len();
        for &k in &plan.rungs {
            let (rx, ry, m, small) = &maps[&(k, t.shape.config.min_magnitude.to_bits())];
            let prior = (!t.shape.colours.is_empty()).then(|| ColourPrior::new(&t.shape.colours, small));
            for p in search(t.shape, m, MIN_RAW_SCORE, MIN_SHAPE_SCORE.min(opts.min_score)) {
                let (u, v) = ((p.x as f64 + 0.5) / rx - 0.5, (p.y as f64 + 0.5) / ry - 0.5);
                let b = t.shape.boxes[p.template];
                let bbox = [u + b[0] as f64 / rx, v + b[1] as f64 / ry, (b[2] - b[0]) as f64 / rx, (b[3] - b[1]) as f64 / ry];
                let colour = prior.as_ref().map(|c| c.box_mean((p.x + b[0] as i32) as i64, (p.y + b[1] as i32) as i64, (p.x + b[2] as i32) as i64, (p.y + b[3] as i32) as i64));
                // Ranked by the template, how much of the box has the object's colours (for
                // objects with colours), and how many orientations the template spans: one
                // of one or two orientations answers poles and other boxes' edges too.
                let spread = (t.shape.orientation_spread(p.template) / FULL_SPREAD).min(1.0);
                let rank = p.score * colour.map_or(1.0, |c| c.min(1.0)) * spread;
                candidates.push(Candidate { target: ti, template: p.template, u, v, rho: rung_scale(k), bbox, score: p.score, rank });
            }
        }
        searched.push(Searched { object_id: t.id.to_string(), distance_m: plan.range, scales: plan.rungs.len(), candidates: candidates.len() - before });
    }
    (candidates, searched)
}

/// Each object's best candidates (its own suppression first), so one object's clutter
/// matches cannot crowd another object out of verification.
fn best_per_object(candidates: &[Candidate], objects: usize, opts: &DetectOptions) -> Vec<usize> {
    let mut kept = Vec::new();
    for ti in 0..objects {
        let mut own: Vec<usize> = (0..candidates.len()).filter(|&i| candidates[i].target == ti).collect();
        own.sort_by(|&a, &b| candidates[b].rank.total_cmp(&candidates[a].rank));
        own.truncate(RANKED_PER_OBJECT);
        // A match on part of the object (its print answers a smaller view) gives way to a
        // larger match around it that ranks nearly as well.
        let boxes: Vec<[f64; 4]> = own.iter().map(|&i| candidates[i].bbox).collect();
        let ranks: Vec<f32> = own.iter().map(|&i| candidates[i].rank).collect();
        let parts = parts_of_larger(&boxes, &ranks, &vec![0; own.len()], PART_RANK_RATIO);
        let own: Vec<usize> = own.iter().zip(&parts).filter(|(_, &p)| !p).map(|(&i, _)| i).collect();
        let boxes: Vec<[f64; 4]> = own.iter().map(|&i| candidates[i].bbox).collect();
        let scores: Vec<f32> = own.iter().map(|&i| candidates[i].rank).collect();
        kept.extend(suppress(&boxes, &scores, NMS_IOU).into_iter().take(VERIFIED_PER_OBJECT.max(opts.max_detections)).map(|j| own[j]));
    }
    kept
}

/// A verified candidate: its index, the pose, the render's evidence, the combined score.
type Checked = (usize, Pose, Evidence, f32);

/// The kept candidates rendered at their coarse poses (the render's evidence joins the
/// score), best first; the best few of each object looked at again from viewpoints turned a
/// little: the templates' views are ~30° apart, and a render from the right view lines up
/// with the print as well as with the outline.
fn verify_kept(image: &RgbImage, k: &Intrinsics, targets: &[Target], candidates: &[Candidate], kept: &[usize], renderer: &RenderPool) -> Result<Vec<Checked>, DetectError> {
    let mut verified: Vec<Checked> = kept
        .par_iter()
        .map(|&i| {
            let c = &candidates[i];
            let t = &targets[c.target];
            let pose = coarse_pose(t.shape, t.mesh, k, c);
            let ev = match Window::new(image, k, c.bbox) {
                Some(w) => w.evidence(renderer, t.mesh, &pose).map_err(|e| render_error(t, e))?,
                None => Evidence::default(),
            };
            Ok((i, pose, ev, combined_score(&ev)))
        })
        .collect::<Result<_, DetectError>>()?;
    verified.sort_by(|a, b| b.3.total_cmp(&a.3));
    let mut looked_at = vec![0usize; targets.len()];
    let second: Vec<bool> = verified
        .iter()
        .map(|v| {
            let seen = &mut looked_at[candidates[v.0].target];
            *seen += 1;
            *seen <= VIEW_REFINED_PER_OBJECT
        })
        .collect();
    verified.par_iter_mut().zip(second).filter(|(_, second)| *second).try_for_each(|(v, _)| {
        let c = &candidates[v.0];
        let t = &targets[c.target];
        if let Some(w) = Window::new(image, k, c.bbox) {
            (v.1, v.2, v.3) = view_refined(&w, renderer, t.mesh, (v.1, v.2, v.3)).map_err(|e| render_error(t, e))?;
        }
        Ok::<(), DetectError>(())
    })?;
    Ok(verified)
}

/// The verified candidates that score enough and are not a part of a larger one (by the
/// verified score now: the render of a smaller view can agree with the print a little
/// better than the whole object's render does), overlaps suppressed, best first, at most
/// `max_detections`.
fn passed_and_apart<'a>(candidates: &[Candidate], verified: &'a [Checked], opts: &DetectOptions) -> Vec<&'a Checked> {
    let parts = parts_of_larger(
        &verified.iter().map(|v| candidates[v.0].bbox).collect::<Vec<_>>(),
        &verified.iter().map(|v| v.3).collect::<Vec<_>>(),
        &verified.iter().map(|v| candidates[v.0].target).collect::<Vec<_>>(),
        PART_SCORE_RATIO,
    );
    let passed: Vec<&Checked> = verified.iter().zip(&parts).filter(|(v, &part)| !part && v.3 >= opts.min_score).map(|(v, _)| v).collect();
    let order = suppress(&passed.iter().map(|v| candidates[v.0].bbox).collect::<Vec<_>>(), &passed.iter().map(|v| v.3).collect::<Vec<_>>(), NMS_IOU);
    order.into_iter().take(opts.max_detections).map(|j| passed[j]).collect()
}

/// `image` resampled by `rho` (whole pixels), with the factors it was resampled by in x and y.
pub fn resampled(image: &RgbImage, rho: f64) -> (RgbImage, f64, f64) {
    let (w, h) = (((image.width() as f64 * rho).round() as u32).max(1), ((image.height() as f64 * rho).round() as u32).max(1));
    let small = if (w, h) == image.dimensions() { image.clone() } else { imageops::resize(image, w, h, imageops::FilterType::Triangle) };
    (small, w as f64 / image.width() as f64, h as f64 / image.height() as f64)
}

/// The template's rotation, turned so that the optical axis points at the found centre
/// (an object off the axis looks like one on it seen from a turned camera), at the
/// distance the scale implies.
fn coarse_pose(shape: &ShapeModel, mesh: &Mesh, k: &Intrinsics, c: &Candidate) -> Pose {
    let r = mesh.bounding_radius().max(1e-6);
    let f = (k.fx * k.fy).sqrt();
    let dist = distance_for_scale(shape.config.canonical_px as f64, f, r, c.rho);
    let ray = Vector3::new((c.u - k.cx) / k.fx, (c.v - k.cy) / k.fy, 1.0).normalize();
    let align = Rotation3::rotation_between(&Vector3::z(), &ray).unwrap_or_else(Rotation3::identity);
    let rotation = align * shape.config.rotation(c.template);
    let centre = Vector3::from(mesh.bbox_center());
    Pose::new(rotation, ray * dist - rotation * centre)
}

/// A candidate's pose, evidence and score after one sweep of turns of its viewpoint (about
/// the camera's x and y axes through the object's centre), each turn kept when it scores
/// better.
fn view_refined(window: &Window, renderer: &RenderPool, mesh: &Mesh, start: (Pose, Evidence, f32)) -> Result<(Pose, Evidence, f32), crate::render::RenderError> {
    let mut best = start;
    for (ax, ay) in [(1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)] {
        let turned = best.0.turned_in_camera(&Vector3::from(mesh.bbox_center()), &nalgebra::Unit::new_normalize(Vector3::new(ax, ay, 0.0)), VIEW_STEP_DEG.to_radians());
        let ev = window.evidence(renderer, mesh, &turned)?;
        let s = combined_score(&ev);
        if s > best.2 {
            best = (turned, ev, s);
        }
    }
    Ok(best)
}

fn render_error(t: &Target, e: crate::render::RenderError) -> DetectError {
    DetectError::Render { object: t.id.to_string(), message: e.to_string() }
}

/// The detection's score, from what the render at the candidate's pose says (the template
/// score chose the candidates and says nothing more about them: docs/detection.md): the
/// outline's agreement, times the colour overlap, times the interior edges' agreement,
/// softened by half since occluders and the render-to-real gap take some print away from
/// true objects too. A product, so one absent part of the evidence (the outline there, but
/// not the colours) is enough to rank a candidate low. A check that cannot be made (no
/// colours on the mesh, no interior edges in the render) counts half way: neither for nor
/// against. Counting it as passed let an outline alone pass the threshold, which painted
/// clutter does for meshes without colours (20 false detections per empty image).
pub fn combined_score(ev: &Evidence) -> f32 {
    let texture = 0.5 + 0.5 * ev.texture.unwrap_or(0.5);
    ev.outline * ev.colour.map_or(0.5, |c| c.max(0.0)) * texture
}

/// The highest `combined_score` a render of `mesh` can reach: 1 for a mesh with colours,
/// half for one without (its colour check cannot be made and counts half way).
pub fn best_possible_score(mesh: &Mesh) -> f32 {
    if mesh.has_colours() {
        1.0
    } else {
        0.5
    }
}

#[allow(clippy::too_many_arguments)]
fn finish(image: &RgbImage, k: &Intrinsics, t: &Target, pose: Pose, c: &Candidate, evidence: Evidence, score: f32, refine: bool, renderer: &RenderPool) -> Result<Detection, DetectError> {
    let render = renderer.render(t.mesh, &pose, k, &RenderOptions::grey()).map_err(|e| render_error(t, e))?;
    let mut mask = render.mask;
    let mut source = MaskSource::Silhouette;
    if let Some(b) = bbox_of(&mask) {
        if refine {
            // The segmenter gets the silhouette's box widened a little (the pose is coarse).
            let grow = 0.1 * b[2].max(b[3]);
            let grown = [b[0] - grow, b[1] - grow, b[2] + 2.0 * grow, b[3] + 2.0 * grow];
            if let Ok(pb) = PixelBox::from_xywh(grown, image.width(), image.height()) {
                let seg = segment_box(image, &pb, &SegmentConfig::default());
                if seg.method == Method::GraphCut && mask_iou(&seg.mask, &mask) >= MIN_SEGMENT_AGREEMENT {
                    mask = seg.mask;
                    source = MaskSource::GraphCut;
                }
            }
        }
    } else {
        // The object is behind the camera or off the image at this pose: the template's
        // box, clipped, is all there is.
        if let Ok(pb) = PixelBox::from_xywh(c.bbox, image.width(), image.height()) {
            mask = pb.filled(image.width(), image.height());
        }
    }
    let bbox = bbox_of(&mask).unwrap_or(c.bbox);
    Ok(Detection { object_id: t.id.to_string(), bbox, score, shape_score: c.score, evidence, mask, mask_source: source, pose, template: c.template })
}

/// [x, y, w, h] of a mask's nonzero pixels.
pub fn bbox_of(mask: &GrayImage) -> Option<[f64; 4]> {
    crate::features::mask_bbox(mask).map(|(u0, v0, u1, v1)| [u0 as f64, v0 as f64, (u1 - u0 + 1) as f64, (v1 - v0 + 1) as f64])
}

#[cfg(test)]
mod tests {
    use super::DetectTimings;

    /// The service answers `by_stage`: every serialised field, by its name without `_ms`.
    #[test]
    fn stages_by_name_are_the_serialised_fields() {
        let t = DetectTimings { responses_ms: 1.0, search_ms: 2.0, verify_ms: 3.0, masks_ms: 4.0, total_ms: 10.0 };
        let json = serde_json::to_value(&t).unwrap();
        let fields: std::collections::BTreeMap<String, f64> = json.as_object().unwrap().iter().map(|(k, v)| (k.trim_end_matches("_ms").to_string(), v.as_f64().unwrap())).collect();
        assert_eq!(t.by_stage(), fields);
    }
}
