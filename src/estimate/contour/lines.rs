//! Correspondence lines: the model's contour points projected at a pose, each with a short
//! line of segments along its projected normal, and from the foreground probability of
//! those segments a distribution over where the object's outline crosses the line (the
//! discrete formulation of SRT3D, with a smoothed step as the segment likelihood).

use super::photo_edge::{edge_offset, profile_inside_px};
use super::posterior::Posterior;
use crate::geometry::{Intrinsics, Pose};
use crate::onboard::ContourModel;
use image::RgbImage;
use nalgebra::{Matrix2x3, Point3, Vector2, Vector3};
use rayon::prelude::*;

/// Largest share of the background probability a segment's likelihood reaches (the
/// smoothed step runs from 0.5 − this to 0.5 + this); below 0.5 so that one wrong segment
/// cannot veto a location.
const STEP_AMPLITUDE: f64 = 0.43;

/// Lines of segments at most this long (px) look for the photo's edge near the mask's
/// outline (`photo_edge`): at coarser scales the mask's pixel steps are below what the
/// line resolves anyway.
const PHOTO_EDGE_MAX_SEGMENT_PX: f64 = 2.0;
/// How far (px) from the mask's outline the photo's edge may lie: the mask's own pixel
/// steps, and a mask drawn a pixel wide or narrow, as segmenters' often are (at 1.0 the
/// true outline sat on the reach's border under such a mask and fewer lines found it:
/// `tests/contour.rs`, photo_edges_keep_the_depth_under_a_mask_a_pixel_too_wide).
const PHOTO_EDGE_REACH_PX: f64 = 1.5;

/// Where fine lines read the photo's edges.
#[derive(Clone, Copy)]
pub struct PhotoLines<'a> {
    pub image: &'a RgbImage,
    /// Only lines whose surface stays plain (`ContourModel::plain_m`) as far inside the
    /// outline as the edge finder reads: on a printed object the others could take a print's
    /// edge for the outline.
    pub plain_only: bool,
}

/// One correspondence line.
#[derive(Clone, Debug)]
pub struct Line {
    /// The contour point, object frame (metres).
    pub object_point: Vector3<f64>,
    /// Where the point projected when the line was built, and the unit outward normal there.
    pub centre: Vector2<f64>,
    pub normal: Vector2<f64>,
    /// Mean and variance (px, px²) of the outline's offset from `centre` along `normal`.
    pub mean: f64,
    pub variance: f64,
    /// The line crosses from object to background (some segment clearly each).
    pub edge: bool,
    /// How far the line reaches inside the model's outline, px.
    pub inside_px: f64,
    /// `mean` is where the photo's edge is, to a fraction of a pixel, rather than the
    /// mask's outline.
    pub photo_edge: bool,
}

/// Line settings for one scale.
#[derive(Clone, Copy, Debug)]
pub struct LineScale {
    /// Segment length, pixels.
    pub segment_px: f64,
    /// Segments on each side of the centre at most (fewer where the object or the gap to
    /// it along the normal is shorter).
    pub segments: usize,
}

/// Jacobian of the pinhole projection at camera-frame point `p`.
pub fn projection_jacobian(k: &Intrinsics, p: &Point3<f64>) -> Matrix2x3<f64> {
    let iz = 1.0 / p.z;
    Matrix2x3::new(k.fx * iz, 0.0, -k.fx * p.x * iz * iz, 0.0, k.fy * iz, -k.fy * p.y * iz * iz)
}

/// Direction from the object's bounding-box centre to the camera, object frame.
pub fn camera_direction(pose: &Pose, centre: &Vector3<f64>) -> Vector3<f64> {
    pose.inverse().translation - centre
}

/// Builds the lines of the view nearest to `pose` and measures the outline on each: on
/// the mask, and at fine scales, where `photo` is given, on the photo's edge beside it.
pub fn build_lines(cm: &ContourModel, centre: &Vector3<f64>, pose: &Pose, k: &Intrinsics, post: &Posterior<'_>, scale: LineScale, photo: Option<PhotoLines<'_>>) -> Vec<Line> {
    let view = cm.nearest_view(&camera_direction(pose, centre));
    let photo = photo.filter(|_| scale.segment_px <= PHOTO_EDGE_MAX_SEGMENT_PX);
    cm.view_range(view).into_par_iter().filter_map(|i| line(cm, i, pose, k, post, scale, photo)).collect()
}

/// Contour point `i` of the model seen at `pose`.
pub struct ProjectedRimPoint {
    /// The point, object frame (metres).
    pub object_point: Vector3<f64>,
    /// Where it projects, and the unit outward normal of the outline there.
    pub centre: Vector2<f64>,
    pub normal: Vector2<f64>,
    /// Image pixels per metre at its depth.
    pub px_per_m: f64,
}

/// Contour point `i` projected at `pose`; `None` behind the camera or where its normal
/// projects to nothing (seen edge-on).
pub fn project_rim_point(cm: &ContourModel, i: usize, pose: &Pose, k: &Intrinsics) -> Option<ProjectedRimPoint> {
    let x = Vector3::new(cm.points[i][0] as f64, cm.points[i][1] as f64, cm.points[i][2] as f64);
    let n = Vector3::new(cm.normals[i][0] as f64, cm.normals[i][1] as f64, cm.normals[i][2] as f64);
    let p = Point3::from(pose.rotation * x + pose.translation);
    let centre = k.project(&p)?;
    let n2 = projection_jacobian(k, &p) * (pose.rotation * n);
    let len = n2.norm();
    if len < 1e-9 {
        return None;
    }
    Some(ProjectedRimPoint { object_point: x, centre, normal: n2 / len, px_per_m: k.fx.max(k.fy) / p.z })
}

/// Line `i` of the model at `pose`; `None` when it cannot be measured at this scale.
fn line(cm: &ContourModel, i: usize, pose: &Pose, k: &Intrinsics, post: &Posterior<'_>, scale: LineScale, photo: Option<PhotoLines<'_>>) -> Option<Line> {
    let ProjectedRimPoint { object_point: x, centre: centre_px, normal, px_per_m } = project_rim_point(cm, i, pose, k)?;
    let inner = ((cm.foreground_m[i] as f64 * px_per_m / scale.segment_px).floor() as usize).min(scale.segments);
    let outer = ((cm.background_m[i] as f64 * px_per_m / scale.segment_px).floor() as usize).min(scale.segments);
    // Fewer than two segments a side cannot place an outline (a thin part at a coarse
    // scale): the line waits for a finer scale.
    if inner < 2 || outer < 2 {
        return None;
    }
    let probs = segment_probabilities(post, &centre_px, &normal, scale.segment_px, inner, outer);
    let (mean, variance) = outline_distribution(&probs, inner, scale.segment_px);
    let edge = probs.iter().any(|&p| p > 0.7) && probs.iter().any(|&p| p < 0.3);
    // The photo moves the outline within the mask's pixel step; its weight stays the
    // mask's, so a line is trusted no more for having found a sharp edge.
    let plain = |p: &PhotoLines<'_>| !p.plain_only || cm.plain_m(i).is_some_and(|m| m as f64 * px_per_m >= profile_inside_px(PHOTO_EDGE_REACH_PX));
    let on_photo = photo.filter(|p| edge && plain(p)).and_then(|p| edge_offset(p.image, &centre_px, &normal, mean, PHOTO_EDGE_REACH_PX));
    Some(Line { object_point: x, centre: centre_px, normal, mean: on_photo.unwrap_or(mean), variance, edge, inside_px: inner as f64 * scale.segment_px, photo_edge: on_photo.is_some() })
}

/// Mean foreground probability of each segment, innermost first: `inner` segments inside
/// the projected outline, then `outer` outside.
fn segment_probabilities(post: &Posterior<'_>, c: &Vector2<f64>, n: &Vector2<f64>, s: f64, inner: usize, outer: usize) -> Vec<f64> {
    let samples = s.round().max(1.0) as usize;
    (0..inner + outer)
        .map(|r| {
            let start = (r as f64 - inner as f64) * s;
            let sum: f64 = (0..samples)
                .map(|j| {
                    let d = start + (j as f64 + 0.5) * s / samples as f64;
                    post.foreground(c.x + n.x * d, c.y + n.y * d) as f64
                })
                .sum();
            sum / samples as f64
        })
        .collect()
}

/// Half-segment steps beyond which the smoothed step is flat (tanh(3.5) ≈ 0.998): there a
/// segment's likelihood no longer depends on the exact offset, which `outline_distribution`
/// uses to sum the far segments by prefix sums instead of one logarithm per pair.
const STEP_REACH: i64 = 7;

/// The smoothed step at k = −REACH − 1 ..= REACH + 1 half-segment steps beyond the outline:
/// the same for every line, so its `tanh`s are taken once per process, not per line.
fn step_table() -> &'static [f64; 2 * STEP_REACH as usize + 3] {
    static TABLE: std::sync::OnceLock<[f64; 2 * STEP_REACH as usize + 3]> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| std::array::from_fn(|i| 0.5 + STEP_AMPLITUDE * ((i as i64 - STEP_REACH - 1) as f64 * 0.5).tanh()))
}

/// Lowest and highest segment probability `outline_distribution` takes: the posterior's
/// own bounds are 0.1 and 0.9, so this changes nothing it gives; it keeps every segment's
/// chance at least 0.07, so that a product over a line's (at most a few dozen) segments
/// stays far above f64's smallest value.
const PROB_BOUNDS: (f64, f64) = (0.01, 0.99);

/// Mean and variance (px) of the outline's offset along the line, given the segments'
/// foreground probabilities: a uniform prior over offsets at half-segment steps, and for
/// each segment the likelihood of its probability if the outline sat at that offset.
///
/// The likelihoods are multiplied, not summed as logarithms: a candidate's weight is the
/// product of its far-inside segments' chances (a prefix product), of its far-outside ones'
/// (a suffix product) and of its near ones', with no logarithm or exponential per
/// candidate (they were a tenth of an estimate's time).
pub fn outline_distribution(probs: &[f64], inner: usize, s: f64) -> (f64, f64) {
    let n = probs.len();
    let candidates = 2 * n + 1;
    let offset = |c: usize| (c as f64 * 0.5 - inner as f64) * s;
    // Segment r seen from candidate c sits (2r + 1 − c)/2 segments beyond the outline, so
    // its likelihood depends on k = 2r + 1 − c alone.
    let steps = step_table();
    // A segment's chance under a step value h is h·(1 − p) + (1 − h)·p = p + h·(1 − 2p):
    // p and 1 − 2p per segment, one multiply-add per (segment, candidate).
    let terms: Vec<(f64, f64)> = probs.iter().map(|p| p.clamp(PROB_BOUNDS.0, PROB_BOUNDS.1)).map(|p| (p, 1.0 - 2.0 * p)).collect();
    let chance = |(p, q): (f64, f64), h_bg: f64| p + h_bg * q;
    let (flat_in, flat_out) = (steps[0], steps[steps.len() - 1]);
    // inside[r]: the chances of segments 0..r all far inside; outside[r]: of segments r..n
    // all far outside.
    let mut inside = vec![1.0; n + 1];
    let mut outside = vec![1.0; n + 1];
    for (r, &t) in terms.iter().enumerate() {
        inside[r + 1] = inside[r] * chance(t, flat_in);
    }
    for (r, &t) in terms.iter().enumerate().rev() {
        outside[r] = outside[r + 1] * chance(t, flat_out);
    }
    let near = &steps[1..steps.len() - 1]; // k = −REACH ..= REACH
    let w: Vec<f64> = (0..candidates as i64)
        .map(|c| {
            // Segments with k < −REACH (far inside): r < (c − 1 − REACH)/2; k > REACH: r > (c − 1 + REACH)/2.
            let lo = ((c - 1 - STEP_REACH + 1).div_euclid(2)).clamp(0, n as i64) as usize; // first r with k ≥ −REACH
            let hi = ((c - 1 + STEP_REACH).div_euclid(2) + 1).clamp(lo as i64, n as i64) as usize; // first r with k > REACH
                                                                                                   // Segment lo's step, then every second one (k grows by 2 with r).
            let first_k = (2 * lo as i64 + 1 - c + STEP_REACH) as usize;
            let near_chance: f64 = terms[lo..hi].iter().zip(near[first_k..].iter().step_by(2)).map(|(&t, &h)| chance(t, h)).product();
            inside[lo] * outside[hi] * near_chance
        })
        .collect();
    let total: f64 = w.iter().sum();
    let mean = w.iter().enumerate().map(|(c, wi)| wi * offset(c)).sum::<f64>() / total;
    let var = w.iter().enumerate().map(|(c, wi)| wi * (offset(c) - mean).powi(2)).sum::<f64>() / total;
    // Never more certain than the candidate spacing allows.
    (mean, var + s * s / 12.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outline_found_where_probabilities_flip() {
        // Four object segments, then background from the third outer one on: the outline
        // is two segments (2·s px) outside the centre.
        let s = 2.0;
        let probs = [0.9, 0.9, 0.9, 0.9, 0.9, 0.9, 0.1, 0.1, 0.1, 0.1];
        let (mean, var) = outline_distribution(&probs, 4, s);
        assert!((mean - 4.0).abs() < 0.5, "mean {mean}");
        // About one segment's uncertainty: the smoothed step and the 0.9 / 0.1 contrast.
        assert!(var < 1.5 * s * s, "variance {var}");
        // Uninformative segments: a flat distribution centred on the line's middle.
        let (mean, var) = outline_distribution(&[0.5; 8], 4, s);
        assert!(mean.abs() < 1e-9 && var > 10.0);
    }

    /// The product evaluation equals summing every segment's log-likelihood with the exact
    /// step, on smooth probabilities and on a long line of the posterior's extremes (where
    /// a product of every segment's chance is smallest).
    #[test]
    fn fast_distribution_matches_the_direct_sum() {
        let smooth: Vec<f64> = (0..20).map(|i| 0.5 + 0.4 * ((i as f64) * 0.7).sin()).collect();
        let extremes: Vec<f64> = (0..64).map(|i| if (i * 7) % 5 < 2 { 0.9 } else { 0.1 }).collect();
        for (probs, inners) in [(&smooth, [3usize, 8, 12]), (&extremes, [5, 32, 60])] {
            for inner in inners {
                let s = 1.5;
                let n = probs.len();
                let offset = |c: usize| (c as f64 * 0.5 - inner as f64) * s;
                let log_l: Vec<f64> = (0..2 * n + 1)
                    .map(|c| {
                        probs
                            .iter()
                            .enumerate()
                            .map(|(r, &p)| {
                                let x = (r as f64 + 0.5 - inner as f64) * s - offset(c);
                                let k = (2.0 * x / s).round() as i64;
                                let h = 0.5 + STEP_AMPLITUDE * ((k.clamp(-STEP_REACH - 1, STEP_REACH + 1)) as f64 * 0.5).tanh();
                                (h * (1.0 - p) + (1.0 - h) * p).ln()
                            })
                            .sum()
                    })
                    .collect();
                let top = log_l.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
                let w: Vec<f64> = log_l.iter().map(|l| (l - top).exp()).collect();
                let total = w.iter().sum::<f64>();
                let mean = w.iter().enumerate().map(|(c, wi)| wi * offset(c)).sum::<f64>() / total;
                let var = w.iter().enumerate().map(|(c, wi)| wi * (offset(c) - mean).powi(2)).sum::<f64>() / total + s * s / 12.0;
                let (fast_mean, fast_var) = outline_distribution(probs, inner, s);
                assert!((fast_mean - mean).abs() < 1e-9 && (fast_var - var).abs() < 1e-9, "n {n}, inner {inner}: {fast_mean}, {fast_var} vs {mean}, {var}");
            }
        }
    }

    #[test]
    fn projection_jacobian_matches_finite_differences() {
        let k = Intrinsics { fx: 600.0, fy: 580.0, cx: 320.0, cy: 240.0, width: 640, height: 480 };
        let p = Point3::new(0.05, -0.03, 0.7);
        let j = projection_jacobian(&k, &p);
        let proj = |q: &Point3<f64>| Vector2::new(k.fx * q.x / q.z + k.cx, k.fy * q.y / q.z + k.cy);
        for a in 0..3 {
            let mut q = p;
            q[a] += 1e-7;
            let num = (proj(&q) - proj(&p)) / 1e-7;
            assert!((num - j.column(a)).norm() < 1e-3);
        }
    }
}
