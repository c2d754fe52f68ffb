//! Pose errors against ground truth. The errors themselves are symmetry-free; for a
//! symmetric object, measure against [`closest_symmetric`] truth, as BOP's MSSD does.

use crate::geometry::{geodesic_distance, Pose};
use nalgebra::Point3;

pub fn rotation_error_deg(est: &Pose, gt: &Pose) -> f64 {
    geodesic_distance(&est.rotation, &gt.rotation).to_degrees()
}

pub fn translation_error_m(est: &Pose, gt: &Pose) -> f64 {
    (est.translation - gt.translation).norm()
}

/// The truth turned by the symmetry (`symmetries`: model-frame transformations, identity
/// included) that brings it closest to `est`, by MSSD over `vertices` (a sample will do):
/// errors measured against it are BOP's symmetry-aware errors.
pub use crate::geometry::surface_distance::closest_symmetric;
/// Maximum symmetry-free surface distance: the largest displacement of a model vertex
/// between the two poses, metres (BOP's MSSD with the identity as the only symmetry).
pub use crate::geometry::surface_distance::max_displacement as mssd;
pub use crate::geometry::surface_distance::sample_points;

/// ADD: the mean displacement of the model's points between the two poses, metres.
pub fn add(est: &Pose, gt: &Pose, points: &[[f32; 3]]) -> f64 {
    let point = |v: &[f32; 3]| Point3::new(v[0] as f64, v[1] as f64, v[2] as f64);
    points.iter().map(|v| (est.transform_point(&point(v)) - gt.transform_point(&point(v))).norm()).sum::<f64>() / points.len().max(1) as f64
}

/// ADD-S: the mean distance from each point at the estimate to the nearest point at the
/// truth, metres (for symmetric objects). Quadratic in the points: pass a sample.
pub fn add_s(est: &Pose, gt: &Pose, points: &[[f32; 3]]) -> f64 {
    let point = |v: &[f32; 3]| Point3::new(v[0] as f64, v[1] as f64, v[2] as f64);
    let truth: Vec<Point3<f64>> = points.iter().map(|v| gt.transform_point(&point(v))).collect();
    let nearest = |p: Point3<f64>| truth.iter().map(|q| (p - q).norm_squared()).fold(f64::INFINITY, f64::min).sqrt();
    points.iter().map(|v| nearest(est.transform_point(&point(v)))).sum::<f64>() / points.len().max(1) as f64
}

/// Area under the accuracy–threshold curve for thresholds from 0 to `max` (normalised to
/// 0–1), the figure video pose trackers report for ADD and ADD-S (PoseCNN's convention,
/// `max` = 0.1 m). A missing pose is an infinite error.
pub fn auc(errors: &[f64], max: f64) -> f64 {
    if errors.is_empty() || max <= 0.0 {
        return 0.0;
    }
    // The curve is a step function; its integral is the mean of (max - e) over errors under max.
    errors.iter().filter(|e| **e < max).map(|e| (max - e.max(0.0)) / max).sum::<f64>() / errors.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Vector3};

    #[test]
    fn add_add_s_and_auc() {
        let gt = Pose::new(Rotation3::identity(), Vector3::new(0.0, 0.0, 1.0));
        let pts = [[0.1f32, 0.0, 0.0], [-0.1, 0.0, 0.0]];
        // A half-turn about y swaps the two points: ADD sees 0.2 m, ADD-S nothing.
        let flipped = Pose::new(Rotation3::from_axis_angle(&Vector3::y_axis(), std::f64::consts::PI), gt.translation);
        assert!((add(&flipped, &gt, &pts) - 0.2).abs() < 1e-6);
        assert!(add_s(&flipped, &gt, &pts) < 1e-6);
        let shifted = Pose::new(Rotation3::identity(), Vector3::new(0.0, 0.01, 1.0));
        assert!((add(&shifted, &gt, &pts) - 0.01).abs() < 1e-9 && (add_s(&shifted, &gt, &pts) - 0.01).abs() < 1e-9);
        // Errors 0 and 0.05 of max 0.1: areas 1 and 0.5; a miss adds a zero.
        assert!((auc(&[0.0, 0.05], 0.1) - 0.75).abs() < 1e-12);
        assert!((auc(&[0.0, 0.05, f64::INFINITY], 0.1) - 0.5).abs() < 1e-12);
        assert_eq!(auc(&[], 0.1), 0.0);
        assert_eq!(sample_points(&[[0.0; 3]; 10], 3).len(), 3);
        assert_eq!(sample_points(&[[0.0; 3]; 2], 1000).len(), 2);
    }

    #[test]
    fn known_errors() {
        let gt = Pose::new(Rotation3::identity(), Vector3::new(0.0, 0.0, 1.0));
        let shifted = Pose::new(Rotation3::identity(), Vector3::new(0.003, 0.004, 1.0));
        let verts = [[0.1f32, 0.0, 0.0], [-0.1, 0.0, 0.0]];
        assert!((translation_error_m(&shifted, &gt) - 0.005).abs() < 1e-12);
        assert!((mssd(&shifted, &gt, &verts) - 0.005).abs() < 1e-9);
        let turned = Pose::new(Rotation3::from_axis_angle(&Vector3::z_axis(), std::f64::consts::FRAC_PI_2), gt.translation);
        assert!((rotation_error_deg(&turned, &gt) - 90.0).abs() < 1e-9);
        // A vertex 0.1 m from the axis moves by 0.1·√2 under a 90° turn.
        assert!((mssd(&turned, &gt, &verts) - 0.1 * 2f64.sqrt()).abs() < 1e-6);
        assert_eq!(mssd(&gt, &gt, &verts), 0.0);
    }
}
