//! What a Kinect-class depth camera would measure of a rendered scene: the renderer's
//! exact depth made into a sensor's, so that generated benchmarks do not flatter RGB-D
//! estimation and tracking.
//!
//! The effects, each settable and each measured on real structured-light and
//! time-of-flight cameras:
//! - axial noise growing with distance, σ(z) = a + b·(z − c)² (Nguyen, Izadi and Lovell,
//!   3DIMPVT 2012, for the Kinect: 1.2 mm + 1.9 mm·(z/1 m − 0.4)²);
//! - lateral noise at depth edges (a pixel near an edge reads either side of it);
//! - shadows: the emitter sits a baseline beside the camera, so background points it
//!   cannot light from there, beside every near edge, are not measured;
//! - holes on grazing surfaces (turned nearly edge-on to the ray), on dark surfaces
//!   (too little light comes back) and a few anywhere (speckle);
//! - quantisation: disparity is measured in fractions of a pixel, so depth steps grow
//!   with z².

use crate::geometry::Intrinsics;
use crate::mesh::procedural::Rng;
use image::RgbImage;
use nalgebra::Vector3;

#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct SensorModel {
    /// Off: the exact depth as it is (for tests that compare depth with a render).
    pub enabled: bool,
    /// Axial noise σ(z) = `axial_mm[0]` + `axial_mm[1]`·(z/1 m − `axial_centre_m`)², mm.
    pub axial_mm: [f64; 2],
    pub axial_centre_m: f64,
    /// Standard deviation of where a pixel within a pixel of a depth edge reads, pixels.
    pub lateral_px: f64,
    /// Emitter beside the camera along +x, metres (0: no shadows). Kinect v1: 75 mm.
    pub baseline_m: f64,
    /// Surfaces turned more than this from facing the camera (degrees) are not measured.
    pub grazing_deg: f64,
    /// Pixels darker than this (0–255 luminance) are missing with `dark_dropout` chance.
    pub dark_below: u8,
    pub dark_dropout: f64,
    /// Chance that any pixel is missing.
    pub dropout: f64,
    /// Depth step at 1 m, millimetres (it scales with z²; Kinect v1: 1/8 pixel of
    /// disparity at f = 580 px and a 75 mm baseline is 2.9 mm). 0: no quantisation.
    pub step_mm_at_1m: f64,
}

impl Default for SensorModel {
    /// A Kinect v1-class structured-light camera.
    fn default() -> Self {
        Self { enabled: true, axial_mm: [1.2, 1.9], axial_centre_m: 0.4, lateral_px: 0.8, baseline_m: 0.075, grazing_deg: 80.0, dark_below: 20, dark_dropout: 0.5, dropout: 0.002, step_mm_at_1m: 2.9 }
    }
}

impl SensorModel {
    /// The renderer's depth unchanged.
    pub fn exact() -> Self {
        Self { enabled: false, ..Self::default() }
    }

    /// Axial standard deviation at depth `z` metres, metres.
    pub fn axial_sigma(&self, z: f64) -> f64 {
        (self.axial_mm[0] + self.axial_mm[1] * (z - self.axial_centre_m).powi(2)) / 1000.0
    }

    /// What the sensor measures of the `exact` depth (metres, row-major at `k`'s size,
    /// 0 = nothing there) of a scene whose colour image is `rgb` (for dark surfaces).
    /// `seed` makes the noise reproducible.
    pub fn measure(&self, exact: &[f32], rgb: Option<&RgbImage>, k: &Intrinsics, seed: u64) -> Vec<f32> {
        let (w, h) = (k.width as usize, k.height as usize);
        assert_eq!(exact.len(), w * h, "depth is the camera's size");
        if !self.enabled {
            return exact.to_vec();
        }
        let mut rng = Rng::new(seed);
        let missing = self.unmeasurable(exact, k);
        let edge = near_edges(exact, w, h);
        let mut out = vec![0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                if missing[i] {
                    continue;
                }
                let mut z = exact[i] as f64;
                if edge[i] && self.lateral_px > 0.0 {
                    let jitter = |rng: &mut Rng, c: usize, n: usize| (c as f64 + (self.lateral_px * rng.normal()).round()).clamp(0.0, n as f64 - 1.0) as usize;
                    let (sx, sy) = (jitter(&mut rng, x, w), jitter(&mut rng, y, h));
                    z = exact[sy * w + sx] as f64;
                }
                if z <= 0.0 {
                    continue;
                }
                z += self.axial_sigma(z) * rng.normal();
                if self.step_mm_at_1m > 0.0 {
                    // In inverse depth (disparity) the steps are even: dz = z²·step.
                    let step = self.step_mm_at_1m / 1000.0;
                    z = 1.0 / ((1.0 / z / step).round() * step);
                }
                let dark = rgb.is_some_and(|img| luminance(img.get_pixel(x as u32, y as u32)) < self.dark_below as f64);
                if (dark && rng.uniform() < self.dark_dropout) || rng.uniform() < self.dropout {
                    continue;
                }
                out[i] = z.max(0.0) as f32;
            }
        }
        out
    }

    /// Pixels the sensor cannot measure whatever the noise: grazing surfaces and the
    /// emitter's shadows.
    fn unmeasurable(&self, exact: &[f32], k: &Intrinsics) -> Vec<bool> {
        let (w, h) = (k.width as usize, k.height as usize);
        let mut missing = vec![false; w * h];
        let point = |x: usize, y: usize| -> Option<Vector3<f64>> {
            let z = exact[y * w + x] as f64;
            (z > 0.0).then(|| k.back_project(x as f64, y as f64, z).coords)
        };
        let cos_limit = self.grazing_deg.to_radians().cos();
        for y in 1..h.saturating_sub(1) {
            for x in 1..w.saturating_sub(1) {
                let Some(c) = point(x, y) else { continue };
                // Along each axis the neighbour nearer in depth: beside an edge it is the one
                // on the same surface, where a grazing surface is steep either way.
                let along = |a: Option<Vector3<f64>>, b: Option<Vector3<f64>>| match (a, b) {
                    (Some(a), Some(b)) if (a.z - c.z).abs() <= (b.z - c.z).abs() => Some(c - a),
                    (_, Some(b)) => Some(b - c),
                    (Some(a), None) => Some(c - a),
                    (None, None) => None,
                };
                let (Some(dx), Some(dy)) = (along(point(x - 1, y), point(x + 1, y)), along(point(x, y - 1), point(x, y + 1))) else { continue };
                let n = dx.cross(&dy);
                let facing = n.dot(&c).abs() / (n.norm() * c.norm()).max(1e-12);
                if facing < cos_limit {
                    missing[y * w + x] = true;
                }
            }
        }
        if self.baseline_m > 0.0 {
            for y in 0..h {
                shadow_row(&exact[y * w..(y + 1) * w], k.fx * self.baseline_m, &mut missing[y * w..(y + 1) * w]);
            }
        }
        missing
    }
}

/// Marks the points of one row the emitter cannot light. The emitter, `fb` = focal ×
/// baseline (pixel·metres) to the camera's +x, sees the point at column x and depth z at
/// its own column x − fb/z; a point is in shadow when a nearer surface takes that column.
/// Surfaces are splatted between neighbouring pixels so that no gap lets light through.
fn shadow_row(row: &[f32], fb: f64, missing: &mut [bool]) {
    let w = row.len();
    let column = |x: usize| x as f64 - fb / row[x] as f64;
    let lo = (0..w).filter(|&x| row[x] > 0.0).map(column).fold(f64::INFINITY, f64::min);
    if !lo.is_finite() {
        return;
    }
    let origin = lo.floor();
    let span = (w as f64 - origin).ceil() as usize + 2;
    let mut nearest = vec![f32::INFINITY; span];
    let mut splat = |a: f64, b: f64, z: f32| {
        let (a, b) = (a.min(b) - origin, a.max(b) - origin);
        let (first, last) = (a.round() as usize, (b.round() as usize).min(span - 1));
        for n in nearest.iter_mut().take(last + 1).skip(first) {
            *n = n.min(z);
        }
    };
    for x in 0..w {
        let z = row[x];
        if z <= 0.0 {
            continue;
        }
        let next = (x + 1 < w && row[x + 1] > 0.0 && (row[x + 1] - z).abs() < 0.02 * z).then(|| column(x + 1));
        splat(column(x), next.unwrap_or(column(x)), z);
    }
    for x in 0..w {
        let z = row[x];
        if z > 0.0 && nearest[(column(x) - origin).round() as usize] < z * 0.99 {
            missing[x] = true;
        }
    }
}

/// Pixels with a neighbour (8-connected) on another surface (depth differing by over 3 %).
fn near_edges(exact: &[f32], w: usize, h: usize) -> Vec<bool> {
    let mut edge = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            let z = exact[y * w + x];
            if z <= 0.0 {
                continue;
            }
            'around: for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                    if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                        continue;
                    }
                    let n = exact[ny as usize * w + nx as usize];
                    if n <= 0.0 || (n - z).abs() > 0.03 * z {
                        edge[y * w + x] = true;
                        break 'around;
                    }
                }
            }
        }
    }
    edge
}

fn luminance(p: &image::Rgb<u8>) -> f64 {
    0.299 * p[0] as f64 + 0.587 * p[1] as f64 + 0.114 * p[2] as f64
}

/// A flat background (a wall or table top behind the scene) filling the pixels where
/// `depth` has nothing: through the image centre at `distance` metres, tilted by `tilt`
/// (tangents of its slope along x and y; keep them small so it stays behind the scene).
pub fn fill_with_plane(depth: &mut [f32], k: &Intrinsics, distance: f64, tilt: (f64, f64)) {
    let w = k.width as usize;
    for (i, z) in depth.iter_mut().enumerate().filter(|(_, z)| **z <= 0.0) {
        let (u, v) = (((i % w) as f64 - k.cx) / k.fx, ((i / w) as f64 - k.cy) / k.fy);
        let denominator = 1.0 + tilt.0 * u + tilt.1 * v;
        if denominator > 0.2 {
            *z = (distance / denominator) as f32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> Intrinsics {
        Intrinsics::new(400.0, 400.0, 79.5, 59.5, 160, 120).unwrap()
    }

    /// A box 0.5 m away in front of a wall at 1 m.
    fn block_on_wall(k: &Intrinsics) -> Vec<f32> {
        let mut d = vec![0f32; (k.width * k.height) as usize];
        for y in 40..80 {
            for x in 60..100 {
                d[y * k.width as usize + x] = 0.5;
            }
        }
        fill_with_plane(&mut d, k, 1.0, (0.0, 0.0));
        d
    }

    #[test]
    fn exact_leaves_the_depth_alone() {
        let k = camera();
        let d = block_on_wall(&k);
        assert_eq!(SensorModel::exact().measure(&d, None, &k, 1), d);
    }

    #[test]
    fn noise_grows_with_distance_and_is_reproducible() {
        let k = camera();
        let sensor = SensorModel { dropout: 0.0, step_mm_at_1m: 0.0, ..SensorModel::default() };
        let d = block_on_wall(&k);
        let a = sensor.measure(&d, None, &k, 3);
        assert_eq!(a, sensor.measure(&d, None, &k, 3), "same seed, same noise");
        assert_ne!(a, sensor.measure(&d, None, &k, 4));
        let spread = |x0: usize, y0: usize, z: f32| {
            let e: Vec<f64> = (y0..y0 + 10).flat_map(|y| (x0..x0 + 10).map(move |x| (y, x))).map(|(y, x)| a[y * 160 + x]).filter(|&v| v > 0.0).map(|v| (v - z) as f64).collect();
            (e.iter().map(|v| v * v).sum::<f64>() / e.len() as f64).sqrt()
        };
        let (near, far) = (spread(70, 50, 0.5), spread(5, 5, 1.0));
        // σ(0.5 m) = 1.22 mm, σ(1 m) = 1.88 mm.
        assert!((near - 0.00122).abs() < 0.0004 && (far - 0.00188).abs() < 0.0005, "{near} {far}");
    }

    #[test]
    fn shadows_fall_beside_near_edges_and_grazing_surfaces_are_holes() {
        let k = camera();
        let sensor = SensorModel { lateral_px: 0.0, dropout: 0.0, ..SensorModel::default() };
        let d = block_on_wall(&k);
        let m = sensor.measure(&d, None, &k, 1);
        // The emitter 75 mm to +x casts the block's shadow on the wall left of it: fb (1/0.5
        // − 1/1) = 30 px wide, and none on the right.
        let row = 60 * 160;
        assert!((31..59).all(|x| m[row + x] == 0.0), "{:?}", &m[row + 25..row + 62]);
        assert!(m[row + 25] > 0.9 && m[row + 65] > 0.4 && m[row + 101] > 0.9 && m[row + 110] > 0.9);
        // A floor seen nearly edge-on: gone.
        let mut floor = vec![0f32; 160 * 120];
        fill_with_plane(&mut floor, &k, 1.0, (0.0, 60.0));
        let (seen, there) = (sensor.measure(&floor, None, &k, 1).iter().filter(|&&z| z > 0.0).count(), floor.iter().filter(|&&z| z > 0.0).count());
        assert!(there > 160 * 120 / 3 && seen < there / 10, "{seen} of {there} measured on a grazing floor");
    }

    #[test]
    fn dark_pixels_and_steps() {
        let k = camera();
        let d = vec![0.8f32; 160 * 120];
        let rgb = RgbImage::from_fn(160, 120, |x, _| if x < 80 { image::Rgb([5, 5, 5]) } else { image::Rgb([200, 200, 200]) });
        let sensor = SensorModel { dropout: 0.0, ..SensorModel::default() };
        let m = sensor.measure(&d, Some(&rgb), &k, 1);
        let holes = |x0: usize| (0..120).flat_map(|y| (x0..x0 + 80).map(move |x| y * 160 + x)).filter(|&i| m[i] == 0.0).count() as f64 / 9600.0;
        assert!((holes(0) - 0.5).abs() < 0.05 && holes(80) == 0.0, "{} {}", holes(0), holes(80));
        // Whole steps of inverse depth, 2.9 mm apart at 1 m (1.9 mm at 0.8 m).
        let steps = |z: f32| 1.0 / (z as f64 * 0.0029);
        assert!(m.iter().filter(|&&z| z > 0.0).all(|&z| (steps(z) - steps(z).round()).abs() < 1e-2), "quantised");
    }
}
