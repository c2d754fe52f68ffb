//! One regularised Gauss–Newton update of the pose from correspondence lines: the pose
//! changes by `T ← T·ΔT` with ΔT = (exp(ω), v) in the object frame, and each line asks its
//! contour point to move along the line's normal by the measured outline offset.

use super::lines::{projection_jacobian, Line};
use super::occlusion::{median, visibility, LineResidual};
use super::print_points::PrintPoint;
use crate::geometry::{Intrinsics, Pose};
use nalgebra::{Matrix6, Point3, Rotation3, Vector2, Vector3, Vector6};

/// Regularisation, separate for rotation and translation (Tikhonov): a prior that the
/// hypothesis is roughly right, pulling the total change since the start back towards
/// zero with the weight of this many average lines. Directions the outline pins down move
/// freely; directions it cannot see (a turn about a symmetry axis, a face-on tilt) stay.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Regularisation {
    pub rotation: f64,
    pub translation: f64,
}

impl Default for Regularisation {
    fn default() -> Self {
        Self { rotation: 0.05, translation: 0.02 }
    }
}

/// Offsets farther than this many robust standard deviations from zero get no weight
/// (Tukey): a mask's stray pixels, and without the occlusion model an occluder's edges
/// where they are a minority that disagrees with the rest.
const TUKEY_SIGMAS: f64 = 3.0;

/// Print points (`print_points`) for an update, with the standard deviation of their
/// positions in the photo, px.
#[derive(Clone, Copy)]
pub struct PointTerm<'a> {
    pub points: &'a [PrintPoint],
    pub sigma_px: f64,
}

impl PointTerm<'_> {
    /// No points: the outline alone.
    pub const NONE: PointTerm<'static> = PointTerm { points: &[], sigma_px: 1.0 };
}

/// One Gauss–Newton step: the turn ω and shift v (object frame) and the step's
/// covariance, the inverse of the weighted normal matrix (prior included; rows ω then v).
pub struct Step {
    pub omega: Vector3<f64>,
    pub v: Vector3<f64>,
    pub covariance: Matrix6<f64>,
    /// The expected number of lines that see the object's own outline: those with an edge,
    /// each counted by the occlusion model's probability (1 without the model).
    pub own_edges: f64,
}

impl Step {
    /// Standard deviation of the pose's depth (camera z, metres) after the step at `pose`:
    /// the shift's covariance turned into the camera frame.
    pub fn depth_sigma(&self, pose: &Pose) -> f64 {
        let r = pose.rotation.matrix();
        let cov_v = self.covariance.fixed_view::<3, 3>(3, 3);
        let row = r.row(2);
        (row * cov_v * row.transpose())[(0, 0)].max(0.0).sqrt()
    }
}

/// The update that best explains the lines' offsets at `pose`, given the prior towards
/// `start`, or `None` when the lines do not constrain the pose (no line with an edge).
/// Each line's weight is its biweight over its offset variance (px²), so the covariance is
/// in the units of the pose as far as those variances are right; with `occlusion`, times
/// the probability that its edge is the object's own (`occlusion::visibility`).
///
/// `points` add their reprojection offsets, x and y, each with their standard deviation;
/// the prior stays in units of the lines.
#[allow(clippy::too_many_arguments)]
pub fn gauss_newton_update(lines: &[Line], points: PointTerm<'_>, pose: &Pose, start: &Pose, k: &Intrinsics, reg: &Regularisation, radius: f64, occlusion: bool) -> Option<Step> {
    struct Row {
        j: Vector6<f64>,
        residual: f64,
        variance: f64,
        inside_px: f64,
    }
    let mut rows = Vec::with_capacity(lines.len());
    let mut depth = 0.0;
    for l in lines.iter().filter(|l| l.edge) {
        let p = Point3::from(pose.rotation * l.object_point + pose.translation);
        let Some(uv) = k.project(&p) else { continue };
        depth += p.z;
        let residual = l.mean - l.normal.dot(&(uv - l.centre));
        rows.push(Row { j: offset_jacobian(pose, k, &p, &l.object_point, &l.normal), residual, variance: l.variance, inside_px: l.inside_px });
    }
    if rows.is_empty() {
        return None;
    }
    let n = rows.len() as f64;
    depth /= n;
    let line_sigma = median(rows.iter().map(|r| r.variance.sqrt()).collect());
    // Robust scale of the offsets, never below the lines' own uncertainty: with the
    // occlusion model, the spread of the edges it takes for the object's own.
    let (own, spread, own_edges) = if occlusion {
        let v = visibility(&rows.iter().map(|r| LineResidual { residual: r.residual, variance: r.variance, inside_px: r.inside_px }).collect::<Vec<_>>(), line_sigma);
        let own_edges = v.own_edges();
        (v.own_edge, v.spread_px, own_edges)
    } else {
        (vec![1.0; rows.len()], (1.4826 * median(rows.iter().map(|r| r.residual.abs()).collect())).max(line_sigma), n)
    };
    let cutoff = TUKEY_SIGMAS * spread;
    let mut h = Matrix6::<f64>::zeros();
    let mut g = Vector6::<f64>::zeros();
    let mut weight_sum = 0.0;
    for (r, p_own) in rows.iter().zip(&own) {
        let u = r.residual / cutoff;
        if u.abs() >= 1.0 {
            continue;
        }
        let w = p_own * (1.0 - u * u).powi(2) / r.variance;
        h += r.j * r.j.transpose() * w;
        g += r.j * (w * r.residual);
        weight_sum += w;
    }
    if weight_sum == 0.0 {
        return None;
    }
    // Print points, two rows each (x and y), robust among themselves: a point matched to a
    // repeat of its print is an outlier there whatever the lines say.
    let point_rows: Vec<(Vector6<f64>, f64)> = points
        .points
        .iter()
        .flat_map(|pt| {
            let p = Point3::from(pose.rotation * pt.object_point + pose.translation);
            let uv = k.project(&p);
            [Vector2::x(), Vector2::y()].into_iter().filter_map(move |n| Some((offset_jacobian(pose, k, &p, &pt.object_point, &n), n.dot(&(pt.observed - uv?)))))
        })
        .collect();
    if !point_rows.is_empty() {
        let spread = (1.4826 * median(point_rows.iter().map(|r| r.1.abs()).collect())).max(points.sigma_px);
        for (j, residual) in &point_rows {
            let u = residual / (TUKEY_SIGMAS * spread);
            if u.abs() < 1.0 {
                let w = (1.0 - u * u).powi(2) / (points.sigma_px * points.sigma_px);
                h += j * j.transpose() * w;
                g += j * (w * residual);
            }
        }
    }
    // The prior, in units of an average line: a line moves about f·radius/z px per radian
    // of turn and f/z px per metre of sideways shift (f·radius/z² along the depth).
    let w_mean = weight_sum / n;
    let f = k.fx.max(k.fy);
    let (px_rad, px_m, px_m_depth) = (f * radius / depth, f / depth, f * radius / (depth * depth));
    let prior = [
        reg.rotation * w_mean * px_rad * px_rad,
        reg.rotation * w_mean * px_rad * px_rad,
        reg.rotation * w_mean * px_rad * px_rad,
        reg.translation * w_mean * px_m * px_m,
        reg.translation * w_mean * px_m * px_m,
        reg.translation * w_mean * px_m_depth * px_m_depth,
    ];
    let since = start.inverse().compose(pose);
    let so_far = since.rotation.scaled_axis();
    let moved = [so_far.x, so_far.y, so_far.z, since.translation.x, since.translation.y, since.translation.z];
    // A trace-relative floor keeps the system solvable when the lines leave a direction
    // entirely unseen and the prior is off.
    let floor = 1e-9 * h.trace();
    for i in 0..6 {
        h[(i, i)] += prior[i] + floor;
        g[i] -= prior[i] * moved[i];
    }
    let chol = h.cholesky()?;
    let step = chol.solve(&g);
    Some(Step { omega: Vector3::new(step[0], step[1], step[2]), v: Vector3::new(step[3], step[4], step[5]), covariance: chol.inverse(), own_edges })
}

/// How a point's image offset along `n` changes with the update (ω, v) at `pose`: the
/// point `x` (object frame) at camera-frame `p`. b = (nᵀ·J_π·R)ᵀ answers an object-frame
/// shift, and a turn moves the point by ω × x, hence −b × x.
fn offset_jacobian(pose: &Pose, k: &Intrinsics, p: &Point3<f64>, x: &Vector3<f64>, n: &Vector2<f64>) -> Vector6<f64> {
    let b: Vector3<f64> = pose.rotation.inverse() * (projection_jacobian(k, p).transpose() * n);
    let c = -b.cross(x);
    Vector6::new(c.x, c.y, c.z, b.x, b.y, b.z)
}

/// `pose · (exp(ω), v)`: the object turns by ω and shifts by v in its own frame.
pub fn apply_update(pose: &Pose, omega: &Vector3<f64>, v: &Vector3<f64>) -> Pose {
    let dr = Rotation3::new(*omega);
    Pose::new(pose.rotation * dr, pose.translation + pose.rotation * v)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Lines that know the true outline exactly recover a small shift in one step.
    #[test]
    fn recovers_a_translation_from_exact_lines() {
        let k = Intrinsics { fx: 600.0, fy: 600.0, cx: 320.0, cy: 240.0, width: 640, height: 480 };
        let truth = Pose::new(Rotation3::from_euler_angles(0.2, -0.1, 0.3), Vector3::new(0.0, 0.0, 0.6));
        let start = Pose::new(truth.rotation, truth.translation + Vector3::new(0.004, -0.003, 0.0));
        // Points on a ring in the object's x–y plane with radial normals.
        let mut lines = Vec::new();
        for i in 0..72 {
            let a = i as f64 * 5f64.to_radians();
            let x = Vector3::new(0.05 * a.cos(), 0.05 * a.sin(), 0.01 * (3.0 * a).sin());
            let proj = |pose: &Pose| {
                let p = pose.rotation * x + pose.translation;
                Vector2::new(k.fx * p.x / p.z + k.cx, k.fy * p.y / p.z + k.cy)
            };
            let (c, t) = (proj(&start), proj(&truth));
            let n = (c - Vector2::new(320.0, 240.0)).normalize();
            lines.push(Line { object_point: x, centre: c, normal: n, mean: n.dot(&(t - c)), variance: 1.0, edge: true, inside_px: 20.0, photo_edge: false });
        }
        let reg = Regularisation { rotation: 0.0, translation: 0.0 };
        let mut pose = start;
        for _ in 0..3 {
            let Step { omega: w, v, .. } = gauss_newton_update(&lines, PointTerm::NONE, &pose, &start, &k, &reg, 0.05, true).unwrap();
            pose = apply_update(&pose, &w, &v);
        }
        let err = (pose.translation - truth.translation).norm();
        assert!(err < 1e-3, "translation error {err} m after the update");
        assert!(gauss_newton_update(&[], PointTerm::NONE, &start, &start, &k, &reg, 0.05, true).is_none());
    }

    /// At the true pose, with half the ring's lines seeing an occluder's edge 12 px inside
    /// the outline: the occlusion model leaves the pose where it is and counts about half
    /// the lines as the object's own; without it the step moves the pose towards the
    /// occluder.
    #[test]
    fn occluded_lines_do_not_pull_the_pose() {
        let k = Intrinsics { fx: 600.0, fy: 600.0, cx: 320.0, cy: 240.0, width: 640, height: 480 };
        let truth = Pose::new(Rotation3::from_euler_angles(0.2, -0.1, 0.3), Vector3::new(0.0, 0.0, 0.6));
        let lines: Vec<Line> = (0..72)
            .map(|i| {
                let a = i as f64 * 5f64.to_radians();
                let x = Vector3::new(0.05 * a.cos(), 0.05 * a.sin(), 0.0);
                let p = truth.rotation * x + truth.translation;
                let c = Vector2::new(k.fx * p.x / p.z + k.cx, k.fy * p.y / p.z + k.cy);
                let n = (c - Vector2::new(320.0, 240.0)).normalize();
                let mean = if i < 36 { 0.0 } else { -12.0 };
                Line { object_point: x, centre: c, normal: n, mean, variance: 1.0, edge: true, inside_px: 40.0, photo_edge: false }
            })
            .collect();
        let reg = Regularisation::default();
        let moved = |occlusion: bool| {
            let s = gauss_newton_update(&lines, PointTerm::NONE, &truth, &truth, &k, &reg, 0.05, occlusion).unwrap();
            (apply_update(&truth, &s.omega, &s.v).translation - truth.translation).norm()
        };
        let with = gauss_newton_update(&lines, PointTerm::NONE, &truth, &truth, &k, &reg, 0.05, true).unwrap();
        assert!((with.own_edges - 36.0).abs() < 3.0, "own edges {}", with.own_edges);
        assert!(moved(true) < 2e-4, "moved {} m with the occlusion model", moved(true));
        assert!(moved(false) > 5.0 * moved(true).max(1e-4), "moved {} m without, {} m with", moved(false), moved(true));
    }
}
