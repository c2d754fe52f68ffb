//! Minimal solver: Lambda Twist P3P (Persson & Nordberg, ECCV 2018), written from the paper.
//!
//! The depths `λᵢ` along the three rays satisfy `λᵢ² + λⱼ² + bᵢⱼλᵢλⱼ = aᵢⱼ` (law of cosines,
//! `bᵢⱼ = −2 cos∠(yᵢ, yⱼ)`, `aᵢⱼ = |xᵢ − xⱼ|²`). Two homogeneous combinations of these are
//! conics in λ; one real root of a cubic gives the degenerate member of their pencil, a pair of
//! lines, and each line meets the conics in at most two points: up to four poses, no quartic.

use nalgebra::{Matrix3, Rotation3, Vector3};

use super::algebra::{adjugate, cubic_root, eigen_known_zero, quadratic_roots};
use crate::geometry::Pose;

/// Up to four poses, on the stack: this runs thousands of times per RANSAC call.
#[derive(Clone, Copy, Debug)]
pub struct P3pSolutions {
    poses: [Pose; 4],
    len: usize,
}

impl P3pSolutions {
    fn empty() -> Self {
        Self { poses: [Pose::identity(); 4], len: 0 }
    }

    fn push(&mut self, pose: Pose) {
        if self.len < 4 {
            self.poses[self.len] = pose;
            self.len += 1;
        }
    }

    pub fn as_slice(&self) -> &[Pose] {
        &self.poses[..self.len]
    }
}

/// Every pose `T_cam_obj` with `λᵢ·bearingᵢ = R·worldᵢ + t`, `λᵢ > 0`, for three object points
/// and their unit bearing vectors (camera frame). Degenerate triples (collinear or coincident
/// points, parallel rays) give no solutions rather than garbage.
pub fn p3p(world: &[Vector3<f64>; 3], bearings: &[Vector3<f64>; 3]) -> P3pSolutions {
    let mut out = P3pSolutions::empty();
    let [x1, x2, x3] = world;
    let [y1, y2, y3] = bearings;
    let (d12, d13, d23) = (x1 - x2, x1 - x3, x2 - x3);
    // Work with distances scaled to O(1) so that the tolerances below are unit-free.
    let scale = d12.norm_squared().max(d13.norm_squared()).max(d23.norm_squared());
    let world_frame = match frame(&d12, &d13) {
        Some(f) if scale > 0.0 => f,
        _ => return out,
    };
    let (a12, a13, a23) = (d12.norm_squared() / scale, d13.norm_squared() / scale, d23.norm_squared() / scale);
    let (b12, b13, b23) = (-2.0 * y1.dot(y2), -2.0 * y1.dot(y3), -2.0 * y2.dot(y3));
    let eq = Equations { a12, a13, a23, b12, b13, b23 };

    // D1 = a23·M12 − a12·M23 and D2 = a23·M13 − a13·M23, Mᵢⱼ the quadratic form of equation ij:
    // both vanish on the solutions and neither has a constant term.
    let d1 = Matrix3::new(
        a23,
        0.5 * a23 * b12,
        0.0, //
        0.5 * a23 * b12,
        a23 - a12,
        -0.5 * a12 * b23, //
        0.0,
        -0.5 * a12 * b23,
        -a12,
    );
    let d2 = Matrix3::new(
        a23,
        0.0,
        0.5 * a23 * b13, //
        0.0,
        -a13,
        -0.5 * a13 * b23, //
        0.5 * a23 * b13,
        -0.5 * a13 * b23,
        a23 - a13,
    );
    // det(D1 + g·D2) = det D2·g³ + tr(adj D2·D1)·g² + tr(adj D1·D2)·g + det D1.
    // A vanishing det D2 makes g = ∞ a root: D2 itself is then the degenerate member.
    let c3 = d2.determinant();
    let degenerate_member = if c3.abs() > 1e-12 {
        let g = cubic_root((adjugate(&d2) * d1).trace() / c3, (adjugate(&d1) * d2).trace() / c3, d1.determinant() / c3);
        d1 + d2 * g
    } else {
        d2
    };
    let Some((l0, v0, l1, v1)) = eigen_known_zero(&degenerate_member) else { return out };

    // λᵀAλ = l0(v0·λ)² + l1(v1·λ)² = 0 splits into the lines (v0 − s·v1)·λ = 0, s = ±√(−l1/l0).
    let s = (-l1 / l0).max(0.0).sqrt();
    for s in [s, -s] {
        let n = v0 - v1 * s;
        if n.x.abs() < 1e-12 {
            continue;
        }
        // On the line, λ1 = w0·λ2 + w1·λ3; put that and λ3 = τ·λ2 into a13·E12 − a12·E13.
        let (w0, w1) = (-n.y / n.x, -n.z / n.x);
        let qa = (a13 - a12) * w1 * w1 - a12 * b13 * w1 - a12;
        let qb = 2.0 * (a13 - a12) * w0 * w1 + a13 * b12 * w1 - a12 * b13 * w0;
        let qc = (a13 - a12) * w0 * w0 + a13 * b12 * w0 + a13;
        for tau in quadratic_roots(qa, qb, qc).into_iter().flatten() {
            if tau <= 0.0 {
                continue;
            }
            // E23 fixes the scale: λ2²(1 + b23·τ + τ²) = a23.
            let d = a23 / (tau * (b23 + tau) + 1.0);
            if !d.is_finite() || d <= 0.0 {
                continue;
            }
            let l2 = d.sqrt();
            let l3 = tau * l2;
            let lambda = eq.polish(Vector3::new(w0 * l2 + w1 * l3, l2, l3));
            // Both checks matter: a spurious root (same-sign eigenvalues) passes the first.
            if lambda.iter().all(|&l| l > 0.0) && eq.residual(&lambda) < 1e-8 {
                out.push(pose_from_depths(world, bearings, &(lambda * scale.sqrt()), &world_frame));
            }
        }
    }
    out
}

/// The three law-of-cosines equations, distances scaled to O(1).
struct Equations {
    a12: f64,
    a13: f64,
    a23: f64,
    b12: f64,
    b13: f64,
    b23: f64,
}

impl Equations {
    fn residuals(&self, l: &Vector3<f64>) -> Vector3<f64> {
        Vector3::new(l.x * l.x + l.y * l.y + self.b12 * l.x * l.y - self.a12, l.x * l.x + l.z * l.z + self.b13 * l.x * l.z - self.a13, l.y * l.y + l.z * l.z + self.b23 * l.y * l.z - self.a23)
    }

    fn residual(&self, l: &Vector3<f64>) -> f64 {
        self.residuals(l).abs().sum()
    }

    /// Newton steps on the three equations, where needed: the closed form loses digits when
    /// the pencil is nearly degenerate, and this gets them back.
    fn polish(&self, mut l: Vector3<f64>) -> Vector3<f64> {
        for _ in 0..5 {
            let r = self.residuals(&l);
            // Distances are O(1) here. 1e-10 leaves pose errors ~1e-10, far below what RANSAC
            // can tell and what LM then polishes anyway; tighter costs a 3×3 solve per root.
            if r.abs().sum() < 1e-10 {
                break;
            }
            let j = Matrix3::new(
                2.0 * l.x + self.b12 * l.y,
                2.0 * l.y + self.b12 * l.x,
                0.0, //
                2.0 * l.x + self.b13 * l.z,
                0.0,
                2.0 * l.z + self.b13 * l.x, //
                0.0,
                2.0 * l.y + self.b23 * l.z,
                2.0 * l.z + self.b23 * l.y,
            );
            match j.try_inverse() {
                Some(inv) => l -= inv * r,
                None => break,
            }
        }
        l
    }
}

/// Orthonormal frame (columns) of a triangle from two of its edges; `None` when collinear.
fn frame(e1: &Vector3<f64>, e2: &Vector3<f64>) -> Option<Matrix3<f64>> {
    let n = e1.cross(e2);
    // Written so that NaN fails it too.
    if n.norm_squared() > 1e-20 * e1.norm_squared() * e2.norm_squared() {
        let u = e1.normalize();
        let w = n.normalize();
        Some(Matrix3::from_columns(&[u, w.cross(&u), w]))
    } else {
        None
    }
}

/// The rigid motion taking the world triangle onto the camera one: orthonormal by
/// construction (frame to frame), where the paper's `Y·X⁻¹` is only as orthogonal as λ is exact.
fn pose_from_depths(world: &[Vector3<f64>; 3], bearings: &[Vector3<f64>; 3], lambda: &Vector3<f64>, world_frame: &Matrix3<f64>) -> Pose {
    let p = [bearings[0] * lambda.x, bearings[1] * lambda.y, bearings[2] * lambda.z];
    let camera_frame = frame(&(p[0] - p[1]), &(p[0] - p[2])).unwrap_or_else(Matrix3::identity);
    let r = camera_frame * world_frame.transpose();
    let centroid_cam = (p[0] + p[1] + p[2]) / 3.0;
    let centroid_obj = (world[0] + world[1] + world[2]) / 3.0;
    let rotation = Rotation3::from_matrix_unchecked(r);
    Pose::new(rotation, centroid_cam - rotation * centroid_obj)
}
