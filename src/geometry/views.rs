//! Template viewpoints: icosphere vertices (out-of-plane) × in-plane rotations about the
//! optical axis, each turned into a `T_cam_obj` that looks at the object's centre.

use super::pose::Pose;
use nalgebra::{Rotation3, Unit, Vector3};
use std::collections::HashMap;

/// Unit vectors of a subdivided icosahedron: 12, 42, 162, 642 vertices for levels 0–3.
pub fn icosphere(level: u32) -> Vec<Vector3<f64>> {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let mut verts: Vec<Vector3<f64>> = [
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ]
    .iter()
    .map(|v| Vector3::from(*v).normalize())
    .collect();
    let mut faces: Vec<[usize; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..level {
        let mut midpoint: HashMap<(usize, usize), usize> = HashMap::new();
        let mut mid = |a: usize, b: usize, verts: &mut Vec<Vector3<f64>>| {
            let key = (a.min(b), a.max(b));
            *midpoint.entry(key).or_insert_with(|| {
                verts.push(((verts[a] + verts[b]) * 0.5).normalize());
                verts.len() - 1
            })
        };
        let mut next = Vec::with_capacity(faces.len() * 4);
        for [a, b, c] in faces {
            let ab = mid(a, b, &mut verts);
            let bc = mid(b, c, &mut verts);
            let ca = mid(c, a, &mut verts);
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        faces = next;
    }
    verts
}

/// Rotation (object → camera) of a camera on the unit direction `dir` (from the object
/// centre towards the camera) looking at the centre, with a stable choice of "up".
pub fn look_at_rotation(dir: &Vector3<f64>) -> Rotation3<f64> {
    let z_cam = -dir.normalize(); // camera z axis (forward) expressed in the object frame
                                  // Object +z is "up" unless the camera looks along it; then fall back to +y.
    let up = if z_cam.z.abs() > 0.99 { Vector3::y() } else { Vector3::z() };
    let x_cam = z_cam.cross(&up).normalize(); // right, so that image y points "down"
    let y_cam = z_cam.cross(&x_cam);
    // Rows are the camera axes in object coordinates: R maps object vectors into the camera.
    let m = nalgebra::Matrix3::from_rows(&[x_cam.transpose(), y_cam.transpose(), z_cam.transpose()]);
    Rotation3::from_matrix_unchecked(m)
}

/// Rotation by `angle` radians about the camera's optical axis (+z), applied after the
/// view rotation: an image rotated about the principal point.
pub fn in_plane_rotation(angle: f64) -> Rotation3<f64> {
    Rotation3::from_axis_angle(&Unit::new_unchecked(Vector3::z()), angle)
}

/// Parameters of the template sphere. `level` 2 and 12 in-plane steps give 1944 templates.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ViewSampling {
    pub level: u32,
    pub in_plane_steps: u32,
}

impl Default for ViewSampling {
    fn default() -> Self {
        Self { level: 2, in_plane_steps: 12 }
    }
}

impl ViewSampling {
    pub fn validate(&self) -> Result<(), String> {
        if self.level > 3 {
            return Err(format!("icosphere level must be 0–3, got {}", self.level));
        }
        if self.in_plane_steps == 0 || self.in_plane_steps > 360 {
            return Err(format!("in-plane steps must be 1–360, got {}", self.in_plane_steps));
        }
        Ok(())
    }

    pub fn in_plane_angles(&self) -> Vec<f64> {
        (0..self.in_plane_steps).map(|k| k as f64 * std::f64::consts::TAU / self.in_plane_steps as f64).collect()
    }
}

/// Camera-to-object distance at which a sphere of `radius` about the object centre fills
/// `fill` of the narrower image half-extent for focal length `f` (pixels).
pub fn fitted_distance(radius: f64, f: f64, half_extent_px: f64, fill: f64) -> f64 {
    // The sphere's silhouette half-angle α satisfies sin α = r/d; its image radius is f·tan α.
    let tan_a = (half_extent_px * fill) / f;
    let sin_a = tan_a / (1.0 + tan_a * tan_a).sqrt();
    radius / sin_a
}

/// `T_cam_obj` for a view direction and in-plane angle that puts `centre` (object frame,
/// metres) on the optical axis at `distance` metres.
pub fn view_pose(dir: &Vector3<f64>, in_plane: f64, centre: &Vector3<f64>, distance: f64) -> Pose {
    let r = in_plane_rotation(in_plane) * look_at_rotation(dir);
    let t = Vector3::new(0.0, 0.0, distance) - r * centre;
    Pose::new(r, t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::pose::geodesic_distance;

    #[test]
    fn icosphere_vertex_counts() {
        let counts: Vec<usize> = (0..4).map(|l| icosphere(l).len()).collect();
        assert_eq!(counts, vec![12, 42, 162, 642]);
        assert!(icosphere(2).iter().all(|v| (v.norm() - 1.0).abs() < 1e-12));
    }

    #[test]
    fn view_pose_puts_centre_on_axis_and_camera_on_direction() {
        let centre = Vector3::new(0.01, -0.02, 0.03);
        for dir in icosphere(1) {
            for a in [0.0, 1.0, 4.0] {
                let p = view_pose(&dir, a, &centre, 0.5);
                let c = p.rotation * centre + p.translation;
                assert!((c - Vector3::new(0.0, 0.0, 0.5)).norm() < 1e-12);
                // The camera centre in object coordinates sits along `dir` from the centre.
                let cam = p.inverse().translation;
                assert!(((cam - centre).normalize() - dir).norm() < 1e-9);
                assert!((p.rotation.matrix().determinant() - 1.0).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn templates_cover_rotations() {
        // 1944 templates; every random rotation is within ~20° of some template.
        let dirs = icosphere(2);
        let s = ViewSampling::default();
        let rots: Vec<Rotation3<f64>> = dirs.iter().flat_map(|d| s.in_plane_angles().into_iter().map(move |a| in_plane_rotation(a) * look_at_rotation(d))).collect();
        assert_eq!(rots.len(), 1944);
        let mut worst: f64 = 0.0;
        for i in 0..50 {
            let q = Rotation3::from_euler_angles(i as f64 * 0.37, i as f64 * 1.13, i as f64 * 0.71);
            let best = rots.iter().map(|r| geodesic_distance(r, &q)).fold(f64::INFINITY, f64::min);
            worst = worst.max(best);
        }
        assert!(worst.to_degrees() < 20.0, "worst nearest-template distance {}°", worst.to_degrees());
    }

    #[test]
    fn fitted_distance_fills_image() {
        let d = fitted_distance(0.1, 500.0, 256.0, 0.8);
        // The tangent cone of the sphere projects to a circle of radius f·tan(asin(r/d)).
        let a = (0.1f64 / d).asin();
        assert!((500.0 * a.tan() - 256.0 * 0.8).abs() < 1e-9);
    }
}
