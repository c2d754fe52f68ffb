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

use super::gradients::{bin_of, colour_gradients, BINS};
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
}

impl ShapeModel {
    pub fn template_count(&self) -> usize {
        self.boxes.len()
    }

    pub fn template(&self, t: usize) -> &[Feature] {
        let n = self.config.features;
        &self.features[t * n..(t + 1) * n]
    }

    pub fn memory_bytes(&self) -> usize {
        self.features.len() * 3 + self.boxes.len() * 4
    }

    /// Checks the arrays agree with the configuration (used after loading).
    pub fn validate(&self) -> Result<(), String> {
        self.config.validate()?;
        let t = self.config.template_count();
        if self.boxes.len() != t || self.features.len() != t * self.config.features {
            return Err(format!("detector arrays do not match {t} templates × {} features", self.config.features));
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
        let mut model = ShapeModel { config: *config, features: vec![], boxes: vec![] };
        for chunk in views.chunks(32) {
            let renders = renderer.render_batch(mesh, chunk, &RenderOptions::default())?;
            let per_view: Vec<Vec<(Vec<Feature>, [i8; 4])>> = renders
                .par_iter()
                .map(|r| {
                    let (rgb, mask) = (downsample_rgb(&r.rgb, SUPERSAMPLE), downsample_mask(&r.mask, SUPERSAMPLE));
                    let base = view_features(&rgb, &mask, config);
                    (0..config.in_plane_steps as usize).map(|turn| turned(&base, &mask, config.angle(turn))).collect()
                })
                .collect();
            for view in per_view {
                for (features, bx) in view {
                    model.features.extend(features);
                    model.boxes.push(bx);
                }
            }
        }
        Ok(model)
    }
}

/// A feature before the in-plane turn: position relative to the centre and angle.
#[derive(Clone, Copy, Debug)]
struct BaseFeature {
    x: f32,
    y: f32,
    angle: f32,
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

/// A cell is object when at least half of it is.
fn downsample_mask(mask: &GrayImage, f: u32) -> GrayImage {
    GrayImage::from_fn(mask.width() / f, mask.height() / f, |x, y| {
        let mut n = 0;
        for yy in y * f..(y + 1) * f {
            for xx in x * f..(x + 1) * f {
                n += (mask.get_pixel(xx, yy)[0] > 0) as u32;
            }
        }
        image::Luma([if n * 2 >= f * f { 255 } else { 0 }])
    })
}

/// The features of one canonical view: contour and interior candidates, each spread out.
fn view_features(rgb: &RgbImage, mask: &GrayImage, config: &DetectorConfig) -> Vec<BaseFeature> {
    let (w, h) = (rgb.width() as usize, rgb.height() as usize);
    let centre = (w as f32 - 1.0) * 0.5;
    let mask_rgb = RgbImage::from_fn(mask.width(), mask.height(), |x, y| {
        let v = mask.get_pixel(x, y)[0];
        image::Rgb([v, v, v])
    });
    let outline = colour_gradients(&mask_rgb);
    let colour = colour_gradients(rgb);
    let peak = outline.magnitude.iter().copied().fold(0.0f32, f32::max);
    let fg = |x: usize, y: usize| mask.get_pixel(x as u32, y as u32)[0] > 0;
    let (mut contour, mut interior) = (Vec::new(), Vec::new());
    for y in 1..h.saturating_sub(1) {
        for x in 1..w.saturating_sub(1) {
            let i = y * w + x;
            let f = BaseFeature { x: x as f32 - centre, y: y as f32 - centre, angle: 0.0 };
            // The outline: object pixels next to background, with the mask's own gradient
            // (the rendered colours there meet black, which no photo shows).
            if fg(x, y) && outline.magnitude[i] >= 0.25 * peak {
                contour.push((outline.magnitude[i], BaseFeature { angle: outline.angle[i], ..f }));
            } else if fg(x, y) && outline.magnitude[i] == 0.0 && colour.magnitude[i] >= config.min_magnitude * 1.5 {
                interior.push((colour.magnitude[i], BaseFeature { angle: colour.angle[i], ..f }));
            }
        }
    }
    let n = config.features;
    let mut picked = scattered(&contour, n.div_ceil(2), config.canonical_px as f32 / 6.0);
    let rest = n - picked.len();
    picked.extend(scattered(&interior, rest, config.canonical_px as f32 / 8.0));
    if picked.len() < n {
        // Too little texture: more of the outline instead.
        let more = scattered(&contour, n, 1.0);
        for f in more {
            if picked.len() == n {
                break;
            }
            if !picked.iter().any(|p| p.x == f.x && p.y == f.y) {
                picked.push(f);
            }
        }
    }
    picked
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

/// The view's features and silhouette box after an in-plane turn by `angle` about the
/// centre (the image turns with the camera's roll, exactly: the centre is on the axis).
fn turned(base: &[BaseFeature], mask: &GrayImage, angle: f64) -> (Vec<Feature>, [i8; 4]) {
    let (s, c) = (angle.sin() as f32, angle.cos() as f32);
    let rot = |x: f32, y: f32| (c * x - s * y, s * x + c * y);
    let n = base.len().max(1);
    // A view with fewer candidates than asked repeats its features (same score share).
    let features = (0..n)
        .filter_map(|i| base.get(i % base.len().max(1)))
        .map(|f| {
            let (x, y) = rot(f.x, f.y);
            Feature { dx: x.round().clamp(-127.0, 127.0) as i8, dy: y.round().clamp(-127.0, 127.0) as i8, orientation: bin_of(f.angle + angle as f32) as i8 }
        })
        .collect();
    let centre = (mask.width() as f32 - 1.0) * 0.5;
    let (mut lo, mut hi) = ((f32::MAX, f32::MAX), (f32::MIN, f32::MIN));
    for (x, y, p) in mask.enumerate_pixels() {
        if p[0] > 0 {
            for (cx, cy) in [(-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5)] {
                let (u, v) = rot(x as f32 - centre + cx, y as f32 - centre + cy);
                lo = (lo.0.min(u), lo.1.min(v));
                hi = (hi.0.max(u), hi.1.max(v));
            }
        }
    }
    let b = if lo.0 > hi.0 { [0, 0, 0, 0] } else { [lo.0.floor(), lo.1.floor(), hi.0.ceil(), hi.1.ceil()].map(|v| v.clamp(-127.0, 127.0) as i8) };
    (features, b)
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
        let c: Vec<(f32, BaseFeature)> = (0..100).map(|i| (i as f32, BaseFeature { x: (i % 10) as f32, y: (i / 10) as f32, angle: 0.0 })).collect();
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
    fn a_quarter_turn_turns_offsets_and_orientations() {
        let mask = GrayImage::from_fn(11, 11, |x, y| image::Luma([if (3..8).contains(&x) && (4..7).contains(&y) { 255 } else { 0 }]));
        let base = [BaseFeature { x: 2.0, y: 0.0, angle: 0.0 }];
        let (f, b) = turned(&base, &mask, std::f64::consts::FRAC_PI_2);
        // (2, 0) turns to (0, 2); a horizontal gradient becomes a vertical one (bin 4).
        assert_eq!(f[0], Feature { dx: 0, dy: 2, orientation: 4 });
        // The 5 × 3 box turns into a 3 × 5 one.
        assert_eq!(b, [-2, -3, 2, 3]);
    }
}
