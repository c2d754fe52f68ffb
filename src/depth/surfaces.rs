//! Surfaces in a depth image: planes fitted to measured points (the table an object stands
//! on) and the pixels grouped into surfaces that no depth jump separates. Both the mask
//! proposal of one box (`masks::depth_proposal`) and the segmentation of a whole frame
//! (`detect::depth_segments`) are built from these.

use super::DepthImage;
use crate::geometry::Intrinsics;
use nalgebra::{Point3, Vector3};

/// Neighbours whose depths differ by more than this share of their depth (and
/// `MIN_JUMP_M`) are on different surfaces.
pub const JUMP_SHARE: f64 = 0.015;
pub const MIN_JUMP_M: f64 = 0.005;

/// A plane `n · p = d` with `n` towards the camera.
#[derive(Clone, Debug, PartialEq)]
pub struct Plane {
    pub normal: Vector3<f64>,
    pub offset: f64,
}

impl Plane {
    /// Signed distance of `p` from the plane, positive on the camera's side.
    pub fn above(&self, p: &Point3<f64>) -> f64 {
        self.normal.dot(&p.coords) - self.offset
    }

    /// Whether the surface through the four neighbours of a point (left, right, up, down)
    /// is turned like the plane (normals within about 35°); a missing neighbour says it is.
    /// Where an object's side meets the table its points lie on the plane but face elsewhere.
    pub fn faces_like(&self, [l, r, u, d]: [Option<Point3<f64>>; 4]) -> bool {
        let (Some(l), Some(r), Some(u), Some(d)) = (l, r, u, d) else { return true };
        match (r - l).cross(&(d - u)).try_normalize(1e-12) {
            Some(n) => n.dot(&self.normal).abs() > 0.8,
            None => true,
        }
    }
}

/// The plane most of `points` lie on (within `tolerance_m`), by RANSAC with a fixed seed
/// (the same answer for the same points), with the count of its inliers; None for fewer
/// than 30 points.
pub fn dominant_plane(points: &[Point3<f64>], tolerance_m: f64) -> Option<(Plane, usize)> {
    if points.len() < 30 {
        return None;
    }
    let mut seed = 0x9E37_79B9_7F4A_7C15u64;
    let mut pick = |n: usize| {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed % n as u64) as usize
    };
    let mut best: Option<(Plane, usize)> = None;
    for _ in 0..200 {
        let (a, b, c) = (points[pick(points.len())], points[pick(points.len())], points[pick(points.len())]);
        let Some(mut normal) = (b - a).cross(&(c - a)).try_normalize(1e-12) else { continue };
        if normal.dot(&a.coords) > 0.0 {
            normal = -normal;
        }
        let plane = Plane { offset: normal.dot(&a.coords), normal };
        let inliers = points.iter().filter(|p| plane.above(p).abs() < tolerance_m).count();
        if best.as_ref().is_none_or(|(_, n)| inliers > *n) {
            best = Some((plane, inliers));
        }
    }
    best
}

/// The measured point at pixel (x, y) of `depth`, None outside the image or unmeasured.
pub fn point_at(depth: &DepthImage, k: &Intrinsics, x: i64, y: i64) -> Option<Point3<f64>> {
    let z = depth.at(u32::try_from(x).ok()?, u32::try_from(y).ok()?) as f64;
    (z > 0.0).then(|| k.back_project(x as f64, y as f64, z))
}

/// Whether the point at pixel (x, y) belongs to something other than `plane`: off it by
/// more than `tolerance_m` on the camera's side or less than `behind_m` behind it, or near
/// it but facing elsewhere (checked `step` pixels around). Behind a support means under the
/// table (the floor past its edge), but a plane extended is not the surface itself: the
/// plane of a raised shelf at the back of a desk passes through the things on the desk in
/// front of it, a few centimetres below it, so a frame's segmentation lets `behind_m` be an
/// object's size.
pub fn off_plane(depth: &DepthImage, k: &Intrinsics, plane: &Plane, (x, y): (i64, i64), tolerance_m: f64, behind_m: f64, step: i64) -> bool {
    let Some(p) = point_at(depth, k, x, y) else { return false };
    let above = plane.above(&p);
    if above.abs() <= tolerance_m {
        let near = |dx: i64, dy: i64| point_at(depth, k, x + dx, y + dy);
        return !plane.faces_like([near(-step, 0), near(step, 0), near(0, -step), near(0, step)]);
    }
    above > 0.0 || -above < behind_m
}

/// 4-connected surfaces of the `member` cells of a `w × h` grid, split where neighbouring
/// depths (`z_at`, metres) jump; each cell's surface label, None for non-members.
pub fn surfaces(w: usize, h: usize, member: &[bool], z_at: &dyn Fn(usize, usize) -> f64) -> Vec<Option<usize>> {
    let mut label = vec![None; w * h];
    let mut stack = Vec::new();
    let mut next = 0;
    for start in 0..w * h {
        if label[start].is_some() || !member[start] {
            continue;
        }
        label[start] = Some(next);
        stack.push(start);
        while let Some(i) = stack.pop() {
            let (x, y) = (i % w, i / w);
            let z = z_at(x, y);
            let neighbours = [(x > 0).then(|| i - 1), (x + 1 < w).then(|| i + 1), (y > 0).then(|| i - w), (y + 1 < h).then(|| i + w)];
            for n in neighbours.into_iter().flatten() {
                if label[n].is_none() && member[n] && (z_at(n % w, n / w) - z).abs() < (JUMP_SHARE * z).max(MIN_JUMP_M) {
                    label[n] = Some(next);
                    stack.push(n);
                }
            }
        }
        next += 1;
    }
    label
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_plane_most_points_lie_on_is_found_facing_the_camera() {
        // A floor z = 1 + 0.5 y seen from above, and a few points off it.
        let mut pts: Vec<Point3<f64>> = (0..400).map(|i| Point3::new((i % 20) as f64 * 0.05, (i / 20) as f64 * 0.05, 0.0)).map(|p| Point3::new(p.x, p.y, 1.0 + 0.5 * p.y)).collect();
        pts.extend((0..50).map(|i| Point3::new(i as f64 * 0.01, 0.3, 0.6)));
        let (plane, inliers) = dominant_plane(&pts, 0.005).unwrap();
        assert_eq!(inliers, 400);
        assert!(plane.normal.z < 0.0, "normal {:?} must face the camera", plane.normal);
        assert!(plane.above(&Point3::new(0.1, 0.3, 0.6)) > 0.2);
        assert!(dominant_plane(&pts[..20], 0.005).is_none());
    }

    #[test]
    fn a_point_below_a_planes_extension_belongs_to_something_unless_far_below() {
        // A frontal plane at 1 m (offset -1 with the normal towards the camera) and a frame
        // whose left column is 3 cm behind it, middle 30 cm behind, right on it.
        let k = Intrinsics::new(100.0, 100.0, 1.5, 1.5, 3, 3).unwrap();
        let depth = DepthImage::from_metres(3, 3, (0..9).map(|i| [1.03, 1.3, 1.0][i % 3]).collect()).unwrap();
        let plane = Plane { normal: -Vector3::z(), offset: -1.0 };
        let off = |x: i64, behind_m: f64| off_plane(&depth, &k, &plane, (x, 1), 0.01, behind_m, 1);
        assert!(off(0, 0.2), "3 cm under a raised shelf's plane: a thing on the desk below it");
        assert!(!off(1, 0.2), "30 cm under it: the floor");
        assert!(!off(0, 0.01), "a box's proposal drops everything under its support");
        assert!(!off(2, 0.2), "on the plane and facing like it");
    }

    #[test]
    fn surfaces_split_where_depth_jumps_and_skip_non_members() {
        // Two flat patches at 1.0 m and 1.1 m side by side, and a column left out.
        let (w, h) = (10, 4);
        let z = |x: usize, _y: usize| if x < 5 { 1.0 } else { 1.1 };
        let member: Vec<bool> = (0..w * h).map(|i| i % w != 8).collect();
        let label = surfaces(w, h, &member, &z);
        assert_eq!(label[0], label[4 + 3 * w]);
        assert_ne!(label[4], label[5]);
        assert_eq!(label[8], None);
        assert_ne!(label[7], label[9], "the gap splits the far patch");
    }
}
