//! Colour samples from either side of the object's outline at a pose, read along the
//! contour model's normals (M3T's way of learning its histograms every frame from the
//! correspondence lines' pixels, with no render).

use crate::estimate::contour::lines::{camera_direction, project_rim_point, ProjectedRimPoint};
use crate::geometry::{Intrinsics, Pose};
use crate::onboard::ContourModel;
use image::RgbImage;
use nalgebra::Vector3;

/// Pixels nearer the outline than this (px) are left out on both sides: the projected
/// outline is a pixel or so off the true one, and edge pixels mix both colours.
const SKIP_PX: f64 = 1.5;

/// Each contour point of the view nearest `pose`, projected, with `reach_px` pixels read
/// inwards (object) and outwards (background) along its normal, as far as the object
/// (or the background before the object again) goes there. Pixels off the image are
/// skipped.
pub fn outline_samples(cm: &ContourModel, centre: &Vector3<f64>, pose: &Pose, k: &Intrinsics, image: &RgbImage, reach_px: f64) -> Vec<(image::Rgb<u8>, bool)> {
    let view = cm.nearest_view(&camera_direction(pose, centre));
    let mut out = Vec::new();
    for i in cm.view_range(view) {
        let Some(ProjectedRimPoint { centre: c, normal, px_per_m, .. }) = project_rim_point(cm, i, pose, k) else { continue };
        for (inside, extent_m) in [(true, cm.foreground_m[i]), (false, cm.background_m[i])] {
            let reach = reach_px.min(extent_m as f64 * px_per_m - SKIP_PX);
            let sign = if inside { -1.0 } else { 1.0 };
            let mut t = SKIP_PX;
            while t <= reach {
                let (u, v) = (c.x + sign * t * normal.x, c.y + sign * t * normal.y);
                if u >= 0.0 && v >= 0.0 && (u as u32) < image.width() && (v as u32) < image.height() {
                    out.push((*image.get_pixel(u as u32, v as u32), inside));
                }
                t += 1.0;
            }
        }
    }
    out
}
