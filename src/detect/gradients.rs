//! Image gradients as shape-based matching uses them (LINE-2D, Hinterstoisser et al., PAMI
//! 2012): the colour gradient of the strongest channel, its orientation quantised to 8 bins
//! over a half turn (the sign is ignored: an object edge may be darker or brighter than
//! whatever lies behind it), kept only where a 3×3 neighbourhood agrees.
//! Templates (rendered views) and images go through the same functions, so the two sides
//! quantise alike.

use image::RgbImage;

/// Orientation bins over [0, π).
pub const BINS: usize = 8;

/// Per-pixel gradient of an RGB image: magnitude and angle in [0, π) of the channel with
/// the largest magnitude (after a 3×3 binomial blur: Sobel on raw pixels is mostly noise).
pub struct Gradients {
    pub width: usize,
    pub height: usize,
    pub magnitude: Vec<f32>,
    pub angle: Vec<f32>,
}

/// Bin of an angle (radians, any value; taken modulo π).
pub fn bin_of(angle: f32) -> u8 {
    let t = angle.rem_euclid(std::f32::consts::PI) / std::f32::consts::PI * BINS as f32;
    (t.round() as usize % BINS) as u8
}

fn blurred_channels(rgb: &RgbImage) -> [Vec<f32>; 3] {
    let (w, h) = (rgb.width() as usize, rgb.height() as usize);
    let raw = rgb.as_raw();
    let mut out: [Vec<f32>; 3] = [vec![0.0; w * h], vec![0.0; w * h], vec![0.0; w * h]];
    let mut tmp = vec![0.0f32; w * h];
    for (c, plane) in out.iter_mut().enumerate() {
        // Rows then columns with [1 2 1]/4, edges clamped.
        for y in 0..h {
            for x in 0..w {
                let at = |xx: usize| raw[(y * w + xx) * 3 + c] as f32;
                let (l, r) = (x.saturating_sub(1), (x + 1).min(w - 1));
                tmp[y * w + x] = (at(l) + 2.0 * at(x) + at(r)) * 0.25;
            }
        }
        for y in 0..h {
            let (u, d) = (y.saturating_sub(1), (y + 1).min(h - 1));
            for x in 0..w {
                plane[y * w + x] = (tmp[u * w + x] + 2.0 * tmp[y * w + x] + tmp[d * w + x]) * 0.25;
            }
        }
    }
    out
}

/// Sobel gradients of the blurred image; border pixels get none.
pub fn colour_gradients(rgb: &RgbImage) -> Gradients {
    let (w, h) = (rgb.width() as usize, rgb.height() as usize);
    let mut g = Gradients { width: w, height: h, magnitude: vec![0.0; w * h], angle: vec![0.0; w * h] };
    if w < 3 || h < 3 {
        return g;
    }
    let planes = blurred_channels(rgb);
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let (mut best, mut gx_best, mut gy_best) = (0.0f32, 0.0f32, 0.0f32);
            for p in &planes {
                let at = |dx: isize, dy: isize| p[(y as isize + dy) as usize * w + (x as isize + dx) as usize];
                let gx = (at(1, -1) + 2.0 * at(1, 0) + at(1, 1)) - (at(-1, -1) + 2.0 * at(-1, 0) + at(-1, 1));
                let gy = (at(-1, 1) + 2.0 * at(0, 1) + at(1, 1)) - (at(-1, -1) + 2.0 * at(0, -1) + at(1, -1));
                let m = gx * gx + gy * gy;
                if m > best {
                    (best, gx_best, gy_best) = (m, gx, gy);
                }
            }
            let i = y * w + x;
            g.magnitude[i] = best.sqrt();
            g.angle[i] = gy_best.atan2(gx_best).rem_euclid(std::f32::consts::PI);
        }
    }
    g
}

/// Gradients of a silhouette (0–255 coverage): the outline's own orientation, as if the
/// object stood on any background.
pub fn mask_gradients(mask: &image::GrayImage) -> Gradients {
    let rgb = RgbImage::from_fn(mask.width(), mask.height(), |x, y| {
        let v = mask.get_pixel(x, y)[0];
        image::Rgb([v, v, v])
    });
    colour_gradients(&rgb)
}

/// One orientation bit per pixel (`1 << bin`), 0 where the gradient is weaker than
/// `min_magnitude` or its 3×3 neighbourhood does not agree on a bin (at least 5 of the 9
/// strong pixels in the same bin: LINE-2D's vote, which drops noise and texture speckle).
pub fn quantised_bits(g: &Gradients, min_magnitude: f32) -> Vec<u8> {
    let (w, h) = (g.width, g.height);
    let bins: Vec<u8> = g.magnitude.iter().zip(&g.angle).map(|(&m, &a)| if m >= min_magnitude { bin_of(a) + 1 } else { 0 }).collect();
    let mut out = vec![0u8; w * h];
    if w < 3 || h < 3 {
        return out;
    }
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            if bins[y * w + x] == 0 {
                continue;
            }
            let mut hist = [0u8; BINS + 1];
            for yy in y - 1..=y + 1 {
                for xx in x - 1..=x + 1 {
                    hist[bins[yy * w + xx] as usize] += 1;
                }
            }
            let (b, n) = hist.iter().enumerate().skip(1).max_by_key(|&(_, &n)| n).map(|(b, &n)| (b, n)).unwrap_or((0, 0));
            if n >= 5 {
                out[y * w + x] = 1 << (b - 1);
            }
        }
    }
    out
}

/// The bits OR-ed over a `t × t` window (offsets −t/2 .. t/2 − 1 in x and y): a feature
/// then matches wherever its orientation occurs within that window, which gives the
/// search its tolerance to small shape and pose differences.
pub fn spread(bits: &[u8], w: usize, h: usize, t: usize) -> Vec<u8> {
    let rows = or_along(bits, w, h, t, 1, w);
    or_along(&rows, w, h, t, w, h)
}

/// One pass of `spread`: each pixel ORs the `t` pixels at offsets −t/2 .. t/2 − 1 along
/// one axis (`step` 1: along rows of `len` = w; `step` w: along columns of `len` = h).
fn or_along(bits: &[u8], w: usize, h: usize, t: usize, step: usize, len: usize) -> Vec<u8> {
    let lo = (t / 2) as isize;
    let hi = t as isize - lo - 1;
    let mut out = vec![0u8; w * h];
    for i in 0..w * h {
        // Position of pixel i along the axis.
        let c = if step == 1 { i % w } else { i / w } as isize;
        let mut acc = 0u8;
        for d in -lo..=hi {
            if (0..len as isize).contains(&(c + d)) {
                acc |= bits[(i as isize + d * step as isize) as usize];
            }
        }
        out[i] = acc;
    }
    out
}

/// Similarity of a template orientation to the bits present at a pixel: 4 for the same bin,
/// 1 for a neighbouring one, else 0 (LINE-2D's table: a feature's worth is almost all in
/// its exact orientation; the neighbour credit absorbs quantisation at bin borders).
pub fn similarity_table() -> [[u8; 256]; BINS] {
    let mut lut = [[0u8; 256]; BINS];
    for (o, row) in lut.iter_mut().enumerate() {
        for (bits, v) in row.iter_mut().enumerate() {
            let mut best = 0u8;
            for b in 0..BINS {
                if bits & (1 << b) != 0 {
                    let d = (o as isize - b as isize).rem_euclid(BINS as isize).min((b as isize - o as isize).rem_euclid(BINS as isize));
                    best = best.max(match d {
                        0 => 4,
                        1 => 1,
                        _ => 0,
                    });
                }
            }
            *v = best;
        }
    }
    lut
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vertical_edge(w: u32, h: u32, at: u32) -> RgbImage {
        RgbImage::from_fn(w, h, |x, _| if x < at { image::Rgb([20, 20, 20]) } else { image::Rgb([220, 30, 30]) })
    }

    #[test]
    fn a_vertical_edge_has_a_horizontal_gradient() {
        let g = colour_gradients(&vertical_edge(16, 16, 8));
        let bits = quantised_bits(&g, 30.0);
        // Pixels on the edge carry bin 0 (gradient along +x); flat areas nothing.
        assert_eq!(bits[8 * 16 + 8], 1);
        assert_eq!(bits[8 * 16 + 7], 1);
        assert_eq!(bits[8 * 16 + 2], 0);
        // A darker-to-brighter and a brighter-to-darker edge quantise alike.
        let flipped = RgbImage::from_fn(16, 16, |x, _| if x < 8 { image::Rgb([220, 30, 30]) } else { image::Rgb([20, 20, 20]) });
        assert_eq!(quantised_bits(&colour_gradients(&flipped), 30.0)[8 * 16 + 8], 1);
    }

    #[test]
    fn bins_wrap_at_a_half_turn() {
        assert_eq!(bin_of(0.0), 0);
        assert_eq!(bin_of(std::f32::consts::PI), 0);
        assert_eq!(bin_of(std::f32::consts::FRAC_PI_2), 4);
        assert_eq!(bin_of(-std::f32::consts::FRAC_PI_8), 7);
    }

    #[test]
    fn spreading_covers_its_window_only() {
        let (w, h) = (8, 8);
        let mut bits = vec![0u8; w * h];
        bits[4 * w + 4] = 0b100;
        let s = spread(&bits, w, h, 4);
        // Offsets −2..1: the bit reaches x, y in 3..=6.
        for y in 0..h {
            for x in 0..w {
                let inside = (3..=6).contains(&x) && (3..=6).contains(&y);
                assert_eq!(s[y * w + x] != 0, inside, "{x},{y}");
            }
        }
    }

    #[test]
    fn similarity_is_exact_or_neighbour() {
        let lut = similarity_table();
        assert_eq!(lut[0][0b1], 4);
        assert_eq!(lut[0][0b10], 1);
        assert_eq!(lut[0][0b1000_0000], 1);
        assert_eq!(lut[0][0b100], 0);
        assert_eq!(lut[3][0b1000 | 0b1], 4);
        assert_eq!(lut[5][0], 0);
    }
}
