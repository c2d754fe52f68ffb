//! The sparse viewpoint model of the region-based trackers (SRT3D / ICG by Stoiber et al.):
//! for many viewpoints on an icosphere, a sample of silhouette contour points stored in the
//! object frame with their outward contour normals and how far the object (inwards) and the
//! background (outwards) continue along each normal. At run time the contour refiner picks
//! the nearest view and projects its points: no rendering inside the refinement loop.

use super::point_grid::{i16_to_unit, unit_to_i16, PointGrid};
use super::template_camera::base_intrinsics;
use crate::features::grey;
use crate::geometry::views::{fitted_distance, icosphere, view_pose};
use crate::geometry::{Intrinsics, Pose};
use crate::mesh::Mesh;
use crate::render::{RenderError, RenderOptions, RenderOutput, RenderPool};
use nalgebra::Vector3;
use rayon::prelude::*;

/// How a contour model is sampled; stored with it.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ContourConfig {
    /// Icosphere level of the viewpoints (3: 642 views, about 8° apart).
    pub level: u32,
    /// Side of the square silhouette renders, pixels.
    pub render_size: u32,
    /// Contour points kept per view.
    pub points_per_view: usize,
}

impl Default for ContourConfig {
    fn default() -> Self {
        Self { level: 3, render_size: 320, points_per_view: 200 }
    }
}

impl ContourConfig {
    pub fn validate(&self) -> Result<(), String> {
        if self.level > 4 {
            return Err(format!("contour icosphere level must be 0–4, got {}", self.level));
        }
        if !(64..=2048).contains(&self.render_size) {
            return Err(format!("contour render size must be 64–2048 px, got {}", self.render_size));
        }
        if !(8..=2000).contains(&self.points_per_view) {
            return Err(format!("contour points per view must be 8–2000, got {}", self.points_per_view));
        }
        Ok(())
    }
}

/// Contour points of every view, `views × points_per_view` rows in view order.
#[derive(Clone, Debug, PartialEq)]
pub struct ContourModel {
    pub config: ContourConfig,
    /// Unit direction from the object centre towards the camera, object frame, per view.
    pub directions: Vec<[f32; 3]>,
    /// Object-frame point on the silhouette rim (metres).
    pub points: Vec<[f32; 3]>,
    /// Object-frame unit vector along the image-plane contour normal, pointing out of the
    /// silhouette.
    pub normals: Vec<[f32; 3]>,
    /// Metres the silhouette continues inwards (against the normal) before background.
    pub foreground_m: Vec<f32>,
    /// Metres of background outwards (along the normal) before the object again, capped at
    /// the render's extent.
    pub background_m: Vec<f32>,
    /// For objects with colours of their own: how far inwards from the rim the surface's
    /// colour stays plain (no print edge), in 255ths of `foreground_m`. Where it is short, an
    /// edge the photo shows just inside the outline may be the print's, not the outline's
    /// (`estimate::contour::photo_edge`). Empty for objects without colours (nothing is
    /// printed on them) and for objects stored before it was kept (unknown).
    pub plain_share: Vec<u8>,
}

/// One contour point of one view, before it joins the model's arrays.
#[derive(Clone, Copy)]
struct RimPoint {
    point: [f32; 3],
    normal: [f32; 3],
    foreground_m: f32,
    background_m: f32,
    plain_share: u8,
}

/// Largest grey-level difference (0–255) from the rim's own colour that still counts as the
/// same plain surface. Scanned textures darken towards the rim (their lighting is baked
/// in), so the photo-edge finder's least clear edge (12) ended most runs within a pixel or
/// two and left 13 % of the HOPE objects' lines on the photo's edges; at 30 the pipeline on
/// those objects from boxes did best (docs/benchmarks/estimation-outlines.md, "Outlines
/// from the photo's edges"). A smooth darkening that remains is the edge finder's to refuse
/// (a run lopsided about its centroid).
const PLAIN_TOLERANCE: f32 = 30.0;

/// Views rendered at once (bounds memory: renders are small, but keep batches modest).
const VIEW_CHUNK: usize = 32;

impl ContourModel {
    pub fn view_count(&self) -> usize {
        self.directions.len()
    }

    /// Rows of view `v`.
    pub fn view_range(&self, v: usize) -> std::ops::Range<usize> {
        let p = self.config.points_per_view;
        v * p..(v + 1) * p
    }

    /// The view whose direction is closest to `dir` (object frame, centre → camera).
    pub fn nearest_view(&self, dir: &Vector3<f64>) -> usize {
        let d = dir.normalize();
        let dot = |v: &[f32; 3]| v[0] as f64 * d.x + v[1] as f64 * d.y + v[2] as f64 * d.z;
        (0..self.directions.len()).max_by(|&a, &b| dot(&self.directions[a]).total_cmp(&dot(&self.directions[b]))).unwrap_or(0)
    }

    /// Heap bytes of the arrays.
    pub fn memory_bytes(&self) -> usize {
        self.directions.len() * 12 + self.points.len() * 12 + self.normals.len() * 12 + self.foreground_m.len() * 4 + self.background_m.len() * 4 + self.plain_share.len()
    }

    /// Metres the surface's colour stays plain inwards from row `i`'s rim point; `None`
    /// where that is not known (no colours, or an object stored before it was kept).
    pub fn plain_m(&self, i: usize) -> Option<f32> {
        self.plain_share.get(i).map(|&s| self.foreground_m[i] * s as f32 / 255.0)
    }

    /// Checks the arrays agree with the configuration (used after loading).
    pub fn validate(&self) -> Result<(), String> {
        self.config.validate()?;
        let rows = self.directions.len() * self.config.points_per_view;
        if self.directions.is_empty() {
            return Err("contour model has no views".into());
        }
        if [self.points.len(), self.normals.len(), self.foreground_m.len(), self.background_m.len()].iter().any(|&n| n != rows) || !(self.plain_share.is_empty() || self.plain_share.len() == rows) {
            return Err(format!("contour arrays do not match {} views × {} points", self.directions.len(), self.config.points_per_view));
        }
        let finite = |v: &[f32]| v.iter().all(|x| x.is_finite());
        if !finite(bytemuck::cast_slice(&self.points)) || !finite(bytemuck::cast_slice(&self.normals)) || !finite(&self.foreground_m) || !finite(&self.background_m) {
            return Err("contour model holds non-finite values".into());
        }
        Ok(())
    }

    /// Renders the silhouette of `mesh` from every viewpoint and samples its contour (and,
    /// for a mesh with colours, how far its print stays plain inside the rim).
    pub fn build(mesh: &Mesh, renderer: &RenderPool, config: &ContourConfig) -> Result<ContourModel, RenderError> {
        config.validate().map_err(RenderError::InvalidOptions)?;
        // A long focal length puts the camera about ten radii away, where real cameras
        // usually are: the rim (which surface points form the outline) depends on the
        // camera's distance, and a wide-angle close-up would see a different one.
        let k = Intrinsics { fx: 4.0 * config.render_size as f64, fy: 4.0 * config.render_size as f64, ..base_intrinsics(config.render_size) };
        let (centre, radius) = (Vector3::from(mesh.bbox_center()), mesh.bounding_radius().max(1e-6));
        let distance = fitted_distance(radius, k.fx, config.render_size as f64 * 0.5, 0.85);
        let dirs = icosphere(config.level);
        // A silhouette needs no appearance (the grey render skips texture lookups); the plain
        // runs of a coloured mesh need its own colours, unlit, so that only the print (not
        // the renderer's shading) ends a run.
        let coloured = mesh.has_colours();
        let opts = if coloured { RenderOptions { light_intensity: 0.0, ambient: 1.0, ..RenderOptions::default() } } else { RenderOptions::grey() };
        let mut model = ContourModel { config: *config, directions: vec![], points: vec![], normals: vec![], foreground_m: vec![], background_m: vec![], plain_share: vec![] };
        for chunk in dirs.chunks(VIEW_CHUNK) {
            let views: Vec<(Pose, Intrinsics)> = chunk.iter().map(|d| (view_pose(d, 0.0, &centre, distance), k)).collect();
            let renders = renderer.render_batch(mesh, &views, &opts)?;
            let rims: Vec<Vec<RimPoint>> = renders.par_iter().zip(views.par_iter()).map(|(r, (pose, k))| rim_points(r, pose, k, config.points_per_view)).collect();
            for (d, rim) in chunk.iter().zip(rims) {
                // A view that shows nothing (degenerate mesh) contributes no rows; keeping the
                // per-view stride fixed means skipping the view entirely.
                if rim.len() != config.points_per_view {
                    continue;
                }
                model.directions.push([d.x as f32, d.y as f32, d.z as f32]);
                for p in rim {
                    model.points.push(p.point);
                    model.normals.push(p.normal);
                    model.foreground_m.push(p.foreground_m);
                    model.background_m.push(p.background_m);
                    if coloured {
                        model.plain_share.push(p.plain_share);
                    }
                }
            }
        }
        if model.directions.is_empty() {
            return Err(RenderError::InvalidOptions("no view of the mesh has a silhouette contour (is the mesh degenerate?)".into()));
        }
        // Kept as they will be stored, so a loaded object refines as the onboarded one did.
        let grid = Self::storage_grid(mesh);
        model.points.iter_mut().for_each(|p| *p = grid.snap(*p));
        model.normals.iter_mut().for_each(|n| *n = i16_to_unit(unit_to_i16(*n)));
        Ok(model)
    }

    /// The grid the contour points are stored on (format 7): the mesh's bounding box with a
    /// margin for rim samples a little outside it (a render's depth is not exact), made
    /// again from the stored mesh when loading.
    pub fn storage_grid(mesh: &Mesh) -> PointGrid {
        let (lo, hi) = mesh.bbox();
        PointGrid::around_box(lo, hi, 0.05)
    }
}

/// Outward unit normal of the silhouette at contour pixel (x, y): away from the centroid of
/// the object pixels in a small disc (robust on staircase edges, unlike a 2-pixel gradient).
fn contour_normal(mask: &image::GrayImage, x: i64, y: i64) -> Option<(f64, f64)> {
    const R: i64 = 3;
    let (w, h) = (mask.width() as i64, mask.height() as i64);
    let (mut sx, mut sy) = (0.0, 0.0);
    for dy in -R..=R {
        for dx in -R..=R {
            if dx * dx + dy * dy > R * R {
                continue;
            }
            let (px, py) = (x + dx, y + dy);
            let fg = px >= 0 && py >= 0 && px < w && py < h && mask.get_pixel(px as u32, py as u32)[0] > 0;
            if fg {
                sx += dx as f64;
                sy += dy as f64;
            }
        }
    }
    let n = (sx * sx + sy * sy).sqrt();
    // A balanced disc (a one-pixel-thin sliver) has no defined side.
    if n < 1.0 {
        None
    } else {
        Some((-sx / n, -sy / n))
    }
}

/// Pixels walked from (x, y) along (nx, ny) while the mask equals `inside`.
fn run_length(mask: &image::GrayImage, x: f64, y: f64, nx: f64, ny: f64, inside: bool) -> f64 {
    walk(mask.width(), mask.height(), x, y, nx, ny, |px, py| (mask.get_pixel(px, py)[0] > 0) == inside)
}

/// Pixels walked from (x, y) along (nx, ny), one pixel a step, while `go` holds for the
/// pixel reached and it lies inside a `w` × `h` image.
fn walk(w: u32, h: u32, x: f64, y: f64, nx: f64, ny: f64, go: impl Fn(u32, u32) -> bool) -> f64 {
    let mut s = 1.0;
    loop {
        let (px, py) = ((x + nx * s).round(), (y + ny * s).round());
        if px < 0.0 || py < 0.0 || px >= w as f64 || py >= h as f64 || !go(px as u32, py as u32) {
            return s;
        }
        s += 1.0;
    }
}

/// Share (255ths) of the object's run inwards from rim pixel (x, y) over which the render's
/// colour stays within `PLAIN_TOLERANCE` of the rim's own.
fn plain_share(r: &RenderOutput, x: i64, y: i64, nx: f64, ny: f64, object_run: f64) -> u8 {
    let rim = grey(r.rgb.get_pixel(x as u32, y as u32));
    let plain = walk(r.rgb.width(), r.rgb.height(), x as f64, y as f64, -nx, -ny, |px, py| r.mask.get_pixel(px, py)[0] > 0 && (grey(r.rgb.get_pixel(px, py)) - rim).abs() <= PLAIN_TOLERANCE);
    (255.0 * (plain / object_run).min(1.0)).round() as u8
}

/// `count` contour points of one silhouette render, evenly spread over its contour pixels;
/// empty when the render shows fewer usable contour pixels than that.
fn rim_points(r: &RenderOutput, pose: &Pose, k: &Intrinsics, count: usize) -> Vec<RimPoint> {
    let mask = &r.mask;
    let (w, h) = (mask.width() as i64, mask.height() as i64);
    let fg = |x: i64, y: i64| x >= 0 && y >= 0 && x < w && y < h && mask.get_pixel(x as u32, y as u32)[0] > 0;
    let mut rim = Vec::new();
    for y in 0..h {
        for x in 0..w {
            if fg(x, y) && (!fg(x - 1, y) || !fg(x + 1, y) || !fg(x, y - 1) || !fg(x, y + 1)) {
                rim.push((x, y));
            }
        }
    }
    let inv = pose.inverse();
    let mut out = Vec::with_capacity(count);
    // Raster order with an even stride keeps the sample proportional to contour length
    // everywhere; an unusable pixel (no defined normal) gives way to the next one.
    let stride = rim.len() as f64 / count as f64;
    for s in 0..count {
        let (first, end) = ((s as f64 * stride) as usize, (((s + 1) as f64 * stride) as usize).min(rim.len()));
        if let Some(p) = (first..end).find_map(|j| rim_point(r, &inv, k, rim[j])) {
            out.push(p);
        }
    }
    // A few ranges without a usable pixel: repeat earlier points so every view keeps the
    // fixed stride (a repeat only weighs its line twice). Mostly unusable: drop the view.
    if out.len() * 2 < count {
        return Vec::new();
    }
    let have = out.len();
    for i in 0..count.saturating_sub(have) {
        let p = &out[i % have];
        out.push(*p);
    }
    out
}

/// The rim point at contour pixel (x, y) of render `r` (camera → object by `inv`).
fn rim_point(r: &RenderOutput, inv: &Pose, k: &Intrinsics, (x, y): (i64, i64)) -> Option<RimPoint> {
    let mask = &r.mask;
    let (nx, ny) = contour_normal(mask, x, y)?;
    let z = r.depth_at(x as u32, y as u32) as f64;
    if z <= 0.0 {
        return None;
    }
    // The rim lies on the pixel's outer edge, half a pixel out along the normal.
    let (u, v) = (x as f64 + 0.5 * nx, y as f64 + 0.5 * ny);
    let p = inv.transform_point(&k.back_project(u, v, z));
    let n = inv.rotation * Vector3::new(nx, ny, 0.0);
    let px_to_m = z / k.fx;
    let object_run = run_length(mask, x as f64, y as f64, -nx, -ny, true);
    Some(RimPoint {
        point: [p.x as f32, p.y as f32, p.z as f32],
        normal: [n.x as f32, n.y as f32, n.z as f32],
        foreground_m: (object_run * px_to_m) as f32,
        background_m: (run_length(mask, x as f64, y as f64, nx, ny, false) * px_to_m) as f32,
        plain_share: plain_share(r, x, y, nx, ny, object_run),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::RgbImage;

    #[test]
    fn normal_points_out_of_a_disc() {
        let mut m = image::GrayImage::new(64, 64);
        for y in 0..64 {
            for x in 0..64 {
                if (x as f64 - 32.0).powi(2) + (y as f64 - 32.0).powi(2) < 20.0f64.powi(2) {
                    m.put_pixel(x, y, image::Luma([255]));
                }
            }
        }
        // Right edge of the disc: the normal points right; top edge: up (−y).
        let (nx, ny) = contour_normal(&m, 51, 32).unwrap();
        assert!(nx > 0.95 && ny.abs() < 0.2, "{nx} {ny}");
        let (nx, ny) = contour_normal(&m, 32, 13).unwrap();
        assert!(ny < -0.95 && nx.abs() < 0.2, "{nx} {ny}");
        // Across the disc from the right edge: about 39 px of object, then background to the border.
        assert!((run_length(&m, 51.0, 32.0, -1.0, 0.0, true) - 39.0).abs() <= 1.0);
        assert_eq!(run_length(&m, 51.0, 32.0, 1.0, 0.0, false), 13.0);
    }

    #[test]
    fn plain_runs_end_at_the_first_print_edge() {
        // A 30 px square of plain grey with a dark stripe 4 px in from its left side, and a
        // slow shading drift (under the tolerance) towards its right side.
        let (w, h) = (40u32, 40u32);
        let inside = |x: u32, y: u32| (5..35).contains(&x) && (5..35).contains(&y);
        let rgb = RgbImage::from_fn(w, h, |x, y| match (inside(x, y), x) {
            (false, _) => image::Rgb([0, 0, 0]),
            (true, 9) => image::Rgb([40, 40, 40]),
            (true, x) => image::Rgb([(150 - (x.saturating_sub(20) / 2)) as u8; 3]),
        });
        let mask = image::GrayImage::from_fn(w, h, |x, y| image::Luma([if inside(x, y) { 255 } else { 0 }]));
        let r = RenderOutput { rgb, depth: vec![], mask };
        // From the left rim (x = 5) inwards: x = 5..8 plain, the stripe at x = 9 ends it:
        // 4 of the 30 pixels across.
        assert_eq!(plain_share(&r, 5, 20, -1.0, 0.0, 30.0), (255.0 * 4.0 / 30.0_f64).round() as u8);
        // From the right rim (x = 34): the drift of 7 levels never ends it, and the stripe
        // does at x = 9, 25 pixels in.
        assert_eq!(plain_share(&r, 34, 20, 1.0, 0.0, 30.0), (255.0 * 25.0 / 30.0_f64).round() as u8);
        // From the top rim down a column clear of the stripe: plain all the way across.
        assert_eq!(plain_share(&r, 20, 5, 0.0, -1.0, 30.0), 255);
    }

    #[test]
    fn config_bounds() {
        assert!(ContourConfig::default().validate().is_ok());
        assert!(ContourConfig { level: 5, ..Default::default() }.validate().is_err());
        assert!(ContourConfig { points_per_view: 2, ..Default::default() }.validate().is_err());
    }
}
