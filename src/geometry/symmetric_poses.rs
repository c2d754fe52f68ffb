//! Whether two poses of an object are the same pose up to one of its symmetries: a pose
//! turned by a symmetry shows the same image, so verification need not refine and render
//! both.

use super::symmetry::{symmetry_transformations, ObjectSymmetries};
use super::{geodesic_distance, Pose};
use nalgebra::{Point3, Unit, Vector3};

/// Rotation within which two poses count as the same, radians (1°).
const SAME_ROTATION: f64 = 1.0 * std::f64::consts::PI / 180.0;
/// Distance within which two poses place the object at the same spot, share of its diameter.
const SAME_PLACE: f64 = 0.01;

/// An object's symmetries, ready for comparing poses.
#[derive(Clone, Debug)]
pub struct SymmetricPoses {
    /// The identity and the discrete symmetries (model frame, metres).
    discrete: Vec<Pose>,
    /// A continuous symmetry's axis and a point on it (model frame, metres).
    axis: Option<(Unit<Vector3<f64>>, Point3<f64>)>,
    place_tolerance: f64,
}

impl SymmetricPoses {
    /// `None` when the object has no symmetry (every pose is its own class).
    pub fn new(symmetries: &ObjectSymmetries, diameter: f64) -> Option<Self> {
        if symmetries.is_empty() {
            return None;
        }
        let discrete = symmetry_transformations(&symmetries.discrete, &[], 1.0).ok()?;
        let axis = symmetries.continuous.first().and_then(|c| Some((Unit::try_new(Vector3::from(c.axis), 1e-12)?, Point3::from(c.offset))));
        Some(Self { discrete, axis, place_tolerance: SAME_PLACE * diameter })
    }

    /// Whether `b` is `a` up to a symmetry: `b ≈ a ∘ S` for some discrete `S` (with a
    /// continuous axis: up to any turn about it, so only the axis's image and a point on it
    /// are compared).
    pub fn same(&self, a: &Pose, b: &Pose) -> bool {
        self.discrete.iter().any(|s| {
            let turned = a.compose(s);
            match &self.axis {
                None => geodesic_distance(&turned.rotation, &b.rotation) < SAME_ROTATION && (turned.translation - b.translation).norm() < self.place_tolerance,
                Some((axis, point)) => {
                    let (da, db) = (turned.rotation * axis.into_inner(), b.rotation * axis.into_inner());
                    da.angle(&db) < SAME_ROTATION && (turned.transform_point(point) - b.transform_point(point)).norm() < self.place_tolerance
                }
            }
        })
    }

    /// `poses` without those that repeat an earlier one up to a symmetry (the first of each
    /// class is kept, so order them best first).
    pub fn distinct<T>(&self, items: Vec<T>, pose: impl Fn(&T) -> &Pose) -> Vec<T> {
        let mut kept: Vec<T> = Vec::with_capacity(items.len());
        for item in items {
            if !kept.iter().any(|k| self.same(pose(k), pose(&item))) {
                kept.push(item);
            }
        }
        kept
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::symmetry::{ContinuousSymmetry, DiscreteSymmetry};
    use nalgebra::Rotation3;

    fn at(rotation: Rotation3<f64>) -> Pose {
        Pose::new(rotation, Vector3::new(0.0, 0.0, 0.5))
    }

    #[test]
    fn a_half_turn_symmetry_makes_the_turned_pose_the_same() {
        let half_z = DiscreteSymmetry::from_pose(&Pose::new(Rotation3::from_axis_angle(&Vector3::z_axis(), std::f64::consts::PI), Vector3::zeros()));
        let s = SymmetricPoses::new(&ObjectSymmetries { discrete: vec![half_z], continuous: vec![] }, 0.2).unwrap();
        let a = at(Rotation3::from_euler_angles(0.3, -0.2, 0.1));
        let turned = a.compose(&Pose::new(Rotation3::from_axis_angle(&Vector3::z_axis(), std::f64::consts::PI + 0.01), Vector3::zeros()));
        let quarter = a.compose(&Pose::new(Rotation3::from_axis_angle(&Vector3::z_axis(), std::f64::consts::FRAC_PI_2), Vector3::zeros()));
        assert!(s.same(&a, &turned));
        assert!(!s.same(&a, &quarter));
        let moved = Pose::new(a.rotation, a.translation + Vector3::new(0.05, 0.0, 0.0));
        assert!(!s.same(&a, &moved), "5 cm away is another pose of a 20 cm object");
        let tilted = a.compose(&Pose::new(Rotation3::from_axis_angle(&Vector3::x_axis(), 0.05), Vector3::zeros()));
        assert!(!s.same(&a, &tilted), "3° is another pose");
    }

    #[test]
    fn a_continuous_axis_makes_every_turn_about_it_the_same() {
        let c = ContinuousSymmetry { axis: [0.0, 0.0, 1.0], offset: [0.0, 0.0, 0.0] };
        let s = SymmetricPoses::new(&ObjectSymmetries { discrete: vec![], continuous: vec![c] }, 0.1).unwrap();
        let a = at(Rotation3::from_euler_angles(0.4, 0.1, -0.3));
        let spun = a.compose(&Pose::new(Rotation3::from_axis_angle(&Vector3::z_axis(), 1.234), Vector3::zeros()));
        let tilted = a.compose(&Pose::new(Rotation3::from_axis_angle(&Vector3::x_axis(), 0.5), Vector3::zeros()));
        assert!(s.same(&a, &spun));
        assert!(!s.same(&a, &tilted));
        let kept = s.distinct(vec![a, spun, tilted], |p| p);
        assert_eq!(kept.len(), 2);
    }

    #[test]
    fn no_symmetry_compares_nothing() {
        assert!(SymmetricPoses::new(&ObjectSymmetries::default(), 0.1).is_none());
    }
}
