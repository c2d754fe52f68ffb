//! Per-pixel probability that a pixel shows the object, from the caller's mask. The mask
//! is the cue that crosses the render-to-real gap untouched; it is softened (never 0 or 1)
//! so that a few wrong mask pixels cannot veto an outline, and it says nothing (0.5) where
//! it cannot know: outside the image, and on pixels the caller marks as unknown (another
//! detection that may hide this object).

use image::GrayImage;

pub struct Posterior<'a> {
    mask: &'a GrayImage,
    unknown: Option<&'a GrayImage>,
    /// Probability given to a background mask pixel (1 − this to an object pixel).
    softness: f32,
}

impl<'a> Posterior<'a> {
    pub fn new(mask: &'a GrayImage, unknown: Option<&'a GrayImage>) -> Self {
        Self { mask, unknown: unknown.filter(|u| u.dimensions() == mask.dimensions()), softness: 0.1 }
    }

    /// Foreground probability at image point (u, v) (pixel centres at integers).
    pub fn foreground(&self, u: f64, v: f64) -> f32 {
        let (x, y) = (u.round(), v.round());
        if x < 0.0 || y < 0.0 || x >= self.mask.width() as f64 || y >= self.mask.height() as f64 {
            return 0.5;
        }
        let (x, y) = (x as u32, y as u32);
        if self.mask.get_pixel(x, y)[0] > 0 {
            return 1.0 - self.softness;
        }
        if self.unknown.is_some_and(|u| u.get_pixel(x, y)[0] > 0) {
            return 0.5;
        }
        self.softness
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
        assert_eq!(p.foreground(1.2, 0.9), 0.9);
        assert_eq!(p.foreground(0.0, 0.0), 0.1);
        assert_eq!(p.foreground(2.0, 2.0), 0.5);
        assert_eq!(p.foreground(-1.0, 2.0), 0.5);
        assert_eq!(p.foreground(4.0, 2.0), 0.5);
    }
}
