//! A caller's box in whole pixels, checked and clipped to the image: what every mask made
//! from a box starts from.

use super::{MaskError, OBJECT};
use image::{GrayImage, Luma};

/// A box clipped to the image, in whole pixels: columns `x0..x1`, rows `y0..y1`. Pixels
/// partly covered by a fractional box count as inside.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PixelBox {
    pub x0: u32,
    pub y0: u32,
    pub x1: u32,
    pub y1: u32,
}

impl PixelBox {
    /// Checks `[x, y, w, h]` (pixels) and clips it to a `width × height` image.
    pub fn from_xywh(bbox: [f64; 4], width: u32, height: u32) -> Result<PixelBox, MaskError> {
        if bbox.iter().any(|v| !v.is_finite()) {
            return Err(MaskError::NonFiniteBox { bbox });
        }
        let [x, y, w, h] = bbox;
        if w <= 0.0 || h <= 0.0 {
            return Err(MaskError::ZeroAreaBox { bbox });
        }
        // Saturating float→int casts keep huge boxes panic-free.
        let clip = |v: f64, limit: u32| (v as i64).clamp(0, limit as i64) as u32;
        let (x0, x1) = (clip(x.floor(), width), clip((x + w).ceil(), width));
        let (y0, y1) = (clip(y.floor(), height), clip((y + h).ceil(), height));
        if x0 >= x1 || y0 >= y1 {
            return Err(MaskError::BoxOutsideImage { bbox, width, height });
        }
        Ok(PixelBox { x0, y0, x1, y1 })
    }

    pub fn width(&self) -> u32 {
        self.x1 - self.x0
    }

    pub fn height(&self) -> u32 {
        self.y1 - self.y0
    }

    pub fn area(&self) -> u64 {
        self.width() as u64 * self.height() as u64
    }

    pub fn contains(&self, x: u32, y: u32) -> bool {
        (self.x0..self.x1).contains(&x) && (self.y0..self.y1).contains(&y)
    }

    /// A `width × height` mask with this box filled.
    pub fn filled(&self, width: u32, height: u32) -> GrayImage {
        GrayImage::from_fn(width, height, |x, y| Luma([if self.contains(x, y) { OBJECT } else { 0 }]))
    }
}
