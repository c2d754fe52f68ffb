//! Sub-pixel outline positions from the photo itself. A mask places the outline in
//! whole-pixel steps; along a straight edge nearly aligned with the pixel grid, every line
//! sees the same step, so many lines do not average it away, and a small object ends up a
//! few per cent off in depth. A camera's pixels integrate the light over their area, so
//! the photo's intensity profile across the outline says where within the pixel the edge
//! lies. Where the photo shows one clear edge within a pixel of the mask's outline, the
//! line takes the edge's position; elsewhere (a low-contrast outline, texture or another
//! edge nearby) it keeps the mask's.

use crate::features::grey;
use crate::geometry::pixel::floor_i64;
use image::RgbImage;
use nalgebra::Vector2;

/// Profile sample spacing along the line, px.
const STEP_PX: f64 = 0.25;
/// How far past the search window the profile runs, px: a blurred edge's transition
/// (σ up to about 1 px) must fit inside it for its centroid to be whole.
const MARGIN_PX: f64 = 2.5;
/// Least rise across the edge, grey levels: well above the sensor noise of one sample
/// difference, below an outline against a similar background.
const MIN_STEP: f64 = 12.0;
/// A rival slope (the other way, or apart from the edge's own run) at least this share of
/// the edge's steepest makes the position ambiguous: texture or a second edge.
const MAX_RIVAL: f64 = 0.5;
/// Most (px) by which the run may reach farther on one side of its centroid than on the
/// other. An edge averaged over pixel areas and blurred symmetrically is nearly symmetric
/// about its position (a sharp one by up to a pixel, where a sliver of slope falls in the
/// neighbouring pixel interval); a ramp joined to the edge on one side (a print darkening
/// towards the outline, shading) is not, and would pull the centroid off the outline.
const MAX_ASYMMETRY_PX: f64 = 1.0;
/// The edge's run: the samples around the steepest whose slope is above this share of it.
/// Lower takes in the whole of a blurred edge (0.5 left small objects less precise in
/// `bench refine`); what lies beyond a run is judged by `MAX_RIVAL`.
const RUN_FLOOR: f64 = 0.1;

/// Luminance (0–255) at image point (u, v), pixel centres at integers, bilinear; `None`
/// where the four pixels are not all inside the image.
fn luminance(img: &RgbImage, u: f64, v: f64) -> Option<f64> {
    let (x0, y0) = (floor_i64(u), floor_i64(v));
    if x0 < 0 || y0 < 0 || x0 + 1 >= img.width() as i64 || y0 + 1 >= img.height() as i64 {
        return None;
    }
    let (fx, fy, x, y) = (u - x0 as f64, v - y0 as f64, x0 as u32, y0 as u32);
    let lum = |x: u32, y: u32| grey(img.get_pixel(x, y)) as f64;
    let top = lum(x, y) * (1.0 - fx) + lum(x + 1, y) * fx;
    let bottom = lum(x, y + 1) * (1.0 - fx) + lum(x + 1, y + 1) * fx;
    Some(top * (1.0 - fy) + bottom * fy)
}

/// How far inside the true outline the profile of `edge_offset` with this `reach` may read:
/// the outline anywhere within `reach` of the expected offset, the profile `reach` and a
/// margin beyond that. A print edge nearer than this could be taken for the outline.
pub fn profile_inside_px(reach: f64) -> f64 {
    2.0 * reach + MARGIN_PX
}

/// Where the photo's edge crosses the line through `centre` along unit `normal`, as an
/// offset along the normal (px), if there is one clear edge within `reach` px of the
/// offset `expected` (the mask's outline). The position is the centroid of the profile's
/// slope over the edge's run, which for an edge averaged over pixel areas (and blurred
/// symmetrically) is where the edge is, to a fraction of a pixel.
pub fn edge_offset(img: &RgbImage, centre: &Vector2<f64>, normal: &Vector2<f64>, expected: f64, reach: f64) -> Option<f64> {
    let start = expected - reach - MARGIN_PX;
    let n = ((2.0 * (reach + MARGIN_PX)) / STEP_PX).round() as usize + 1;
    let mut profile = Vec::with_capacity(n);
    for i in 0..n {
        let t = start + i as f64 * STEP_PX;
        profile.push(luminance(img, centre.x + normal.x * t, centre.y + normal.y * t)?);
    }
    // Slopes between samples (grey levels per px), at the samples' midpoints, signed so
    // that the rise across the whole profile is positive.
    let sign = if profile[n - 1] >= profile[0] { 1.0 } else { -1.0 };
    let slopes: Vec<f64> = profile.windows(2).map(|w| sign * (w[1] - w[0]) / STEP_PX).collect();
    let at = |i: usize| start + (i as f64 + 0.5) * STEP_PX;
    // The steepest rise inside the window.
    let peak = (0..slopes.len()).filter(|&i| (at(i) - expected).abs() <= reach).max_by(|&a, &b| slopes[a].total_cmp(&slopes[b]))?;
    let top = slopes[peak];
    if top <= 0.0 {
        return None;
    }
    // The edge's run: the rising samples around the peak.
    let floor = RUN_FLOOR * top;
    let (mut lo, mut hi) = (peak, peak);
    while lo > 0 && slopes[lo - 1] > floor {
        lo -= 1;
    }
    while hi + 1 < slopes.len() && slopes[hi + 1] > floor {
        hi += 1;
    }
    // A run reaching the profile's end may be cut short: its centroid would be biased.
    if lo == 0 || hi + 1 == slopes.len() {
        return None;
    }
    let rise: f64 = slopes[lo..=hi].iter().sum::<f64>() * STEP_PX;
    let rival = slopes.iter().enumerate().filter(|&(i, _)| i < lo || i > hi).map(|(_, s)| s.abs()).fold(0.0, f64::max);
    let falls = slopes[lo..=hi].iter().fold(0.0f64, |m, s| m.max(-s));
    if rise < MIN_STEP || rival > MAX_RIVAL * top || falls > MAX_RIVAL * top {
        return None;
    }
    let weight: f64 = slopes[lo..=hi].iter().sum();
    let centroid = (lo..=hi).map(|i| slopes[i] * at(i)).sum::<f64>() / weight;
    let (below, above) = (centroid - at(lo), at(hi) - centroid);
    if (below - above).abs() > MAX_ASYMMETRY_PX {
        return None;
    }
    ((centroid - expected).abs() <= reach).then_some(centroid)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A dark disc of radius `r` on a bright ground, each pixel the mean over 8×8 samples
    /// of its area (as a sensor integrates), blurred by nothing.
    fn disc(r: f64, centre: (f64, f64), size: u32) -> RgbImage {
        RgbImage::from_fn(size, size, |x, y| {
            let mut inside = 0;
            for j in 0..8 {
                for i in 0..8 {
                    let (u, v) = (x as f64 - 0.5 + (i as f64 + 0.5) / 8.0, y as f64 - 0.5 + (j as f64 + 0.5) / 8.0);
                    inside += ((u - centre.0).hypot(v - centre.1) < r) as u32;
                }
            }
            let g = (200.0 - 150.0 * inside as f64 / 64.0).round() as u8;
            image::Rgb([g, g, g])
        })
    }

    #[test]
    fn finds_an_area_averaged_edge_to_a_fraction_of_a_pixel() {
        let (c, r) = ((31.3, 30.8), 12.37);
        let img = disc(r, c, 64);
        let errors: Vec<f64> = (0..36)
            .map(|k| {
                let a = (k as f64 * 10.0).to_radians();
                let normal = Vector2::new(a.cos(), a.sin());
                // The line's centre a little inside the outline; the mask says the outline
                // is half a pixel farther out.
                let centre = Vector2::new(c.0, c.1) + normal * (r - 0.8);
                edge_offset(&img, &centre, &normal, 1.3, 1.0).expect("a clear edge") - 0.8
            })
            .collect();
        // A mask's outline is off by up to half a pixel (0.29 px RMS); the photo's edge by a
        // tenth at most, and without bias, so that lines together place it closer still.
        let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
        let bias = errors.iter().sum::<f64>() / errors.len() as f64;
        let worst = errors.iter().fold(0.0f64, |m, e| m.max(e.abs()));
        assert!(worst < 0.15 && rms < 0.06 && bias.abs() < 0.02, "worst {worst}, RMS {rms}, bias {bias} px");
    }

    /// Offsets found around the disc at 36 angles, minus the true one; the mask's outline
    /// said 0.5 px farther out.
    fn disc_errors(img: &RgbImage, c: (f64, f64), r: f64) -> Vec<Option<f64>> {
        (0..36)
            .map(|k| {
                let a = (k as f64 * 10.0).to_radians();
                let normal = Vector2::new(a.cos(), a.sin());
                let centre = Vector2::new(c.0, c.1) + normal * (r - 0.8);
                edge_offset(img, &centre, &normal, 1.3, 1.0).map(|o| o - 0.8)
            })
            .collect()
    }

    #[test]
    fn a_blurred_edge_is_found_where_it_is() {
        // Optics and demosaicing blur a photo's edges symmetrically: still one edge, found
        // without bias.
        let (c, r) = ((31.3, 30.8), 12.37);
        let img = crate::eval::degrade::gaussian_blur(&disc(r, c, 64), 0.8);
        let found: Vec<f64> = disc_errors(&img, c, r).into_iter().map(|e| e.expect("a blurred edge is still one edge")).collect();
        let worst = found.iter().fold(0.0f64, |m, e| m.max(e.abs()));
        assert!(worst < 0.15, "worst {worst} px");
    }

    #[test]
    fn an_edge_with_a_ramp_joined_inside_is_not_taken() {
        // A dark ground, the object's edge at x = 16 (rising 60 levels), then its print
        // brightening by 60 more over the next 3 px, as a label darkened towards the outline
        // does: the centroid of the joined run would sit a pixel inside the outline.
        let ramp = RgbImage::from_fn(40, 8, |x, _| {
            let g = if x < 16 { 40.0 } else { 100.0 + 60.0 * ((x as f64 - 15.5) / 3.0).min(1.0) };
            image::Rgb([g as u8; 3])
        });
        let (centre, normal) = (Vector2::new(16.0, 4.0), Vector2::new(-1.0, 0.0));
        assert_eq!(edge_offset(&ramp, &centre, &normal, 0.5, 1.5), None);
        // The same edge with the print plain: found, between pixels 15 and 16.
        let plain = RgbImage::from_fn(40, 8, |x, _| image::Rgb([if x < 16 { 40 } else { 100 }; 3]));
        let found = edge_offset(&plain, &centre, &normal, 0.5, 1.5).expect("a plain edge");
        assert!((found - 0.5).abs() < 0.05, "{found}");
    }

    #[test]
    fn no_edge_on_flat_ground_noise_or_a_faint_step() {
        let flat = RgbImage::from_pixel(32, 32, image::Rgb([120, 120, 120]));
        let (centre, normal) = (Vector2::new(16.0, 16.0), Vector2::new(1.0, 0.0));
        assert_eq!(edge_offset(&flat, &centre, &normal, 0.0, 1.0), None);
        let faint = RgbImage::from_fn(32, 32, |x, _| image::Rgb([if x < 16 { 120 } else { 126 }; 3]));
        assert_eq!(edge_offset(&faint, &centre, &normal, 0.0, 1.0), None);
        // Two steps a pixel and a half apart: neither is the outline for sure.
        let double = RgbImage::from_fn(32, 32, |x, _| {
            image::Rgb(
                [if x < 16 {
                    40
                } else if x < 18 {
                    120
                } else {
                    200
                }; 3],
            )
        });
        assert_eq!(edge_offset(&double, &centre, &normal, 1.0, 1.0), None);
        // Past the image border there is no profile.
        assert_eq!(edge_offset(&flat, &Vector2::new(1.0, 16.0), &normal, -1.0, 1.0), None);
    }

    #[test]
    fn an_edge_beyond_reach_is_not_taken() {
        let step = RgbImage::from_fn(32, 32, |x, _| image::Rgb([if x < 20 { 40 } else { 200 }; 3]));
        let (centre, normal) = (Vector2::new(16.0, 16.0), Vector2::new(1.0, 0.0));
        // The edge is at 19.5, 3.5 px along the line; the mask says 3.0 (found) or 1.0 (not).
        let found = edge_offset(&step, &centre, &normal, 3.0, 1.0).unwrap();
        assert!((found - 3.5).abs() < 0.05, "{found}");
        assert_eq!(edge_offset(&step, &centre, &normal, 1.0, 1.0), None);
    }
}
