//! A box's mask proposal from the depth camera: the surface inside the box split from what
//! lies behind it and beside it at depth discontinuities, with the support plane removed.
//!
//! Colour cuts inside a box take in clutter of the object's colours and miss faces of
//! other colours; depth separates an object from a printed table or a wall however alike
//! they look. The support plane (the table the object stands on) is found in a ring just
//! outside the box, where the object is not, so a large flat face of the object itself is
//! not taken for it; what lies on or behind it is dropped, and the rest of the box split
//! where neighbouring depths jump. The part that fills the box's centre most is the object.

use super::PixelBox;
use crate::depth::surfaces::{dominant_plane, off_plane, point_at, surfaces, Plane};
use crate::depth::DepthImage;
use crate::geometry::Intrinsics;
use image::{GrayImage, Luma};

/// Points off the plane by less than this (metres) lie on it.
const ON_PLANE_M: f64 = 0.008;

/// The object's mask inside `bbox` from `depth` (camera `k`), or None where the depth
/// shows too little inside the box.
pub fn depth_proposal(depth: &DepthImage, k: &Intrinsics, bbox: &PixelBox) -> Option<GrayImage> {
    let (w, h) = (depth.width(), depth.height());
    let plane = support_plane(depth, k, bbox);
    let (bw, bh) = ((bbox.x1 - bbox.x0) as usize, (bbox.y1 - bbox.y0) as usize);
    // Box pixels with a measurement that are not the support plane (or under it).
    let z_at = |x: usize, y: usize| depth.at(bbox.x0 + x as u32, bbox.y0 + y as u32) as f64;
    let member: Vec<bool> = (0..bw * bh)
        .map(|i| {
            let (x, y) = ((bbox.x0 as usize + i % bw) as i64, (bbox.y0 as usize + i / bw) as i64);
            match &plane {
                Some(plane) => off_plane(depth, k, plane, (x, y), ON_PLANE_M, ON_PLANE_M, 2),
                None => point_at(depth, k, x, y).is_some(),
            }
        })
        .collect();
    let label = surfaces(bw, bh, &member, &z_at);
    // The surface that fills the box's centre most (centre pixels count four times).
    let mut weight = vec![0.0f64; label.iter().flatten().max().map_or(0, |m| m + 1)];
    for (i, l) in label.iter().enumerate() {
        if let Some(l) = l {
            let (x, y) = (i % bw, i / bw);
            let central = x * 4 >= bw && x * 4 < bw * 3 && y * 4 >= bh && y * 4 < bh * 3;
            weight[*l] += if central { 4.0 } else { 1.0 };
        }
    }
    let (best, &score) = weight.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1))?;
    if score < 50.0 || score < 0.02 * (bw * bh) as f64 {
        return None;
    }
    let mut mask = GrayImage::new(w, h);
    for (i, l) in label.iter().enumerate() {
        if *l == Some(best) {
            mask.put_pixel(bbox.x0 + (i % bw) as u32, bbox.y0 + (i / bw) as u32, Luma([255]));
        }
    }
    Some(close_holes(mask, bbox))
}

/// The dominant plane of a ring around the box (a quarter of the box's larger side wide),
/// where it holds at least a third of the ring's measured points: RANSAC with a fixed seed.
fn support_plane(depth: &DepthImage, k: &Intrinsics, bbox: &PixelBox) -> Option<Plane> {
    let margin = ((bbox.x1 - bbox.x0).max(bbox.y1 - bbox.y0) / 4).max(4);
    let (x0, y0) = (bbox.x0.saturating_sub(margin), bbox.y0.saturating_sub(margin));
    let (x1, y1) = ((bbox.x1 + margin).min(depth.width()), (bbox.y1 + margin).min(depth.height()));
    let mut ring = Vec::new();
    for y in (y0..y1).step_by(2) {
        for x in (x0..x1).step_by(2) {
            let inside = x >= bbox.x0 && x < bbox.x1 && y >= bbox.y0 && y < bbox.y1;
            let z = depth.at(x, y);
            if !inside && z > 0.0 {
                ring.push(k.back_project(x as f64, y as f64, z as f64));
            }
        }
    }
    let (plane, inliers) = dominant_plane(&ring, ON_PLANE_M)?;
    (inliers * 3 >= ring.len()).then_some(plane)
}

/// The mask closed by two pixels inside the box: the depth's missing pixels (dark or
/// shiny spots, edges) within the object do not leave holes in its mask.
pub fn close_holes(mask: GrayImage, bbox: &PixelBox) -> GrayImage {
    let grow = |m: &GrayImage, set: bool| {
        let mut out = m.clone();
        for y in bbox.y0..bbox.y1 {
            for x in bbox.x0..bbox.x1 {
                let mut any = false;
                let mut all = true;
                for (dx, dy) in [(-2i32, 0i32), (2, 0), (0, -2), (0, 2), (-1, -1), (1, 1), (-1, 1), (1, -1)] {
                    let (nx, ny) = (x as i32 + dx, y as i32 + dy);
                    let v = nx >= bbox.x0 as i32 && ny >= bbox.y0 as i32 && nx < bbox.x1 as i32 && ny < bbox.y1 as i32 && m.get_pixel(nx as u32, ny as u32)[0] > 0;
                    any |= v;
                    all &= v;
                }
                let here = m.get_pixel(x, y)[0] > 0;
                let keep = if set { here || any } else { here && all };
                out.put_pixel(x, y, Luma([if keep { 255 } else { 0 }]));
            }
        }
        out
    };
    let dilated = grow(&mask, true);
    let closed = grow(&dilated, false);
    // Closing never takes away a pixel the surface held.
    let mut out = closed;
    for (o, m) in out.pixels_mut().zip(mask.pixels()) {
        if m[0] > 0 {
            *o = Luma([255]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A table tilted away from the camera, a 6 × 4 cm block standing on it at 0.6 m, and a
    /// wall far behind: the proposal is the block, without the table or the wall, even
    /// where the block has a hole in its depth.
    #[test]
    fn the_block_on_the_table_is_split_from_the_table_and_the_wall() {
        let (w, h) = (160u32, 120u32);
        let k = Intrinsics::new(200.0, 200.0, 80.0, 60.0, w, h).unwrap();
        // Table: the plane y = 0.08 (below the camera), seen up to 2 m.
        let table = |_x: u32, y: u32| {
            let ray_y = (y as f64 - k.cy) / k.fy;
            if ray_y > 0.0 {
                (0.08 / ray_y).min(2.0)
            } else {
                2.0
            }
        };
        let block = |x: u32, y: u32| {
            let (rx, ry) = ((x as f64 - k.cx) / k.fx, (y as f64 - k.cy) / k.fy);
            let z = 0.6;
            ((rx * z).abs() < 0.03 && ry * z > 0.04 && ry * z < 0.08).then_some(z)
        };
        let mut values = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let hole = (78..81).contains(&x) && (y as f64 - 60.0) * 0.6 / 200.0 > 0.06 && (y as f64 - 60.0) * 0.6 / 200.0 < 0.062;
                values.push(if hole { 0.0 } else { block(x, y).unwrap_or_else(|| table(x, y)) as f32 });
            }
        }
        let depth = DepthImage::from_metres(w, h, values).unwrap();
        let truth: Vec<(u32, u32)> = (0..h).flat_map(|y| (0..w).map(move |x| (x, y))).filter(|&(x, y)| block(x, y).is_some()).collect();
        let (xs, ys): (Vec<u32>, Vec<u32>) = truth.iter().copied().unzip();
        // A detector's box, a few pixels loose.
        let bbox = PixelBox { x0: xs.iter().min().unwrap() - 4, y0: ys.iter().min().unwrap() - 4, x1: xs.iter().max().unwrap() + 5, y1: (ys.iter().max().unwrap() + 5).min(h) };
        let mask = depth_proposal(&depth, &k, &bbox).expect("a proposal");
        let covered = truth.iter().filter(|&&(x, y)| mask.get_pixel(x, y)[0] > 0).count();
        let extra = mask.enumerate_pixels().filter(|(x, y, p)| p[0] > 0 && block(*x, *y).is_none()).count();
        // The rows where the block meets the table may go with it (the normals there mix).
        assert!(covered as f64 > 0.9 * truth.len() as f64, "{covered} of {}", truth.len());
        assert!((extra as f64) < 0.05 * truth.len() as f64, "{extra} pixels beside the block");
    }

    #[test]
    fn a_box_with_no_depth_proposes_nothing() {
        let k = Intrinsics::new(200.0, 200.0, 80.0, 60.0, 160, 120).unwrap();
        let depth = DepthImage::from_metres(160, 120, vec![0.0; 160 * 120]).unwrap();
        assert!(depth_proposal(&depth, &k, &PixelBox { x0: 40, y0: 30, x1: 120, y1: 90 }).is_none());
    }
}
