//! Real frames behind the generated objects: the photo in place of the procedural clutter
//! and, where the frame has one, its measured depth in place of the flat wall. Real
//! clutter (cables, printed paper, furniture, reflections) is what procedural backgrounds
//! do not show, and what boxes from a real detector take in.

use anyhow::{bail, Result};
use image::imageops::{resize, FilterType};
use image::RgbImage;

/// A real frame: its photo and, where it has one, its depth (metres, row-major, 0 where
/// nothing was measured).
#[derive(Clone, Debug, PartialEq)]
pub struct Background {
    pub rgb: RgbImage,
    pub depth: Option<Vec<f32>>,
}

/// The real depth is placed behind the scene: scaled so that its 5th percentile lies this
/// many times as far as the farthest generated surface (a real table nearer than a floating
/// object would hide it in depth but not in colour).
const BEHIND: f64 = 1.3;

impl Background {
    /// Refuses a depth of another size than the photo, or not finite / negative.
    pub fn new(rgb: RgbImage, depth: Option<Vec<f32>>) -> Result<Self> {
        if let Some(d) = &depth {
            let (w, h) = rgb.dimensions();
            if d.len() != (w * h) as usize {
                bail!("background depth holds {} values for a {w}x{h} photo", d.len());
            }
            if let Some(bad) = d.iter().find(|z| !z.is_finite() || **z < 0.0) {
                bail!("background depth holds {bad}, not a distance");
            }
        }
        Ok(Self { rgb, depth })
    }

    /// The photo and depth at `w`×`h` (stretched where the frame's size differs: smooth for
    /// the photo, nearest for the depth, which must not blend surfaces).
    pub(super) fn fitted(&self, w: u32, h: u32) -> (RgbImage, Option<Vec<f32>>) {
        (self.photo_at(w, h), self.depth_at(w, h))
    }

    /// The photo alone at `w`×`h` (an occluder's texture needs no depth).
    pub(super) fn photo_at(&self, w: u32, h: u32) -> RgbImage {
        if self.rgb.dimensions() == (w, h) {
            return self.rgb.clone();
        }
        resize(&self.rgb, w, h, FilterType::Triangle)
    }

    fn depth_at(&self, w: u32, h: u32) -> Option<Vec<f32>> {
        let d = self.depth.as_ref()?;
        let (sw, sh) = self.rgb.dimensions();
        if (sw, sh) == (w, h) {
            return Some(d.clone());
        }
        // By hand: `image`'s resize clamps float pixels to [0, 1], which depth in metres is not.
        let near = |i: u32, n: u32, sn: u32| (((i as f64 + 0.5) * sn as f64 / n as f64) as u32).min(sn - 1);
        Some((0..h).flat_map(|y| (0..w).map(move |x| (near(x, w, sw), near(y, h, sh)))).map(|(x, y)| d[(y * sw + x) as usize]).collect())
    }
}

/// One of `backgrounds`, drawn from `rng` (which must not be empty).
pub(super) fn pick<'a>(backgrounds: &'a [Background], rng: &mut crate::mesh::procedural::Rng) -> &'a Background {
    &backgrounds[(rng.next_u64() % backgrounds.len() as u64) as usize]
}

/// Fills the pixels of `depth` that hold no generated surface with `real`, scaled so that
/// it lies behind `farthest`, the farthest generated surface (`BEHIND`); the real frame's
/// holes stay holes.
pub(super) fn fill_behind(depth: &mut [f32], farthest: f64, real: &[f32]) {
    let mut measured: Vec<f32> = real.iter().copied().filter(|&z| z > 0.0).collect();
    if measured.is_empty() {
        return;
    }
    let k = measured.len() / 20;
    let near = *measured.select_nth_unstable_by(k, f32::total_cmp).1 as f64;
    let scale = if farthest > 0.0 { (BEHIND * farthest / near).max(1.0) } else { 1.0 };
    for (d, &r) in depth.iter_mut().zip(real) {
        if *d <= 0.0 {
            *d = (r as f64 * scale) as f32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::Rgb;

    #[test]
    fn the_real_depth_goes_behind_the_scene_and_keeps_its_holes() {
        let mut depth = vec![0.0, 0.8, 1.0, 0.0, 0.0];
        let real = [0.5, 0.5, 0.5, 0.0, 2.0];
        fill_behind(&mut depth, 1.0, &real);
        // 5th percentile 0.5 m moved to 1.3 × 1.0 m: a scale of 2.6.
        assert_eq!(depth[1..3], [0.8, 1.0]);
        assert!((depth[0] - 1.3).abs() < 1e-6 && depth[3] == 0.0 && (depth[4] - 5.2).abs() < 1e-5, "{depth:?}");
        // A frame already behind is not moved nearer.
        let mut near = vec![0.0, 0.3];
        fill_behind(&mut near, 0.3, &[4.0, 4.0]);
        assert_eq!(near, [4.0, 0.3]);
    }

    #[test]
    fn a_frame_is_fitted_to_the_image_and_bad_depth_is_refused() {
        let rgb = RgbImage::from_pixel(8, 6, Rgb([10, 20, 30]));
        let b = Background::new(rgb.clone(), Some(vec![1.5; 48])).unwrap();
        let (photo, depth) = b.fitted(16, 12);
        assert_eq!(photo.dimensions(), (16, 12));
        assert_eq!(*photo.get_pixel(5, 5), Rgb([10, 20, 30]));
        assert_eq!(depth.unwrap(), vec![1.5; 192]);
        // Nearest, never blended, and not clamped to [0, 1].
        let two = Background::new(RgbImage::new(2, 1), Some(vec![1.0, 3.0])).unwrap();
        assert_eq!(two.fitted(4, 2).1.unwrap(), [1.0, 1.0, 3.0, 3.0, 1.0, 1.0, 3.0, 3.0]);
        assert!(Background::new(rgb.clone(), Some(vec![1.0; 47])).unwrap_err().to_string().contains("47 values"));
        assert!(Background::new(rgb, Some(vec![f32::NAN; 48])).is_err());
    }
}
