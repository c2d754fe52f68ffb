//! The second pose of a flat target. Seen from afar, a planar point set and its mirror image
//! through the plane perpendicular to the line of sight project alike: reprojection error has
//! two minima, and RANSAC + LM from a noisy minimal sample may settle in the wrong one (35°
//! off in the synthetic tests). The mirrored pose starts LM in the other basin; the caller
//! keeps whichever fits better. For a solid object the mirror is a poor pose and loses.

use nalgebra::{Matrix3, Rotation3};

use super::matches::Matches;
use super::spread::spread;
use crate::geometry::Pose;

/// `pose` with the inliers' best-fit plane reflected through the plane perpendicular to the
/// line of sight to their centroid, which stays put. `None` if there is no line of sight.
pub(crate) fn mirrored(m: &Matches, idx: &[usize], pose: &Pose) -> Option<Pose> {
    let s = spread(idx.iter().map(|&i| m.point(i)))?;
    let centre_cam = pose.rotation * s.mean + pose.translation;
    let view = centre_cam.try_normalize(1e-12)?;
    let normal = pose.rotation * s.axes[2];
    // Reflection through the view plane times reflection through the object plane: a
    // rotation (two reflections) that acts on the object plane as the view-plane mirror.
    let reflect = |a: &nalgebra::Vector3<f64>| Matrix3::identity() - a * a.transpose() * 2.0;
    let flip = Rotation3::from_matrix_unchecked(reflect(&view) * reflect(&normal));
    let rotation = flip * pose.rotation;
    Some(Pose::new(rotation, centre_cam - rotation * s.mean))
}
