//! Closed-form algebra for the P3P solver: polynomial roots and the eigen-pairs of a singular
//! symmetric 3×3. Written out because nalgebra's general eigen-solver iterates, at several
//! times the cost, and P3P runs hundreds of times per call.

use nalgebra::{Matrix3, Vector3};

/// Rows r0, r1, r2 → adjugate with columns r1×r2, r2×r0, r0×r1.
pub(crate) fn adjugate(m: &Matrix3<f64>) -> Matrix3<f64> {
    let (r0, r1, r2) = (m.row(0).transpose(), m.row(1).transpose(), m.row(2).transpose());
    Matrix3::from_columns(&[r1.cross(&r2), r2.cross(&r0), r0.cross(&r1)])
}

/// One real root of g³ + b·g² + c·g + d. Newton from the quadratic model beside the outer
/// stationary point converges to an extreme root, whatever the spacing of the others.
pub(crate) fn cubic_root(b: f64, c: f64, d: f64) -> f64 {
    let h = |x: f64| ((x + b) * x + c) * x + d;
    let dh = |x: f64| (3.0 * x + 2.0 * b) * x + c;
    let disc = b * b - 3.0 * c;
    let mut x = if disc > 0.0 {
        let s = disc.sqrt();
        let left = (-b - s) / 3.0; // local maximum
        let hl = h(left);
        if hl > 0.0 {
            left - (hl / s).sqrt()
        } else {
            let right = (-b + s) / 3.0; // local minimum
            right + (-h(right) / s).max(0.0).sqrt()
        }
    } else {
        // Monotone: Newton from the inflection point cannot overshoot into a wrong basin.
        let x = -b / 3.0;
        if dh(x).abs() < 1e-4 {
            x + 1.0
        } else {
            x
        }
    };
    // Convergence is quadratic: after a step of 1e-9 the error left is ~1e-18, so stop there
    // rather than wait for |h| to reach a fixed tolerance it may never reach.
    for _ in 0..50 {
        let df = dh(x);
        if df == 0.0 {
            break;
        }
        let step = h(x) / df;
        x -= step;
        if step.abs() <= 1e-9 * x.abs().max(1.0) {
            break;
        }
    }
    x
}

/// Eigen-pairs of a symmetric 3×3 known to be singular: the two others, largest magnitude first.
pub(crate) fn eigen_known_zero(a: &Matrix3<f64>) -> Option<(f64, Vector3<f64>, f64, Vector3<f64>)> {
    // λ² − tr·λ + (sum of principal 2×2 minors) = 0.
    let tr = a.trace();
    let minors = a[(0, 0)] * a[(1, 1)] - a[(0, 1)] * a[(1, 0)] + a[(0, 0)] * a[(2, 2)] - a[(0, 2)] * a[(2, 0)] + a[(1, 1)] * a[(2, 2)] - a[(1, 2)] * a[(2, 1)];
    let [e0, e1] = quadratic_roots(1.0, -tr, minors);
    let (mut e0, mut e1) = (e0?, e1?);
    if e0.abs() < e1.abs() {
        std::mem::swap(&mut e0, &mut e1);
    }
    if e0.abs() > 1e-14 {
        Some((e0, null_vector(&(a - Matrix3::identity() * e0))?, e1, null_vector(&(a - Matrix3::identity() * e1))?))
    } else {
        None
    }
}

/// Unit vector spanning the null space of a rank-2 matrix: the best-conditioned cross product
/// of two of its rows.
fn null_vector(m: &Matrix3<f64>) -> Option<Vector3<f64>> {
    let (r0, r1, r2) = (m.row(0).transpose(), m.row(1).transpose(), m.row(2).transpose());
    let mut best = r0.cross(&r1);
    for v in [r0.cross(&r2), r1.cross(&r2)] {
        if v.norm_squared() > best.norm_squared() {
            best = v;
        }
    }
    best.try_normalize(1e-150)
}

/// Real roots of a·x² + b·x + c (a may be 0), cancellation-free.
pub(crate) fn quadratic_roots(a: f64, b: f64, c: f64) -> [Option<f64>; 2] {
    if a == 0.0 {
        return [(b != 0.0).then(|| -c / b), None];
    }
    let disc = b * b - 4.0 * a * c;
    if disc < 0.0 {
        return [None, None];
    }
    let q = -0.5 * (b + b.signum() * disc.sqrt());
    if q == 0.0 {
        return [Some(0.0), Some(0.0)];
    }
    [Some(q / a), Some(c / q)]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cubic_root_is_a_root() {
        // Three real roots (1, 2, −3), one real root, and a triple root.
        for (b, c, d) in [(0.0, -7.0, 6.0), (1.0, 1.0, 1.0), (-3.0, 3.0, -1.0), (4.0, -1e-6, 3.0)] {
            let x = cubic_root(b, c, d);
            let h = ((x + b) * x + c) * x + d;
            assert!(h.abs() < 1e-9, "x³ + {b}x² + {c}x + {d} at {x} = {h}");
        }
    }

    #[test]
    fn adjugate_times_matrix_is_determinant() {
        let m = Matrix3::new(2.0, -1.0, 0.5, 0.3, 4.0, -2.0, 1.0, 0.0, 3.0);
        assert!((adjugate(&m) * m - Matrix3::identity() * m.determinant()).norm() < 1e-12);
    }

    #[test]
    fn eigen_pairs_of_a_singular_symmetric_matrix() {
        let (u, v) = (Vector3::new(1.0, 2.0, 2.0) / 3.0, Vector3::new(2.0, -2.0, 1.0) / 3.0);
        let a = u * u.transpose() * -5.0 + v * v.transpose() * 2.0;
        let (l0, v0, l1, v1) = eigen_known_zero(&a).unwrap();
        assert!((l0 + 5.0).abs() < 1e-12 && (l1 - 2.0).abs() < 1e-12);
        assert!((v0.dot(&u).abs() - 1.0).abs() < 1e-12 && (v1.dot(&v).abs() - 1.0).abs() < 1e-12);
    }
}
