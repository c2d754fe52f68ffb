//! A depth frame cut into the things that stand in it: the large planes (the table, the
//! floor, a wall) removed, the rest grouped into surfaces that no depth jump separates,
//! each with its size in metres. Clutter can paint an object's outline and colours into
//! the photo but not a surface of the object's size standing off the table, so these
//! segments are where the depth detector (`depth_detector`) looks.

use super::segment_cuts::{group_by_surface, neighbouring_pairs, split_at_necks, split_by_depth, MIN_PIXELS};
use crate::depth::surfaces::{dominant_plane, off_plane, point_at, surfaces, Plane};
use crate::depth::DepthImage;
use crate::geometry::Intrinsics;
use crate::masks::depth_proposal::close_holes;
use crate::masks::PixelBox;
use image::{GrayImage, Luma};
use nalgebra::{Matrix3, Point3, SymmetricEigen, Vector3};

/// Points within this of a plane (metres) lie on it.
const ON_PLANE_M: f64 = 0.01;
/// A plane holding at least this share of the frame's measured points, and spreading
/// wider than `PLANE_OVER_OBJECT` × the largest object looked for, is a support (or a
/// wall), never an object's face; at most `MAX_PLANES` are taken away.
const MIN_PLANE_SHARE: f64 = 0.12;
const MAX_PLANES: usize = 3;
const PLANE_OVER_OBJECT: f64 = 1.5;
/// Planes are fitted to every `PLANE_STEP`-th pixel in x and y.
const PLANE_STEP: usize = 4;

/// One surface standing in the frame.
#[derive(Clone, Debug)]
pub struct Segment {
    /// Image-sized, 255 = the segment (small depth holes inside it closed).
    pub mask: GrayImage,
    /// [x, y, w, h] in pixels.
    pub bbox: [f64; 4],
    /// Measured pixels in it.
    pub pixels: usize,
    /// Its size, metres: the diagonal of its points' spread along their principal axes
    /// (2nd to 98th percentile), so a few stray pixels at its edges do not count.
    pub extent_m: f64,
    /// Its span, metres: the largest distance between two of its points, once those
    /// outside the 2nd to 98th percentile along any principal axis are set aside. What an
    /// object's diameter bounds: the box diagonal (`extent_m`) of a rounded thing's view
    /// runs past its diameter (a whole mug's view: about 170 mm against 125 mm).
    pub span_m: f64,
    /// Mean of its points, camera frame, metres.
    pub centre: Point3<f64>,
    /// Median depth of its pixels, metres.
    pub median_z: f64,
    /// How solid it is: its pixels over its extent squared in pixels at its depth. The
    /// surface of a solid thing fills a good part of the square on its diagonal (a disc
    /// about 0.4, a 4 : 1 rectangle 0.24); a cable, a rim or sensor noise along furniture
    /// edges spreads as far over few pixels (0.05–0.15 on the real frames).
    pub fill: f64,
}

/// What the segmentation found: the segments, largest first, and the planes taken away.
pub struct Segmentation {
    pub segments: Vec<Segment>,
    pub planes: Vec<Plane>,
}

/// The frame's segments (camera `k`, registered to `depth`), for objects of at most
/// `largest_m` across (a flat face of one is never taken for the table); a segment whose
/// extent passes `too_large_m` (larger than any object can look) is also offered cut at
/// its depths and at its necks, and neighbouring surfaces joined in pairs (`segment_cuts`).
pub fn segment_frame(depth: &DepthImage, k: &Intrinsics, largest_m: f64, too_large_m: f64) -> Segmentation {
    let (w, h) = (depth.width() as usize, depth.height() as usize);
    let planes = support_planes(depth, k, PLANE_OVER_OBJECT * largest_m);
    let member: Vec<bool> = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as i64, (i / w) as i64);
            point_at(depth, k, x, y).is_some() && planes.iter().all(|p| off_plane(depth, k, p, (x, y), ON_PLANE_M, largest_m, 2))
        })
        .collect();
    let label = surfaces(w, h, &member, &|x, y| depth.at(x as u32, y as u32) as f64);
    let members = group_by_surface(&label, 0..w * h);
    let mut segments: Vec<Segment> = Vec::new();
    // The pieces joined in pairs: the surfaces that can be an object, with the parts cut
    // from those that cannot, once at their depths and once at their necks (the two cuts
    // overlap; the parts of one cut share no pixel, as `neighbouring_pairs` needs).
    let mut primaries: Vec<Vec<usize>> = Vec::new();
    let (mut depth_parts, mut neck_parts): (Vec<Vec<usize>>, Vec<Vec<usize>>) = (Vec::new(), Vec::new());
    for m in members.into_iter().filter(|m| m.len() >= MIN_PIXELS) {
        let Some(whole) = describe(depth, k, &m) else { continue };
        if whole.extent_m > too_large_m {
            let (by_depth, at_necks) = (split_by_depth(depth, &m), split_at_necks(w, h, &m));
            segments.extend(by_depth.iter().chain(&at_necks).filter_map(|part| describe(depth, k, part)));
            depth_parts.extend(by_depth);
            neck_parts.extend(at_necks);
        } else {
            primaries.push(m);
        }
        segments.push(whole);
    }
    let first_part = primaries.len();
    for (round, parts) in [depth_parts, neck_parts].into_iter().enumerate() {
        let pieces: Vec<&[usize]> = primaries.iter().chain(&parts).map(Vec::as_slice).collect();
        // Pairs of two primaries are the same in both rounds: joined in the first only.
        for (a, b) in neighbouring_pairs(w, h, &pieces).into_iter().filter(|&(_, b)| round == 0 || b >= first_part) {
            let joined: Vec<usize> = pieces[a].iter().chain(pieces[b]).copied().collect();
            segments.extend(describe(depth, k, &joined).filter(|s| s.span_m <= too_large_m));
        }
    }
    segments.sort_by_key(|s| std::cmp::Reverse(s.pixels));
    Segmentation { segments, planes }
}

/// Up to `MAX_PLANES` planes that each hold `MIN_PLANE_SHARE` of the measured points and
/// spread wider than `wider_than_m`.
fn support_planes(depth: &DepthImage, k: &Intrinsics, wider_than_m: f64) -> Vec<Plane> {
    let mut points: Vec<Point3<f64>> = Vec::new();
    for y in (0..depth.height() as i64).step_by(PLANE_STEP) {
        for x in (0..depth.width() as i64).step_by(PLANE_STEP) {
            points.extend(point_at(depth, k, x, y));
        }
    }
    let total = points.len();
    let mut planes = Vec::new();
    while planes.len() < MAX_PLANES {
        let Some((plane, inliers)) = dominant_plane(&points, ON_PLANE_M) else { break };
        if (inliers as f64) < MIN_PLANE_SHARE * total as f64 {
            break;
        }
        let (on, off): (Vec<Point3<f64>>, Vec<Point3<f64>>) = points.into_iter().partition(|p| plane.above(p).abs() < ON_PLANE_M);
        points = off;
        if spread(&on) > wider_than_m {
            planes.push(plane);
        }
    }
    planes
}

/// The diagonal of the points' axis-aligned bounds, metres (0 for none).
fn spread(points: &[Point3<f64>]) -> f64 {
    let lo = points.iter().fold(Vector3::repeat(f64::INFINITY), |a, p| a.inf(&p.coords));
    let hi = points.iter().fold(Vector3::repeat(f64::NEG_INFINITY), |a, p| a.sup(&p.coords));
    if points.is_empty() {
        0.0
    } else {
        (hi - lo).norm()
    }
}

/// Points sampled for a segment's span: every pair of them is measured.
const SPAN_SAMPLES: usize = 400;

/// The largest distance between two of `points` (an evenly strided sample of at most
/// `SPAN_SAMPLES` of them), metres.
fn span(points: &[&Point3<f64>]) -> f64 {
    let step = points.len().div_ceil(SPAN_SAMPLES).max(1);
    let sample: Vec<&Point3<f64>> = points.iter().step_by(step).copied().collect();
    sample.iter().enumerate().flat_map(|(i, a)| sample[i + 1..].iter().map(move |b| (*a - *b).norm_squared())).fold(0.0, f64::max).sqrt()
}

/// A segment from its pixel indices (row-major); None when its points have no spread.
fn describe(depth: &DepthImage, k: &Intrinsics, pixels: &[usize]) -> Option<Segment> {
    let w = depth.width() as usize;
    let points: Vec<Point3<f64>> = pixels.iter().filter_map(|&i| point_at(depth, k, (i % w) as i64, (i / w) as i64)).collect();
    let n = points.len() as f64;
    let centre = Point3::from(points.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n);
    let cov = points.iter().fold(Matrix3::zeros(), |a, p| {
        let d = p - centre;
        a + d * d.transpose()
    }) / n;
    let axes = SymmetricEigen::new(cov).eigenvectors;
    // Each point along the three principal axes, once: for the percentiles and for the
    // points kept inside them.
    let along_axes: Vec<[f64; 3]> = points.iter().map(|p| [0, 1, 2].map(|a| (p - centre).dot(&axes.column(a)))).collect();
    let mut spread2 = 0.0;
    let mut bounds = [(0.0, 0.0); 3];
    for (a, bound) in bounds.iter_mut().enumerate() {
        let mut along: Vec<f64> = along_axes.iter().map(|q| q[a]).collect();
        along.sort_by(f64::total_cmp);
        let at = |q: f64| along[((along.len() - 1) as f64 * q).round() as usize];
        *bound = (at(0.02), at(0.98));
        spread2 += (at(0.98) - at(0.02)).powi(2);
    }
    let kept: Vec<&Point3<f64>> = points.iter().zip(&along_axes).filter(|(_, q)| (0..3).all(|a| (bounds[a].0..=bounds[a].1).contains(&q[a]))).map(|(p, _)| p).collect();
    let span_m = span(&kept);
    let mut zs: Vec<f64> = points.iter().map(|p| p.z).collect();
    let mid = zs.len() / 2;
    let median_z = *zs.select_nth_unstable_by(mid, f64::total_cmp).1;
    let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
    let (width, height) = (depth.width(), depth.height());
    let mut mask = GrayImage::new(width, height);
    for &i in pixels {
        let (x, y) = (i % w, i / w);
        (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
        mask.put_pixel(x as u32, y as u32, Luma([crate::masks::OBJECT]));
    }
    let region = PixelBox { x0: x0.saturating_sub(2) as u32, y0: y0.saturating_sub(2) as u32, x1: ((x1 + 3) as u32).min(width), y1: ((y1 + 3) as u32).min(height) };
    let mask = close_holes(mask, &region);
    let extent_px = 0.5 * (k.fx + k.fy) * spread2.sqrt() / median_z;
    let fill = points.len() as f64 / (extent_px * extent_px).max(1.0);
    (spread2 > 0.0).then(|| Segment { mask, bbox: [x0 as f64, y0 as f64, (x1 - x0 + 1) as f64, (y1 - y0 + 1) as f64], pixels: pixels.len(), extent_m: spread2.sqrt(), span_m, centre, median_z, fill })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A table below the camera, a wall behind it, a 6 × 4 cm block and a 12 × 3 cm slab on
    /// the table, a gap between them: two segments of about their sizes, table and wall gone.
    #[test]
    fn the_things_on_the_table_are_segments_of_their_size() {
        let (w, h) = (320u32, 240u32);
        let k = Intrinsics::new(300.0, 300.0, 160.0, 120.0, w, h).unwrap();
        // The table: the plane y = 0.1 seen out to 2 m; the objects stand on it at z ≈ 0.7 m.
        let table = |y: u32| {
            let ray_y = (y as f64 - k.cy) / k.fy;
            if ray_y > 0.0 {
                (0.1 / ray_y).min(2.0)
            } else {
                2.0
            }
        };
        // Boxes given by their x range, height above the table and front face z.
        let things = [(-0.10, -0.04, 0.04, 0.7), (0.0, 0.12, 0.03, 0.75)];
        let depth_at = |x: u32, y: u32| -> f64 {
            let (rx, ry) = ((x as f64 - k.cx) / k.fx, (y as f64 - k.cy) / k.fy);
            for (xa, xb, top, z) in things {
                let (px, py) = (rx * z, ry * z);
                if px >= xa && px <= xb && py >= 0.1 - top && py <= 0.1 {
                    return z;
                }
            }
            table(y)
        };
        let values: Vec<f32> = (0..h).flat_map(|y| (0..w).map(move |x| (x, y))).map(|(x, y)| depth_at(x, y) as f32).collect();
        let depth = DepthImage::from_metres(w, h, values).unwrap();
        let seg = segment_frame(&depth, &k, 0.15, 0.18);
        // The table and the wall 2 m away are planes (the objects' faces are too small to be).
        assert_eq!(seg.planes.len(), 2);
        assert_eq!(seg.segments.len(), 2, "{:?}", seg.segments.iter().map(|s| (s.bbox, s.extent_m)).collect::<Vec<_>>());
        let mut extents: Vec<f64> = seg.segments.iter().map(|s| s.extent_m).collect();
        extents.sort_by(f64::total_cmp);
        // Front faces only: 6 × 4 cm (diagonal 7.2 cm) and 12 × 3 cm (12.4 cm).
        assert!((extents[0] - 0.072).abs() < 0.012 && (extents[1] - 0.124).abs() < 0.015, "{extents:?}");
        assert!(seg.segments.iter().all(|s| (s.median_z - 0.7).abs() < 0.06));
        // Front faces seen square on: 6 × 4 cm fills 24/52 of its diagonal's square, 12 × 3 cm 36/153.
        let mut fills: Vec<f64> = seg.segments.iter().map(|s| s.fill).collect();
        fills.sort_by(f64::total_cmp);
        assert!((fills[0] - 0.235).abs() < 0.05 && (fills[1] - 0.46).abs() < 0.08, "{fills:?}");
    }

    /// A 6 cm block's face (0.5 m, left) touching a 10 cm drum (0.56 m, right), the depth
    /// ramping from one to the other over 12 px (5 mm a pixel, under the jump that splits
    /// surfaces: all one surface), a wall behind; with `inside`, above the drum its inside
    /// (a mug's inside seen over its rim), a surface of its own 6 cm farther. The whole is
    /// always a segment; returns the boxes of the segments, for objects of 10 cm and
    /// segments cut past `too_large_m`.
    fn block_and_drum(inside: bool, too_large_m: f64) -> Vec<[f64; 4]> {
        let (w, h) = (200u32, 150u32);
        let k = Intrinsics::new(300.0, 300.0, 100.0, 75.0, w, h).unwrap();
        let values: Vec<f32> = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| {
                if inside && (35..50).contains(&y) && (110..=150).contains(&x) {
                    return 0.62;
                }
                if !(50..=100).contains(&y) || !(40..=160).contains(&x) {
                    return 0.9;
                }
                let t = ((x as f64 - 94.0) / 12.0).clamp(0.0, 1.0);
                (0.5 + 0.06 * t) as f32
            })
            .collect();
        let depth = DepthImage::from_metres(w, h, values).unwrap();
        let boxes: Vec<[f64; 4]> = segment_frame(&depth, &k, 0.1, too_large_m).segments.iter().map(|s| s.bbox).collect();
        assert!(boxes.iter().any(|b| b[0] == 40.0 && b[2] == 121.0 && b[1] == 50.0), "the block and the drum, one surface: {boxes:?}");
        boxes
    }

    /// The block and the drum: one surface, larger than either object looked for, also
    /// offered cut at its depths, as the two things.
    #[test]
    fn touching_things_one_in_front_are_also_offered_apart() {
        let boxes = block_and_drum(false, 0.12);
        assert!(boxes.iter().any(|b| b[0] == 40.0 && b[2] < 70.0), "the block alone: {boxes:?}");
        assert!(boxes.iter().any(|b| b[0] > 90.0 && b[0] + b[2] == 161.0), "the drum alone: {boxes:?}");
    }

    /// With the drum's inside above it: the drum cut from the block at their depths is also
    /// offered joined with its inside, as one thing.
    #[test]
    fn a_part_cut_at_its_depth_is_joined_with_its_neighbour() {
        let boxes = block_and_drum(true, 0.2);
        assert!(boxes.iter().any(|b| b[1] == 35.0 && b[1] + b[3] == 101.0 && b[0] > 90.0), "the drum with its inside: {boxes:?}");
        assert!(!boxes.iter().any(|b| b[1] == 35.0 && b[0] == 40.0 && b[3] > 20.0), "the block is not joined to the inside it does not touch: {boxes:?}");
    }

    #[test]
    fn a_round_things_span_is_its_diameter_not_its_box_diagonal() {
        let rim: Vec<Point3<f64>> = (0..360).map(|d| (d as f64).to_radians()).map(|a| Point3::new(0.05 * a.cos(), 0.05 * a.sin(), 0.6)).collect();
        let refs: Vec<&Point3<f64>> = rim.iter().collect();
        assert!((span(&refs) - 0.1).abs() < 1e-3, "{}", span(&refs));
    }

    #[test]
    fn a_frame_without_depth_has_no_segments() {
        let k = Intrinsics::new(300.0, 300.0, 80.0, 60.0, 160, 120).unwrap();
        let depth = DepthImage::from_metres(160, 120, vec![0.0; 160 * 120]).unwrap();
        let seg = segment_frame(&depth, &k, 0.15, 0.18);
        assert!(seg.segments.is_empty() && seg.planes.is_empty());
    }
}
