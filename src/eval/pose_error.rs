//! Pose errors against ground truth (no symmetries here; the BOP evaluation adds them).

use crate::geometry::{geodesic_distance, Pose};
use nalgebra::Point3;

pub fn rotation_error_deg(est: &Pose, gt: &Pose) -> f64 {
    geodesic_distance(&est.rotation, &gt.rotation).to_degrees()
}

pub fn translation_error_m(est: &Pose, gt: &Pose) -> f64 {
    (est.translation - gt.translation).norm()
}

/// Maximum symmetry-free surface distance: the largest displacement of a model vertex
/// between the two poses, metres (BOP's MSSD with the identity as the only symmetry).
pub fn mssd(est: &Pose, gt: &Pose, vertices: &[[f32; 3]]) -> f64 {
    vertices
        .iter()
        .map(|v| {
            let p = Point3::new(v[0] as f64, v[1] as f64, v[2] as f64);
            (est.transform_point(&p) - gt.transform_point(&p)).norm()
        })
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Vector3};

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
