//! Per-pixel probability that a pixel shows the object, from the caller's mask. The mask
//! is the cue that crosses the render-to-real gap untouched; it is softened (never 0 or 1)
//! so that a few wrong mask pixels cannot veto an outline, and it says nothing (0.5) where
//! it cannot know: outside the image, and on pixels the caller marks as unknown (another
//! detection that may hide this object).

use image::GrayImage;

pub struct Posterior<'a> {
    mask: &'a GrayImage,
    unknown: Option<&'a GrayImage>,
    /// The probability each mask value gives (but 0.5 on `unknown`'s pixels): 0 the
    /// softness, any other value 1 − the softness; or for a graded mask, the value's
    /// probability (value / 255) kept within those bounds. A table, because the lines read
    /// four pixels for each of their samples, and a division each was a measurable part of
    /// a tracking step.
    levels: [f32; 256],
}

/// Probability given to a background mask pixel (1 − this to an object pixel).
const SOFTNESS: f32 = 0.1;

impl<'a> Posterior<'a> {
    pub fn new(mask: &'a GrayImage, unknown: Option<&'a GrayImage>) -> Self {
        let levels = std::array::from_fn(|v| if v > 0 { 1.0 - SOFTNESS } else { SOFTNESS });
        Self { mask, unknown: unknown.filter(|u| u.dimensions() == mask.dimensions()), levels }
    }

    /// From an image of foreground probabilities (0 = surely background, 255 = surely the
    /// object), e.g. a tracker's colour posterior.
    pub fn probabilities(probs: &'a GrayImage) -> Self {
        Self { mask: probs, unknown: None, levels: std::array::from_fn(|v| (v as f32 / 255.0).clamp(SOFTNESS, 1.0 - SOFTNESS)) }
    }

    /// Foreground probability at image point (u, v) (pixel centres at integers),
    /// bilinear between the four nearest pixels: the outline's position along a line then
    /// moves continuously with the line, so many lines together place it to a fraction of a
    /// pixel (nearest-pixel lookups left small objects a few per cent off in depth).
    pub fn foreground(&self, u: f64, v: f64) -> f32 {
        let (x0, y0) = (crate::geometry::pixel::floor_i64(u), crate::geometry::pixel::floor_i64(v));
        let (fx, fy) = ((u - x0 as f64) as f32, (v - y0 as f64) as f32);
        let (w, h) = (self.mask.width() as i64, self.mask.height() as i64);
        // The four pixels by index from the first when all are inside (nearly every sample
        // of every line): one bounds check instead of four.
        let [a, b, c, d] = if x0 >= 0 && y0 >= 0 && x0 + 1 < w && y0 + 1 < h {
            let i = (y0 * w + x0) as usize;
            [i, i + 1, i + w as usize, i + w as usize + 1].map(|i| self.at(i))
        } else {
            [(x0, y0), (x0 + 1, y0), (x0, y0 + 1), (x0 + 1, y0 + 1)].map(|(x, y)| self.pixel(x, y))
        };
        let top = a * (1.0 - fx) + b * fx;
        let bottom = c * (1.0 - fx) + d * fx;
        top * (1.0 - fy) + bottom * fy
    }

    /// Foreground probability of pixel (x, y).
    fn pixel(&self, x: i64, y: i64) -> f32 {
        let (w, h) = (self.mask.width() as i64, self.mask.height() as i64);
        if x < 0 || y < 0 || x >= w || y >= h {
            return 0.5;
        }
        self.at((y * w + x) as usize)
    }

    /// Foreground probability of the pixel at raw index `i` (inside the image).
    #[inline]
    fn at(&self, i: usize) -> f32 {
        // The raw buffers by index: four reads per sample of every line, where `get_pixel`
        // would check the bounds again each time.
        let value = self.mask.as_raw()[i];
        if value == 0 && self.unknown.is_some_and(|u| u.as_raw()[i] > 0) {
            return 0.5;
        }
        self.levels[value as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mask_outside_and_unknown() {
        let mut m = GrayImage::new(4, 4);
        m.put_pixel(1, 1, image::Luma([255]));
        let mut u = GrayImage::new(4, 4);
        u.put_pixel(2, 2, image::Luma([255]));
        let p = Posterior::new(&m, Some(&u));
        assert_eq!(p.foreground(1.0, 1.0), 0.9);
        // Between pixels: bilinear.
        assert!((p.foreground(1.5, 1.0) - 0.5).abs() < 1e-6);
        assert!((p.foreground(1.25, 0.75) - (0.9 * 0.75 * 0.75 + 0.1 * (1.0 - 0.75 * 0.75))).abs() < 1e-6);
        assert_eq!(p.foreground(0.0, 0.0), 0.1);
        assert_eq!(p.foreground(2.0, 2.0), 0.5);
        assert_eq!(p.foreground(-1.0, 2.0), 0.5);
        assert_eq!(p.foreground(4.0, 2.0), 0.5);
        // Graded: the value is the probability, within the same bounds.
        m.put_pixel(2, 1, image::Luma([128]));
        let g = Posterior::probabilities(&m);
        assert_eq!((g.foreground(1.0, 1.0), g.foreground(0.0, 0.0), g.foreground(-1.0, 0.0)), (0.9, 0.1, 0.5));
        assert!((g.foreground(2.0, 1.0) - 128.0 / 255.0).abs() < 1e-6);
        // Inside, across the border and outside: the four pixels' bilinear blend, each as
        // `pixel` gives it.
        let p = Posterior::new(&m, Some(&u));
        for (i, j) in (0..26).flat_map(|i| (0..26).map(move |j| (i, j))) {
            let (x, y) = (-1.5 + 0.27 * i as f64, -1.5 + 0.27 * j as f64);
            let (x0, y0) = (x.floor() as i64, y.floor() as i64);
            let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
            let top = p.pixel(x0, y0) * (1.0 - fx) + p.pixel(x0 + 1, y0) * fx;
            let bottom = p.pixel(x0, y0 + 1) * (1.0 - fx) + p.pixel(x0 + 1, y0 + 1) * fx;
            assert_eq!(p.foreground(x, y), top * (1.0 - fy) + bottom * fy, "at ({x}, {y})");
        }
    }
}
