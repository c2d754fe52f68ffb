//! Response maps of one image at one scale, computed once and shared by every template of
//! every object: for each of the 8 orientations, how well the spread image orientations at
//! each pixel agree with it (0–4). Also stored "linearised" (LINE-2D): for a search stride
//! `t`, the `t²` sub-images of pixels (t·gx + rx, t·gy + ry), so that one template feature
//! adds a contiguous run of bytes to the score of every grid position at once.

use super::gradients::{colour_gradients, quantised_bits, similarity_table, spread, BINS};
use image::RgbImage;

pub struct ResponseMaps {
    pub width: usize,
    pub height: usize,
    /// Search stride in pixels.
    pub stride: usize,
    /// Grid of search positions: (gw × gh), position (gx, gy) is pixel (stride·gx, stride·gy).
    pub gw: usize,
    pub gh: usize,
    /// `[orientation][ry·stride + rx]` → gw × gh bytes.
    linear: Vec<Vec<Vec<u8>>>,
    /// `[orientation]` → width × height bytes, for scoring at single-pixel steps.
    full: Vec<Vec<u8>>,
    /// Share of pixels with a quantised orientation (before spreading): clutter measure.
    pub edge_density: f32,
}

impl ResponseMaps {
    pub fn compute(rgb: &RgbImage, min_magnitude: f32, spread_t: usize, stride: usize) -> ResponseMaps {
        let g = colour_gradients(rgb);
        let bits = quantised_bits(&g, min_magnitude);
        let edge_density = bits.iter().filter(|&&b| b != 0).count() as f32 / bits.len().max(1) as f32;
        let (w, h) = (g.width, g.height);
        let spread_bits = spread(&bits, w, h, spread_t);
        let lut = similarity_table();
        let full: Vec<Vec<u8>> = (0..BINS).map(|o| spread_bits.iter().map(|&b| lut[o][b as usize]).collect()).collect();
        let (gw, gh) = (w.div_ceil(stride), h.div_ceil(stride));
        let linear = full
            .iter()
            .map(|map| {
                (0..stride * stride)
                    .map(|r| {
                        let (ry, rx) = (r / stride, r % stride);
                        let mut sub = vec![0u8; gw * gh];
                        for gy in 0..gh {
                            let y = gy * stride + ry;
                            if y >= h {
                                continue;
                            }
                            for gx in 0..gw {
                                let x = gx * stride + rx;
                                if x < w {
                                    sub[gy * gw + gx] = map[y * w + x];
                                }
                            }
                        }
                        sub
                    })
                    .collect()
            })
            .collect();
        ResponseMaps { width: w, height: h, stride, gw, gh, linear, full, edge_density }
    }

    /// Adds feature (dx, dy, orientation)'s responses to `acc` (gw × gh) for every grid
    /// position; positions whose feature falls outside the image get nothing.
    pub fn accumulate(&self, acc: &mut [u8], dx: i32, dy: i32, orientation: u8) {
        let t = self.stride as i32;
        let (rx, ry) = (dx.rem_euclid(t), dy.rem_euclid(t));
        let (sx, sy) = (dx.div_euclid(t), dy.div_euclid(t));
        let mem = &self.linear[orientation as usize][(ry * t + rx) as usize];
        let (gw, gh) = (self.gw as i32, self.gh as i32);
        let (x0, x1) = ((-sx).max(0), (gw - sx).min(gw));
        if x0 >= x1 {
            return;
        }
        for gy in (-sy).max(0)..(gh - sy).min(gh) {
            let dst = &mut acc[(gy * gw + x0) as usize..(gy * gw + x1) as usize];
            let src_start = ((gy + sy) * gw + x0 + sx) as usize;
            let src = &mem[src_start..src_start + dst.len()];
            // Plain byte adds: at most 63 features × 4 fits a byte, and this loop vectorises.
            for (d, s) in dst.iter_mut().zip(src) {
                *d = d.wrapping_add(*s);
            }
        }
    }

    /// Mean response over all 8 orientations at pixel (x, y): what a feature of a random
    /// orientation would get there (high where clutter has edges of every orientation).
    pub fn chance_at(&self, x: i32, y: i32) -> f32 {
        if x < 0 || y < 0 || x as usize >= self.width || y as usize >= self.height {
            return 0.0;
        }
        let i = y as usize * self.width + x as usize;
        self.full.iter().map(|m| m[i] as f32).sum::<f32>() / BINS as f32
    }

    /// The response of one feature at pixel (x, y) (0 outside the image).
    pub fn at(&self, x: i32, y: i32, orientation: u8) -> u8 {
        if x < 0 || y < 0 || x as usize >= self.width || y as usize >= self.height {
            return 0;
        }
        self.full[orientation as usize][y as usize * self.width + x as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn linear_accumulation_equals_direct_lookups() {
        // Blocks of hashed colours: edges of both orientations all over.
        let img = RgbImage::from_fn(37, 29, |x, y| {
            let h = ((x / 5) * 7919 + (y / 5) * 104_729) % 251;
            image::Rgb([h as u8, (h * 3 % 251) as u8, 0])
        });
        let r = ResponseMaps::compute(&img, 20.0, 4, 4);
        assert!(r.edge_density > 0.05);
        for &(dx, dy, o) in &[(0, 0, 0u8), (5, -3, 2), (-9, 7, 4), (13, 2, 6), (-40, 0, 1)] {
            let mut acc = vec![0u8; r.gw * r.gh];
            r.accumulate(&mut acc, dx, dy, o);
            for gy in 0..r.gh {
                for gx in 0..r.gw {
                    let want = r.at((gx * 4) as i32 + dx, (gy * 4) as i32 + dy, o);
                    assert_eq!(acc[gy * r.gw + gx], want, "feature ({dx},{dy},{o}) at grid {gx},{gy}");
                }
            }
        }
    }
}
