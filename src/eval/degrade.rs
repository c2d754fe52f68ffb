//! Image degradations that simulate the render-to-real gap on a clean render: clutter
//! behind the object, blur, colour shift and sensor noise.

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
}
