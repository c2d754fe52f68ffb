//! A pose fitted to the measured depth: robust point-to-plane ICP of the model surface a
//! hypothesis shows against the depth camera's surface, with what the fit says of the pose.
//!
//! The model side comes from the hypothesis's render (every visible surface point, with the
//! normal of the rendered surface, which is exact where the sensor's is noisy); the scene
//! side by projective association, the measured depth at the pixel each model point
//! projects to, as KinectFusion does: no search tree, one lookup per point, which suits a
//! depth image registered to the camera the poses are in. First the depth is set by the
//! median of the per-point depth differences (a pose from a box can be tens of
//! centimetres off in depth, beyond any ICP's basin), then Gauss-Newton on the
//! point-to-plane residuals with Tukey weights and a gate that narrows each iteration.
//! Measured points well in front of the model are occluders and left out; measured
//! points well behind it mean the camera sees through where the model would be (free
//! space), which is the strongest evidence against a pose.

use crate::depth::DepthImage;
use crate::geometry::{Intrinsics, Pose};
use crate::render::RenderOutput;
use nalgebra::{Matrix6, Point3, Rotation3, Vector3, Vector6};

/// Share of the pairs' weight that holds each motion still in a Gauss-Newton step.
const DAMPING: f64 = 0.1;

/// Model surface points at most (a sparser grid over larger renders).
const MAX_SAMPLES: usize = 1500;

/// A visible model surface point and its outward normal, in the object's frame.
#[derive(Clone, Copy, Debug)]
pub struct SurfaceSample {
    pub point: Vector3<f64>,
    pub normal: Vector3<f64>,
}

/// What the measured depth says of a pose, over the model points it shows.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct DepthFit {
    /// Model points shown (sampled from the render).
    pub points: usize,
    /// Share of them with a measurement at their pixel.
    pub measured_share: f64,
    /// Among the measured: within `tolerance_mm` of the model surface along the ray ...
    pub inlier_share: f64,
    /// ... measured behind the model surface by more (the camera sees through the model) ...
    pub free_space_share: f64,
    /// ... and measured in front by more (an occluder, or the pose is too far).
    pub occluded_share: f64,
    /// RMS point-to-plane residual of the inliers, millimetres.
    pub rms_mm: f64,
    pub tolerance_mm: f64,
    /// How far the fit moved the object's centre, millimetres.
    pub moved_mm: f64,
}

impl DepthFit {
    /// A [-1, 1] score: the share that agrees, less the share seen through.
    pub fn score(&self) -> f64 {
        if self.points == 0 || self.measured_share == 0.0 {
            return 0.0;
        }
        self.inlier_share - self.free_space_share
    }
}

/// The render's visible surface as object-frame samples (normals from the rendered depth's
/// central differences; pixels across a depth edge are skipped). `camera` is the render's.
pub fn visible_samples(render: &RenderOutput, pose: &Pose, camera: &Intrinsics) -> Vec<SurfaceSample> {
    let (w, h) = (render.width(), render.height());
    let covered = render.depth.iter().filter(|&&z| z > 0.0).count();
    let step = ((covered as f64 / MAX_SAMPLES as f64).sqrt().ceil() as u32).max(1);
    let at = |x: u32, y: u32| -> Option<Point3<f64>> {
        let z = render.depth[(y * w + x) as usize];
        (z > 0.0).then(|| camera.back_project(x as f64, y as f64, z as f64))
    };
    let inverse = pose.inverse();
    let mut out = Vec::new();
    for y in (1..h.saturating_sub(1)).step_by(step as usize) {
        for x in (1..w.saturating_sub(1)).step_by(step as usize) {
            let (Some(c), Some(l), Some(r), Some(u), Some(d)) = (at(x, y), at(x - 1, y), at(x + 1, y), at(x, y - 1), at(x, y + 1)) else { continue };
            let Some(n) = grid_normal(&c.coords, [l.coords, r.coords, u.coords, d.coords], 0.02) else { continue };
            out.push(SurfaceSample { point: inverse.transform_point(&c).coords, normal: inverse.rotation * n });
        }
    }
    out
}

/// The unit normal, facing the camera, at camera-frame point `c` of a grid of surface
/// points from its left, right, up and down neighbours (central differences); `None`
/// across a depth edge (a neighbour further than `edge_share` of `c`'s depth from it:
/// another surface) or where the neighbours are degenerate.
pub(super) fn grid_normal(c: &Vector3<f64>, [l, r, u, d]: [Vector3<f64>; 4], edge_share: f64) -> Option<Vector3<f64>> {
    let edge = edge_share * c.z;
    if [l, r, u, d].iter().any(|p| (p.z - c.z).abs() > edge) {
        return None;
    }
    let n = (r - l).cross(&(d - u)).try_normalize(1e-15)?;
    Some(if n.dot(c) > 0.0 { -n } else { n })
}

/// How the fit runs.
#[derive(Clone, Copy, Debug)]
pub struct DepthFitConfig {
    pub iterations: usize,
    /// The first gate, as a share of the object's diameter (at least 2 cm) ...
    pub start_gate: f64,
    /// ... narrowed by this each iteration down to the inlier tolerance.
    pub gate_shrink: f64,
    /// Set the depth first by the median depth difference, however large (a pose from a
    /// box can be tens of centimetres off). Off for tracking, where a pose is close and a
    /// surface far behind it must refute it rather than pull it there.
    pub depth_first: bool,
}

impl Default for DepthFitConfig {
    fn default() -> Self {
        Self { iterations: 15, start_gate: 0.25, gate_shrink: 0.75, depth_first: true }
    }
}

/// Inlier tolerance for an object of `diameter` metres: 5 % of it, within 5–15 mm
/// (Kinect-class noise is 2–5 mm at 1 m).
pub(super) fn tolerance(diameter: f64) -> f64 {
    (0.05 * diameter).clamp(0.005, 0.015)
}

/// `pose` fitted to `depth` (full image, camera `k`) over `samples`; the fit's report at
/// the fitted pose. A pose with too few measured points comes back unchanged.
pub fn fit(samples: &[SurfaceSample], pose: &Pose, depth: &DepthImage, k: &Intrinsics, diameter: f64, cfg: &DepthFitConfig) -> (Pose, DepthFit) {
    let tol = tolerance(diameter);
    let centre = samples.iter().fold(Vector3::zeros(), |a, s| a + s.point) / samples.len().max(1) as f64;
    let mut current = *pose;
    // The depth first: tens of centimetres off is common from a box.
    for _ in 0..if cfg.depth_first { 2 } else { 0 } {
        let diffs = depth_differences(samples, &current, depth, k);
        if diffs.len() < 10 {
            break;
        }
        let shift = median(diffs);
        if shift.abs() < 0.5 * tol {
            break;
        }
        current = along_ray(&current, &centre, shift);
    }
    let mut gate = (cfg.start_gate * diameter).max(0.02);
    for _ in 0..cfg.iterations {
        let Some(step) = gauss_newton_step(samples, &current, depth, k, gate) else { break };
        current = step;
        gate = (gate * cfg.gate_shrink).max(tol);
    }
    let moved = (current.transform_point(&Point3::from(centre)) - pose.transform_point(&Point3::from(centre))).norm();
    let mut report = measure(samples, &current, depth, k, tol);
    report.moved_mm = moved * 1000.0;
    (current, report)
}

/// Measured z less model z, per sample with a measurement at its pixel.
pub(super) fn depth_differences(samples: &[SurfaceSample], pose: &Pose, depth: &DepthImage, k: &Intrinsics) -> Vec<f64> {
    samples
        .iter()
        .filter_map(|s| {
            let x = pose.rotation * s.point + pose.translation;
            let uv = k.project(&Point3::from(x))?;
            let d = depth.nearest(uv.x, uv.y) as f64;
            (d > 0.0).then_some(d - x.z)
        })
        .collect()
}

/// `pose` moved `dz` deeper along the ray through its `centre` (so its image stays put).
pub(super) fn along_ray(pose: &Pose, centre: &Vector3<f64>, dz: f64) -> Pose {
    let c = pose.rotation * centre + pose.translation;
    if c.z <= 1e-9 {
        return *pose;
    }
    Pose::new(pose.rotation, pose.translation + c * (dz / c.z))
}

pub(super) fn median(mut v: Vec<f64>) -> f64 {
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// One robust point-to-plane Gauss-Newton step about the matched points' centroid; None
/// with fewer than 12 pairs within `gate` or a singular system.
fn gauss_newton_step(samples: &[SurfaceSample], pose: &Pose, depth: &DepthImage, k: &Intrinsics, gate: f64) -> Option<Pose> {
    let pairs: Vec<(Vector3<f64>, Vector3<f64>, f64)> = samples
        .iter()
        .filter_map(|s| {
            let x = pose.rotation * s.point + pose.translation;
            let uv = k.project(&Point3::from(x))?;
            let d = depth.nearest(uv.x, uv.y) as f64;
            if d <= 0.0 || (d - x.z).abs() > gate {
                return None;
            }
            let q = k.back_project(uv.x, uv.y, d).coords;
            let n = pose.rotation * s.normal;
            Some((x, n, n.dot(&(x - q))))
        })
        .collect();
    if pairs.len() < 12 {
        return None;
    }
    let c = pairs.iter().fold(Vector3::zeros(), |a, p| a + p.0) / pairs.len() as f64;
    let (mut a, mut b, mut total) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros(), 0.0);
    for (x, n, r) in &pairs {
        // Tukey's biweight: points near the gate count little.
        let u = r / gate;
        let w = if u.abs() < 1.0 { (1.0 - u * u).powi(2) } else { 0.0 };
        let j = Vector6::from_iterator((x - c).cross(n).iter().chain(n.iter()).copied());
        a += w * j * j.transpose();
        b += w * j * *r;
        total += w;
    }
    // Damping towards staying put, as if a tenth of the pairs held each motion: a plane or
    // a cylinder leaves some motions unconstrained (sliding along a face), which would
    // otherwise run with the sensor's noise, tens of millimetres over the iterations
    // (`b2tf bench depth-fit`); a constrained motion still takes 75–90 % of its step.
    let radius = (pairs.iter().map(|p| (p.0 - c).norm_squared()).sum::<f64>() / pairs.len() as f64).sqrt();
    let hold = DAMPING * total.max(1e-12);
    for i in 0..3 {
        a[(i, i)] += hold * radius * radius;
        a[(i + 3, i + 3)] += hold;
    }
    let delta = a.cholesky()?.solve(&(-b));
    // A trust region of the gate: a step moves no point further than the gate lets pairs
    // be.
    let reach = Vector3::new(delta[0], delta[1], delta[2]).norm() * radius + Vector3::new(delta[3], delta[4], delta[5]).norm();
    let delta = if reach > gate { delta * (gate / reach) } else { delta };
    let turn = Rotation3::new(Vector3::new(delta[0], delta[1], delta[2]));
    let shift = Vector3::new(delta[3], delta[4], delta[5]);
    Some(Pose::new(turn * pose.rotation, turn * (pose.translation - c) + c + shift))
}

/// The fit's report at `pose`, with inliers within `tol` along the ray.
fn measure(samples: &[SurfaceSample], pose: &Pose, depth: &DepthImage, k: &Intrinsics, tol: f64) -> DepthFit {
    let (mut measured, mut inliers, mut behind, mut front, mut sq) = (0usize, 0usize, 0usize, 0usize, 0.0);
    for s in samples {
        let x = pose.rotation * s.point + pose.translation;
        let Some(uv) = k.project(&Point3::from(x)) else { continue };
        let d = depth.nearest(uv.x, uv.y) as f64;
        if d <= 0.0 {
            continue;
        }
        measured += 1;
        let dz = d - x.z;
        if dz > tol {
            behind += 1;
        } else if dz < -tol {
            front += 1;
        } else {
            inliers += 1;
            let q = k.back_project(uv.x, uv.y, d).coords;
            sq += (pose.rotation * s.normal).dot(&(x - q)).powi(2);
        }
    }
    let share = |n: usize| if measured == 0 { 0.0 } else { n as f64 / measured as f64 };
    DepthFit {
        points: samples.len(),
        measured_share: if samples.is_empty() { 0.0 } else { measured as f64 / samples.len() as f64 },
        inlier_share: share(inliers),
        free_space_share: share(behind),
        occluded_share: share(front),
        rms_mm: if inliers == 0 { f64::NAN } else { (sq / inliers as f64).sqrt() * 1000.0 },
        tolerance_mm: tol * 1000.0,
        moved_mm: 0.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::RenderOptions;

    /// A textured box seen by a 320×240 camera, its true render's depth as the measurement.
    #[test]
    fn a_pose_off_in_depth_and_turned_comes_back_to_the_measured_surface() {
        let Some(pool) = crate::render::tests::test_pool() else { return };
        let mesh = crate::mesh::procedural::textured_box([0.08, 0.05, 0.03], 3);
        let k = Intrinsics::new(300.0, 300.0, 160.0, 120.0, 320, 240).unwrap();
        let truth = Pose::new(Rotation3::from_euler_angles(0.5, -0.4, 0.3), Vector3::new(0.01, -0.005, 0.45));
        let seen = pool.render_batch(&mesh, &[(truth, k)], &RenderOptions::default()).unwrap().remove(0);
        let depth = DepthImage::from_metres(320, 240, seen.depth.clone()).unwrap();
        let diameter = mesh.diameter();
        let (_, at_truth) = fit(&visible_samples(&seen, &truth, &k), &truth, &depth, &k, diameter, &DepthFitConfig::default());
        assert!(at_truth.inlier_share > 0.98 && at_truth.free_space_share < 0.01 && at_truth.moved_mm < 1.0, "{at_truth:?}");

        // 6 cm too deep, 8° off and 5 mm aside: the render of that guess gives the samples.
        let off = Pose::new(Rotation3::from_euler_angles(0.08, 0.06, -0.05) * truth.rotation, truth.translation + Vector3::new(0.005, 0.0, 0.06));
        let guess = pool.render_batch(&mesh, &[(off, k)], &RenderOptions::default()).unwrap().remove(0);
        let samples = visible_samples(&guess, &off, &k);
        assert!(samples.len() > 200, "{}", samples.len());
        let (_, before) = fit(&samples, &off, &depth, &k, diameter, &DepthFitConfig { iterations: 0, ..Default::default() });
        let (fitted, after) = fit(&samples, &off, &depth, &k, diameter, &DepthFitConfig::default());
        let dt = (fitted.translation - truth.translation).norm();
        let dr = crate::geometry::geodesic_distance(&fitted.rotation, &truth.rotation).to_degrees();
        assert!(dt < 0.003 && dr < 1.5, "{dt} m, {dr}°: {after:?}");
        assert!(after.inlier_share > 0.95 && after.score() > before.score(), "{before:?} → {after:?}");
        assert!(after.rms_mm < 2.0 && after.moved_mm > 40.0, "{after:?}");
    }

    #[test]
    fn a_pose_too_near_sees_free_space_and_one_too_far_an_occluder() {
        let samples: Vec<SurfaceSample> =
            (0..100).map(|i| SurfaceSample { point: Vector3::new((i % 10) as f64 * 0.005 - 0.025, (i / 10) as f64 * 0.005 - 0.025, 0.0), normal: -Vector3::z() }).collect();
        let k = Intrinsics::new(300.0, 300.0, 50.0, 50.0, 100, 100).unwrap();
        let depth = DepthImage::from_metres(100, 100, vec![0.5; 100 * 100]).unwrap();
        let cfg = DepthFitConfig { iterations: 0, ..Default::default() };
        let at = |z: f64| measure(&samples, &Pose::new(Rotation3::identity(), Vector3::new(0.0, 0.0, z)), &depth, &k, tolerance(0.07));
        let (near, right, far) = (at(0.45), at(0.5), at(0.55));
        assert!(near.free_space_share > 0.99 && near.score() < -0.9, "{near:?}");
        assert!(right.inlier_share > 0.99 && right.rms_mm < 0.01, "{right:?}");
        assert!(far.occluded_share > 0.99 && far.score() == 0.0, "{far:?}");
        // The median depth difference alone brings a flat patch to the wall.
        let (p, _) = fit(&samples, &Pose::new(Rotation3::identity(), Vector3::new(0.0, 0.0, 0.6)), &depth, &k, 0.07, &cfg);
        assert!((p.translation.z - 0.5).abs() < 1e-3, "{}", p.translation);
    }
}
