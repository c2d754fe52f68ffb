//! Pictures for people: a mesh drawn at an estimated pose over the photo (tinted
//! silhouette, outline and object axes), to check by eye that an estimate lines up.

use super::{RenderError, RenderOptions, RenderPool};
use crate::geometry::{Intrinsics, Pose};
use crate::mesh::Mesh;
use image::{Rgb, RgbImage};
use nalgebra::{Point3, Vector3};

/// Draws `mesh` at `pose` over `photo`: the covered area tinted, its outline in `color`,
/// and the object's x (red), y (green), z (blue) axes from the bounding-box centre.
pub fn draw_overlay(photo: &RgbImage, renderer: &RenderPool, mesh: &Mesh, pose: &Pose, k: &Intrinsics, color: [u8; 3]) -> Result<RgbImage, RenderError> {
    let r = renderer.render(mesh, pose, k, &RenderOptions::default())?;
    let mut out = photo.clone();
    let (w, h) = out.dimensions();
    for y in 0..h {
        for x in 0..w {
            if !r.is_foreground(x, y) {
                continue;
            }
            let p = out.get_pixel_mut(x, y);
            for c in 0..3 {
                p[c] = ((p[c] as u16 * 2 + color[c] as u16) / 3) as u8;
            }
            let edge = [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)].iter().any(|(dx, dy)| {
                let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 || !r.is_foreground(nx as u32, ny as u32)
            });
            if edge {
                draw_dot(&mut out, x as f64, y as f64, 1, color);
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
