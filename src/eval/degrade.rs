//! Image degradations that simulate the render-to-real gap on a clean render: clutter
//! behind the object, blur, colour shift, sensor noise, JPEG, and an object's print that
//! differs a little from its mesh's texture.

use crate::mesh::procedural::Rng;
use image::{GrayImage, RgbImage};

/// Procedural clutter: overlapping random rectangles and discs over a random gradient.
pub fn clutter_background(w: u32, h: u32, rng: &mut Rng) -> RgbImage {
    let c0 = [rng.range(0.0, 255.0), rng.range(0.0, 255.0), rng.range(0.0, 255.0)];
    let c1 = [rng.range(0.0, 255.0), rng.range(0.0, 255.0), rng.range(0.0, 255.0)];
    let mut img = RgbImage::from_fn(w, h, |x, y| {
        let t = (x as f64 / w as f64 + y as f64 / h as f64) * 0.5;
        image::Rgb(std::array::from_fn(|k| (c0[k] * (1.0 - t) + c1[k] * t) as u8))
    });
    let scale = w.min(h) as f64;
    for _ in 0..40 {
        let col = image::Rgb([rng.range(0.0, 255.0) as u8, rng.range(0.0, 255.0) as u8, rng.range(0.0, 255.0) as u8]);
        let (cx, cy) = (rng.range(0.0, w as f64), rng.range(0.0, h as f64));
        let (rx, ry) = (rng.range(0.02, 0.15) * scale, rng.range(0.02, 0.15) * scale);
        let disc = rng.uniform() < 0.5;
        let (x0, x1) = ((cx - rx).max(0.0) as u32, ((cx + rx) as u32).min(w));
        let (y0, y1) = ((cy - ry).max(0.0) as u32, ((cy + ry) as u32).min(h));
        for y in y0..y1 {
            for x in x0..x1 {
                let (dx, dy) = ((x as f64 - cx) / rx, (y as f64 - cy) / ry);
                if !disc || dx * dx + dy * dy < 1.0 {
                    img.put_pixel(x, y, col);
                }
            }
        }
    }
    img
}

/// Object pixels (mask > 0) from `fg`, the rest from `bg`.
pub fn composite(fg: &RgbImage, mask: &GrayImage, bg: &RgbImage) -> RgbImage {
    RgbImage::from_fn(fg.width(), fg.height(), |x, y| if mask.get_pixel(x, y)[0] > 0 { *fg.get_pixel(x, y) } else { *bg.get_pixel(x, y) })
}

/// Separable Gaussian blur with standard deviation `sigma` pixels.
pub fn gaussian_blur(img: &RgbImage, sigma: f64) -> RgbImage {
    if sigma <= 0.0 {
        return img.clone();
    }
    let r = (3.0 * sigma).ceil() as i64;
    let k: Vec<f64> = (-r..=r).map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp()).collect();
    let norm: f64 = k.iter().sum();
    let (w, h) = (img.width() as i64, img.height() as i64);
    let pass = |src: &RgbImage, horizontal: bool| {
        RgbImage::from_fn(w as u32, h as u32, |x, y| {
            let mut acc = [0f64; 3];
            for (i, kv) in k.iter().enumerate() {
                let d = i as i64 - r;
                let (sx, sy) = if horizontal { ((x as i64 + d).clamp(0, w - 1), y as i64) } else { (x as i64, (y as i64 + d).clamp(0, h - 1)) };
                let p = src.get_pixel(sx as u32, sy as u32);
                for c in 0..3 {
                    acc[c] += p[c] as f64 * kv;
                }
            }
            image::Rgb(acc.map(|a| (a / norm).round().clamp(0.0, 255.0) as u8))
        })
    };
    pass(&pass(img, true), false)
}

/// Per-channel gain and offset (white balance and exposure differences).
pub fn color_shift(img: &RgbImage, gains: [f64; 3], offsets: [f64; 3]) -> RgbImage {
    RgbImage::from_fn(img.width(), img.height(), |x, y| {
        let p = img.get_pixel(x, y);
        image::Rgb(std::array::from_fn(|c| (p[c] as f64 * gains[c] + offsets[c]).round().clamp(0.0, 255.0) as u8))
    })
}

/// Additive Gaussian noise of `sigma` grey levels.
pub fn add_noise(img: &RgbImage, sigma: f64, rng: &mut Rng) -> RgbImage {
    let mut out = img.clone();
    for p in out.pixels_mut() {
        for c in 0..3 {
            p[c] = (p[c] as f64 + sigma * rng.normal()).round().clamp(0.0, 255.0) as u8;
        }
    }
    out
}

/// The image after a JPEG round trip at `quality` (1–100), as a camera or a pipeline that
/// stores frames leaves it: 8×8 block artefacts and chroma subsampling.
pub fn jpeg_round_trip(img: &RgbImage, quality: u8) -> anyhow::Result<RgbImage> {
    let mut bytes = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, quality.clamp(1, 100)).encode_image(img)?;
    Ok(image::load_from_memory_with_format(&bytes, image::ImageFormat::Jpeg)?.to_rgb8())
}

/// How an object's print differs from its mesh's texture in one photo: per channel, a
/// colour gain that varies linearly across the object's box (`gain[c] = base[c] +
/// slope[c]·(u, v)`, u and v in −1…1), and a misregistration of the print by `shift` pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PrintDrift {
    pub base: [f64; 3],
    pub slope: [[f64; 2]; 3],
    pub shift: (i32, i32),
}

impl PrintDrift {
    /// A drift whose gain stays within 1 ± `gain`, and whose shift is at most `shift_px`
    /// pixels along each axis.
    pub fn sample(gain: f64, shift_px: f64, rng: &mut Rng) -> Self {
        let shift = |rng: &mut Rng| rng.range(-shift_px, shift_px).round() as i32;
        Self {
            base: std::array::from_fn(|_| 1.0 + rng.range(-gain, gain) * 0.5),
            slope: std::array::from_fn(|_| [rng.range(-gain, gain) * 0.25, rng.range(-gain, gain) * 0.25]),
            shift: (shift(rng), shift(rng)),
        }
    }

    /// Applies the drift to the pixels of `img` under `mask` (an object rendered alone);
    /// pixels whose shifted source falls off the object keep their own colour, so the
    /// outline does not move.
    pub fn apply(&self, img: &mut RgbImage, mask: &GrayImage) {
        let inside = |x: i64, y: i64| x >= 0 && y >= 0 && x < mask.width() as i64 && y < mask.height() as i64 && mask.get_pixel(x as u32, y as u32)[0] > 0;
        let Some((x0, y0, x1, y1)) = crate::features::mask_bbox(mask) else { return };
        let (cx, cy) = ((x0 + x1) as f64 * 0.5, (y0 + y1) as f64 * 0.5);
        let (hx, hy) = (((x1 - x0) as f64 * 0.5).max(1.0), ((y1 - y0) as f64 * 0.5).max(1.0));
        let source = img.clone();
        for y in y0..=y1 {
            for x in x0..=x1 {
                if !inside(x as i64, y as i64) {
                    continue;
                }
                let (sx, sy) = (x as i64 + self.shift.0 as i64, y as i64 + self.shift.1 as i64);
                let p = if inside(sx, sy) { *source.get_pixel(sx as u32, sy as u32) } else { *source.get_pixel(x, y) };
                let (u, v) = ((x as f64 - cx) / hx, (y as f64 - cy) / hy);
                let gain = |c: usize| self.base[c] + self.slope[c][0] * u + self.slope[c][1] * v;
                img.put_pixel(x, y, image::Rgb(std::array::from_fn(|c| (p[c] as f64 * gain(c)).round().clamp(0.0, 255.0) as u8)));
            }
        }
    }
}

/// Binary dilation by a square of radius `r` (segmentation masks overshoot the object).
pub fn dilate(mask: &GrayImage, r: u32) -> GrayImage {
    let (w, h) = mask.dimensions();
    GrayImage::from_fn(w, h, |x, y| {
        let (x0, x1) = (x.saturating_sub(r), (x + r).min(w - 1));
        let (y0, y1) = (y.saturating_sub(r), (y + r).min(h - 1));
        let on = (y0..=y1).any(|yy| (x0..=x1).any(|xx| mask.get_pixel(xx, yy)[0] > 0));
        image::Luma([if on { 255 } else { 0 }])
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blur_preserves_flat_images_and_dilate_grows() {
        let flat = RgbImage::from_pixel(20, 10, image::Rgb([10, 100, 200]));
        assert_eq!(gaussian_blur(&flat, 1.5), flat);
        let mut m = GrayImage::new(9, 9);
        m.put_pixel(4, 4, image::Luma([255]));
        let d = dilate(&m, 2);
        assert_eq!(d.pixels().filter(|p| p[0] > 0).count(), 25);
        let mut rng = Rng::new(1);
        let noisy = add_noise(&flat, 5.0, &mut rng);
        assert_ne!(noisy, flat);
        let bg = clutter_background(32, 32, &mut rng);
        let c = composite(&image::imageops::crop_imm(&flat, 0, 0, 9, 9).to_image(), &d, &image::imageops::crop_imm(&bg, 0, 0, 9, 9).to_image());
        assert_eq!(c.get_pixel(4, 4).0, [10, 100, 200]);
    }

    #[test]
    fn jpeg_round_trip_loses_detail_and_keeps_the_size() {
        let mut rng = Rng::new(3);
        let img = add_noise(&clutter_background(64, 48, &mut rng), 20.0, &mut rng);
        let (fine, coarse) = (jpeg_round_trip(&img, 95).unwrap(), jpeg_round_trip(&img, 20).unwrap());
        assert_eq!(coarse.dimensions(), (64, 48));
        let err = |o: &RgbImage| o.as_raw().iter().zip(img.as_raw()).map(|(a, b)| (*a as f64 - *b as f64).abs()).sum::<f64>() / img.as_raw().len() as f64;
        assert!(err(&coarse) > err(&fine) && err(&fine) > 0.0, "quality 20: {}, 95: {}", err(&coarse), err(&fine));
    }

    #[test]
    fn print_drift_changes_the_object_only_and_within_its_gain() {
        let mut img = RgbImage::from_fn(40, 30, |x, _| image::Rgb([100, 100, if x < 20 { 50 } else { 150 }]));
        let before = img.clone();
        let mut mask = GrayImage::new(40, 30);
        for y in 5..25 {
            for x in 10..30 {
                mask.put_pixel(x, y, image::Luma([255]));
            }
        }
        let drift = PrintDrift { base: [1.1, 0.95, 1.0], slope: [[0.05, 0.0], [0.0, -0.05], [0.0, 0.0]], shift: (2, 0) };
        drift.apply(&mut img, &mask);
        for (x, y, p) in img.enumerate_pixels() {
            let q = before.get_pixel(x, y);
            if mask.get_pixel(x, y)[0] == 0 {
                assert_eq!(p, q, "({x}, {y}) is off the object");
                continue;
            }
            // Red: gain 1.1 ± 0.05 of 100; green 0.95 ± 0.05; blue moved by the 2-pixel
            // shift (its edge at x = 20 reads from x + 2), except where the source is off the object.
            assert!((104..=116).contains(&p[0]) && (89..=101).contains(&p[1]), "({x}, {y}): {p:?}");
            let source_x = if x + 2 < 30 { x + 2 } else { x };
            assert_eq!(p[2], before.get_pixel(source_x, y)[2], "({x}, {y})");
        }
        let sampled = PrintDrift::sample(0.2, 1.5, &mut Rng::new(4));
        assert!(sampled.base.iter().all(|b| (b - 1.0).abs() <= 0.1) && sampled.shift.0.abs() <= 2 && sampled.shift.1.abs() <= 2);
    }
}
