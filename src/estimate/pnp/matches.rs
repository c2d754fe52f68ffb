//! The matches as every stage wants them: image points moved once to the normalised image
//! plane, so that scoring a hypothesis against hundreds of matches costs no division, and
//! reprojection errors still come out in pixels (anisotropic focal lengths included).

use nalgebra::{Matrix3, Vector3};

use crate::geometry::{Intrinsics, Pose};

pub(crate) struct Matches<'a> {
    pub(crate) object: &'a [[f64; 3]],
    /// `((u − cx)/fx, (v − cy)/fy)` per match.
    pub(crate) normalised: Vec<[f64; 2]>,
    pub(crate) fx: f64,
    pub(crate) fy: f64,
    threshold_sq: f64,
}

impl<'a> Matches<'a> {
    pub(crate) fn new(image: &[[f64; 2]], object: &'a [[f64; 3]], k: &Intrinsics, threshold_px: f64) -> Self {
        let normalised = image.iter().map(|p| [(p[0] - k.cx) / k.fx, (p[1] - k.cy) / k.fy]).collect();
        Self { object, normalised, fx: k.fx, fy: k.fy, threshold_sq: threshold_px * threshold_px }
    }

    pub(crate) fn len(&self) -> usize {
        self.object.len()
    }

    pub(crate) fn point(&self, i: usize) -> Vector3<f64> {
        Vector3::from(self.object[i])
    }

    /// Unit ray through image point `i`, camera frame.
    pub(crate) fn bearing(&self, i: usize) -> Vector3<f64> {
        let [x, y] = self.normalised[i];
        Vector3::new(x, y, 1.0).normalize()
    }

    /// Squared pixel error of match `i` for camera-frame point `p`, scaled by `p.z²`:
    /// comparing it with `threshold² · z²` avoids the division. Only meaningful for `p.z > 0`.
    #[inline(always)]
    fn scaled_error_sq(&self, i: usize, p: &Vector3<f64>) -> f64 {
        let [x, y] = self.normalised[i];
        let ex = p.x - x * p.z;
        let ey = p.y - y * p.z;
        self.fx * self.fx * ex * ex + self.fy * self.fy * ey * ey
    }

    #[inline(always)]
    pub(crate) fn is_inlier(&self, i: usize, r: &Matrix3<f64>, t: &Vector3<f64>) -> bool {
        let p = r * self.point(i) + t;
        // Behind (or on) the camera plane is an outlier whatever it reprojects to.
        p.z > 0.0 && self.scaled_error_sq(i, &p) < self.threshold_sq * p.z * p.z
    }

    /// MSAC score: Σ min(error², threshold²) over all matches, behind-camera ones at the cap.
    /// Ranks poses by fit as well as support, for choosing between refined candidates.
    pub(crate) fn truncated_cost(&self, pose: &Pose) -> f64 {
        let r = pose.rotation.matrix();
        (0..self.len())
            .map(|i| {
                let p = r * self.point(i) + pose.translation;
                if p.z <= 0.0 {
                    self.threshold_sq
                } else {
                    (self.scaled_error_sq(i, &p) / (p.z * p.z)).min(self.threshold_sq)
                }
            })
            .sum()
    }

    pub(crate) fn inliers(&self, pose: &Pose) -> Vec<usize> {
        let r = pose.rotation.matrix();
        (0..self.len()).filter(|&i| self.is_inlier(i, r, &pose.translation)).collect()
    }

    /// Mean Euclidean reprojection error over `idx`, pixels (∞ if one is behind the camera).
    pub(crate) fn mean_error_px(&self, pose: &Pose, idx: &[usize]) -> f64 {
        if idx.is_empty() {
            return 0.0;
        }
        let sum: f64 = idx
            .iter()
            .map(|&i| {
                let p = pose.transform_point(&self.point(i).into()).coords;
                if p.z <= 0.0 {
                    f64::INFINITY
                } else {
                    self.scaled_error_sq(i, &p).sqrt() / p.z
                }
            })
            .sum();
        sum / idx.len() as f64
    }
}
