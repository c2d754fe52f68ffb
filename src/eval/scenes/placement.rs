//! Random cameras and object poses: rotation uniform over SO(3), distance from the wanted
//! image fill, and a position that keeps the whole object inside the frame.

use super::config::SceneConfig;
use crate::geometry::{Intrinsics, Pose};
use crate::mesh::procedural::Rng;
use crate::mesh::Mesh;
use nalgebra::{Point3, Quaternion, Rotation3, UnitQuaternion, Vector3};

/// Per image: square pixels, focal from the configured range, principal point up to 1 % of
/// the size off centre (real calibrations never sit exactly on it, and a centred one would
/// hide a half-pixel or swapped-axis slip downstream).
pub(super) fn sample_intrinsics(cfg: &SceneConfig, rng: &mut Rng) -> Intrinsics {
    let (w, h) = cfg.image_size;
    let f = rng.range(cfg.focal_range.0, cfg.focal_range.1) * w as f64;
    let cx = (w as f64 - 1.0) * 0.5 + rng.range(-0.01, 0.01) * w as f64;
    let cy = (h as f64 - 1.0) * 0.5 + rng.range(-0.01, 0.01) * h as f64;
    Intrinsics::new(f, f, cx, cy, w, h).expect("validated config gives valid intrinsics")
}

/// A normalised 4D Gaussian is uniform on the unit quaternions, hence uniform over SO(3).
pub(super) fn random_rotation(rng: &mut Rng) -> Rotation3<f64> {
    loop {
        let q = Quaternion::new(rng.normal(), rng.normal(), rng.normal(), rng.normal());
        if q.norm() > 1e-6 {
            return UnitQuaternion::from_quaternion(q).to_rotation_matrix();
        }
    }
}

/// The sphere about the bounding-box centre that holds every vertex: whatever the
/// rotation, the object stays inside it, so framing can be decided before rendering.
#[derive(Clone, Copy, Debug)]
pub(super) struct Extent {
    pub centre: Vector3<f64>,
    pub radius: f64,
    pub diameter: f64,
}

impl Extent {
    pub fn of(mesh: &Mesh) -> Self {
        Self { centre: Vector3::from(mesh.bbox_center()), radius: mesh.bounding_radius(), diameter: mesh.diameter() }
    }
}

/// A candidate pose and its image footprint (projected centre and bounding-sphere radius).
#[derive(Clone, Copy, Debug)]
pub(super) struct Placement {
    pub pose: Pose,
    pub centre_px: (f64, f64),
    pub radius_px: f64,
}

impl Placement {
    /// Cheap pre-filter before rendering: footprints whose centres are closer than a share
    /// of their summed radii nearly always hide too much of one of them. The share shrinks
    /// with the visibility required, so permissive settings still allow deep overlaps.
    pub fn crowds(&self, other: &Placement, min_visible: f64) -> bool {
        let (dx, dy) = (self.centre_px.0 - other.centre_px.0, self.centre_px.1 - other.centre_px.1);
        (dx * dx + dy * dy).sqrt() < 0.7 * min_visible * (self.radius_px + other.radius_px)
    }
}

/// How far beside its neighbour a clustered object's image centre is drawn, as a share of
/// the two bounding circles' summed radii: below 1 the circles overlap, and since a
/// bounding circle is larger than the silhouette inside it, the objects then touch or
/// hide a little of each other (placements that hide too much are drawn again).
const BESIDE_DISTANCE: (f64, f64) = (0.55, 0.95);

/// An object whose diameter spans `fill` of the image height, randomly rotated, at a random
/// image position where its bounding sphere lies entirely inside the frame, or, given
/// `beside`, next to that placement in the image. `None` when the drawn position does not
/// fit (the caller draws again).
pub(super) fn sample_placement(ext: &Extent, k: &Intrinsics, fill: f64, beside: Option<&Placement>, rng: &mut Rng) -> Option<Placement> {
    let z = k.fy * ext.diameter / (fill * k.height as f64);
    let radius_px = k.fx.max(k.fy) * ext.radius / z;
    let (w, h) = (k.width as f64 - 1.0, k.height as f64 - 1.0);
    if 2.0 * radius_px >= w.min(h) {
        return None;
    }
    let (u, v) = match beside {
        None => (rng.range(radius_px, w - radius_px), rng.range(radius_px, h - radius_px)),
        Some(q) => {
            let angle = rng.range(0.0, std::f64::consts::TAU);
            let d = rng.range(BESIDE_DISTANCE.0, BESIDE_DISTANCE.1) * (q.radius_px + radius_px);
            let (u, v) = (q.centre_px.0 + d * angle.cos(), q.centre_px.1 + d * angle.sin());
            if u < radius_px || u > w - radius_px || v < radius_px || v > h - radius_px {
                return None;
            }
            (u, v)
        }
    };
    let centre = k.back_project(u, v, z);
    if !sphere_in_frame(&centre, ext.radius, k) {
        return None;
    }
    let rotation = random_rotation(rng);
    let pose = Pose::new(rotation, centre.coords - rotation * ext.centre);
    Some(Placement { pose, centre_px: (u, v), radius_px })
}

/// Pixel bounds `[u0, v0, u1, v1]` of a sphere's exact silhouette, `None` unless it lies
/// wholly in front of the camera. Per image axis, the extremes are where planes through the
/// camera centre touch the sphere: x = m·z with |c.x − m·c.z| = r·√(1 + m²), solved for m
/// (off-axis spheres project to ellipses wider than f·r/z, which a radius alone misses).
fn sphere_bounds(c: &Point3<f64>, r: f64, k: &Intrinsics) -> Option<[f64; 4]> {
    let den = c.z * c.z - r * r;
    if c.z <= 0.0 || den <= 0.0 {
        return None;
    }
    let extremes = |a: f64| {
        let s = r * (a * a + den).sqrt();
        ((a * c.z - s) / den, (a * c.z + s) / den)
    };
    let ((x0, x1), (y0, y1)) = (extremes(c.x), extremes(c.y));
    Some([k.fx * x0 + k.cx, k.fy * y0 + k.cy, k.fx * x1 + k.cx, k.fy * y1 + k.cy])
}

/// Pixel centres run from 0 to size − 1.
fn sphere_in_frame(c: &Point3<f64>, r: f64, k: &Intrinsics) -> bool {
    sphere_bounds(c, r, k).is_some_and(|[u0, v0, u1, v1]| u0 >= 0.0 && v0 >= 0.0 && u1 <= k.width as f64 - 1.0 && v1 <= k.height as f64 - 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::procedural::textured_box;

    #[test]
    fn rotations_are_spread_and_placements_fit() {
        let mut rng = Rng::new(3);
        // Uniform over SO(3): the rotated x axis has mean ≈ 0 in every coordinate.
        let mean = (0..4000).map(|_| random_rotation(&mut rng) * Vector3::x()).sum::<Vector3<f64>>() / 4000.0;
        assert!(mean.norm() < 0.05, "mean rotated axis {mean:?}");
        let mesh = textured_box([0.1, 0.06, 0.16], 1);
        let ext = Extent::of(&mesh);
        assert!((ext.radius - ext.diameter * 0.5).abs() < 1e-6, "a box's enclosing radius is half its diagonal");
        let k = sample_intrinsics(&SceneConfig::default(), &mut rng);
        let mut placed = 0;
        for _ in 0..200 {
            let Some(p) = sample_placement(&ext, &k, 0.3, None, &mut rng) else { continue };
            placed += 1;
            for v in mesh.positions() {
                let q = p.pose.transform_point(&Point3::new(v[0] as f64, v[1] as f64, v[2] as f64));
                let uv = k.project(&q).unwrap();
                assert!(uv.x >= 0.0 && uv.y >= 0.0 && uv.x <= 639.0 && uv.y <= 479.0, "vertex at {uv:?}");
            }
            // The diameter spans about 30 % of the height at the object's distance.
            let centre = p.pose.transform_point(&Point3::from(ext.centre));
            assert!((k.fy * ext.diameter / centre.z / 480.0 - 0.3).abs() < 1e-9);
        }
        assert!(placed > 100, "only {placed} of 200 placements fitted");
        // Beside a placement: centres at 0.55–0.95 of the summed radii, still in the frame.
        let first = (0..50).find_map(|_| sample_placement(&ext, &k, 0.2, None, &mut rng)).unwrap();
        let mut beside = 0;
        for _ in 0..200 {
            let Some(p) = sample_placement(&ext, &k, 0.2, Some(&first), &mut rng) else { continue };
            beside += 1;
            let d = ((p.centre_px.0 - first.centre_px.0).powi(2) + (p.centre_px.1 - first.centre_px.1).powi(2)).sqrt();
            let sum = p.radius_px + first.radius_px;
            assert!(d >= 0.55 * sum - 1e-9 && d <= 0.95 * sum + 1e-9, "{d} px apart for radii summing to {sum}");
            assert!(p.centre_px.0 >= p.radius_px && p.centre_px.0 <= 639.0 - p.radius_px);
        }
        assert!(beside > 20, "only {beside} of 200 placements beside the first fitted");
        // The silhouette bound is exact: points on the sphere reach it and never pass it.
        for c in [Point3::new(0.0, 0.0, 0.5), Point3::new(0.2, -0.15, 0.4), Point3::new(-0.3, 0.1, 0.35)] {
            let b = sphere_bounds(&c, 0.1, &k).unwrap();
            let mut seen = [f64::MAX, f64::MAX, f64::MIN, f64::MIN];
            for _ in 0..20000 {
                let d = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
                let uv = k.project(&(c + d * 0.1)).unwrap();
                seen = [seen[0].min(uv.x), seen[1].min(uv.y), seen[2].max(uv.x), seen[3].max(uv.y)];
            }
            for i in 0..4 {
                let inward = if i < 2 { seen[i] - b[i] } else { b[i] - seen[i] };
                assert!((-1e-9..0.5).contains(&inward), "bound {i}: {b:?} vs points {seen:?}");
            }
        }
    }
}
