//! Finds a mesh's symmetries from its geometry and appearance, so that onboarding can store
//! them without the user writing a BOP `models_info.json`.
//!
//! A symmetry is a rotation about an axis through the surface's centroid (every symmetry
//! keeps the surface, so it keeps its centroid) that maps the surface onto itself *and* each
//! surface point onto one of the same colour: a textured box whose faces differ has none,
//! the same box untextured has three half-turns. The surface is sampled densely (area-
//! weighted, with the albedo at each sample); a candidate rotation passes when nearly every
//! rotated sample lands within a tolerance of some sample, of a similar colour.
//!
//! Candidate axes: the principal axes of the surface's spread, the dominant directions of
//! its face normals (a cube's spread has no principal axes; its faces do), and the sums and
//! differences of those (a cube's edge and corner axes). About each, turns of 2π/n for n up
//! to 12 are tried, and three unrelated angles for a continuous symmetry.

use super::types::Mesh;
use crate::geometry::symmetry::{ContinuousSymmetry, DiscreteSymmetry, ObjectSymmetries};
use crate::geometry::Pose;
use nalgebra::{Matrix3, Rotation3, Unit, Vector3};
use std::collections::HashMap;

/// How hard the finder looks and what it accepts.
#[derive(Clone, Debug)]
pub struct FinderConfig {
    /// Surface samples the rotated ones are compared with.
    pub samples: usize,
    /// Of those, how many are rotated per test.
    pub probes: usize,
    /// A rotated sample must land this close to a sample (fraction of the diameter).
    pub tolerance: f64,
    /// Share of rotated samples allowed to land nowhere (sampling gaps, small details).
    pub max_geometry_misses: f64,
    /// Albedo difference (RGB distance, 0–1 channels) above which two samples differ.
    pub colour_difference: f32,
    /// Share of rotated samples allowed to land on a different colour.
    pub max_colour_misses: f64,
    /// Highest order of a discrete rotation tried about one axis.
    pub max_order: u32,
}

impl Default for FinderConfig {
    fn default() -> Self {
        Self { samples: 30_000, probes: 2_000, tolerance: 0.01, max_geometry_misses: 0.03, colour_difference: 0.25, max_colour_misses: 0.15, max_order: 12 }
    }
}

/// Angles (radians) a continuous symmetry must pass: unrelated to each other and to 2π/n
/// for small n, so that no discrete symmetry passes all three.
const CONTINUOUS_TEST_ANGLES: [f64; 3] = [0.413, 1.379, 2.671];

/// The mesh's symmetries (translations and offsets in metres, about the surface centroid).
pub fn find_symmetries(mesh: &Mesh, config: &FinderConfig) -> ObjectSymmetries {
    let surface = Surface::sample(mesh, config.samples.max(100));
    let centre = surface.centroid();
    let tester = Tester::new(&surface, centre, mesh.diameter() * config.tolerance, config);
    let axes = candidate_axes(&surface, centre);

    let mut continuous: Vec<Vector3<f64>> = Vec::new();
    let mut generators: Vec<(Vector3<f64>, u32)> = Vec::new();
    for axis in &axes {
        if CONTINUOUS_TEST_ANGLES.iter().all(|&a| tester.passes(&rotation(axis, a))) {
            continuous.push(*axis);
        } else if let Some(n) = (2..=config.max_order).rev().find(|&n| tester.passes(&rotation(axis, std::f64::consts::TAU / n as f64))) {
            generators.push((*axis, n));
        }
    }
    let offset = [centre.x, centre.y, centre.z];
    let about_centre = |r: &Matrix3<f64>| DiscreteSymmetry { rotation: r.map(tidy), translation: (centre - r * centre).map(tidy) };
    if !continuous.is_empty() {
        // BOP's form: the free axis, plus one half-turn across it if there is one (a
        // cylinder's flip; a cup has none). Other discrete symmetries are turns about the axis.
        let axis = continuous[0];
        let flip = generators.iter().find(|(g, n)| n % 2 == 0 && g.dot(&axis).abs() < 0.05).map(|(g, _)| about_centre(&rotation(g, std::f64::consts::PI)));
        return ObjectSymmetries { discrete: flip.into_iter().collect(), continuous: continuous.iter().map(|a| ContinuousSymmetry { axis: [a.x, a.y, a.z], offset }).collect() };
    }
    let group = close_group(generators.iter().map(|(a, n)| rotation(a, std::f64::consts::TAU / *n as f64)).collect());
    ObjectSymmetries { discrete: group.iter().filter(|r| !is_identity(r)).filter(|r| tester.passes(r)).map(about_centre).collect(), continuous: Vec::new() }
}

/// The symmetries as transformations of the object frame (identity first), one per
/// discrete symmetry and `steps` per continuous axis: for tests and for comparing poses.
pub fn symmetry_poses(symmetries: &ObjectSymmetries, steps: usize) -> Vec<Pose> {
    let step = std::f64::consts::PI / steps.max(1) as f64;
    crate::geometry::symmetry::symmetry_transformations(&symmetries.discrete, &symmetries.continuous, step).unwrap_or_else(|_| vec![Pose::identity()])
}

/// Area-weighted samples of the surface with the albedo there.
struct Surface {
    points: Vec<Vector3<f64>>,
    colours: Vec<[f32; 3]>,
    /// Unit face normal and area of every triangle.
    faces: Vec<(Vector3<f64>, f64)>,
    face_centres: Vec<Vector3<f64>>,
}

impl Surface {
    fn sample(mesh: &Mesh, n: usize) -> Self {
        let pos = |i: u32| Vector3::from(mesh.positions()[i as usize].map(f64::from));
        let faces: Vec<(Vector3<f64>, f64)> = mesh
            .triangles()
            .iter()
            .map(|t| {
                let c = (pos(t[1]) - pos(t[0])).cross(&(pos(t[2]) - pos(t[0])));
                let area = 0.5 * c.norm();
                (if area > 0.0 { c / (2.0 * area) } else { Vector3::zeros() }, area)
            })
            .collect();
        let mut cumulative = Vec::with_capacity(faces.len());
        let mut total = 0.0;
        for (_, a) in &faces {
            total += a;
            cumulative.push(total);
        }
        let material_of = material_per_triangle(mesh);
        // Decoded once here, not per sample (a stored texture is held encoded); one that
        // cannot be decoded counts as untextured, as the renderer draws it.
        let textures: Vec<Option<std::sync::Arc<image::RgbaImage>>> = mesh.materials().iter().map(|m| m.texture.as_ref().and_then(|t| t.pixels().ok())).collect();
        let mut rng = super::procedural::Rng::new(0x5EED_5A3D);
        let (mut points, mut colours) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for _ in 0..n {
            let at = rng.uniform() * total;
            let f = cumulative.partition_point(|&c| c < at).min(faces.len() - 1);
            let (r1, r2) = (rng.uniform().sqrt(), rng.uniform());
            let w = [1.0 - r1, r1 * (1.0 - r2), r1 * r2];
            let t = mesh.triangles()[f];
            points.push(pos(t[0]) * w[0] + pos(t[1]) * w[1] + pos(t[2]) * w[2]);
            colours.push(albedo(mesh, &textures, t, w, material_of[f]));
        }
        let face_centres = mesh.triangles().iter().map(|t| (pos(t[0]) + pos(t[1]) + pos(t[2])) / 3.0).collect();
        Self { points, colours, faces, face_centres }
    }

    /// The exact area-weighted centroid of the surface (the samples' mean is off by a few
    /// thousandths of the diameter).
    fn centroid(&self) -> Vector3<f64> {
        let total: f64 = self.faces.iter().map(|(_, a)| a).sum();
        if total <= 0.0 {
            return self.points.iter().sum::<Vector3<f64>>() / self.points.len() as f64;
        }
        self.face_centres.iter().zip(&self.faces).map(|(c, (_, a))| c * *a).sum::<Vector3<f64>>() / total
    }
}

fn material_per_triangle(mesh: &Mesh) -> Vec<usize> {
    let mut m = vec![0usize; mesh.triangles().len()];
    for p in mesh.parts() {
        let range = p.first_triangle as usize..(p.first_triangle + p.triangle_count) as usize;
        m[range].iter_mut().for_each(|x| *x = p.material as usize);
    }
    m
}

/// Base colour × texture × vertex colour at barycentric `w` of triangle `t`, as rendered
/// without light.
fn albedo(mesh: &Mesh, textures: &[Option<std::sync::Arc<image::RgbaImage>>], t: [u32; 3], w: [f64; 3], material: usize) -> [f32; 3] {
    let lerp = |v: &[[f32; 2]]| -> [f64; 2] { [0, 1].map(|k| (0..3).map(|i| w[i] * v[t[i] as usize][k] as f64).sum()) };
    let mut c = mesh.materials().get(material).map(|m| [m.base_color[0], m.base_color[1], m.base_color[2]]).unwrap_or([1.0; 3]);
    if let (Some(tex), Some(uvs)) = (textures.get(material).and_then(Option::as_ref), mesh.uvs()) {
        let [u, v] = lerp(uvs);
        // UVs have v up; the image's row 0 is its top.
        let x = ((u.rem_euclid(1.0) * tex.width() as f64) as u32).min(tex.width() - 1);
        let y = (((1.0 - v).rem_euclid(1.0) * tex.height() as f64) as u32).min(tex.height() - 1);
        let px = tex.get_pixel(x, y);
        (0..3).for_each(|k| c[k] *= px[k] as f32 / 255.0);
    }
    if let Some(vc) = mesh.colors() {
        (0..3).for_each(|k| c[k] *= (0..3).map(|i| w[i] as f32 * vc[t[i] as usize][k]).sum::<f32>());
    }
    c
}

/// Principal axes of the samples' spread and of the face normals, the dominant normal
/// directions, and their sums and differences; duplicates (either sign) removed.
fn candidate_axes(s: &Surface, centre: Vector3<f64>) -> Vec<Vector3<f64>> {
    let mut spread = Matrix3::zeros();
    for p in &s.points {
        let d = p - centre;
        spread += d * d.transpose();
    }
    let mut normal_tensor = Matrix3::zeros();
    for (n, a) in &s.faces {
        normal_tensor += *a * n * n.transpose();
    }
    let mut base: Vec<Vector3<f64>> = Vec::new();
    for m in [spread, normal_tensor] {
        let e = m.symmetric_eigen();
        base.extend((0..3).map(|i| e.eigenvectors.column(i).into_owned()));
    }
    let normals = dominant_normals(s, 6);
    // Sums and differences of the spread's axes and the three main normal directions.
    let firsts: Vec<Vector3<f64>> = base.iter().take(3).chain(normals.iter().take(3)).cloned().collect();
    base.extend(normals.iter().cloned());
    let mut axes: Vec<Vector3<f64>> = Vec::new();
    let mut push = |v: Vector3<f64>| {
        if let Some(u) = v.try_normalize(1e-9) {
            if !axes.iter().any(|a| a.dot(&u).abs() > 0.999) {
                axes.push(u);
            }
        }
    };
    base.iter().for_each(|&v| push(v));
    for (i, a) in firsts.iter().enumerate() {
        for b in &firsts[i + 1..] {
            push(a + b);
            push(a - b);
            for c in &firsts {
                push(a + b + c);
                push(a + b - c);
                push(a - b + c);
                push(a - b - c);
            }
        }
    }
    axes
}

/// The `k` directions (as axes) carrying the most face area, on a grid of directions.
fn dominant_normals(s: &Surface, k: usize) -> Vec<Vector3<f64>> {
    let dirs = crate::geometry::icosphere(3);
    let mut area = vec![0.0; dirs.len()];
    let mut sum = vec![Vector3::zeros(); dirs.len()];
    for (n, a) in &s.faces {
        if *a <= 0.0 {
            continue;
        }
        // Fold to one hemisphere: an axis has no sign.
        let (i, sign) = dirs.iter().enumerate().map(|(i, d)| (i, d.dot(n))).max_by(|x, y| x.1.abs().total_cmp(&y.1.abs())).map(|(i, d)| (i, d.signum())).expect("directions");
        area[i] += a;
        sum[i] += *a * sign * n;
    }
    let mut order: Vec<usize> = (0..dirs.len()).filter(|&i| area[i] > 0.0).collect();
    order.sort_by(|&a, &b| area[b].total_cmp(&area[a]));
    order.into_iter().take(k).map(|i| sum[i] / area[i]).collect()
}

/// Rounding noise (cos 90° = 6e-17) written as the zero it is.
fn tidy(x: f64) -> f64 {
    if x.abs() < 1e-12 {
        0.0
    } else {
        x
    }
}

fn rotation(axis: &Vector3<f64>, angle: f64) -> Matrix3<f64> {
    *Rotation3::from_axis_angle(&Unit::new_normalize(*axis), angle).matrix()
}

fn is_identity(r: &Matrix3<f64>) -> bool {
    (r - Matrix3::identity()).norm() < 0.05
}

/// The rotations generated by `generators` (identity included), by repeated products;
/// capped at 120 elements (the largest finite rotation group in 3D has 60).
fn close_group(generators: Vec<Matrix3<f64>>) -> Vec<Matrix3<f64>> {
    let mut group = vec![Matrix3::identity()];
    let mut frontier = vec![Matrix3::identity()];
    while let Some(g) = frontier.pop() {
        for h in &generators {
            let p = h * g;
            if group.len() < 120 && !group.iter().any(|q| (q - p).norm() < 0.05) {
                group.push(p);
                frontier.push(p);
            }
        }
    }
    group
}

/// Rotates probe samples about the centre and checks where they land.
struct Tester<'a> {
    surface: &'a Surface,
    centre: Vector3<f64>,
    tolerance: f64,
    grid: HashMap<[i32; 3], Vec<u32>>,
    probes: Vec<usize>,
    config: &'a FinderConfig,
}

impl<'a> Tester<'a> {
    fn new(surface: &'a Surface, centre: Vector3<f64>, tolerance: f64, config: &'a FinderConfig) -> Self {
        let tolerance = tolerance.max(1e-9);
        let mut grid: HashMap<[i32; 3], Vec<u32>> = HashMap::new();
        for (i, p) in surface.points.iter().enumerate() {
            grid.entry(cell(p, tolerance)).or_default().push(i as u32);
        }
        let stride = (surface.points.len() / config.probes.max(1)).max(1);
        let probes = (0..surface.points.len()).step_by(stride).collect();
        Self { surface, centre, tolerance, grid, probes, config }
    }

    /// Whether `r` (about the centre) maps the sampled surface onto itself, colours included.
    fn passes(&self, r: &Matrix3<f64>) -> bool {
        let n = self.probes.len() as f64;
        let (max_geometry, max_colour) = ((self.config.max_geometry_misses * n) as usize, (self.config.max_colour_misses * n) as usize);
        let (mut geometry_misses, mut colour_misses) = (0, 0);
        for &i in &self.probes {
            let q = r * (self.surface.points[i] - self.centre) + self.centre;
            match self.nearest(&q) {
                None => geometry_misses += 1,
                Some(j) => {
                    let (a, b) = (self.surface.colours[i], self.surface.colours[j]);
                    let d = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
                    if d > self.config.colour_difference {
                        colour_misses += 1;
                    }
                }
            }
            if geometry_misses > max_geometry || colour_misses > max_colour {
                return false;
            }
        }
        true
    }

    /// The nearest sample within the tolerance of `q`.
    fn nearest(&self, q: &Vector3<f64>) -> Option<usize> {
        let c = cell(q, self.tolerance);
        let mut best: Option<(usize, f64)> = None;
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    for &j in self.grid.get(&[c[0] + dx, c[1] + dy, c[2] + dz]).into_iter().flatten() {
                        let d = (self.surface.points[j as usize] - q).norm();
                        if d <= self.tolerance && best.is_none_or(|(_, bd)| d < bd) {
                            best = Some((j as usize, d));
                        }
                    }
                }
            }
        }
        best.map(|(j, _)| j)
    }
}

fn cell(p: &Vector3<f64>, size: f64) -> [i32; 3] {
    [(p.x / size).floor() as i32, (p.y / size).floor() as i32, (p.z / size).floor() as i32]
}

#[cfg(test)]
#[path = "symmetry_finder_tests.rs"]
mod tests;
