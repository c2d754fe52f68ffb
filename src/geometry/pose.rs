//! Rigid transforms `T_cam_obj` (object → camera, as BOP's `cam_R_m2c`/`cam_t_m2c`),
//! translations in metres.

use nalgebra::{Matrix3, Matrix4, Point3, Rotation3, Unit, Vector3};

#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Pose {
    pub rotation: Rotation3<f64>,
    /// Metres.
    pub translation: Vector3<f64>,
}

impl Pose {
    pub fn new(rotation: Rotation3<f64>, translation: Vector3<f64>) -> Self {
        Self { rotation, translation }
    }

    pub fn identity() -> Self {
        Self::new(Rotation3::identity(), Vector3::zeros())
    }

    /// From a row-major 3×3 rotation (re-orthonormalised) and a translation in metres.
    pub fn from_row_major(r: &[f64; 9], t: [f64; 3]) -> Self {
        let m = Matrix3::from_row_slice(r);
        Self::new(Rotation3::from_matrix(&m), Vector3::from(t))
    }

    pub fn rotation_row_major(&self) -> [f64; 9] {
        let m = self.rotation.matrix();
        [m[(0, 0)], m[(0, 1)], m[(0, 2)], m[(1, 0)], m[(1, 1)], m[(1, 2)], m[(2, 0)], m[(2, 1)], m[(2, 2)]]
    }

    pub fn transform_point(&self, p: &Point3<f64>) -> Point3<f64> {
        Point3::from(self.rotation * p.coords + self.translation)
    }

    pub fn inverse(&self) -> Self {
        let r = self.rotation.inverse();
        Self::new(r, -(r * self.translation))
    }

    /// `self ∘ other`: apply `other` first.
    pub fn compose(&self, other: &Pose) -> Self {
        Self::new(self.rotation * other.rotation, self.rotation * other.translation + self.translation)
    }

    /// This pose turned by `angle` (radians) about `axis`, a direction in the camera's frame,
    /// through the object point `centre` (which stays where it was in the camera's frame).
    pub fn turned_in_camera(&self, centre: &Vector3<f64>, axis: &Unit<Vector3<f64>>, angle: f64) -> Pose {
        let in_camera = self.rotation * centre + self.translation;
        let rotation = Rotation3::from_axis_angle(axis, angle) * self.rotation;
        Pose::new(rotation, in_camera - rotation * centre)
    }

    pub fn to_homogeneous(&self) -> Matrix4<f64> {
        let mut m = Matrix4::identity();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(self.rotation.matrix());
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.translation);
        m
    }
}

/// Geodesic distance between two rotations: the angle of `a⁻¹·b`, in radians, in [0, π].
pub fn geodesic_distance(a: &Rotation3<f64>, b: &Rotation3<f64>) -> f64 {
    let rel = a.inverse() * b;
    let cos = ((rel.matrix().trace() - 1.0) * 0.5).clamp(-1.0, 1.0);
    cos.acos()
}
