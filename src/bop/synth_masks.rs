//! Imperfect copies of a true mask, as a real detector's lower-scoring proposals look:
//! too tight, too loose, or misplaced. `b2tf bop synth` writes them beside the true masks
//! so that the multi-mask selection has wrong candidates to reject.

use image::{GrayImage, Luma};

/// Square structuring element of half-side `r`: `grow` dilates, otherwise erodes.
/// Separable (rows, then columns), so O(pixels · r).
pub fn morph(mask: &GrayImage, r: u32, grow: bool) -> GrayImage {
    let (w, h) = mask.dimensions();
    let pick = |acc: bool, v: bool| if grow { acc || v } else { acc && v };
    let pass = |src: &GrayImage, horizontal: bool| {
        GrayImage::from_fn(w, h, |x, y| {
            let (c, n) = if horizontal { (x, w) } else { (y, h) };
            let lo = c.saturating_sub(r);
            let hi = (c + r).min(n - 1);
            let mut acc = !grow;
            for i in lo..=hi {
                let (sx, sy) = if horizontal { (i, y) } else { (x, i) };
                acc = pick(acc, src.get_pixel(sx, sy)[0] > 0);
            }
            // Outside the image counts as background, so erosion also eats masks cut by the border.
            if !grow && (c < r || c + r >= n) {
                acc = false;
            }
            Luma([if acc { 255 } else { 0 }])
        })
    };
    pass(&pass(mask, true), false)
}

/// The mask moved by (dx, dy) pixels; what leaves the image is lost.
pub fn shift(mask: &GrayImage, dx: i64, dy: i64) -> GrayImage {
    let (w, h) = mask.dimensions();
    GrayImage::from_fn(w, h, |x, y| {
        let (sx, sy) = (x as i64 - dx, y as i64 - dy);
        if sx >= 0 && sy >= 0 && sx < w as i64 && sy < h as i64 {
            *mask.get_pixel(sx as u32, sy as u32)
        } else {
            Luma([0])
        }
    })
}

pub fn area(mask: &GrayImage) -> usize {
    mask.as_raw().iter().filter(|&&v| v > 0).count()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(w: u32, h: u32, x0: u32, y0: u32, side: u32) -> GrayImage {
        GrayImage::from_fn(w, h, |x, y| Luma([if (x0..x0 + side).contains(&x) && (y0..y0 + side).contains(&y) { 255 } else { 0 }]))
    }

    #[test]
    fn erode_dilate_shift_known_areas() {
        let m = square(20, 20, 5, 5, 6);
        assert_eq!(area(&morph(&m, 1, false)), 16);
        assert_eq!(area(&morph(&m, 2, true)), 100);
        assert_eq!(area(&morph(&m, 2, false)), 4);
        assert_eq!(area(&morph(&m, 3, false)), 0);
        let s = shift(&m, 3, -2);
        assert_eq!(s, square(20, 20, 8, 3, 6));
        // Shifted past the border, the part outside is gone.
        assert_eq!(area(&shift(&m, 12, 0)), 6 * 3);
        // Erosion treats the outside as background.
        assert_eq!(area(&morph(&square(4, 4, 0, 0, 4), 1, false)), 4);
    }
}
