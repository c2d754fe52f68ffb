//! Finds onboarded objects in an RGB-D frame: every surface standing off the table
//! (`depth_segments`) whose size in metres fits an object is a candidate of that object,
//! with the segment as its mask and a placement from the measured surface. Nothing is
//! learned and nothing is painted: clutter in the photo makes no segment, and a thing of
//! the wrong size is no candidate. Which object a segment is, and its turn, the estimator
//! decides with the confirmation at the estimated pose (`confirm`, with the depth check of
//! `depth_check`): the candidates' scores here rank by size and solidity only.

use super::depth_segments::{segment_frame, Segment};
use super::detector::{check_options, DetectError, DetectOptions, DetectReport, DetectTimings, Detection, MaskSource, Searched, Target};
use super::verify::Evidence;
use crate::depth::DepthImage;
use crate::geometry::{Intrinsics, Pose};
use image::RgbImage;
use nalgebra::{Rotation3, Vector3};
use std::time::Instant;

/// A segment fits an object when its extent is at most this share of the object's
/// diameter (and `SIZE_NOISE_M` more, for the sensor's ragged edges) ...
const MAX_EXTENT_SHARE: f64 = 1.15;
const SIZE_NOISE_M: f64 = 0.01;
/// ... and at least this share: less is too little of it in view to estimate from.
const MIN_EXTENT_SHARE: f64 = 0.25;
/// A segment filling at least this much of its diagonal's square (`Segment::fill`) is as
/// solid as an object's view (a 4 : 1 rectangle fills 0.24); thinner or sparser ones rank
/// lower in proportion: the size alone ties a cable's run with an object.
const SOLID_FILL: f64 = 0.2;

/// Looks for every target in the frame (`image` with its registered `depth`).
pub fn detect_with_depth(image: &RgbImage, depth: &DepthImage, k: &Intrinsics, targets: &[Target], opts: &DetectOptions) -> Result<DetectReport, DetectError> {
    let t0 = Instant::now();
    check_options(opts)?;
    if depth.dimensions() != image.dimensions() {
        let (w, h) = depth.dimensions();
        return Err(DetectError::BadInput(format!("depth is {w}×{h} but the image is {}×{}: it must be registered to the colour image", image.width(), image.height())));
    }
    let largest = targets.iter().map(|t| t.mesh.diameter()).fold(0.0, f64::max);
    let segmentation = segment_frame(depth, k, largest, largest_fit(largest));
    let segments: Vec<&Segment> = segmentation.segments.iter().filter(|s| in_range(s, opts)).collect();
    let search_ms = t0.elapsed().as_secs_f64() * 1e3;
    let nearest = segments.iter().map(|s| s.median_z).fold(f64::INFINITY, f64::min);
    let farthest = segments.iter().map(|s| s.median_z).fold(0.0, f64::max);
    // Each object's fits, (score, (target, segment)). Segments share no pixel, so no suppression is
    // needed within an object; across objects a segment stays a candidate of each object it
    // fits (the size cannot tell them apart; the confirmation at the estimated pose does).
    let mut fits: Vec<Vec<(f32, (usize, usize))>> = Vec::new();
    let mut searched = Vec::new();
    for (ti, t) in targets.iter().enumerate() {
        let d = t.mesh.diameter().max(1e-6);
        let mut own: Vec<(f32, (usize, usize))> = segments.iter().enumerate().filter_map(|(si, s)| fit(s, d).map(|fit| (fit, (ti, si)))).collect();
        searched.push(Searched { object_id: t.id.to_string(), distance_m: [nearest, farthest], scales: 1, candidates: own.len() });
        own.retain(|f| f.0 >= opts.min_score);
        own.sort_by(|a, b| b.0.total_cmp(&a.0));
        fits.push(own);
    }
    let fits = fairly_ranked(fits, opts.max_detections);
    // Masks are copied only for the detections answered.
    let kept: Vec<Detection> = fits.into_iter().map(|(score, (ti, si))| candidate(&targets[ti], segments[si], score)).collect();
    let reason = kept.is_empty().then(|| why_none(&segmentation.segments, &segments, targets, opts));
    let total_ms = t0.elapsed().as_secs_f64() * 1e3;
    Ok(DetectReport { detections: kept, searched, timings: DetectTimings { search_ms, total_ms, ..Default::default() }, reason })
}

/// At most `max` fits over all objects (each object's best first), taken rank by rank: every
/// object's best before any object's second, and within a rank the higher score first.
/// Sizes tie often (a segment fits every object of about its size), so a plain sort by
/// score would fill the budget with the first objects searched and leave the last none.
fn fairly_ranked<T>(per_object: Vec<Vec<(f32, T)>>, max: usize) -> Vec<(f32, T)> {
    let mut all: Vec<(usize, f32, T)> = per_object.into_iter().flat_map(|own| own.into_iter().enumerate().map(|(rank, (score, t))| (rank, score, t))).collect();
    all.sort_by(|a, b| a.0.cmp(&b.0).then(b.1.total_cmp(&a.1)));
    all.into_iter().take(max).map(|(_, score, t)| (score, t)).collect()
}

/// Whether the segment lies within the caller's distance range.
fn in_range(s: &Segment, opts: &DetectOptions) -> bool {
    opts.min_distance_m.is_none_or(|m| s.median_z >= m) && opts.max_distance_m.is_none_or(|m| s.median_z <= m)
}

/// The largest segment extent (metres) that can be an object of `diameter`.
fn largest_fit(diameter: f64) -> f64 {
    MAX_EXTENT_SHARE * diameter + SIZE_NOISE_M
}

/// How well a segment `extent` (metres) fits an object of `diameter`: None when it cannot
/// be the object; else 0–1, highest for a segment as large as the object (a whole view
/// spans most of the diameter), lower for a small part of it in view.
fn size_fit(extent: f64, diameter: f64) -> Option<f32> {
    if extent > largest_fit(diameter) || extent < MIN_EXTENT_SHARE * diameter {
        return None;
    }
    let share = extent / diameter;
    Some(if share <= 0.8 { (share / 0.8).sqrt() } else { 1.0 } as f32)
}

/// How well segment `s` can be a view of an object of `diameter`: its span against the
/// diameter (not its box diagonal, which a round thing's view runs past), times its
/// solidity; None when its size rules the object out.
fn fit(s: &Segment, diameter: f64) -> Option<f32> {
    size_fit(s.span_m, diameter).map(|f| f * solidity(s.fill))
}

/// How solid a segment of `fill` is, 0–1 (`SOLID_FILL` and more: 1).
fn solidity(fill: f64) -> f32 {
    (fill / SOLID_FILL).min(1.0) as f32
}

/// The candidate of target `t` on segment `s`: its mask and box, and a placement (the
/// object's centre behind the surface's centre by half its radius, its first template's
/// turn facing the camera): where it is, not how it is turned.
fn candidate(t: &Target, s: &Segment, score: f32) -> Detection {
    let r = t.mesh.bounding_radius();
    let ray = s.centre.coords.normalize();
    let align = Rotation3::rotation_between(&Vector3::z(), &ray).unwrap_or_else(Rotation3::identity);
    let rotation = align * t.shape.config.rotation(0);
    let centre = s.centre.coords + ray * (0.5 * r);
    let pose = Pose::new(rotation, centre - rotation * Vector3::from(t.mesh.bbox_center()));
    Detection { object_id: t.id.to_string(), bbox: s.bbox, score, shape_score: 0.0, evidence: Evidence::default(), mask: s.mask.clone(), mask_source: MaskSource::DepthSegment, pose, template: 0 }
}

/// Why a frame gave no candidate, in the words a caller can act on.
fn why_none(all: &[Segment], in_range: &[&Segment], targets: &[Target], opts: &DetectOptions) -> String {
    if all.is_empty() {
        return "the depth shows nothing standing off the table or the walls (no segment)".to_string();
    }
    if in_range.is_empty() {
        return format!("no segment within the distance range ({} segments outside it)", all.len());
    }
    let sizes: Vec<String> = in_range.iter().take(5).map(|s| format!("{:.0} mm", s.extent_m * 1e3)).collect();
    let wanted: Vec<String> = targets.iter().map(|t| format!("{} {:.0} mm", t.id, t.mesh.diameter() * 1e3)).collect();
    format!("no segment of the objects' size ({} segments, largest first: {}; objects: {}) scored {} or more", in_range.len(), sizes.join(", "), wanted.join(", "), opts.min_score)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn segments_fit_objects_of_their_size_only() {
        assert_eq!(size_fit(0.2, 0.2), Some(1.0));
        assert!(size_fit(0.08, 0.2).unwrap() < 0.8);
        assert_eq!(size_fit(0.3, 0.2), None, "larger than the object");
        assert_eq!(size_fit(0.03, 0.2), None, "too little of it");
        assert!(size_fit(0.225, 0.2).is_some(), "ragged edges allowed for");
    }

    #[test]
    fn a_round_things_view_fits_by_its_span_not_its_box_diagonal() {
        // A whole mug's view (diameter 125 mm): its box diagonal 170 mm is past what the mug
        // can be, its span is the mug's size.
        let mug = Segment { mask: image::GrayImage::new(1, 1), bbox: [0.0; 4], pixels: 1, extent_m: 0.170, span_m: 0.125, centre: nalgebra::Point3::origin(), median_z: 0.7, fill: 0.4 };
        assert_eq!(size_fit(mug.extent_m, 0.125), None);
        assert_eq!(fit(&mug, 0.125), Some(1.0));
        // A cable's run as long: the same size, a fifth as solid.
        let cable = Segment { fill: 0.04, ..mug.clone() };
        assert!((fit(&cable, 0.125).unwrap() - 0.2).abs() < 1e-6);
        assert_eq!(fit(&mug, 0.05), None, "larger than a small part");
    }

    #[test]
    fn every_object_keeps_its_best_fits_within_the_budget() {
        // Object 0 has three perfect fits, object 1 two weaker ones: a budget of 3 keeps
        // each object's best before anyone's third.
        let fits = vec![vec![(1.0, "a0"), (1.0, "a1"), (1.0, "a2")], vec![(0.7, "b0"), (0.6, "b1")]];
        assert_eq!(fairly_ranked(fits.clone(), 3), vec![(1.0, "a0"), (0.7, "b0"), (1.0, "a1")]);
        assert_eq!(fairly_ranked(fits, 10).len(), 5);
    }
}
