//! Hypothesis verification: every hypothesis of a mask is refined, scored on the evidence
//! that survives the render-to-real gap (the outline against the mask, one render's
//! silhouette IoU, and whether the render's interior edges run where the photo's do), and
//! the best one is kept. The multi-mask selection then runs on the survivors.

use super::hypotheses::Source;
use super::refine::RefineReport;
use super::select::{render_window, window_iou};
use crate::geometry::{Intrinsics, Pose};
use crate::render::{RenderOutput, RenderPool};
use image::{GrayImage, RgbImage};

#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct VerifyConfig {
    /// Refine and verify the extra hypotheses at all (off: the pipeline's pose alone). On by
    /// default: on generated HOPE scenes it gained 2–16 points of MSSD recall for about
    /// 0.1 s per instance on 2 CPU cores (docs/benchmarks.md, "Contour refiner").
    pub enabled: bool,
    /// Retrieved templates placed at the mask as extra hypotheses.
    pub templates: usize,
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
}

impl Default for VerifyConfig {
    fn default() -> Self {
        Self { enabled: true, templates: 3, rendered: 3, contour_tie: 0.05, max_rendered: 8, weights: [0.4, 0.3, 0.3] }
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
    pub score: f64,
    /// The window render behind `iou` and `appearance`, kept for the winner so that
    /// selection does not render the same pose again.
    #[serde(skip)]
    pub render: Option<RenderOutput>,
}

/// Grey level of an sRGB pixel (0–255).
fn grey(p: &image::Rgb<u8>) -> f32 {
    0.299 * p[0] as f32 + 0.587 * p[1] as f32 + 0.114 * p[2] as f32
}

/// Sobel gradient of `at(x, y)` at interior point (x, y).
fn sobel(at: &dyn Fn(u32, u32) -> f32, x: u32, y: u32) -> (f32, f32) {
    let gx = at(x + 1, y - 1) + 2.0 * at(x + 1, y) + at(x + 1, y + 1) - at(x - 1, y - 1) - 2.0 * at(x - 1, y) - at(x - 1, y + 1);
    let gy = at(x - 1, y + 1) + 2.0 * at(x, y + 1) + at(x + 1, y + 1) - at(x - 1, y - 1) - 2.0 * at(x, y - 1) - at(x + 1, y - 1);
    (gx, gy)
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
    if w < 7 || h < 7 {
        return 0.0;
    }
    let r_at = |x: u32, y: u32| grey(render.rgb.get_pixel(x, y));
    let i_at = |x: u32, y: u32| grey(image.get_pixel(x0 + x, y0 + y));
    let inside = |x: u32, y: u32| (-2i64..=2).all(|d| render.mask.get_pixel((x as i64 + d) as u32, y)[0] > 0 && render.mask.get_pixel(x, (y as i64 + d) as u32)[0] > 0) && in_mask(x, y);
    let (mut sum, mut count) = (0.0f64, 0usize);
    for y in 3..h - 3 {
        for x in 3..w - 3 {
            if !inside(x, y) {
                continue;
            }
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
    }
    if count == 0 { 0.0 } else { sum / count as f64 }
}

/// Renders `pose` over the mask's window and measures silhouette IoU and appearance.
pub fn render_evidence(renderer: &RenderPool, mesh: &crate::mesh::Mesh, pose: &Pose, k: &Intrinsics, image: &RgbImage, mask: &GrayImage, window: (u32, u32, u32, u32)) -> Result<(f64, f64, RenderOutput), crate::render::RenderError> {
    let r = render_window(renderer, mesh, pose, k, window)?;
    Ok((window_iou(&r, mask, window) as f64, appearance_agreement(&r, image, mask, window), r))
}

/// Which hypotheses (sorted by contour agreement, best first) get a render: the first
/// `rendered`, then any within `contour_tie` of the best up to `max_rendered`, and the
/// pipeline's own pose (index `pipeline`) in any case: it must be beaten on the evidence.
pub fn to_render(sorted: &[Verified], pipeline: Option<usize>, cfg: &VerifyConfig) -> Vec<usize> {
    let best = sorted.first().map_or(0.0, |v| v.contour);
    let cap = cfg.max_rendered.max(cfg.rendered);
    let mut out: Vec<usize> = (0..sorted.len()).filter(|&i| i < cfg.rendered || sorted[i].contour >= best - cfg.contour_tie).take(cap).collect();
    if let Some(p) = pipeline.filter(|p| !out.contains(p)) {
        out.push(p);
    }
    out
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

    fn striped(width: u32, vertical: bool) -> RgbImage {
        RgbImage::from_fn(width, width, |x, y| {
            let on = if vertical { (x / 4) % 2 == 0 } else { (y / 4) % 2 == 0 };
            if on { image::Rgb([220, 220, 220]) } else { image::Rgb([30, 30, 30]) }
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
    fn hypotheses_the_outline_cannot_separate_all_get_a_render() {
        let v = |contour: f64| Verified { source: Source::Pipeline, pose: Pose::identity(), refinement: RefineReport::default(), contour, iou: f64::NAN, appearance: f64::NAN, score: f64::NAN, render: None };
        let sorted: Vec<Verified> = [0.95, 0.94, 0.93, 0.92, 0.91, 0.7, 0.6].into_iter().map(v).collect();
        let cfg = VerifyConfig { rendered: 2, contour_tie: 0.035, max_rendered: 8, ..Default::default() };
        assert_eq!(to_render(&sorted, None, &cfg), vec![0, 1, 2, 3]);
        // The pipeline's pose is rendered wherever it ranks.
        assert_eq!(to_render(&sorted, Some(6), &cfg), vec![0, 1, 2, 3, 6]);
        // The cap holds, and never cuts below `rendered`.
        assert_eq!(to_render(&sorted, None, &VerifyConfig { max_rendered: 3, ..cfg.clone() }), vec![0, 1, 2]);
        assert_eq!(to_render(&sorted, None, &VerifyConfig { rendered: 3, contour_tie: 0.0, max_rendered: 1, ..cfg }), vec![0, 1, 2]);
    }
}
