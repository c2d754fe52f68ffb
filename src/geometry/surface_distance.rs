//! How far apart two poses put an object's surface: the largest displacement of its points
//! (BOP's MSSD between two poses), symmetry-aware when the object's symmetries are given.
//! The pipeline compares its own hypotheses with it; evaluation compares against the truth.

use super::Pose;
use nalgebra::Point3;

/// The largest displacement of any of `points` (object frame) between poses `a` and `b`, in
/// the unit of the points and translations.
pub fn max_displacement(a: &Pose, b: &Pose, points: &[[f32; 3]]) -> f64 {
    points
        .iter()
        .map(|v| {
            let p = Point3::new(v[0] as f64, v[1] as f64, v[2] as f64);
            (a.transform_point(&p) - b.transform_point(&p)).norm()
        })
        .fold(0.0, f64::max)
}

/// `b` turned by the symmetry (object-frame transformations, identity included) that brings
/// it closest to `a` by [`max_displacement`] over `points`; `b` itself without symmetries.
pub fn closest_symmetric(a: &Pose, b: &Pose, symmetries: &[Pose], points: &[[f32; 3]]) -> Pose {
    nearest_symmetric(a, b, symmetries, points).map_or(*b, |(pose, _)| pose)
}

/// [`max_displacement`] up to the object's symmetries: two poses that show the same object
/// the same way are 0 apart.
pub fn symmetric_distance(a: &Pose, b: &Pose, symmetries: &[Pose], points: &[[f32; 3]]) -> f64 {
    nearest_symmetric(a, b, symmetries, points).map_or_else(|| max_displacement(a, b, points), |(_, distance)| distance)
}

/// The turn of `b` nearest to `a` and its distance, each distance computed once (`None`
/// without symmetries).
fn nearest_symmetric(a: &Pose, b: &Pose, symmetries: &[Pose], points: &[[f32; 3]]) -> Option<(Pose, f64)> {
    symmetries
        .iter()
        .map(|s| {
            let turned = b.compose(s);
            (turned, max_displacement(a, &turned, points))
        })
        .min_by(|x, y| x.1.total_cmp(&y.1))
}

/// At most `n` of `points`, evenly strided (all of them when there are fewer): a surface
/// sample for distances that need not visit every vertex.
pub fn sample_points(points: &[[f32; 3]], n: usize) -> Vec<[f32; 3]> {
    let step = points.len().div_ceil(n.max(1)).max(1);
    points.iter().step_by(step).copied().collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Vector3};
    use std::f64::consts::PI;

    const ROD: [[f32; 3]; 2] = [[0.0, 0.0, -0.1], [0.0, 0.0, 0.1]];

    #[test]
    fn a_half_turned_rod_is_its_length_away_unless_the_half_turn_is_a_symmetry() {
        let a = Pose::new(Rotation3::identity(), Vector3::new(0.0, 0.0, 1.0));
        let half = Pose::new(Rotation3::from_axis_angle(&Vector3::x_axis(), PI), Vector3::zeros());
        let b = a.compose(&half);
        assert!((max_displacement(&a, &b, &ROD) - 0.2).abs() < 1e-6);
        assert!((symmetric_distance(&a, &b, &[Pose::identity()], &ROD) - 0.2).abs() < 1e-6);
        assert!(symmetric_distance(&a, &b, &[Pose::identity(), half], &ROD) < 1e-6);
        // A shift is a shift whatever the symmetries.
        let moved = Pose::new(a.rotation, a.translation + Vector3::new(0.03, 0.0, 0.0));
        assert!((symmetric_distance(&a, &moved, &[Pose::identity(), half], &ROD) - 0.03).abs() < 1e-6);
    }

    #[test]
    fn no_symmetries_leave_the_pose_as_it_is() {
        let a = Pose::identity();
        let b = Pose::new(Rotation3::from_euler_angles(0.1, 0.2, 0.3), Vector3::new(0.0, 0.01, 0.0));
        assert_eq!(closest_symmetric(&a, &b, &[], &ROD), b);
    }

    #[test]
    fn a_sample_strides_evenly_and_keeps_small_sets_whole() {
        let pts: Vec<[f32; 3]> = (0..10).map(|i| [i as f32, 0.0, 0.0]).collect();
        assert_eq!(sample_points(&pts, 5).len(), 5);
        assert_eq!(sample_points(&pts, 100).len(), 10);
        assert_eq!(sample_points(&pts, 0).len(), 1);
    }
}
