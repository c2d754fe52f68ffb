//! What a render returns, and its assembly from padded readback rows.

use image::{GrayImage, RgbImage};

/// One rendered view. All three images are `width × height`, row-major, top row first.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderOutput {
    /// Shaded colour, sRGB-encoded 8-bit; background pixels are exactly
    /// `RenderOptions::background`.
    pub rgb: RgbImage,
    /// Camera-frame z in metres of the nearest surface (not the distance along the ray);
    /// 0 where the mesh does not cover the pixel centre.
    pub depth: Vec<f32>,
    /// 255 where the mesh covers the pixel centre, 0 elsewhere (so `mask` ⇔ `depth > 0`).
    pub mask: GrayImage,
}

impl RenderOutput {
    pub fn width(&self) -> u32 {
        self.rgb.width()
    }

    pub fn height(&self) -> u32 {
        self.rgb.height()
    }

    /// Metric depth at pixel (x, y), 0 for background.
    pub fn depth_at(&self, x: u32, y: u32) -> f32 {
        self.depth[(y * self.width() + x) as usize]
    }

    /// Depth at the pixel nearest (u, v), or at the closest covered pixel within `radius`
    /// pixels (a patch centre on the silhouette edge may fall just outside the object).
    /// `None` when nothing within the radius is covered.
    pub fn depth_near(&self, u: f64, v: f64, radius: i64) -> Option<f32> {
        let (w, h) = (self.width() as i64, self.height() as i64);
        let (x0, y0) = (u.round() as i64, v.round() as i64);
        let mut best: Option<(i64, f32)> = None;
        for ring in 0..=radius.max(0) {
            for dy in -ring..=ring {
                for dx in -ring..=ring {
                    let (x, y) = (x0 + dx, y0 + dy);
                    if dx.abs().max(dy.abs()) != ring || x < 0 || y < 0 || x >= w || y >= h {
                        continue;
                    }
                    let z = self.depth[(y * w + x) as usize];
                    let d2 = dx * dx + dy * dy;
                    if z > 0.0 && best.is_none_or(|(b, _)| d2 < b) {
                        best = Some((d2, z));
                    }
                }
            }
            if best.is_some() {
                break;
            }
        }
        best.map(|(_, z)| z)
    }

    pub fn is_foreground(&self, x: u32, y: u32) -> bool {
        self.mask.get_pixel(x, y)[0] != 0
    }

    /// Inclusive pixel bounds `[min_x, min_y, max_x, max_y]` of the mask, `None` if empty.
    pub fn mask_bbox(&self) -> Option<[u32; 4]> {
        let mut b: Option<[u32; 4]> = None;
        for (x, y, p) in self.mask.enumerate_pixels() {
            if p[0] != 0 {
                let r = b.get_or_insert([x, y, x, y]);
                *r = [r[0].min(x), r[1].min(y), r[2].max(x), r[3].max(y)];
            }
        }
        b
    }
}

/// Builds the output from readback buffers whose rows are `pitch` bytes apart: RGBA8 colour
/// and depth as native-endian f32 bits. Coverage is taken from depth (cleared to 0, and every drawn
/// surface lies beyond the near plane, so z > 0), and background pixels get `background`
/// exactly rather than whatever the clear colour encodes to.
pub(crate) fn assemble(width: u32, height: u32, pitch: usize, rgba: &[u8], depth_bytes: &[u8], background: [u8; 3]) -> RenderOutput {
    let (w, h) = (width as usize, height as usize);
    // Written in place row by row (not pushed pixel by pixel): a fifth of a small mesh's
    // render went into this loop when each pixel grew three vectors.
    let (mut rgb, mut depth, mut mask) = (vec![0u8; w * h * 3], vec![0f32; w * h], vec![0u8; w * h]);
    let rows = rgb.chunks_exact_mut(w * 3).zip(depth.chunks_exact_mut(w)).zip(mask.chunks_exact_mut(w));
    for (y, ((rgb_row, depth_row), mask_row)) in rows.enumerate() {
        let color_in = rgba[y * pitch..][..w * 4].chunks_exact(4);
        // Byte-wise decode: the slice need not be 4-byte aligned (tests pass plain Vec<u8>).
        let depth_in = depth_bytes[y * pitch..][..w * 4].chunks_exact(4).map(|b| f32::from_ne_bytes([b[0], b[1], b[2], b[3]]));
        for ((((px, z), rgb_px), depth_px), mask_px) in color_in.zip(depth_in).zip(rgb_row.chunks_exact_mut(3)).zip(depth_row.iter_mut()).zip(mask_row.iter_mut()) {
            let covered = z > 0.0;
            rgb_px.copy_from_slice(if covered { &px[..3] } else { &background });
            *depth_px = if covered { z } else { 0.0 };
            *mask_px = if covered { 255 } else { 0 };
        }
    }
    RenderOutput { rgb: RgbImage::from_raw(width, height, rgb).expect("sized above"), depth, mask: GrayImage::from_raw(width, height, mask).expect("sized above") }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unpads_rows_and_fills_background() {
        // 2×2 image, rows padded to 12 bytes.
        let pitch = 12;
        let mut rgba = vec![0u8; pitch * 2];
        let mut depth = vec![0u8; pitch * 2];
        rgba[4..8].copy_from_slice(&[10, 20, 30, 255]); // (1, 0)
        depth[4..8].copy_from_slice(&1.5f32.to_ne_bytes());
        rgba[pitch..pitch + 4].copy_from_slice(&[1, 2, 3, 255]); // (0, 1)
        depth[pitch..pitch + 4].copy_from_slice(&0.25f32.to_ne_bytes());
        rgba[8..12].fill(99); // padding must be ignored
        let out = assemble(2, 2, pitch, &rgba, &depth, [7, 8, 9]);
        assert_eq!(out.depth, vec![0.0, 1.5, 0.25, 0.0]);
        assert_eq!(out.rgb.get_pixel(1, 0).0, [10, 20, 30]);
        assert_eq!(out.rgb.get_pixel(0, 1).0, [1, 2, 3]);
        assert_eq!(out.rgb.get_pixel(0, 0).0, [7, 8, 9]);
        assert!(out.is_foreground(1, 0) && !out.is_foreground(1, 1));
        assert_eq!(out.mask_bbox(), Some([0, 0, 1, 1]));
    }
}
