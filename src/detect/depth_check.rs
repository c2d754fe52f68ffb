//! What the depth camera says of an object placed at a pose: the mesh rendered there and
//! its surface compared with the measured one, pixel by pixel over the silhouette, and the
//! segment the pose was estimated from compared with the silhouette. A wrong object fitted
//! to a segment shows in one of two ways: larger than the thing there, its silhouette
//! reaches where the camera sees the table behind it (seen through); smaller, it leaves
//! part of the segment uncovered. A right one agrees with the surface where nothing stands
//! in front of it (occluded pixels say nothing either way).

use crate::depth::DepthImage;
use crate::geometry::{Intrinsics, Pose};
use crate::mesh::Mesh;
use crate::render::{RenderError, RenderOptions, RenderPool};
use image::GrayImage;

/// Longer side of the window rendered for the comparison, pixels.
const WINDOW_PX: f64 = 160.0;

/// Shares of the silhouette's measured pixels, and of the segment's pixels covered.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct DepthAgreement {
    /// Measured within the tolerance of the rendered surface.
    pub agree: f32,
    /// Measured behind it: the camera sees through where the object would be.
    pub seen_through: f32,
    /// Measured in front of it: something stands between the camera and the object.
    pub occluded: f32,
    /// Share of the segment's pixels that the silhouette covers.
    pub covered: f32,
}

impl DepthAgreement {
    /// 0–1: the surface's agreement where it is not hidden, times the segment's coverage.
    /// An object hidden for the most part (less than a third of it in view) counts in
    /// proportion, so an estimate pushed behind a surface cannot pass as occluded.
    pub fn score(&self) -> f32 {
        let visible = self.agree + self.seen_through;
        if visible <= 0.0 {
            return 0.0;
        }
        let fit = self.agree / visible;
        fit * fit * self.covered * (visible / (1.0 / 3.0)).min(1.0)
    }
}

/// Inlier tolerance for an object of `diameter` metres: 5 % of it, within 10–20 mm
/// (sensor noise, and an estimate a few millimetres off).
fn tolerance(diameter: f64) -> f64 {
    (0.05 * diameter).clamp(0.01, 0.02)
}

/// `mesh` at `pose` against `depth` (full image, camera `k`), and against `segment`
/// (image-sized mask, 255 = the segment).
pub fn depth_agreement(depth: &DepthImage, k: &Intrinsics, mesh: &Mesh, pose: &Pose, segment: &GrayImage, renderer: &RenderPool) -> Result<DepthAgreement, RenderError> {
    let Some([x0, y0, x1, y1]) = window(k, mesh, pose, segment) else { return Ok(DepthAgreement::default()) };
    let s = (WINDOW_PX / (x1 - x0).max(y1 - y0)).min(1.0);
    let (w, h) = (((x1 - x0) * s).round().max(4.0) as u32, ((y1 - y0) * s).round().max(4.0) as u32);
    let (sx, sy) = (w as f64 / (x1 - x0), h as f64 / (y1 - y0));
    let camera = Intrinsics { fx: k.fx * sx, fy: k.fy * sy, cx: (k.cx - x0 + 0.5) * sx - 0.5, cy: (k.cy - y0 + 0.5) * sy - 0.5, width: w, height: h };
    let render = renderer.render(mesh, pose, &camera, &RenderOptions::grey())?;
    let tol = tolerance(mesh.diameter()) as f32;
    let (mut agree, mut through, mut occluded, mut in_segment, mut segment_covered) = (0usize, 0usize, 0usize, 0usize, 0usize);
    for j in 0..h {
        for i in 0..w {
            // Window pixel (i, j) sits at image pixel x0 + (i + ½)/s − ½.
            let (u, v) = (x0 + (i as f64 + 0.5) / sx - 0.5, y0 + (j as f64 + 0.5) / sy - 0.5);
            let rendered = render.depth_at(i, j);
            let (xu, yv) = (u.round(), v.round());
            let on_segment = xu >= 0.0 && yv >= 0.0 && segment.get_pixel_checked(xu as u32, yv as u32).is_some_and(|p| p[0] > 0);
            if on_segment {
                in_segment += 1;
                segment_covered += (rendered > 0.0) as usize;
            }
            if rendered <= 0.0 {
                continue;
            }
            let measured = depth.nearest(u, v);
            if measured <= 0.0 {
                continue;
            }
            if measured < rendered - tol {
                occluded += 1;
            } else if measured > rendered + tol {
                through += 1;
            } else {
                agree += 1;
            }
        }
    }
    let measured = (agree + through + occluded).max(1) as f32;
    Ok(DepthAgreement {
        agree: agree as f32 / measured,
        seen_through: through as f32 / measured,
        occluded: occluded as f32 / measured,
        covered: if in_segment == 0 { 0.0 } else { segment_covered as f32 / in_segment as f32 },
    })
}

/// [x0, y0, x1, y1] in image pixels holding the segment and the object's bounding sphere
/// at `pose`, clipped to the image; None when nothing of either is in it.
fn window(k: &Intrinsics, mesh: &Mesh, pose: &Pose, segment: &GrayImage) -> Option<[f64; 4]> {
    let mut b = super::detector::bbox_of(segment).map(|b| [b[0], b[1], b[0] + b[2], b[1] + b[3]]);
    let centre = pose.transform_point(&nalgebra::Point3::from(nalgebra::Vector3::from(mesh.bbox_center())));
    if centre.z > 1e-6 {
        let (r, f) = (mesh.bounding_radius(), k.fx.max(k.fy));
        let (u, v, rad) = (k.fx * centre.x / centre.z + k.cx, k.fy * centre.y / centre.z + k.cy, f * r / (centre.z - r).max(0.5 * centre.z));
        let sphere = [u - rad, v - rad, u + rad, v + rad];
        b = Some(match b {
            Some(s) => [s[0].min(sphere[0]), s[1].min(sphere[1]), s[2].max(sphere[2]), s[3].max(sphere[3])],
            None => sphere,
        });
    }
    let b = b?;
    let clipped = [b[0].max(0.0).floor(), b[1].max(0.0).floor(), b[2].min(k.width as f64).ceil(), b[3].min(k.height as f64).ceil()];
    (clipped[2] - clipped[0] >= 2.0 && clipped[3] - clipped[1] >= 2.0).then_some(clipped)
}
