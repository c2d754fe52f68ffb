//! Hypothesis selection across candidate masks: render each candidate pose, gate on the
//! IoU of its rendered mask with its segmentation mask, and score the survivors with the
//! z-normalised (across hypotheses) global-descriptor cosine, IoU and detector score.

use crate::geometry::{Intrinsics, Pose};
use crate::render::{RenderOptions, RenderOutput, RenderPool};
use image::GrayImage;

#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SelectionConfig {
    /// Hypotheses whose render overlaps their mask less than this are dropped.
    pub iou_gate: f32,
    /// Weights of z-normalised cosine, IoU and detector score.
    pub weights: [f32; 3],
}

impl Default for SelectionConfig {
    fn default() -> Self {
        Self { iou_gate: 0.2, weights: [0.2, 0.5, 0.3] }
    }
}

/// Window of the image around a mask (its box grown by half its size each way), clipped to
/// the image: renders for IoU need only cover where the mask and a sane estimate can be.
pub fn mask_window(mask: &GrayImage) -> Option<(u32, u32, u32, u32)> {
    let (x0, y0, x1, y1) = crate::features::mask_bbox(mask)?;
    let (w, h) = (x1 - x0 + 1, y1 - y0 + 1);
    let (gx, gy) = (w / 2 + 8, h / 2 + 8);
    let (ax, ay) = (x0.saturating_sub(gx), y0.saturating_sub(gy));
    let (bx, by) = ((x1 + gx).min(mask.width() - 1), (y1 + gy).min(mask.height() - 1));
    Some((ax, ay, bx - ax + 1, by - ay + 1))
}

/// Renders `pose` inside `window` (x, y, w, h) of the image of camera `k`, at native resolution.
pub fn render_window(renderer: &RenderPool, mesh: &crate::mesh::Mesh, pose: &Pose, k: &Intrinsics, window: (u32, u32, u32, u32)) -> Result<RenderOutput, crate::render::RenderError> {
    renderer.render(mesh, pose, &window_camera(k, window)?, &RenderOptions::default())
}

/// The camera `k` cut down to `window` (x, y, w, h) (`Intrinsics::window`); an empty window
/// is a render error.
pub fn window_camera(k: &Intrinsics, (x, y, w, h): (u32, u32, u32, u32)) -> Result<Intrinsics, crate::render::RenderError> {
    k.window(x, y, w, h).ok_or_else(|| crate::render::RenderError::InvalidIntrinsics(format!("empty window {w}×{h} at ({x}, {y})")))
}

/// IoU of a window render's mask with the same window of a full-size mask. Where `hidden`
/// (full-size, non-zero where another detection is) covers a pixel that the render covers
/// and the mask does not, that pixel counts neither way: a visible mask says nothing of what
/// is behind what hides it, so a pose reaching under an occluder loses nothing for it.
pub fn window_iou(render: &RenderOutput, mask: &GrayImage, hidden: Option<&GrayImage>, window: (u32, u32, u32, u32)) -> f32 {
    let (x0, y0, w, h) = window;
    let (mut inter, mut union) = (0u64, 0u64);
    for y in 0..h {
        for x in 0..w {
            let a = render.mask.get_pixel(x, y)[0] > 0;
            let b = mask.get_pixel(x0 + x, y0 + y)[0] > 0;
            if a && !b && hidden.is_some_and(|o| o.get_pixel(x0 + x, y0 + y)[0] > 0) {
                continue;
            }
            inter += (a && b) as u64;
            union += (a || b) as u64;
        }
    }
    // Mask pixels outside the window cannot exist: the window contains the whole mask box.
    if union == 0 {
        0.0
    } else {
        inter as f32 / union as f32
    }
}

/// How well a window render fills the caller's box `b`: the IoU of `b` with the box around
/// the render's pixels that no other detection (`hidden`, full-size) covers. An object
/// half hidden behind another detection is judged on the part the box could have seen;
/// 0 when nothing of the render is visible.
pub fn box_agreement(render: &RenderOutput, window: (u32, u32, u32, u32), b: &crate::masks::PixelBox, hidden: Option<&GrayImage>) -> f32 {
    let (x0, y0, w, h) = window;
    let (mut lo, mut hi) = ([u32::MAX; 2], [0u32; 2]);
    for y in 0..h {
        for x in 0..w {
            let (ix, iy) = (x0 + x, y0 + y);
            if render.mask.get_pixel(x, y)[0] == 0 || hidden.is_some_and(|o| o.get_pixel(ix, iy)[0] > 0) {
                continue;
            }
            lo = [lo[0].min(ix), lo[1].min(iy)];
            hi = [hi[0].max(ix + 1), hi[1].max(iy + 1)];
        }
    }
    if lo[0] >= hi[0] {
        return 0.0;
    }
    let span = |a0: u32, a1: u32, b0: u32, b1: u32| a1.min(b1).saturating_sub(a0.max(b0)) as f64;
    let inter = span(lo[0], hi[0], b.x0, b.x1) * span(lo[1], hi[1], b.y0, b.y1);
    let area = |w: u32, h: u32| w as f64 * h as f64;
    let union = area(hi[0] - lo[0], hi[1] - lo[1]) + b.area() as f64 - inter;
    (inter / union) as f32
}

/// z-score of each value across the set; all zeros when the values do not vary.
pub fn z_normalise(v: &[f32]) -> Vec<f32> {
    let n = v.len() as f32;
    if v.is_empty() {
        return vec![];
    }
    let mean = v.iter().sum::<f32>() / n;
    let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f32>() / n).sqrt();
    if sd < 1e-9 {
        vec![0.0; v.len()]
    } else {
        v.iter().map(|x| (x - mean) / sd).collect()
    }
}

/// Combined scores of gated hypotheses given their (cosine, IoU, detector score).
pub fn combined_scores(cos: &[f32], iou: &[f32], det: &[f32], w: &[f32; 3]) -> Vec<f32> {
    let (zc, zi, zd) = (z_normalise(cos), z_normalise(iou), z_normalise(det));
    (0..cos.len()).map(|i| w[0] * zc[i] + w[1] * zi[i] + w[2] * zd[i]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn z_scores_and_weights() {
        assert_eq!(z_normalise(&[2.0, 2.0]), vec![0.0, 0.0]);
        let z = z_normalise(&[1.0, 3.0]);
        assert!((z[0] + 1.0).abs() < 1e-6 && (z[1] - 1.0).abs() < 1e-6);
        // IoU dominates: the second hypothesis wins despite a lower cosine.
        let s = combined_scores(&[0.9, 0.8], &[0.5, 0.9], &[0.9, 0.9], &[0.2, 0.5, 0.3]);
        assert!(s[1] > s[0]);
    }

    #[test]
    fn box_agreement_is_the_iou_of_the_visible_renders_box_with_the_callers() {
        // A render of 20×10 pixels at (12, 14) in a window at (10, 10).
        let mask = GrayImage::from_fn(40, 30, |x, y| image::Luma([if (2..22).contains(&x) && (4..14).contains(&y) { 255 } else { 0 }]));
        let render = RenderOutput { rgb: image::RgbImage::new(40, 30), depth: vec![0.0; 1200], mask };
        let window = (10, 10, 40, 30);
        let exact = crate::masks::PixelBox { x0: 12, y0: 14, x1: 32, y1: 24 };
        assert_eq!(box_agreement(&render, window, &exact, None), 1.0);
        // The caller's box half as wide: IoU 100 / 200.
        let half = crate::masks::PixelBox { x1: 22, ..exact };
        assert_eq!(box_agreement(&render, window, &half, None), 0.5);
        // The render's right half hidden by another detection: it fills the half box.
        let hidden = GrayImage::from_fn(60, 50, |x, _| image::Luma([if x >= 22 { 255 } else { 0 }]));
        assert_eq!(box_agreement(&render, window, &half, Some(&hidden)), 1.0);
        // Nothing visible: no agreement.
        let all = GrayImage::from_pixel(60, 50, image::Luma([255]));
        assert_eq!(box_agreement(&render, window, &exact, Some(&all)), 0.0);
    }

    #[test]
    fn window_covers_mask_with_margin() {
        let mut m = GrayImage::new(100, 80);
        for y in 30..40 {
            for x in 40..60 {
                m.put_pixel(x, y, image::Luma([255]));
            }
        }
        assert_eq!(mask_window(&m), Some((22, 17, 56, 36)));
    }

    /// A render reaching under another detection loses nothing for it; reaching onto bare
    /// background, or leaving the mask's own pixels uncovered, still costs.
    #[test]
    fn iou_spares_what_another_detection_hides() {
        let lit = |x0: u32, x1: u32| GrayImage::from_fn(10, 1, |x, _| image::Luma([if (x0..x1).contains(&x) { 255 } else { 0 }]));
        let render = |x0, x1| RenderOutput { rgb: image::RgbImage::new(10, 1), depth: vec![1.0; 10], mask: lit(x0, x1) };
        let (mask, occluder) = (lit(0, 4), lit(4, 8));
        let window = (0, 0, 10, 1);
        // Twice as long as the visible part, the rest under the occluder: a full match.
        assert_eq!(window_iou(&render(0, 8), &mask, Some(&occluder), window), 1.0);
        assert_eq!(window_iou(&render(0, 8), &mask, None, window), 0.5);
        // Beyond the occluder, onto the background: those two pixels count.
        assert!((window_iou(&render(0, 10), &mask, Some(&occluder), window) - 4.0 / 6.0).abs() < 1e-6);
        // The occluder does not excuse mask pixels the render leaves uncovered.
        assert_eq!(window_iou(&render(2, 8), &mask, Some(&occluder), window), 0.5);
    }
}
