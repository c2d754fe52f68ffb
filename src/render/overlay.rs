//! Pictures for people: a mesh drawn at an estimated pose over the photo (tinted
//! silhouette, outline and object axes), to check by eye that an estimate lines up.

use super::{RenderError, RenderOptions, RenderPool};
use crate::depth::DepthImage;
use crate::geometry::{Intrinsics, Pose};
use crate::mesh::Mesh;
use image::{Rgb, RgbImage};
use nalgebra::{Point3, Vector3};

/// Draws `mesh` at `pose` over `photo`: the covered area tinted, its outline in `color`,
/// and the object's x (red), y (green), z (blue) axes from the bounding-box centre.
pub fn draw_overlay(photo: &RgbImage, renderer: &RenderPool, mesh: &Mesh, pose: &Pose, k: &Intrinsics, color: [u8; 3]) -> Result<RgbImage, RenderError> {
    draw_overlay_seen(photo, None, renderer, mesh, pose, k, color)
}

/// [`draw_overlay`], and with the camera's `depth` (registered to `photo`) where the
/// measured surface stands in front of the posed object, the object drawn as hidden there:
/// not tinted, its outline dashed. Otherwise a part behind a box or a hand is painted over
/// it, and the picture says nothing of what the depth saw.
pub fn draw_overlay_seen(photo: &RgbImage, depth: Option<&DepthImage>, renderer: &RenderPool, mesh: &Mesh, pose: &Pose, k: &Intrinsics, color: [u8; 3]) -> Result<RgbImage, RenderError> {
    let r = renderer.render(mesh, pose, k, &RenderOptions::default())?;
    let margin = hidden_margin(mesh.diameter());
    let hidden = |x: u32, y: u32| depth.is_some_and(|d| in_front(d.at(x, y), r.depth_at(x, y), margin));
    let mut out = photo.clone();
    let (w, h) = out.dimensions();
    for y in 0..h {
        for x in 0..w {
            if !r.is_foreground(x, y) {
                continue;
            }
            let behind = hidden(x, y);
            if !behind {
                let p = out.get_pixel_mut(x, y);
                for c in 0..3 {
                    p[c] = ((p[c] as u16 * 2 + color[c] as u16) / 3) as u8;
                }
            }
            let edge = [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)].iter().any(|(dx, dy)| {
                let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 || !r.is_foreground(nx as u32, ny as u32)
            });
            // A hidden stretch of the outline: dashes of 4 pixels.
            if edge && (!behind || (x + y) / 4 % 2 == 0) {
                draw_dot(&mut out, x as f64, y as f64, if behind { 0 } else { 1 }, color);
            }
        }
    }
    let c = Vector3::from(mesh.bbox_center());
    let len = 0.35 * mesh.diameter();
    let origin = pose.transform_point(&Point3::from(c));
    for (axis, col) in [(Vector3::x(), [255, 0, 0]), (Vector3::y(), [0, 255, 0]), (Vector3::z(), [0, 0, 255])] {
        let tip = pose.transform_point(&Point3::from(c + axis * len));
        if let (Some(a), Some(b)) = (k.project(&origin), k.project(&tip)) {
            draw_line(&mut out, (a.x, a.y), (b.x, b.y), 2, col);
        }
    }
    Ok(out)
}

fn draw_dot(img: &mut RgbImage, x: f64, y: f64, radius: i64, color: [u8; 3]) {
    let (w, h) = (img.width() as i64, img.height() as i64);
    let (cx, cy) = (x.round() as i64, y.round() as i64);
    for dy in -radius..=radius {
        for dx in -radius..=radius {
            let (px, py) = (cx + dx, cy + dy);
            if px >= 0 && py >= 0 && px < w && py < h {
                img.put_pixel(px as u32, py as u32, Rgb(color));
            }
        }
    }
}

/// How far in front of the posed surface a measurement must be to hide it: a tenth of the
/// object's diameter, at least 1 cm (a pose a little off, or the sensor's noise, is not an
/// occluder).
fn hidden_margin(diameter: f64) -> f32 {
    (0.1 * diameter).max(0.01) as f32
}

/// Whether `measured` metres (0: none) stand in front of `rendered` by more than `margin`.
fn in_front(measured: f32, rendered: f32, margin: f32) -> bool {
    measured > 0.0 && rendered > 0.0 && measured < rendered - margin
}

/// A thick line; segments far outside the image are clipped by the per-dot bounds check
/// (their length is capped so a point near the camera plane cannot stall the loop).
pub fn draw_line(img: &mut RgbImage, a: (f64, f64), b: (f64, f64), radius: i64, color: [u8; 3]) {
    let len = ((b.0 - a.0).powi(2) + (b.1 - a.1).powi(2)).sqrt().min(4.0 * (img.width() + img.height()) as f64);
    let steps = len.ceil().max(1.0) as usize;
    for i in 0..=steps {
        let t = i as f64 / steps as f64;
        draw_dot(img, a.0 + (b.0 - a.0) * t, a.1 + (b.1 - a.1) * t, radius, color);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_a_measurement_well_in_front_hides_the_object() {
        let m = hidden_margin(0.2);
        assert!((m - 0.02).abs() < 1e-6 && hidden_margin(0.05) == 0.01);
        assert!(in_front(0.70, 0.80, m), "a box 10 cm in front");
        assert!(!in_front(0.79, 0.80, m), "the object's own surface, a little off");
        assert!(!in_front(0.0, 0.80, m), "nothing measured there");
        assert!(!in_front(0.90, 0.80, m), "behind it");
    }

    /// A box half behind a wall the depth measured: tinted where seen, not where hidden.
    #[test]
    fn the_part_behind_a_measured_surface_is_not_tinted() {
        let Some(pool) = crate::render::tests::test_pool() else { return };
        let k = Intrinsics::new(500.0, 500.0, 80.0, 60.0, 160, 120).unwrap();
        let mesh = crate::mesh::procedural::textured_box([0.1; 3], 1);
        let pose = Pose::new(nalgebra::Rotation3::identity(), nalgebra::Vector3::new(0.0, 0.0, 0.6));
        let photo = RgbImage::from_pixel(160, 120, Rgb([0, 0, 0]));
        // A wall at 0.4 m over the image's left half; nothing measured on the right.
        let metres: Vec<f32> = (0..120 * 160).map(|i| if i % 160 < 80 { 0.4 } else { 0.0 }).collect();
        let depth = DepthImage::from_metres(160, 120, metres).unwrap();
        let seen = draw_overlay_seen(&photo, Some(&depth), &pool, &mesh, &pose, &k, [0, 255, 0]).unwrap();
        let all = draw_overlay(&photo, &pool, &mesh, &pose, &k, [0, 255, 0]).unwrap();
        // Inside the box's silhouette, away from its outline and the axes' lines.
        let (left, right) = ((60, 75), (100, 75));
        assert_eq!(seen.get_pixel(left.0, left.1)[1], 0, "hidden behind the wall: not tinted");
        assert!(all.get_pixel(left.0, left.1)[1] > 0, "without depth it is");
        assert!(seen.get_pixel(right.0, right.1)[1] > 0 && seen.get_pixel(right.0, right.1) == all.get_pixel(right.0, right.1), "seen part as before");
    }
}
