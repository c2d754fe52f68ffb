//! The detector's data for one object, built at onboarding: for every viewpoint on an
//! icosphere and every in-plane turn, a shape template of sparse features (offset from the
//! projected object centre and quantised gradient orientation) at one canonical size,
//! where the object's bounding sphere is `canonical_px` across. Scale is handled on the
//! image side (the image is resampled so the object appears at that size), so one set of
//! templates serves every distance.
//!
//! Features come from renders of the mesh with its colours: about half on the silhouette
//! (its outline is there whatever the background and lighting), the rest the strongest
//! interior edges (texture, creases), each set spread out so no part of the view dominates.

use super::gradients::{colour_gradients, mask_gradients, quantised_bits, BINS};
use crate::geometry::pixel::floor_i64;
use crate::geometry::views::{fitted_distance, icosphere, in_plane_rotation, look_at_rotation, view_pose};
use crate::geometry::{Intrinsics, Pose};
use crate::mesh::Mesh;
use crate::render::{RenderError, RenderOptions, RenderPool};
use image::{GrayImage, RgbImage};
use nalgebra::{Rotation3, Vector3};
use rayon::prelude::*;

/// How the templates are sampled; stored with them.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DetectorConfig {
    /// Icosphere level of the viewpoints (1: 42 views, about 30° apart).
    pub level: u32,
    /// In-plane turns per viewpoint.
    pub in_plane_steps: u32,
    /// Diameter of the object's bounding sphere in the templates, pixels.
    pub canonical_px: u32,
    /// Features per template (at most 63: the scores add up in bytes).
    pub features: usize,
    /// Gradient magnitude (Sobel on 0–255 values) below which a pixel has no orientation.
    pub min_magnitude: f32,
}

impl Default for DetectorConfig {
    fn default() -> Self {
        Self { level: 1, in_plane_steps: 16, canonical_px: 40, features: 48, min_magnitude: 40.0 }
    }
}

/// Share of the base render's half-width the bounding sphere fills.
const FILL: f64 = 0.8;
/// Renders are made at this multiple of the canonical size, then averaged down.
const SUPERSAMPLE: u32 = 4;

impl DetectorConfig {
    pub fn validate(&self) -> Result<(), String> {
        if self.level > 3 {
            return Err(format!("detector icosphere level must be 0–3, got {}", self.level));
        }
        if !(1..=72).contains(&self.in_plane_steps) {
            return Err(format!("detector in-plane steps must be 1–72, got {}", self.in_plane_steps));
        }
        if !(16..=96).contains(&self.canonical_px) {
            return Err(format!("detector canonical size must be 16–96 px, got {}", self.canonical_px));
        }
        if !(8..=63).contains(&self.features) {
            return Err(format!("detector features per template must be 8–63, got {}", self.features));
        }
        if !(self.min_magnitude.is_finite() && self.min_magnitude > 0.0) {
            return Err(format!("detector gradient threshold must be positive, got {}", self.min_magnitude));
        }
        Ok(())
    }

    /// Side of the canonical template image.
    pub fn template_side(&self) -> u32 {
        (self.canonical_px as f64 / FILL).round() as u32
    }

    pub fn template_count(&self) -> usize {
        icosphere(self.level).len() * self.in_plane_steps as usize
    }

    /// Rotation (object → camera) of template `t`, for an object centred on the optical axis.
    pub fn rotation(&self, t: usize) -> Rotation3<f64> {
        let dirs = icosphere(self.level);
        let (view, turn) = (t / self.in_plane_steps as usize, t % self.in_plane_steps as usize);
        in_plane_rotation(self.angle(turn)) * look_at_rotation(&dirs[view])
    }

    fn angle(&self, turn: usize) -> f64 {
        turn as f64 * std::f64::consts::TAU / self.in_plane_steps as f64
    }
}

/// One template feature: offset from the projected object centre in canonical pixels, and
/// orientation bin.
#[derive(Clone, Copy, Debug, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct Feature {
    pub dx: i8,
    pub dy: i8,
    pub orientation: i8,
}

/// Every template of one object.
#[derive(Clone, Debug, PartialEq)]
pub struct ShapeModel {
    pub config: DetectorConfig,
    /// `templates × config.features`, template-major.
    pub features: Vec<Feature>,
    /// Silhouette box per template relative to the centre, canonical pixels: x0, y0, x1, y1
    /// (exclusive ends).
    pub boxes: Vec<[i8; 4]>,
    /// Chromaticity histogram of the object over all views (`verify::chroma_histogram`);
    /// empty for a mesh without colours.
    pub colours: Vec<f32>,
}

impl ShapeModel {
    pub fn template_count(&self) -> usize {
        self.boxes.len()
    }

    pub fn template(&self, t: usize) -> &[Feature] {
        let n = self.config.features;
        &self.features[t * n..(t + 1) * n]
    }

    /// How many orientations template `t`'s features spread over: the entropy of their
    /// orientation histogram, as a share of its maximum (1: all bins equally; 0: one bin).
    /// A template of one or two orientations (a thin or box-like view) matches poles,
    /// rails and the edges of other boxes as well as the object.
    pub fn orientation_spread(&self, t: usize) -> f32 {
        let mut counts = [0f32; super::gradients::BINS];
        for f in self.template(t) {
            counts[f.orientation as usize % super::gradients::BINS] += 1.0;
        }
        let n: f32 = counts.iter().sum();
        if n == 0.0 {
            return 0.0;
        }
        let h: f32 = counts.iter().filter(|&&c| c > 0.0).map(|&c| -(c / n) * (c / n).ln()).sum();
        h / (super::gradients::BINS as f32).ln()
    }

    pub fn memory_bytes(&self) -> usize {
        self.features.len() * 3 + self.boxes.len() * 4 + self.colours.len() * 4
    }

    /// Checks the arrays agree with the configuration (used after loading).
    pub fn validate(&self) -> Result<(), String> {
        self.config.validate()?;
        let t = self.config.template_count();
        if self.boxes.len() != t || self.features.len() != t * self.config.features {
            return Err(format!("detector arrays do not match {t} templates × {} features", self.config.features));
        }
        if !(self.colours.is_empty() || self.colours.len() == super::verify::CHROMA_HISTOGRAM_LEN && self.colours.iter().all(|v| v.is_finite())) {
            return Err(format!("detector colour histogram has {} bins, expected {}", self.colours.len(), super::verify::CHROMA_HISTOGRAM_LEN));
        }
        if self.features.iter().any(|f| f.orientation < 0 || f.orientation as usize >= BINS) {
            return Err("detector feature with an orientation outside 0–7".into());
        }
        Ok(())
    }

    /// Renders the mesh from every viewpoint and samples each view's features.
    pub fn build(mesh: &Mesh, renderer: &RenderPool, config: &DetectorConfig) -> Result<ShapeModel, RenderError> {
        config.validate().map_err(RenderError::InvalidOptions)?;
        let side = config.template_side();
        let size = side * SUPERSAMPLE;
        // Square, fx = fy, principal point at the centre: in-plane turns are exact.
        let c = (size as f64 - 1.0) * 0.5;
        let k = Intrinsics { fx: size as f64, fy: size as f64, cx: c, cy: c, width: size, height: size };
        let (centre, radius) = (Vector3::from(mesh.bbox_center()), mesh.bounding_radius().max(1e-6));
        let distance = fitted_distance(radius, k.fx, size as f64 * 0.5, FILL);
        let dirs = icosphere(config.level);
        let views: Vec<(Pose, Intrinsics)> = dirs.iter().map(|d| (view_pose(d, 0.0, &centre, distance), k)).collect();
        let mut model = ShapeModel { config: *config, features: vec![], boxes: vec![], colours: vec![] };
        let mut colours = [0f32; super::verify::CHROMA_HISTOGRAM_LEN];
        for chunk in views.chunks(32) {
            let renders = renderer.render_batch(mesh, chunk, &RenderOptions::default())?;
            if mesh.has_colours() {
                for r in &renders {
                    let h = super::verify::chroma_histogram(&r.rgb, &r.mask);
                    colours.iter_mut().zip(h).for_each(|(a, b)| *a += b);
                }
            }
            let per_view: Vec<Vec<(Vec<Feature>, [i8; 4])>> = renders
                .par_iter()
                .map(|r| {
                    (0..config.in_plane_steps as usize)
                        .map(|turn| {
                            // The render turned about the principal point (the camera's roll),
                            // then averaged down: each in-plane template goes through the
                            // same quantisation as an image, so the two sides agree.
                            let (rgb, mask) = turn_image(&r.rgb, &r.mask, config.angle(turn));
                            let (rgb, mask) = (downsample_rgb(&rgb, SUPERSAMPLE), downsample_mask(&mask, SUPERSAMPLE));
                            (view_features(&rgb, &mask, config), silhouette_box(&mask))
                        })
                        .collect()
                })
                .collect();
            for view in per_view {
                for (features, bx) in view {
                    model.features.extend(features);
                    model.boxes.push(bx);
                }
            }
        }
        let total: f32 = colours.iter().sum();
        if total > 0.0 {
            model.colours = colours.iter().map(|v| v / total).collect();
        }
        Ok(model)
    }
}

/// A candidate feature: position relative to the centre and orientation bin.
#[derive(Clone, Copy, Debug)]
struct BaseFeature {
    x: f32,
    y: f32,
    bin: u8,
}

fn downsample_rgb(img: &RgbImage, f: u32) -> RgbImage {
    RgbImage::from_fn(img.width() / f, img.height() / f, |x, y| {
        let mut s = [0u32; 3];
        for yy in y * f..(y + 1) * f {
            for xx in x * f..(x + 1) * f {
                let p = img.get_pixel(xx, yy);
                for c in 0..3 {
                    s[c] += p[c] as u32;
                }
            }
        }
        image::Rgb(s.map(|v| (v / (f * f)) as u8))
    })
}

/// Coverage of each cell, 0–255: an anti-aliased silhouette, whose outline has the
/// orientation of the true edge (a thresholded one is a staircase whose local gradients
/// swing by a bin either way, while a photo's edges are smooth).
fn downsample_mask(mask: &GrayImage, f: u32) -> GrayImage {
    GrayImage::from_fn(mask.width() / f, mask.height() / f, |x, y| {
        let mut sum = 0u32;
        for yy in y * f..(y + 1) * f {
            for xx in x * f..(x + 1) * f {
                sum += mask.get_pixel(xx, yy)[0] as u32;
            }
        }
        image::Luma([(sum / (f * f)) as u8])
    })
}

/// A cell is object when at least half of it is.
const INSIDE: u8 = 128;

/// The features of one canonical view: outline and interior candidates, each spread out,
/// quantised as images are (`quantised_bits`, with its vote), exactly `config.features`
/// (repeated when the view has fewer candidates, which keeps the per-template stride).
fn view_features(rgb: &RgbImage, mask: &GrayImage, config: &DetectorConfig) -> Vec<Feature> {
    let (w, h) = (rgb.width() as usize, rgb.height() as usize);
    let centre = (w as f32 - 1.0) * 0.5;
    // The outline from the mask itself: the rendered colours there meet black, which no
    // photo shows; the mask's edge is where any background would make one.
    let outline = mask_gradients(mask);
    let outline_bits = quantised_bits(&outline, config.min_magnitude);
    let colour = colour_gradients(rgb);
    let colour_bits = quantised_bits(&colour, config.min_magnitude * 1.5);
    let fg = |i: usize| mask.as_raw()[i] >= INSIDE;
    let (mut contour, mut interior) = (Vec::new(), Vec::new());
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let at = |bits: u8| BaseFeature { x: x as f32 - centre, y: y as f32 - centre, bin: bits.trailing_zeros() as u8 };
            if fg(i) && outline_bits[i] != 0 {
                contour.push((outline.magnitude[i], at(outline_bits[i])));
            } else if fg(i) && outline.magnitude[i] == 0.0 && colour_bits[i] != 0 {
                interior.push((colour.magnitude[i], at(colour_bits[i])));
            }
        }
    }
    let n = config.features;
    let mut picked = scattered(&contour, n.div_ceil(2), config.canonical_px as f32 / 6.0);
    let rest = n - picked.len();
    picked.extend(scattered(&interior, rest, config.canonical_px as f32 / 8.0));
    if picked.len() < n {
        // Too little texture: more of the outline instead.
        for f in scattered(&contour, n, 1.0) {
            if picked.len() == n {
                break;
            }
            if !picked.iter().any(|p| p.x == f.x && p.y == f.y) {
                picked.push(f);
            }
        }
    }
    let have = picked.len().max(1);
    (0..n).filter_map(|i| picked.get(i % have)).map(|f| Feature { dx: f.x.round().clamp(-127.0, 127.0) as i8, dy: f.y.round().clamp(-127.0, 127.0) as i8, orientation: f.bin as i8 }).collect()
}

/// `rgb` and `mask` turned by `angle` about the image centre (the principal point), both
/// sampled bilinearly.
fn turn_image(rgb: &RgbImage, mask: &GrayImage, angle: f64) -> (RgbImage, GrayImage) {
    if angle == 0.0 {
        return (rgb.clone(), mask.clone());
    }
    let (w, h) = rgb.dimensions();
    let (cx, cy) = ((w as f64 - 1.0) * 0.5, (h as f64 - 1.0) * 0.5);
    let (s, c) = angle.sin_cos();
    let (src_rgb, src_mask) = (rgb.as_raw(), mask.as_raw());
    let (mut turned_rgb, mut turned_mask) = (RgbImage::new(w, h), GrayImage::new(w, h));
    let pixels = turned_rgb.chunks_exact_mut(3).zip(turned_mask.iter_mut());
    for (i, (px, m)) in pixels.enumerate() {
        // Output pixel p shows input pixel R(−angle)·(p − centre) + centre.
        let (dx, dy) = ((i as u32 % w) as f64 - cx, (i as u32 / w) as f64 - cy);
        let (u, v) = (cx + c * dx + s * dy, cy - s * dx + c * dy);
        let (x0, y0) = (floor_i64(u), floor_i64(v));
        let (fx, fy) = (u - x0 as f64, v - y0 as f64);
        // The four bilinear taps, found once for the four channels: the pixel's index
        // (None outside the image, which reads 0) and its weights along x and y.
        let taps = [(0, 0, 1.0 - fx, 1.0 - fy), (1, 0, fx, 1.0 - fy), (0, 1, 1.0 - fx, fy), (1, 1, fx, fy)].map(|(ox, oy, wx, wy)| {
            let (x, y) = (x0.saturating_add(ox), y0.saturating_add(oy));
            let inside = x >= 0 && y >= 0 && x < w as i64 && y < h as i64;
            (inside.then(|| (y * w as i64 + x) as usize), wx, wy)
        });
        let level = |img: &[u8], channels: usize, k: usize| {
            let sum = taps.iter().fold(0.0, |acc, &(at, wx, wy)| acc + at.map_or(0.0, |i| img[i * channels + k] as f64) * wx * wy);
            // Sums are ≥ 0: adding ½ and truncating rounds them, without a libm call.
            (sum + 0.5) as u8
        };
        for (k, level_k) in px.iter_mut().enumerate() {
            *level_k = level(src_rgb, 3, k);
        }
        *m = level(src_mask, 1, 0);
    }
    (turned_rgb, turned_mask)
}

/// Box of a canonical silhouette (cells at least half covered) relative to its centre:
/// x0, y0, x1, y1 (exclusive ends).
fn silhouette_box(mask: &GrayImage) -> [i8; 4] {
    let centre = (mask.width() as f32 - 1.0) * 0.5;
    let inside = GrayImage::from_fn(mask.width(), mask.height(), |x, y| image::Luma([(mask.get_pixel(x, y)[0] >= INSIDE) as u8]));
    match crate::features::mask_bbox(&inside) {
        Some((u0, v0, u1, v1)) => [u0 as f32 - centre - 0.5, v0 as f32 - centre - 0.5, u1 as f32 - centre + 0.5, v1 as f32 - centre + 0.5].map(|v| v.round().clamp(-127.0, 127.0) as i8),
        None => [0, 0, 0, 0],
    }
}

/// Up to `n` candidates, strongest first, no two closer than a distance that starts at
/// `spacing` and shrinks until enough are taken (LINE-2D's scattered selection).
fn scattered(candidates: &[(f32, BaseFeature)], n: usize, spacing: f32) -> Vec<BaseFeature> {
    let mut order: Vec<&(f32, BaseFeature)> = candidates.iter().collect();
    order.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut d = spacing.max(1.0);
    loop {
        let mut out: Vec<BaseFeature> = Vec::with_capacity(n);
        for (_, f) in &order {
            if out.len() == n {
                break;
            }
            if out.iter().all(|p| (p.x - f.x).powi(2) + (p.y - f.y).powi(2) >= d * d) {
                out.push(*f);
            }
        }
        if out.len() == n || d <= 1.0 {
            return out;
        }
        d = (d - 1.0).max(1.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_bounds() {
        assert!(DetectorConfig::default().validate().is_ok());
        assert!(DetectorConfig { features: 64, ..Default::default() }.validate().is_err());
        assert!(DetectorConfig { canonical_px: 8, ..Default::default() }.validate().is_err());
        assert!(DetectorConfig { in_plane_steps: 0, ..Default::default() }.validate().is_err());
        assert_eq!(DetectorConfig::default().template_count(), 42 * 16);
    }

    #[test]
    fn scattered_features_keep_their_distance() {
        let c: Vec<(f32, BaseFeature)> = (0..100).map(|i| (i as f32, BaseFeature { x: (i % 10) as f32, y: (i / 10) as f32, bin: 0 })).collect();
        let f = scattered(&c, 9, 4.0);
        assert_eq!(f.len(), 9);
        for (i, a) in f.iter().enumerate() {
            for b in &f[i + 1..] {
                assert!((a.x - b.x).powi(2) + (a.y - b.y).powi(2) >= 9.0, "{a:?} {b:?}");
            }
        }
        // The strongest candidate always comes first.
        assert_eq!((f[0].x, f[0].y), (9.0, 9.0));
    }

    #[test]
    fn orientation_spread_is_zero_for_one_bin_and_one_for_all_alike() {
        let config = DetectorConfig { features: 16, ..Default::default() };
        let template = |bin: &dyn Fn(usize) -> i8| (0..16).map(|i| Feature { dx: i as i8, dy: 0, orientation: bin(i) }).collect::<Vec<_>>();
        let mut features = template(&|_| 3);
        features.extend(template(&|i| (i % 8) as i8));
        features.extend(template(&|i| (i % 2) as i8 * 4));
        let model = ShapeModel { config, features, boxes: vec![[0; 4]; 3], colours: vec![] };
        assert_eq!(model.orientation_spread(0), 0.0);
        assert!((model.orientation_spread(1) - 1.0).abs() < 1e-5);
        // Two bins equally: a third of the maximum (ln 2 / ln 8).
        assert!((model.orientation_spread(2) - 1.0 / 3.0).abs() < 1e-5);
    }

    #[test]
    fn a_quarter_turn_turns_images_about_the_centre() {
        let mask = GrayImage::from_fn(11, 11, |x, y| image::Luma([if (3..8).contains(&x) && (4..7).contains(&y) { 255 } else { 0 }]));
        let rgb = RgbImage::from_fn(11, 11, |x, _| image::Rgb([(x * 20) as u8, 0, 0]));
        let (r, m) = turn_image(&rgb, &mask, std::f64::consts::FRAC_PI_2);
        // The 5 × 3 box turns into a 3 × 5 one about the centre; a colour ramp along x
        // becomes one along y.
        assert_eq!(silhouette_box(&mask), [-3, -2, 3, 2]);
        assert_eq!(silhouette_box(&m), [-2, -3, 2, 3]);
        assert_eq!(r.get_pixel(5, 3)[0], 60);
        assert_eq!(r.get_pixel(5, 7)[0], 140);
    }
}
