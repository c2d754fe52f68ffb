//! Hypothesis verification: every hypothesis of a mask is refined, scored on the evidence
//! that survives the render-to-real gap (the outline against the mask, one render's
//! silhouette IoU, and whether the render's interior edges run where the photo's do), and
//! the best one is kept. The multi-mask selection then runs on the survivors.

use super::hypotheses::Source;
use super::refine::RefineReport;
use super::select::{window_camera, window_iou};
use crate::features::grey;
use crate::geometry::{Intrinsics, Pose};
use crate::render::{RenderOptions, RenderOutput, RenderPool};
use image::{GrayImage, RgbImage};
use rayon::prelude::*;
use std::ops::Range;

#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct VerifyConfig {
    /// Refine and verify the extra hypotheses at all (off: the pipeline's pose alone). On
    /// by default: on generated HOPE scenes it gained 2–16 points of MSSD recall for about
    /// 0.1 s per instance on 2 CPU cores (docs/benchmarks/estimation-verification.md,
    /// "Contour refiner").
    pub enabled: bool,
    /// Retrieved templates placed at the mask as extra hypotheses.
    pub templates: usize,
    /// The templates with the most matches, each placed where its matches put it (not
    /// where the mask's box does): hypotheses that survive occlusion
    /// (`placement::matched_templates`).
    pub matched_templates: usize,
    /// Spins of the pose about each object axis: this many equal steps of a whole turn
    /// (the quarter turns are the axis flips already; 0 or 4 adds none).
    pub spin_steps: usize,
    /// Hypotheses (best contour agreement first) that get a render for IoU and appearance.
    pub rendered: usize,
    /// Beyond those, every hypothesis whose contour agreement is within this of the best
    /// gets a render too, up to `max_rendered` in all: where the outline cannot tell the
    /// hypotheses apart (a can turned about its axis, a box half-turned), only its render
    /// against the photo can, and a cut at a fixed count would be arbitrary.
    pub contour_tie: f64,
    pub max_rendered: usize,
    /// Weights of silhouette IoU, contour agreement and appearance agreement.
    pub weights: [f64; 3],
    /// Share of colour agreement in the appearance term (the rest is edge agreement),
    /// where the mesh has colours of its own (texture or vertex colours).
    pub colour_share: f64,
    /// Refine one hypothesis per class of poses equal up to the object's symmetries (where
    /// they are known), not each. Off by default: on a uniformly coloured cube it saved
    /// about 110 ms per instance and cost about 5 points of MSSD recall, the copies acting
    /// as restarts of the refiner (docs/estimation.md, "Symmetries").
    pub skip_symmetric: bool,
    /// Share of the backbone's own dense descriptors in the appearance term
    /// (`feature_agreement`: the render and the photo encoded on the same crop, compared
    /// patch by patch); the rest is edges and colour. 0 skips the extra backbone pass. 0.5
    /// by measurement (docs/benchmarks/estimation-verification.md, "Feature-metric
    /// verification"): it separated right from wrong hypotheses best of all terms on
    /// default, harsh and gap scenes, and picked 2 more right poses of 120 for one batched
    /// backbone pass over the renders.
    pub feature_share: f64,
    /// Hypotheses refined in full: the best this many by contour agreement where they
    /// start, and the pipeline's pose always; 0 refines all.
    pub refined: usize,
    /// Hypotheses the contour refiner takes past its first line scale: the best this many
    /// by their outline's agreement with the mask there, the pipeline's pose, the depth's
    /// views and the caller's hints always; the others are dropped. 0 finishes all. 16 of
    /// the 32 by measurement (docs/benchmarks/estimation-occlusion-and-speed.md, "Only the best
    /// hypotheses past the first line scale"): on 510 generated HOPE instances over eleven
    /// sets it changed four verdicts (three to wrong, one to right) for about a seventh
    /// less time an estimate.
    pub finished: usize,
    /// Where the mesh has colours and the winner's print (edges and colour) agrees with
    /// nothing in the photo, render every hypothesis and verify the axis flips of the one
    /// whose print agrees best (`pipeline::second_look`).
    pub second_look: bool,
    /// Silhouette IoU ignores the render's pixels under other detections (where the mask
    /// cannot show this object even when it is there), rather than counting them against
    /// the pose.
    pub occlusion_aware_iou: bool,
    /// Where the pipeline's pose projects to an outline whose box differs from the mask's by
    /// more than a quarter in size or centre, take its flips and spins about that pose
    /// re-placed at the mask (`hypotheses::replaced_at_mask`), which is verified too: PnP can
    /// put the object far off in depth, and flips about a wrong place cannot reach the
    /// right pose.
    pub replace_off_mask: bool,
    /// Tilt the winner by this many degrees each way across the line of sight, refine the
    /// four tilts and judge those the refiner does not bring back (`pipeline::nudge`); 0:
    /// off, at most [`MAX_NUDGE_DEGREES`]. 8 by measurement: on generated HOPE scenes it
    /// gained 1.2–7.5 points of MSSD recall on nine of ten sets, from true masks, boxes and
    /// harsh scenes (small objects settled 4–8° off, their depth pulled to fit the
    /// outline), for 20–55 ms more per instance on 2 CPU cores
    /// (docs/benchmarks/estimation-boxes-and-nudges.md, "The nudge across the line of
    /// sight").
    pub nudge_degrees: f64,
    /// With depth: the template views placed on the measured surface under the mask and
    /// fitted there (`depth_search`), this many of the best, as hypotheses that are always
    /// rendered and judged. 0 turns the search off.
    pub depth_views: usize,
}

impl Default for VerifyConfig {
    fn default() -> Self {
        // Measured on 400 generated HOPE instances
        // (docs/benchmarks/estimation-verification.md, "Contour refiner"): 10 templates and
        // 45° spins give the right pose a candidate far more often than 3 templates and the
        // flips alone (oracle 79.5 → 88.5 % on seed 7), colour agreement picks it more
        // often (+1–1.5 points at any share from 0.25 to 1), and 12 renders kept most of
        // what rendering all would; since only the best 16 are refined to the end, 10 keep
        // what 12 did (709 of 710 answers identical, one more right: "Only the best
        // hypotheses past the first line scale" in
        // docs/benchmarks/estimation-occlusion-and-speed.md). Half of those 10 templates
        // are now the ones with the most matches, placed by their matches: right more
        // often than the retrieved ones placed at the mask, for the same time
        // (docs/benchmarks/estimation-occlusion-and-speed.md, "Templates placed by their
        // matches").
        Self {
            enabled: true,
            templates: 5,
            matched_templates: 5,
            spin_steps: 8,
            rendered: 3,
            contour_tie: 0.05,
            max_rendered: 10,
            weights: [0.4, 0.3, 0.3],
            colour_share: 0.5,
            skip_symmetric: false,
            feature_share: 0.5,
            refined: 0,
            finished: 16,
            second_look: true,
            occlusion_aware_iou: true,
            replace_off_mask: true,
            nudge_degrees: 8.0,
            depth_views: 4,
        }
    }
}

/// The largest nudge: beyond it a turn is no nudge, and the flips and spins cover it.
pub const MAX_NUDGE_DEGREES: f64 = 45.0;

/// `degrees` if it is a nudge (`VerifyConfig::nudge_degrees`): from 0 to
/// [`MAX_NUDGE_DEGREES`]; what is wrong with it otherwise.
pub fn nudge_in_range(degrees: f64) -> Result<f64, String> {
    if (0.0..=MAX_NUDGE_DEGREES).contains(&degrees) {
        Ok(degrees)
    } else {
        Err(format!("{degrees} is outside 0–{MAX_NUDGE_DEGREES} degrees"))
    }
}

/// One verified hypothesis, as reported.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Verified {
    pub source: Source,
    #[serde(skip)]
    pub pose: Pose,
    pub refinement: RefineReport,
    /// Contour agreement after refinement, [0, 1].
    pub contour: f64,
    /// Silhouette IoU and appearance agreement of its render (NaN when not rendered).
    pub iou: f64,
    pub appearance: f64,
    /// The two parts of `appearance`: edge and colour agreement (NaN when not rendered;
    /// colour also where the mesh has no colours).
    pub edges: f64,
    pub colour: f64,
    /// Feature-metric agreement of its render with the photo (NaN when not computed).
    pub features: f64,
    pub score: f64,
    /// The window render behind `iou` and `appearance`, kept for the winner so that
    /// selection does not render the same pose again.
    #[serde(skip)]
    pub render: Option<RenderOutput>,
}

impl Verified {
    /// A refined hypothesis with its contour agreement, not yet rendered or scored.
    pub fn unscored(source: Source, pose: Pose, refinement: RefineReport, contour: f64) -> Self {
        Self { source, pose, refinement, contour, iou: f64::NAN, appearance: f64::NAN, edges: f64::NAN, colour: f64::NAN, features: f64::NAN, score: f64::NAN, render: None }
    }
}

/// Sobel gradient of `at(x, y)` at interior point (x, y).
fn sobel(at: impl Fn(u32, u32) -> f32, x: u32, y: u32) -> (f32, f32) {
    let gx = at(x + 1, y - 1) + 2.0 * at(x + 1, y) + at(x + 1, y + 1) - at(x - 1, y - 1) - 2.0 * at(x - 1, y) - at(x - 1, y + 1);
    let gy = at(x - 1, y + 1) + 2.0 * at(x, y + 1) + at(x + 1, y + 1) - at(x - 1, y - 1) - 2.0 * at(x, y - 1) - at(x + 1, y - 1);
    (gx, gy)
}

/// Whether window pixel (x, y), at least 2 px from the window's edge, lies 2 px or more
/// inside the render's silhouette: its outline's pixels mix object and background.
fn well_inside(render: &RenderOutput, x: u32, y: u32) -> bool {
    // The raw buffer by index: the check runs for every pixel of the silhouette's box, ten
    // reads each.
    let (mask, stride) = (render.mask.as_raw(), render.mask.width() as usize);
    let i = y as usize * stride + x as usize;
    (0..=4).all(|d| mask[i + d - 2] > 0 && mask[i + d * stride - 2 * stride] > 0)
}

/// The columns and rows of a `w × h` window where pixels can lie [`well_inside`] the
/// render's silhouette and the Sobel kernels can read them (3 px from the window's edge):
/// the silhouette's box shrunk by the 2 px `well_inside` asks for. Empty where there is
/// none. The window is up to three object radii a side around a tracked object, its
/// silhouette a third of it.
fn interior_span(render: &RenderOutput, w: u32, h: u32) -> (Range<u32>, Range<u32>) {
    let span = crate::features::mask_bbox(&render.mask).filter(|_| w >= 7 && h >= 7);
    span.map_or((0..0, 0..0), |(lx, ly, hx, hy)| ((lx + 2).max(3)..(hx.saturating_sub(2) + 1).min(w - 3), (ly + 2).max(3)..(hy.saturating_sub(2) + 1).min(h - 3)))
}

/// The pixels of `span` (`interior_span`), row by row, that lie [`well_inside`] the
/// render's silhouette.
fn interior_pixels<'a>(render: &'a RenderOutput, (xs, ys): &(Range<u32>, Range<u32>)) -> impl Iterator<Item = (u32, u32)> + 'a {
    let xs = xs.clone();
    ys.clone().flat_map(move |y| xs.clone().map(move |x| (x, y))).filter(|&(x, y)| well_inside(render, x, y))
}

/// Grey levels of the pixels (x, y) ∈ `xs` × `ys` (an `interior_span`, so at least 3 px
/// from the window's edge) grown by the one pixel a Sobel kernel reaches, read through
/// `at`, and a lookup by the same coordinates: the kernels read each pixel up to six
/// times, and converting it once is most of what the edges cost.
fn grey_patch<'a>((xs, ys): &(Range<u32>, Range<u32>), at: impl Fn(u32, u32) -> &'a image::Rgb<u8>) -> impl Fn(u32, u32) -> f32 {
    let (x0, y0) = (xs.start - 1, ys.start - 1);
    let width = (xs.end + 1 - x0) as usize;
    let values: Vec<f32> = (y0..ys.end + 1).flat_map(|y| (x0..x0 + width as u32).map(move |x| (x, y))).map(|(x, y)| grey(at(x, y))).collect();
    move |x, y| values[(y - y0) as usize * width + (x - x0) as usize]
}

/// Grey-level Sobel magnitude (of 8·255 at most) below which a pixel has no edge.
const EDGE: f32 = 40.0;

/// How well the render's interior edges (its texture, colours and creases; not its
/// outline, which the other terms judge) line up with the photo's, in [0, 1]: over the
/// pixels well inside both the render's silhouette and the mask where either image has an
/// edge, the mean squared cosine between the two gradient orientations (0 where only one
/// has an edge). Counting the photo's edges too matters: a plain side of the object (its
/// back, with the label on the front) must not score well against a printed photo just
/// because its few edges happen to agree. Orientation, not sign or strength: lighting
/// changes both across the gap.
pub fn appearance_agreement(render: &RenderOutput, image: &RgbImage, mask: &GrayImage, window: (u32, u32, u32, u32)) -> f64 {
    let (x0, y0) = (window.0, window.1);
    appearance_agreement_where(render, image, window, &|x, y| mask.get_pixel(x0 + x, y0 + y)[0] > 0)
}

/// [`appearance_agreement`] over the window pixels (window coordinates) that `in_mask`
/// admits, for callers without a mask image (a tracker checks its own render).
pub fn appearance_agreement_where(render: &RenderOutput, image: &RgbImage, window: (u32, u32, u32, u32), in_mask: &dyn Fn(u32, u32) -> bool) -> f64 {
    let (x0, y0, w, h) = window;
    let span = interior_span(render, w, h);
    if span.0.is_empty() || span.1.is_empty() {
        return 0.0;
    }
    let r_at = grey_patch(&span, |x, y| render.rgb.get_pixel(x, y));
    let i_at = grey_patch(&span, |x, y| image.get_pixel(x0 + x, y0 + y));
    let (mut sum, mut count) = (0.0f64, 0usize);
    for (x, y) in interior_pixels(render, &span).filter(|&(x, y)| in_mask(x, y)) {
        let (rx, ry) = sobel(&r_at, x, y);
        let (ix, iy) = sobel(&i_at, x, y);
        let (rm, im) = (rx * rx + ry * ry, ix * ix + iy * iy);
        let (r_edge, i_edge) = (rm >= EDGE * EDGE, im >= EDGE * EDGE);
        if !(r_edge || i_edge) {
            continue;
        }
        count += 1;
        if r_edge && i_edge {
            let dot = (rx * ix + ry * iy) as f64;
            sum += dot * dot / (rm as f64 * im as f64);
        }
    }
    if count == 0 {
        0.0
    } else {
        sum / count as f64
    }
}

/// Colour agreement in [0, 1]: the correlation of the render's and the photo's colours
/// (RGB 3-vectors, each image's mean removed) over the pixels well inside both the
/// render's silhouette and the mask, negative values as 0. Where the edges of a small or
/// blurred object are too few to tell its front from its back, the layout of its colours
/// still can; correlation, not difference, because lighting scales and shifts them.
pub fn colour_agreement(render: &RenderOutput, image: &RgbImage, mask: &GrayImage, window: (u32, u32, u32, u32)) -> f64 {
    let (x0, y0) = (window.0, window.1);
    colour_agreement_where(render, image, window, &|x, y| mask.get_pixel(x0 + x, y0 + y)[0] > 0)
}

/// [`colour_agreement`] over the window pixels (window coordinates) that `in_mask` admits.
pub fn colour_agreement_where(render: &RenderOutput, image: &RgbImage, window: (u32, u32, u32, u32), in_mask: &dyn Fn(u32, u32) -> bool) -> f64 {
    let (x0, y0, w, h) = window;
    let mut px: Vec<([f64; 3], [f64; 3])> = Vec::new();
    for (x, y) in interior_pixels(render, &interior_span(render, w, h)).filter(|&(x, y)| in_mask(x, y)) {
        let r = render.rgb.get_pixel(x, y);
        let i = image.get_pixel(x0 + x, y0 + y);
        px.push(([r[0] as f64, r[1] as f64, r[2] as f64], [i[0] as f64, i[1] as f64, i[2] as f64]));
    }
    if px.len() < 10 {
        return 0.0;
    }
    let n = px.len() as f64;
    let mut mr = [0.0; 3];
    let mut mi = [0.0; 3];
    for (r, i) in &px {
        for c in 0..3 {
            mr[c] += r[c] / n;
            mi[c] += i[c] / n;
        }
    }
    let (mut srr, mut sii, mut sri) = (0.0, 0.0, 0.0);
    for (r, i) in &px {
        for c in 0..3 {
            let (a, b) = (r[c] - mr[c], i[c] - mi[c]);
            srr += a * a;
            sii += b * b;
            sri += a * b;
        }
    }
    if srr <= 0.0 || sii <= 0.0 {
        0.0
    } else {
        (sri / (srr * sii).sqrt()).max(0.0)
    }
}

/// Feature-metric render-and-compare, in [0, 1]: the render and the photo encoded by the
/// backbone on the same crop (so patch k of one covers the pixels of patch k of the other),
/// compared over the patches both cover. Descriptors, not pixels: a backbone's features of
/// a printed label are meant to stay put under light, blur and colour shift, where pixel
/// colours do not. Contrast-normalised: the mean cosine of corresponding patches against
/// the mean cosine of the same patches paired off by half the set (what any two patches of
/// this object share), `(aligned − baseline) / (1 − baseline)`, negative values as 0. Raw
/// cosines of one object's patches sit close together (0.93–0.97 for the embedded backbone
/// across right and wrong poses alike), which would leave the term a tie-breaker. 0 where
/// fewer than 4 patches are covered by both (or have no signal).
pub fn feature_agreement(photo: &crate::features::FeatureMap, render: &crate::features::FeatureMap, min_coverage: f32) -> f64 {
    let zero = |d: &[f32]| d.iter().all(|&x| x == 0.0);
    let both: Vec<usize> = (0..photo.grid.len().min(render.grid.len()))
        .filter(|&k| photo.coverage[k] >= min_coverage && render.coverage[k] >= min_coverage && !zero(photo.descriptor(k)) && !zero(render.descriptor(k)))
        .collect();
    let n = both.len();
    if n < 4 {
        return 0.0;
    }
    let cos = |a: usize, b: usize| photo.descriptor(a).iter().zip(render.descriptor(b)).map(|(x, y)| x * y).sum::<f32>() as f64;
    let aligned = both.iter().map(|&k| cos(k, k)).sum::<f64>() / n as f64;
    let baseline = (0..n).map(|i| cos(both[i], both[(i + n / 2) % n])).sum::<f64>() / n as f64;
    if baseline >= 1.0 - 1e-9 {
        return 0.0;
    }
    ((aligned - baseline) / (1.0 - baseline)).clamp(0.0, 1.0)
}

/// The appearance term with the feature-metric agreement mixed in at `share` (where it
/// was computed).
pub fn with_features(appearance: f64, features: f64, share: f64) -> f64 {
    if features.is_nan() || share <= 0.0 {
        appearance
    } else {
        (1.0 - share) * appearance + share * features
    }
}

/// What one render of a hypothesis says.
pub struct Evidence {
    pub iou: f64,
    pub edges: f64,
    /// NaN where the mesh has no colours of its own.
    pub colour: f64,
    pub render: RenderOutput,
}

/// Edge and colour agreement as one appearance term (edges alone without colours).
pub fn appearance(edges: f64, colour: f64, colour_share: f64) -> f64 {
    if colour.is_nan() {
        edges
    } else {
        (1.0 - colour_share) * edges + colour_share * colour
    }
}

/// Renders each of `poses` over the mask's window (spread over the pool's renderers) and
/// measures silhouette IoU (sparing what `hidden` may hide: `window_iou`) and appearance
/// of each (on all cores), in order.
#[allow(clippy::too_many_arguments)]
pub fn render_evidence(
    renderer: &RenderPool,
    mesh: &crate::mesh::Mesh,
    poses: &[Pose],
    k: &Intrinsics,
    image: &RgbImage,
    mask: &GrayImage,
    hidden: Option<&GrayImage>,
    window: (u32, u32, u32, u32),
) -> Result<Vec<Evidence>, crate::render::RenderError> {
    let camera = window_camera(k, window)?;
    let views: Vec<(Pose, Intrinsics)> = poses.iter().map(|p| (*p, camera)).collect();
    let renders = renderer.render_batch(mesh, &views, &RenderOptions::default())?;
    let coloured = mesh.has_colours();
    Ok(renders
        .into_par_iter()
        .map(|r| Evidence {
            iou: window_iou(&r, mask, hidden, window) as f64,
            edges: appearance_agreement(&r, image, mask, window),
            colour: if coloured { colour_agreement(&r, image, mask, window) } else { f64::NAN },
            render: r,
        })
        .collect())
}

/// Which hypotheses (sorted by contour agreement, best first) get a render: the first
/// `rendered`, then any within `contour_tie` of the best up to `max_rendered`, and those
/// in `always` in any case (the start, the pipeline's own pose: it must be beaten on the
/// evidence; the depth's views, which the outline cannot rank: they come from what it
/// does not see).
pub fn to_render(sorted: &[Verified], always: &[usize], cfg: &VerifyConfig) -> Vec<usize> {
    let best = sorted.first().map_or(0.0, |v| v.contour);
    let cap = cfg.max_rendered.max(cfg.rendered);
    let mut out: Vec<usize> = (0..sorted.len()).filter(|&i| i < cfg.rendered || sorted[i].contour >= best - cfg.contour_tie).take(cap).collect();
    for &p in always {
        if !out.contains(&p) {
            out.push(p);
        }
    }
    out
}

/// Which of `scores` to keep: those `always` names, then the best others, `keep` in all
/// (more where more are always kept). Equal scores go to the earlier, so the choice does
/// not depend on the threads; no score (NaN) ranks last.
pub fn always_and_best(scores: &[f64], always: impl Fn(usize) -> bool, keep: usize) -> Vec<bool> {
    let mut kept: Vec<bool> = (0..scores.len()).map(&always).collect();
    let mut others: Vec<usize> = (0..scores.len()).filter(|&i| !kept[i]).collect();
    others.sort_by(|&a, &b| scores[a].is_nan().cmp(&scores[b].is_nan()).then(scores[b].total_cmp(&scores[a])).then(a.cmp(&b)));
    let room = keep.saturating_sub(scores.len() - others.len());
    for &i in others.iter().take(room) {
        kept[i] = true;
    }
    kept
}

/// Weighted score of the three terms; an unrendered hypothesis counts its contour alone,
/// scaled as if the others matched it (it only competes when nothing was rendered).
pub fn score(v: &Verified, w: &[f64; 3]) -> f64 {
    if v.iou.is_nan() {
        return v.contour * (w[0] + w[1] + w[2]) - 1.0;
    }
    w[0] * v.iou + w[1] * v.contour + w[2] * v.appearance
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn those_always_kept_come_first_then_the_best_scores() {
        let first = |i: usize| i == 0;
        let scores = [0.1, 0.9, 0.5, 0.9, f64::NEG_INFINITY, 0.7];
        assert_eq!(always_and_best(&scores, first, 3), [true, true, false, true, false, false]);
        assert_eq!(always_and_best(&scores, first, 4), [true, true, false, true, false, true]);
        assert_eq!(always_and_best(&scores, first, 1), [true, false, false, false, false, false]);
        assert_eq!(always_and_best(&scores, first, 10), [true; 6]);
        assert!(always_and_best(&[], first, 3).is_empty());
        // No score ranks below every score.
        let unscored = [0.5, f64::NAN, f64::NEG_INFINITY];
        assert_eq!(always_and_best(&unscored, |_| false, 2), [true, false, true]);
        // Those always kept are never cut, even beyond `keep`, wherever they stand.
        let not_first = |i: usize| i == 1 || i == 2;
        assert_eq!(always_and_best(&scores, not_first, 1), [false, true, true, false, false, false]);
        assert_eq!(always_and_best(&scores, not_first, 4), [false, true, true, true, false, true]);
    }

    fn striped(width: u32, vertical: bool) -> RgbImage {
        RgbImage::from_fn(width, width, |x, y| {
            let on = if vertical { (x / 4) % 2 == 0 } else { (y / 4) % 2 == 0 };
            if on {
                image::Rgb([220, 220, 220])
            } else {
                image::Rgb([30, 30, 30])
            }
        })
    }

    #[test]
    fn appearance_agrees_with_itself_and_not_with_a_turned_texture() {
        let full = GrayImage::from_pixel(40, 40, image::Luma([255]));
        let render = RenderOutput { rgb: striped(40, true), depth: vec![1.0; 1600], mask: full.clone() };
        let same = appearance_agreement(&render, &striped(40, true), &full, (0, 0, 40, 40));
        let turned = appearance_agreement(&render, &striped(40, false), &full, (0, 0, 40, 40));
        assert!(same > 0.9, "{same}");
        assert!(turned < 0.1, "{turned}");
        // A plain render against a printed photo: the photo's edges go unexplained.
        let plain = RenderOutput { rgb: RgbImage::from_pixel(40, 40, image::Rgb([128, 128, 128])), depth: vec![1.0; 1600], mask: full.clone() };
        let unexplained = appearance_agreement(&plain, &striped(40, true), &full, (0, 0, 40, 40));
        assert!(unexplained < 0.05, "{unexplained}");
    }

    #[test]
    fn the_interior_is_read_from_the_silhouettes_box_in_row_order() {
        // A disc drawn in a 60 × 50 window's middle, against each edge and corner, too small
        // to have an interior, and absent: the pixels visited are those a scan of the whole
        // window finds well inside, in the same order (so the sums are the same to the bit).
        for (cx, cy, r) in [(30.0, 25.0, 14.0), (0.0, 25.0, 12.0), (59.0, 25.0, 12.0), (30.0, 0.0, 12.0), (30.0, 49.0, 12.0), (2.0, 3.0, 9.0), (57.0, 47.0, 9.0), (30.0, 25.0, 2.0), (30.0, 25.0, -1.0)]
        {
            let mask = GrayImage::from_fn(60, 50, |x, y| image::Luma([if (x as f64 - cx).powi(2) + (y as f64 - cy).powi(2) <= r * r { 255 } else { 0 }]));
            let at = |x: i64, y: i64| mask.get_pixel(x as u32, y as u32)[0] > 0;
            let whole: Vec<(u32, u32)> = (3..47).flat_map(|y| (3..57).map(move |x| (x, y))).filter(|&(x, y)| (-2..=2).all(|d| at(x as i64 + d, y as i64) && at(x as i64, y as i64 + d))).collect();
            let render = RenderOutput { rgb: RgbImage::new(60, 50), depth: vec![0.0; 3000], mask };
            assert_eq!(interior_pixels(&render, &interior_span(&render, 60, 50)).collect::<Vec<_>>(), whole, "disc at ({cx}, {cy}) r {r}");
        }
        let small = RenderOutput { rgb: RgbImage::new(6, 6), depth: vec![1.0; 36], mask: GrayImage::from_pixel(6, 6, image::Luma([255])) };
        assert_eq!(interior_pixels(&small, &interior_span(&small, 6, 6)).count(), 0);
    }

    #[test]
    fn colour_agreement_survives_lighting_and_tells_front_from_back() {
        // A label: red left half, blue right half; the back of the object the other way round.
        let label = |w: u32, gain: f32, offset: f32, flipped: bool| {
            RgbImage::from_fn(w, w, |x, _| {
                let left = (x < w / 2) != flipped;
                let c: [f32; 3] = if left { [200.0, 40.0, 30.0] } else { [30.0, 50.0, 190.0] };
                image::Rgb(c.map(|v| (v * gain + offset).clamp(0.0, 255.0) as u8))
            })
        };
        let full = GrayImage::from_pixel(40, 40, image::Luma([255]));
        let render = RenderOutput { rgb: label(40, 1.0, 0.0, false), depth: vec![1.0; 1600], mask: full.clone() };
        let darker = colour_agreement(&render, &label(40, 0.6, 20.0, false), &full, (0, 0, 40, 40));
        let back = colour_agreement(&render, &label(40, 0.6, 20.0, true), &full, (0, 0, 40, 40));
        assert!(darker > 0.99, "{darker}");
        assert_eq!(back, 0.0, "anti-correlated colours count as no agreement");
        // No colour variation to correlate: no evidence either way.
        let plain = RgbImage::from_pixel(40, 40, image::Rgb([90, 90, 90]));
        assert_eq!(colour_agreement(&render, &plain, &full, (0, 0, 40, 40)), 0.0);
        // Edges alone where the mesh has no colours; a share of each where it does.
        assert_eq!(appearance(0.4, f64::NAN, 0.5), 0.4);
        assert!((appearance(0.4, 0.8, 0.5) - 0.6).abs() < 1e-12);
    }

    /// Corresponding patches alike and unlike the others: 1; a render whose patches match
    /// the photo's no better than any pair of patches: 0; too few patches covered: 0.
    #[test]
    fn feature_agreement_is_contrast_normalised() {
        use crate::features::FeatureMap;
        use crate::geometry::PatchGrid;
        let unit = |a: f32| [a.cos(), a.sin()];
        let map = |rows: Vec<[f32; 2]>, coverage: Vec<f32>| FeatureMap {
            grid: PatchGrid { n: 3, patch: 8 },
            local_dim: 2,
            local: rows.iter().flatten().copied().collect(),
            global: vec![1.0, 0.0],
            coverage,
        };
        let photo = map((0..9).map(|k| unit(k as f32 * 0.35)).collect(), vec![1.0; 9]);
        let same = map((0..9).map(|k| unit(k as f32 * 0.35)).collect(), vec![1.0; 9]);
        assert!((feature_agreement(&photo, &same, 0.5) - 1.0).abs() < 1e-6);
        // The same patches in another order (a turned label): no better than chance.
        let shuffled = map((0..9).map(|k| unit(((k * 4) % 9) as f32 * 0.35)).collect(), vec![1.0; 9]);
        assert!(feature_agreement(&photo, &shuffled, 0.5) < 0.3, "{}", feature_agreement(&photo, &shuffled, 0.5));
        // All alike (a plain object): nothing to tell apart.
        let plain = map(vec![unit(0.0); 9], vec![1.0; 9]);
        assert_eq!(feature_agreement(&plain, &plain, 0.5), 0.0);
        // Three patches covered by both: too few.
        let few = map((0..9).map(|k| unit(k as f32 * 0.35)).collect(), (0..9).map(|k| if k < 3 { 1.0 } else { 0.0 }).collect());
        assert_eq!(feature_agreement(&photo, &few, 0.5), 0.0);
        assert_eq!(with_features(0.4, f64::NAN, 0.5), 0.4);
        assert_eq!(with_features(0.4, 0.8, 0.0), 0.4);
        assert!((with_features(0.4, 0.8, 0.5) - 0.6).abs() < 1e-12);
    }

    #[test]
    fn hypotheses_the_outline_cannot_separate_all_get_a_render() {
        let v = |contour: f64| Verified::unscored(Source::Pipeline, Pose::identity(), RefineReport::default(), contour);
        let sorted: Vec<Verified> = [0.95, 0.94, 0.93, 0.92, 0.91, 0.7, 0.6].into_iter().map(v).collect();
        let cfg = VerifyConfig { rendered: 2, contour_tie: 0.035, max_rendered: 8, ..Default::default() };
        assert_eq!(to_render(&sorted, &[], &cfg), vec![0, 1, 2, 3]);
        // The pipeline's pose is rendered wherever it ranks.
        assert_eq!(to_render(&sorted, &[6], &cfg), vec![0, 1, 2, 3, 6]);
        // The cap holds, and never cuts below `rendered`.
        assert_eq!(to_render(&sorted, &[], &VerifyConfig { max_rendered: 3, ..cfg.clone() }), vec![0, 1, 2]);
        assert_eq!(to_render(&sorted, &[], &VerifyConfig { rendered: 3, contour_tie: 0.0, max_rendered: 1, ..cfg }), vec![0, 1, 2]);
    }
}
