//! Finding a lost object again from the colours its track learnt: the pixels of a window
//! whose smoothed foreground posterior says "object" are grouped into 4-connected regions,
//! and the region with the most evidence among those of a plausible size (against the
//! object's last silhouette) is its mask, holes filled. The mask then goes to a full
//! estimate (session.rs).
//!
//! Why not a generic box segmentation (GrabCut on a box around the last pose, what the
//! session did before): at fast motion the object has often left that box, and GrabCut
//! then segments whatever clutter the box holds, which the estimate turns into a confident
//! wrong pose. The track's own histograms know which colours are the object's and which
//! are its surroundings'. Measured on generated sequences at 10° / 5 cm per frame (the
//! full estimate from the true mask was right on 60 of 60 sampled frames), so the mask
//! is what decides a re-initialisation: docs/tracking.md.

use super::colour::{ColourModel, Window};
use crate::masks::components::components;
use image::{GrayImage, RgbImage};

/// A region smaller than this share of the object's last silhouette is a fragment or
/// clutter; larger than `MAX_AREA_SHARE` it has merged with the background. Broad, as a
/// turn changes a box's silhouette several times over.
const MIN_AREA_SHARE: f64 = 0.15;
const MAX_AREA_SHARE: f64 = 4.0;
/// A region's pixels must say "object" by this much on average (posterior − ½), so that
/// colours only slightly likelier on the object do not make a region.
const MIN_MEAN_MARGIN: f64 = 0.1;

/// The object's mask (a whole-frame image, non-zero on it) among the pixels of `window`,
/// or None when no region there is both object-coloured and about `expected_area` pixels
/// (the object's last silhouette).
pub fn find_by_colour(colours: &ColourModel, image: &RgbImage, window: Window, expected_area: f64) -> Option<GrayImage> {
    let (w, h) = window.size();
    let (w, h) = (w as usize, h as usize);
    let mut posterior = vec![0f32; w * h];
    for (i, p) in posterior.iter_mut().enumerate() {
        *p = colours.probability(image.get_pixel(window.x0 + (i % w) as u32, window.y0 + (i / w) as u32));
    }
    // Smoothing over a few pixels, growing with the object, joins an object's pixels
    // across thin lines of ambiguous colour and drops isolated pixels of clutter.
    let radius = (expected_area.sqrt() / 15.0).clamp(1.0, 4.0) as usize;
    let smooth = box_mean(&posterior, w, h, radius);
    let (labels, sizes) = components(w, h, |i| smooth[i] > 0.5);
    let mut evidence = vec![0f64; sizes.len()];
    for (label, &p) in labels.iter().zip(&smooth) {
        if let Some(c) = label {
            evidence[*c] += 2.0 * p as f64 - 1.0;
        }
    }
    let plausible = |c: &usize| {
        let area = sizes[*c] as f64;
        area >= MIN_AREA_SHARE * expected_area && area <= MAX_AREA_SHARE * expected_area && evidence[*c] / area >= 2.0 * MIN_MEAN_MARGIN
    };
    let best = (0..sizes.len()).filter(plausible).max_by(|&a, &b| evidence[a].total_cmp(&evidence[b]))?;
    // Holes: the regions outside `best` that do not reach the window's edge are inside
    // the object (a label colour the background shares).
    let (outside, count) = components(w, h, |i| labels[i] != Some(best));
    let mut open = vec![false; count.len()];
    for (i, c) in outside.iter().enumerate() {
        let (x, y) = (i % w, i / w);
        if let Some(c) = c.filter(|_| x == 0 || y == 0 || x + 1 == w || y + 1 == h) {
            open[c] = true;
        }
    }
    let mut mask = GrayImage::new(image.width(), image.height());
    for (i, c) in outside.iter().enumerate() {
        if c.is_none_or(|c| !open[c]) {
            mask.put_pixel(window.x0 + (i % w) as u32, window.y0 + (i / w) as u32, image::Luma([255]));
        }
    }
    Some(mask)
}

/// The mean of `values` (a `w × h` grid) over the (2r+1)² square around each cell, clipped
/// at the edges.
fn box_mean(values: &[f32], w: usize, h: usize, r: usize) -> Vec<f32> {
    // Summed-area table with a zero row and column in front.
    let mut sum = vec![0f64; (w + 1) * (h + 1)];
    for y in 0..h {
        let mut row = 0f64;
        for x in 0..w {
            row += values[y * w + x] as f64;
            sum[(y + 1) * (w + 1) + x + 1] = sum[y * (w + 1) + x + 1] + row;
        }
    }
    let mut out = vec![0f32; w * h];
    for y in 0..h {
        let (y0, y1) = (y.saturating_sub(r), (y + r + 1).min(h));
        for x in 0..w {
            let (x0, x1) = (x.saturating_sub(r), (x + r + 1).min(w));
            let s = sum[y1 * (w + 1) + x1] - sum[y0 * (w + 1) + x1] - sum[y1 * (w + 1) + x0] + sum[y0 * (w + 1) + x0];
            out[y * w + x] = (s / ((x1 - x0) * (y1 - y0)) as f64) as f32;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::track::colour::tests::red_square;

    /// A 100×100 frame of blue-green background with the red square (20×20) at `at`, a
    /// blue hole in its middle, and a 4×4 red speck of clutter elsewhere.
    fn frame(at: (u32, u32)) -> RgbImage {
        let mut img = RgbImage::from_pixel(100, 100, image::Rgb([20, 120, 200]));
        for y in 0..20 {
            for x in 0..20 {
                let hole = (8..12).contains(&x) && (8..12).contains(&y);
                img.put_pixel(at.0 + x, at.1 + y, if hole { image::Rgb([20, 120, 200]) } else { image::Rgb([220, 30, 30]) });
            }
        }
        for y in 80..84 {
            for x in 5..9 {
                img.put_pixel(x, y, image::Rgb([220, 30, 30]));
            }
        }
        img
    }

    fn learnt() -> ColourModel {
        let (img, sil) = red_square();
        let mut colours = ColourModel::default();
        assert!(colours.learn(&img, &sil, Window { x0: 0, y0: 0, x1: 40, y1: 40 }, 1.0));
        colours
    }

    #[test]
    fn finds_the_moved_object_and_fills_its_hole() {
        let colours = learnt();
        let img = frame((60, 30));
        let all = Window { x0: 0, y0: 0, x1: 100, y1: 100 };
        let mask = find_by_colour(&colours, &img, all, 400.0).expect("the square is found");
        let inside = |x: u32, y: u32| mask.get_pixel(x, y)[0] > 0;
        assert!(inside(61, 31) && inside(78, 48) && inside(69, 39), "the square, its hole filled");
        assert!(!inside(6, 81), "the speck is too small to be the object");
        assert!(!inside(50, 50) && !inside(59, 40) && !inside(81, 40));
        let area = mask.pixels().filter(|p| p[0] > 0).count();
        assert!((380..=440).contains(&area), "area {area}");
    }

    #[test]
    fn nothing_when_the_window_misses_it_or_the_size_is_wrong() {
        let colours = learnt();
        let img = frame((60, 30));
        assert!(find_by_colour(&colours, &img, Window { x0: 0, y0: 0, x1: 50, y1: 60 }, 400.0).is_none(), "the object is not in this window");
        assert!(find_by_colour(&colours, &img, Window { x0: 0, y0: 0, x1: 100, y1: 100 }, 4000.0).is_none(), "a tenth of the size expected");
        assert!(find_by_colour(&ColourModel::default(), &img, Window { x0: 0, y0: 0, x1: 100, y1: 100 }, 400.0).is_none(), "nothing learnt");
    }

    #[test]
    fn box_mean_of_a_step() {
        let v = [0.0, 0.0, 1.0, 1.0];
        let m = box_mean(&v, 4, 1, 1);
        assert_eq!(m, vec![0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0]);
    }
}
