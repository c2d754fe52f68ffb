//! Settles a segmented mask's outline pixels by how much of each pixel the object covers.
//! A camera's pixel on an outline averages the object and the background; a graph cut
//! labels such mixed pixels whichever way its colour models lean, and the object's
//! mixture (fitted inside the box, where both show) usually explains a blend better than
//! the background's does. The outline then sits up to a pixel (half a pixel on average)
//! outside the object all round, which on a 60 px object is nearly 2 % of its depth. Here each outline pixel's colour is
//! unmixed against the nearest clean object and background colours (a local two-colour
//! matte, as in Bayesian or closed-form matting, one pixel deep): it is the object's where
//! the object covers at least half of it, which is where a mask of the true outline
//! would put it.

use super::pixel_box::PixelBox;
use super::OBJECT;
use image::{GrayImage, Luma, RgbImage};

/// Half-width of the window the clean colours are taken from, px.
const WINDOW: i64 = 2;
/// Fewest clean pixels of each side in the window for a local colour.
const MIN_CLEAN: usize = 3;
/// Least distance (RGB, 0–255) between the local object and background colours: below it
/// a blend says nothing about how much of each the pixel holds.
const MIN_CONTRAST: f64 = 24.0;
/// Most distance of a pixel's colour from the object–background blend line, as a share of
/// the two colours' distance: farther, the pixel is neither (print, a third surface) and
/// keeps its label.
const MAX_OFF_LINE: f64 = 0.5;
/// Passes over the outline: each moves it by at most a pixel.
const PASSES: usize = 2;

/// Relabels the outline pixels of `mask` inside `region` by their coverage; returns how
/// many changed. Pixels outside `region` are left as they are and count as the mask says.
pub fn settle_outline(image: &RgbImage, mask: &mut GrayImage, region: &PixelBox) -> usize {
    let mut changed = 0;
    for _ in 0..PASSES {
        let flips = outline_flips(image, mask, region);
        if flips.is_empty() {
            break;
        }
        for &(x, y) in &flips {
            let object = mask.get_pixel(x, y).0[0] == OBJECT;
            mask.put_pixel(x, y, Luma([if object { 0 } else { OBJECT }]));
        }
        changed += flips.len();
    }
    changed
}

/// The outline pixels whose coverage disagrees with their label, read from `mask` as it is.
fn outline_flips(image: &RgbImage, mask: &GrayImage, region: &PixelBox) -> Vec<(u32, u32)> {
    let (w, h) = (mask.width() as i64, mask.height() as i64);
    let label = |x: i64, y: i64| -> Option<bool> { (x >= 0 && y >= 0 && x < w && y < h).then(|| mask.get_pixel(x as u32, y as u32).0[0] == OBJECT) };
    // Clean: every 8-neighbour inside the image carries the same label.
    let clean = |x: i64, y: i64, l: bool| (-1..=1).all(|dy| (-1..=1).all(|dx| label(x + dx, y + dy).is_none_or(|m| m == l)));
    let colour = |x: i64, y: i64| image.get_pixel(x as u32, y as u32).0.map(f64::from);
    let mut flips = Vec::new();
    for y in region.y0 as i64..region.y1 as i64 {
        for x in region.x0 as i64..region.x1 as i64 {
            let Some(l) = label(x, y) else { continue };
            let on_outline = [(1, 0), (-1, 0), (0, 1), (0, -1)].iter().any(|&(dx, dy)| label(x + dx, y + dy).is_some_and(|m| m != l));
            if !on_outline {
                continue;
            }
            let (mut sum, mut count) = ([[0.0; 3]; 2], [0usize; 2]);
            for wy in y - WINDOW..=y + WINDOW {
                for wx in x - WINDOW..=x + WINDOW {
                    let Some(m) = label(wx, wy) else { continue };
                    if clean(wx, wy, m) {
                        let c = colour(wx, wy);
                        let side = m as usize;
                        (0..3).for_each(|i| sum[side][i] += c[i]);
                        count[side] += 1;
                    }
                }
            }
            if count.iter().any(|&n| n < MIN_CLEAN) {
                continue;
            }
            let [back, object] = [0, 1].map(|s| sum[s].map(|v| v / count[s] as f64));
            if let Some(alpha) = coverage(&colour(x, y), &object, &back) {
                if (alpha >= 0.5) != l {
                    flips.push((x as u32, y as u32));
                }
            }
        }
    }
    flips
}

/// Share of the object in a blend `c` of colours `object` and `back`, where `c` is such a
/// blend and the two differ enough to tell; `None` otherwise.
fn coverage(c: &[f64; 3], object: &[f64; 3], back: &[f64; 3]) -> Option<f64> {
    let d: [f64; 3] = std::array::from_fn(|i| object[i] - back[i]);
    let r: [f64; 3] = std::array::from_fn(|i| c[i] - back[i]);
    let dd: f64 = d.iter().map(|v| v * v).sum();
    if dd < MIN_CONTRAST * MIN_CONTRAST {
        return None;
    }
    let alpha = r.iter().zip(&d).map(|(a, b)| a * b).sum::<f64>() / dd;
    let off: f64 = (0..3).map(|i| (r[i] - alpha * d[i]).powi(2)).sum();
    (off <= MAX_OFF_LINE * MAX_OFF_LINE * dd).then_some(alpha.clamp(0.0, 1.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A disc of radius `r` at (cx, cy) drawn with each pixel's true coverage (4×4
    /// samples), object colour `fg` on `bg`; and the mask of pixels it covers by at least
    /// `threshold`.
    fn disc(size: u32, (cx, cy, r): (f64, f64, f64), fg: [u8; 3], bg: [u8; 3], threshold: f64) -> (RgbImage, GrayImage) {
        let cover = |x: u32, y: u32| {
            let n = 4;
            let inside = (0..n * n).filter(|&s| {
                let (u, v) = (x as f64 + (s % n) as f64 / n as f64 + 0.125, y as f64 + (s / n) as f64 / n as f64 + 0.125);
                (u - cx).powi(2) + (v - cy).powi(2) <= r * r
            });
            inside.count() as f64 / (n * n) as f64
        };
        let img = RgbImage::from_fn(size, size, |x, y| {
            let a = cover(x, y);
            image::Rgb(std::array::from_fn(|i| (fg[i] as f64 * a + bg[i] as f64 * (1.0 - a)).round() as u8))
        });
        let mask = GrayImage::from_fn(size, size, |x, y| Luma([if cover(x, y) >= threshold { OBJECT } else { 0 }]));
        (img, mask)
    }

    fn whole(size: u32) -> PixelBox {
        PixelBox { x0: 0, y0: 0, x1: size, y1: size }
    }

    #[test]
    fn a_mask_holding_every_touched_pixel_shrinks_to_half_coverage() {
        let geometry = (20.3, 19.6, 11.2);
        let (img, mut mask) = disc(40, geometry, [200, 40, 30], [30, 160, 60], 1e-9);
        let (_, truth) = disc(40, geometry, [0; 3], [0; 3], 0.5);
        let wrong_before = mask.pixels().zip(truth.pixels()).filter(|(a, b)| a != b).count();
        assert!(wrong_before > 20, "{wrong_before}");
        let changed = settle_outline(&img, &mut mask, &whole(40));
        let wrong_after = mask.pixels().zip(truth.pixels()).filter(|(a, b)| a != b).count();
        assert_eq!(changed, wrong_before - wrong_after);
        // Rounding the blend to whole grey levels leaves pixels at exactly half undecided.
        assert!(wrong_after <= 2, "{wrong_before} -> {wrong_after}");
    }

    #[test]
    fn a_mask_missing_half_covered_pixels_grows_to_them() {
        let geometry = (20.5, 20.2, 10.7);
        let (img, mut mask) = disc(40, geometry, [220, 220, 220], [20, 20, 90], 0.999);
        let (_, truth) = disc(40, geometry, [0; 3], [0; 3], 0.5);
        settle_outline(&img, &mut mask, &whole(40));
        let wrong = mask.pixels().zip(truth.pixels()).filter(|(a, b)| a != b).count();
        assert!(wrong <= 2, "{wrong}");
    }

    #[test]
    fn a_right_mask_stays() {
        let geometry = (18.0, 21.0, 9.3);
        let (img, mut mask) = disc(40, geometry, [10, 10, 10], [250, 240, 200], 0.5);
        let before = mask.clone();
        settle_outline(&img, &mut mask, &whole(40));
        assert!(mask.pixels().zip(before.pixels()).filter(|(a, b)| a != b).count() <= 2);
    }

    #[test]
    fn without_contrast_or_off_the_blend_nothing_moves() {
        // Object and background nearly alike: no matte can be read.
        let (img, mut mask) = disc(40, (20.0, 20.0, 10.0), [100, 100, 100], [110, 105, 100], 1e-9);
        let before = mask.clone();
        assert_eq!(settle_outline(&img, &mut mask, &whole(40)), 0);
        assert_eq!(mask, before);
        // An outline pixel of a third colour (a print line) is neither side's blend.
        assert_eq!(coverage(&[0.0, 0.0, 255.0], &[255.0, 0.0, 0.0], &[0.0, 255.0, 0.0]), None);
        assert_eq!(coverage(&[127.5, 127.5, 0.0], &[255.0, 0.0, 0.0], &[0.0, 255.0, 0.0]), Some(0.5));
    }

    #[test]
    fn outside_the_region_nothing_changes() {
        let (img, mut mask) = disc(40, (20.3, 19.6, 11.2), [200, 40, 30], [30, 160, 60], 1e-9);
        let before = mask.clone();
        assert_eq!(settle_outline(&img, &mut mask, &PixelBox { x0: 0, y0: 0, x1: 5, y1: 40 }), 0);
        assert_eq!(mask, before);
    }
}
