//! The texture term of the tracker: points on the object's surface with the grey level the
//! frame showed there at the last relearning, and a Gauss–Newton alignment of the pose that
//! makes the current frame show the same grey levels at those points. The outline alone
//! cannot see a turn that keeps it (a can about its axis, a box seen along one of its
//! axes), which the contour step then misses at every frame; the texture sees it.
//!
//! A keyframe's own intensities rather than the mesh's texture: the frame and the keyframe
//! come from the same camera under the same light, a render does not. The alignment runs
//! after the contour step on a blurred frame (a wider basin), with a prior that holds the
//! translation the outline measured, and is kept only when it lowers the residual.
//! Measured on generated HOPE sequences: docs/tracking.md.

use super::colour::Window;
use crate::estimate::contour::lines::projection_jacobian;
use crate::estimate::contour::solve::apply_update;
use crate::geometry::{Intrinsics, Pose};
use crate::render::RenderOutput;
use image::RgbImage;
use nalgebra::{Matrix6, Point3, Vector2, Vector3, Vector6};

#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct PhotometricConfig {
    pub enabled: bool,
    /// Surface points kept at each relearning (those with the strongest texture).
    pub points: usize,
    /// Gaussian blur of the grey frame before alignment, pixels.
    pub blur_sigma: f64,
    pub iterations: usize,
    /// Weight of the prior that holds the contour step's translation, relative to the
    /// points' own information about a shift.
    pub translation_prior: f64,
}

impl Default for PhotometricConfig {
    fn default() -> Self {
        Self { enabled: true, points: 400, blur_sigma: 1.5, iterations: 4, translation_prior: 4.0 }
    }
}

struct Sample {
    /// Object frame.
    point: Point3<f64>,
    normal: Vector3<f64>,
    grey: f32,
}

/// A blurred grey copy of the window of a frame, with bilinear lookups of value and
/// gradient in whole-frame pixel coordinates.
struct GreyWindow {
    window: Window,
    w: usize,
    h: usize,
    values: Vec<f32>,
}

impl GreyWindow {
    fn new(image: &RgbImage, window: Window, sigma: f64) -> Self {
        let (w, h) = window.size();
        let (w, h) = (w as usize, h as usize);
        let mut values = Vec::with_capacity(w * h);
        for (_, colours) in window.colour_rows(image) {
            values.extend(colours.map(|c| crate::features::grey(&c)));
        }
        if sigma > 0.0 {
            values = blur_grey(&values, w, h, sigma);
        }
        Self { window, w, h, values }
    }

    /// Value and gradient at whole-frame (u, v), None within a pixel of the window's edge.
    fn sample(&self, uv: &Vector2<f64>) -> Option<(f64, Vector2<f64>)> {
        let (x, y) = (uv.x - self.window.x0 as f64, uv.y - self.window.y0 as f64);
        if x < 1.0 || y < 1.0 || x >= self.w as f64 - 2.0 || y >= self.h as f64 - 2.0 {
            return None;
        }
        let at = |x: f64, y: f64| {
            let (x0, y0) = (x.floor() as usize, y.floor() as usize);
            let (fx, fy) = (x - x0 as f64, y - y0 as f64);
            let v = |xx: usize, yy: usize| self.values[yy * self.w + xx] as f64;
            (1.0 - fy) * ((1.0 - fx) * v(x0, y0) + fx * v(x0 + 1, y0)) + fy * ((1.0 - fx) * v(x0, y0 + 1) + fx * v(x0 + 1, y0 + 1))
        };
        let g = Vector2::new(at(x + 0.5, y) - at(x - 0.5, y), at(x, y + 0.5) - at(x, y - 0.5));
        Some((at(x, y), g))
    }
}

#[derive(Default)]
pub struct PhotometricModel {
    samples: Vec<Sample>,
}

impl PhotometricModel {
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// Takes new points from `render` (the object at `pose` through `window` alone, with
    /// the window's intrinsics `wk`) and the frame `image` it was checked against: pixels
    /// well inside the silhouette with the strongest grey gradients, back-projected with the
    /// render's depth.
    pub fn learn(&mut self, image: &RgbImage, render: &RenderOutput, window: Window, wk: &Intrinsics, pose: &Pose, config: &PhotometricConfig) {
        // Blurred over the silhouette's part of the window (with the room `align` leaves,
        // so every point reads what the whole window's blur gives): the window is some
        // three object radii a side, and its blur was most of a relearning's time.
        let room = 2 + blur_radius(config.blur_sigma) as u32;
        let Some(region) = drawn_region(render, window, room) else {
            self.samples.clear();
            return;
        };
        self.learn_in(&GreyWindow::new(image, region, config.blur_sigma), render, window, wk, pose, config);
    }

    /// `learn` with the blurred frame `grey` (the window's, or a part of it that holds
    /// every point the render can give).
    fn learn_in(&mut self, grey: &GreyWindow, render: &RenderOutput, window: Window, wk: &Intrinsics, pose: &Pose, config: &PhotometricConfig) {
        let (w, h) = (render.width() as usize, render.height() as usize);
        let depth = |x: usize, y: usize| render.depth[y * w + x] as f64;
        let back = |x: usize, y: usize| {
            let z = depth(x, y);
            Point3::new((x as f64 - wk.cx) / wk.fx * z, (y as f64 - wk.cy) / wk.fy * z, z)
        };
        let inverse = pose.inverse();
        let mut candidates = Vec::new();
        const MARGIN: usize = 3;
        for y in (MARGIN..h.saturating_sub(MARGIN)).step_by(2) {
            for x in (MARGIN..w.saturating_sub(MARGIN)).step_by(2) {
                // Well inside: no depth edge in the neighbourhood (the outline and creases
                // between parts at other depths move differently from the surface).
                let z = depth(x, y);
                if z <= 0.0 || [(x - MARGIN, y), (x + MARGIN, y), (x, y - MARGIN), (x, y + MARGIN)].iter().any(|&(a, b)| (depth(a, b) - z).abs() > 0.05 * z || depth(a, b) <= 0.0) {
                    continue;
                }
                let Some((value, g)) = grey.sample(&Vector2::new((window.x0 as usize + x) as f64, (window.y0 as usize + y) as f64)) else { continue };
                let (p, right, down) = (back(x, y), back(x + 1, y), back(x, y + 1));
                let mut n = (right - p).cross(&(down - p));
                if n.norm() == 0.0 {
                    continue;
                }
                n.normalize_mut();
                if n.dot(&p.coords) > 0.0 {
                    n = -n;
                }
                candidates.push((g.norm(), Sample { point: inverse.transform_point(&p), normal: inverse.rotation * n, grey: value as f32 }));
            }
        }
        candidates.sort_by(|a, b| b.0.total_cmp(&a.0));
        candidates.truncate(config.points);
        // Flat regions carry no information about the pose.
        self.samples = candidates.into_iter().filter(|(g, _)| *g > 1.0).map(|(_, s)| s).collect();
    }

    /// The pose near `start` at which `image` shows the learnt grey levels at the points
    /// facing the camera; `start` itself when the points do not constrain it or the
    /// alignment does not lower their residual.
    pub fn align(&self, image: &RgbImage, window: Window, k: &Intrinsics, start: &Pose, config: &PhotometricConfig) -> Pose {
        if self.samples.len() < 20 {
            return *start;
        }
        // Blurred over the part of the window the points read (`region`) rather than all
        // of it: the points lie inside the silhouette, and the whole window's blur was paid
        // for pixels no point reads.
        let room = 2.0 + blur_radius(config.blur_sigma) as f64;
        let Some(region) = self.region(window, k, start, REACH_PX + room) else { return *start };
        let mut grey = GreyWindow::new(image, region, config.blur_sigma);
        let mut pose = *start;
        let Some(mut cost) = self.cost(&grey, k, &pose) else { return *start };
        for _ in 0..config.iterations {
            let Some(step) = self.step(&grey, k, &pose, start, config) else { break };
            let next = apply_update(&pose, &step.0, &step.1);
            // A step that carried points past the reach left for it: blurred again over
            // both, so that every point reads what a blur of the whole window gives.
            if let Some(needed) = self.region(window, k, &next, room) {
                if !grey.window.contains(&needed) {
                    grey = GreyWindow::new(image, grey.window.union(&needed), config.blur_sigma);
                }
            }
            match self.cost(&grey, k, &next) {
                Some(c) if c < cost => (pose, cost) = (next, c),
                _ => break,
            }
        }
        pose
    }

    /// The part of `window` within `pad` pixels of the points' projections at `pose`
    /// (those that project); None when none does.
    fn region(&self, window: Window, k: &Intrinsics, pose: &Pose, pad: f64) -> Option<Window> {
        let (mut lo, mut hi) = (Vector2::repeat(f64::INFINITY), Vector2::repeat(f64::NEG_INFINITY));
        for uv in self.samples.iter().filter_map(|s| k.project(&pose.transform_point(&s.point))) {
            lo = lo.inf(&uv);
            hi = hi.sup(&uv);
        }
        if lo.x > hi.x {
            return None;
        }
        let clip = |a: f64, min: u32, max: u32| a.clamp(min as f64, max as f64) as u32;
        let region = Window {
            x0: clip((lo.x - pad).floor(), window.x0, window.x1),
            y0: clip((lo.y - pad).floor(), window.y0, window.y1),
            x1: clip((hi.x + pad).ceil(), window.x0, window.x1),
            y1: clip((hi.y + pad).ceil(), window.y0, window.y1),
        };
        (region.x1 > region.x0 && region.y1 > region.y0).then_some(region)
    }

    /// (camera-frame point, projection, learnt grey) of the samples facing the camera at
    /// `pose` and inside the window.
    fn visible<'a>(&'a self, grey: &'a GreyWindow, k: &'a Intrinsics, pose: &'a Pose) -> impl Iterator<Item = (&'a Sample, Point3<f64>, f64, Vector2<f64>)> + 'a {
        self.samples.iter().filter_map(move |s| {
            let p = pose.transform_point(&s.point);
            if p.z <= 0.0 || (pose.rotation * s.normal).dot(&p.coords) >= 0.0 {
                return None;
            }
            let uv = k.project(&p)?;
            let (value, g) = grey.sample(&uv)?;
            Some((s, p, value - s.grey as f64, g))
        })
    }

    /// Robust mean squared residual after removing the mean offset (a change of light).
    fn cost(&self, grey: &GreyWindow, k: &Intrinsics, pose: &Pose) -> Option<f64> {
        let r: Vec<f64> = self.visible(grey, k, pose).map(|v| v.2).collect();
        if r.len() < 20 {
            return None;
        }
        let mean = r.iter().sum::<f64>() / r.len() as f64;
        Some(r.iter().map(|x| huber((x - mean).abs(), HUBER_GREY)).sum::<f64>() / r.len() as f64)
    }

    fn step(&self, grey: &GreyWindow, k: &Intrinsics, pose: &Pose, start: &Pose, config: &PhotometricConfig) -> Option<(Vector3<f64>, Vector3<f64>)> {
        let rows: Vec<(Vector6<f64>, f64)> = self
            .visible(grey, k, pose)
            .map(|(s, p, r, g)| {
                // How the grey level at the point changes with an object-frame turn ω and
                // shift v (the pose becomes pose·(exp(ω), v)).
                let b: Vector3<f64> = pose.rotation.inverse() * (projection_jacobian(k, &p).transpose() * g);
                let c = -b.cross(&s.point.coords);
                (Vector6::new(c.x, c.y, c.z, b.x, b.y, b.z), r)
            })
            .collect();
        if rows.len() < 20 {
            return None;
        }
        let mean = rows.iter().map(|r| r.1).sum::<f64>() / rows.len() as f64;
        let (mut h, mut g) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros());
        for (j, r) in &rows {
            let r = r - mean;
            let w = huber_weight(r.abs(), HUBER_GREY);
            h += j * j.transpose() * w;
            g -= j * (w * r);
        }
        // Hold the translation the outline measured: a prior towards it with this many
        // times the points' own (mean) information about a shift.
        let prior = config.translation_prior * (h[(3, 3)] + h[(4, 4)] + h[(5, 5)]) / 3.0;
        let since = start.inverse().compose(pose);
        for i in 0..3 {
            h[(i + 3, i + 3)] += prior;
            g[i + 3] -= prior * since.translation[i];
        }
        let floor = 1e-9 * h.trace();
        for i in 0..6 {
            h[(i, i)] += floor;
        }
        let step = h.cholesky()?.solve(&g);
        let (omega, v) = (Vector3::new(step[0], step[1], step[2]), Vector3::new(step[3], step[4], step[5]));
        // A step of more than 10° is no small correction: the texture has matched
        // something else.
        (omega.norm() < 10f64.to_radians()).then_some((omega, v))
    }
}

/// Room left around the points' projections at the start for the texture term's steps to
/// carry them, px (a step that carries them further has the window blurred again).
const REACH_PX: f64 = 24.0;

/// The part of `window` within `pad` pixels of the pixels `render` (the window's size)
/// draws the object on (its mask, which is where its depth is); None when it draws none.
fn drawn_region(render: &RenderOutput, window: Window, pad: u32) -> Option<Window> {
    let (x0, y0, x1, y1) = crate::features::mask_bbox(&render.mask)?;
    Some(Window {
        x0: (window.x0 + x0).saturating_sub(pad).max(window.x0),
        y0: (window.y0 + y0).saturating_sub(pad).max(window.y0),
        x1: (window.x0 + x1 + 1 + pad).min(window.x1),
        y1: (window.y0 + y1 + 1 + pad).min(window.y1),
    })
}

/// The blur's kernel reaches this many pixels each side.
fn blur_radius(sigma: f64) -> isize {
    (3.0 * sigma).ceil() as isize
}

/// A separable Gaussian blur of a `w × h` grey grid, edges clamped.
///
/// Both passes add the kernel's taps one shifted row at a time (a row of the grid, or the
/// rows above and below for the vertical pass) rather than a pixel's taps one pixel at a
/// time: the vertical pass then reads rows, not columns `w` apart, and the inner loops
/// run over contiguous values the compiler can vectorise. Each value's taps are still added
/// in the kernel's order, so the sums are those of the pixel-at-a-time form to the bit.
fn blur_grey(values: &[f32], w: usize, h: usize, sigma: f64) -> Vec<f32> {
    let r = blur_radius(sigma);
    let kernel: Vec<f32> = (-r..=r).map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp() as f32).collect();
    let total: f32 = kernel.iter().sum();
    let kernel: Vec<f32> = kernel.iter().map(|k| k / total).collect();
    let mut rows = vec![0f32; values.len()];
    for (src, out) in values.chunks_exact(w).zip(rows.chunks_exact_mut(w)) {
        blur_row(src, out, &kernel);
    }
    let mut out = vec![0f32; values.len()];
    for (y, row) in out.chunks_exact_mut(w).enumerate() {
        for (j, k) in kernel.iter().enumerate() {
            let from = (y as isize + j as isize - r).clamp(0, h as isize - 1) as usize * w;
            for (o, v) in row.iter_mut().zip(&rows[from..from + w]) {
                *o += k * v;
            }
        }
    }
    out
}

/// One row of the horizontal pass into `out` (zeroed): the clamped sum where the kernel
/// reaches past an end, shifted rows added tap by tap in the bounds-free middle.
fn blur_row(src: &[f32], out: &mut [f32], kernel: &[f32]) {
    let (n, r) = (src.len(), kernel.len() / 2);
    let clamped = |i: usize| -> f32 { kernel.iter().enumerate().map(|(j, k)| k * src[(i + j).saturating_sub(r).min(n - 1)]).sum() };
    let ends = r.min(n);
    let middle = ends..n.saturating_sub(r).max(ends);
    for i in (0..ends).chain(middle.end..n) {
        out[i] = clamped(i);
    }
    if middle.is_empty() {
        return;
    }
    for (j, k) in kernel.iter().enumerate() {
        let shifted = &src[middle.start + j - r..middle.end + j - r];
        for (o, v) in out[middle.clone()].iter_mut().zip(shifted) {
            *o += k * v;
        }
    }
}

/// Grey levels beyond this residual count linearly (a highlight, an occluder).
const HUBER_GREY: f64 = 20.0;

fn huber(r: f64, c: f64) -> f64 {
    if r <= c {
        0.5 * r * r
    } else {
        c * (r - 0.5 * c)
    }
}

fn huber_weight(r: f64, c: f64) -> f64 {
    if r <= c {
        1.0
    } else {
        c / r
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What `align` relies on to blur only the points' region: a blurred window read at
    /// least `2 + blur_radius` pixels inside its edge (the room `align` leaves around the
    /// points, in the first region and in any union a step makes it blur again) gives what
    /// the whole frame's blur gives there.
    #[test]
    fn a_region_reads_as_the_whole_window_inside_its_room() {
        let image = RgbImage::from_fn(90, 70, |x, y| image::Rgb([((x * 37 + y * 11) % 251) as u8, ((x * y) % 253) as u8, ((x + 3 * y) % 255) as u8]));
        let sigma = 1.5;
        let whole = Window { x0: 0, y0: 0, x1: 90, y1: 70 };
        let room = 2 + blur_radius(sigma) as u32;
        let whole_grey = GreyWindow::new(&image, whole, sigma);
        let first = Window { x0: 20, y0: 15, x1: 50, y1: 40 };
        let moved = Window { x0: 35, y0: 25, x1: 70, y1: 55 };
        for region in [first, first.union(&moved)] {
            let grey = GreyWindow::new(&image, region, sigma);
            let mut read = 0;
            for y in (region.y0 + room)..(region.y1 - room) {
                for x in (region.x0 + room)..(region.x1 - room) {
                    let uv = Vector2::new(x as f64 + 0.3, y as f64 + 0.6);
                    let ((a, ga), (b, gb)) = (grey.sample(&uv).unwrap(), whole_grey.sample(&uv).unwrap());
                    assert!((a - b).abs() < 1e-3 && (ga - gb).norm() < 1e-3, "{region:?} at ({x}, {y}): {a} against {b}");
                    read += 1;
                }
            }
            assert!(read > 100);
        }
        // Nearer its edge than that, a region's clamped blur differs from the whole's.
        let grey = GreyWindow::new(&image, first, sigma);
        let edge = Vector2::new(first.x0 as f64 + 1.5, first.y0 as f64 + 10.0);
        assert!((grey.sample(&edge).unwrap().0 - whole_grey.sample(&edge).unwrap().0).abs() > 1e-2);
    }

    /// A relearning blurs only the silhouette's part of the window: the points it keeps
    /// are those a blur of the whole window gives, bit for bit, wherever in the window the
    /// object is drawn (its middle, against an edge); a window with nothing drawn keeps none.
    #[test]
    fn learning_from_the_silhouettes_part_keeps_the_whole_windows_points() {
        let image = RgbImage::from_fn(120, 90, |x, y| image::Rgb([((x * 37 + y * 11) % 251) as u8, ((x * y) % 253) as u8, ((x * x + 3 * y) % 255) as u8]));
        let window = Window { x0: 10, y0: 5, x1: 110, y1: 85 };
        let (w, h) = window.size();
        let wk = Intrinsics::new(200.0, 200.0, w as f64 / 2.0, h as f64 / 2.0, w, h).unwrap();
        let pose = Pose::new(nalgebra::Rotation3::from_euler_angles(0.2, -0.1, 0.3), Vector3::new(0.01, 0.0, 0.5));
        let config = PhotometricConfig::default();
        // A tilted plane drawn over a rectangle of the window.
        let drawn = |(x0, y0, x1, y1): (u32, u32, u32, u32)| {
            let inside = |x: u32, y: u32| (x0..x1).contains(&x) && (y0..y1).contains(&y);
            RenderOutput {
                rgb: RgbImage::new(w, h),
                depth: (0..w * h).map(|i| if inside(i % w, i / w) { 0.5 + 0.0004 * (i % w) as f32 - 0.0002 * (i / w) as f32 } else { 0.0 }).collect(),
                mask: image::GrayImage::from_fn(w, h, |x, y| image::Luma([if inside(x, y) { 255 } else { 0 }])),
            }
        };
        for rect in [(30, 20, 70, 60), (0, 0, 40, 50), (60, 40, 100, 80)] {
            let render = drawn(rect);
            let mut part = PhotometricModel::default();
            part.learn(&image, &render, window, &wk, &pose, &config);
            let mut whole = PhotometricModel::default();
            whole.learn_in(&GreyWindow::new(&image, window, config.blur_sigma), &render, window, &wk, &pose, &config);
            assert!(part.len() > 50, "{rect:?}: {} points", part.len());
            assert_eq!(part.len(), whole.len(), "{rect:?}");
            for (a, b) in part.samples.iter().zip(&whole.samples) {
                assert!(a.point == b.point && a.normal == b.normal && a.grey == b.grey, "{rect:?}");
            }
        }
        let mut none = PhotometricModel { samples: vec![Sample { point: Point3::origin(), normal: Vector3::z(), grey: 1.0 }] };
        none.learn(&image, &drawn((0, 0, 0, 0)), window, &wk, &pose, &config);
        assert!(none.is_empty());
    }

    #[test]
    fn blur_keeps_a_constant_and_spreads_a_spike() {
        assert!(blur_grey(&[7.0; 30], 6, 5, 1.5).iter().all(|v| (v - 7.0).abs() < 1e-4));
        let mut spike = vec![0f32; 81];
        spike[40] = 1.0;
        let b = blur_grey(&spike, 9, 9, 1.0);
        assert!((b.iter().sum::<f32>() - 1.0).abs() < 1e-4, "mass kept away from the edges");
        assert!(b[40] > b[41] && (b[41] - b[39]).abs() < 1e-6 && (b[41] - b[31]).abs() < 1e-6, "peaked and symmetric");
        // Every value is the clamped kernel sum, on grids narrower and wider than the kernel.
        for (w, h) in [(3, 4), (10, 11), (12, 30), (40, 9)] {
            let values: Vec<f32> = (0..w * h).map(|i| ((i * 7919) % 251) as f32).collect();
            let sigma = 1.5;
            let r = blur_radius(sigma);
            let g: Vec<f64> = (-r..=r).map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp()).collect();
            let total: f64 = g.iter().sum();
            let at = |x: isize, y: isize| values[y.clamp(0, h as isize - 1) as usize * w + x.clamp(0, w as isize - 1) as usize] as f64;
            let blurred = blur_grey(&values, w, h, sigma);
            for (y, x) in (0..h as isize).flat_map(|y| (0..w as isize).map(move |x| (y, x))) {
                let want: f64 = (-r..=r).map(|j| g[(j + r) as usize] * (-r..=r).map(|i| g[(i + r) as usize] * at(x + i, y + j)).sum::<f64>()).sum::<f64>() / (total * total);
                assert!((blurred[y as usize * w + x as usize] as f64 - want).abs() < 1e-3, "{w}×{h} at ({x}, {y})");
            }
        }
    }
}
