//! Print points: where an object's print shows, the render at a pose and the photo agree
//! pixel for pixel once the pose is right. Small patches of the render around its print's
//! corners are looked for in the photo nearby by normalised cross-correlation (blind to the
//! render's brightness and contrast against the photo's), and each one found ties a surface
//! point (the render's depth there) to where the photo shows it. The outline alone leaves a
//! small object's turn and depth trading off against each other; points inside it do not.

use crate::features::grey;
use crate::geometry::{Intrinsics, Pose};
use crate::render::RenderOutput;
use image::{GrayImage, RgbImage};
use nalgebra::{Vector2, Vector3};

/// One print point of the render found in the photo.
#[derive(Clone, Debug)]
pub struct PrintPoint {
    /// The surface point, object frame (metres).
    pub object_point: Vector3<f64>,
    /// Where the photo shows it, image pixels.
    pub observed: Vector2<f64>,
    /// How far that is from where the pose puts it, px.
    pub offset_px: f64,
}

#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PrintPointConfig {
    /// Patches of (2·radius + 1)² pixels.
    pub patch_radius: u32,
    /// The photo is searched this far (px) each way from where the render has the patch.
    pub search_px: u32,
    /// One point at most per cell of this many pixels a side (spreads them over the print).
    pub cell_px: u32,
    /// Normalised cross-correlation a match needs, and by how much it must beat the best
    /// match two or more pixels away (a repeated print, text, matches in several places).
    pub min_ncc: f64,
    pub min_margin: f64,
    /// Most points per render, the strongest corners first.
    pub max_points: usize,
    /// Look for the print only inside the detection's mask (outside it, the photo shows
    /// something else, unless the mask is wrong there).
    pub within_mask: bool,
}

impl Default for PrintPointConfig {
    fn default() -> Self {
        Self { patch_radius: 3, search_px: 6, cell_px: 5, min_ncc: 0.8, min_margin: 0.1, max_points: 150, within_mask: true }
    }
}

/// A window render with what it was rendered for: the pose, the window (x, y, w, h) of the
/// image, and the camera cut down to it.
pub struct WindowRender<'a> {
    pub render: &'a RenderOutput,
    pub pose: &'a Pose,
    pub window: (u32, u32, u32, u32),
    pub camera: &'a Intrinsics,
}

/// Grey levels of a rectangle of an image (x0, y0 its top-left pixel), row-major; read in
/// image coordinates.
struct Grey {
    v: Vec<f32>,
    x0: i64,
    y0: i64,
    w: i64,
    h: i64,
}

impl Grey {
    /// The rectangle (x0, y0, w, h) of `image`, clipped to it.
    fn of(image: &RgbImage, (x0, y0, w, h): (i64, i64, i64, i64)) -> Self {
        let (ax, ay) = (x0.max(0), y0.max(0));
        let (bx, by) = ((x0 + w).min(image.width() as i64), (y0 + h).min(image.height() as i64));
        let (w, h) = ((bx - ax).max(0), (by - ay).max(0));
        let v = (ay..ay + h).flat_map(|y| (ax..ax + w).map(move |x| (x, y))).map(|(x, y)| grey(image.get_pixel(x as u32, y as u32))).collect();
        Self { v, x0: ax, y0: ay, w, h }
    }

    fn at(&self, x: i64, y: i64) -> f32 {
        self.v[((y - self.y0) * self.w + x - self.x0) as usize]
    }

    /// Whether (x, y) lies `margin` or more pixels inside the rectangle.
    fn inside(&self, x: i64, y: i64, margin: i64) -> bool {
        x - margin >= self.x0 && y - margin >= self.y0 && x + margin < self.x0 + self.w && y + margin < self.y0 + self.h
    }
}

/// Summed-area table over a w×h grid, for box sums in constant time.
struct Integral {
    s: Vec<f64>,
    w: usize,
}

impl Integral {
    fn new(w: usize, h: usize, f: impl Fn(usize, usize) -> f64) -> Self {
        let mut s = vec![0.0; (w + 1) * (h + 1)];
        for y in 0..h {
            let mut row = 0.0;
            for x in 0..w {
                row += f(x, y);
                s[(y + 1) * (w + 1) + x + 1] = s[y * (w + 1) + x + 1] + row;
            }
        }
        Self { s, w }
    }

    /// Sum over the box of radius `r` about (x, y), which must lie inside the grid.
    fn around(&self, x: usize, y: usize, r: usize) -> f64 {
        let row = self.w + 1;
        let (x0, y0, x1, y1) = (x - r, y - r, x + r + 1, y + r + 1);
        self.s[y1 * row + x1] - self.s[y0 * row + x1] - self.s[y1 * row + x0] + self.s[y0 * row + x0]
    }
}

/// Shi–Tomasi corner strength of every pixel of a render (the structure tensor's smaller
/// eigenvalue, central differences summed over the (2·r + 1)² patch) where the patch and its
/// gradients' reach lie wholly inside the silhouette (patches across the outline mix in the
/// background, which the photo does not share); as (strength, x, y).
fn corners(render: &RenderOutput, g: &Grey, r: usize) -> Vec<(f32, i64, i64)> {
    let (w, h) = (g.w as usize, g.h as usize);
    if w < 2 * r + 3 || h < 2 * r + 3 {
        return vec![];
    }
    let gradient = |x: usize, y: usize| {
        if x == 0 || y == 0 || x + 1 == w || y + 1 == h {
            return (0.0, 0.0);
        }
        let (x, y) = (x as i64, y as i64);
        (0.5 * (g.at(x + 1, y) - g.at(x - 1, y)) as f64, 0.5 * (g.at(x, y + 1) - g.at(x, y - 1)) as f64)
    };
    let xx = Integral::new(w, h, |x, y| gradient(x, y).0.powi(2));
    let xy = Integral::new(w, h, |x, y| gradient(x, y).0 * gradient(x, y).1);
    let yy = Integral::new(w, h, |x, y| gradient(x, y).1.powi(2));
    let inside = Integral::new(w, h, |x, y| (render.mask.get_pixel(x as u32, y as u32)[0] > 0) as u8 as f64);
    let full = ((2 * r + 3) * (2 * r + 3)) as f64;
    let mut out = Vec::new();
    for y in r + 1..h - r - 1 {
        for x in r + 1..w - r - 1 {
            if inside.around(x, y, r + 1) < full {
                continue;
            }
            let (a, b, c) = (xx.around(x, y, r), xy.around(x, y, r), yy.around(x, y, r));
            let strength = 0.5 * (a + c) - (0.25 * (a - c).powi(2) + b * b).sqrt();
            out.push((strength as f32, x as i64, y as i64));
        }
    }
    out
}

/// Zero-mean, unit-norm patch of `g` centred at (x, y); `None` where it is flat.
fn normalised_patch(g: &Grey, x: i64, y: i64, r: i64) -> Option<Vec<f32>> {
    let mut p: Vec<f32> = (y - r..=y + r).flat_map(|v| (x - r..=x + r).map(move |u| (u, v))).map(|(u, v)| g.at(u, v)).collect();
    let mean = p.iter().sum::<f32>() / p.len() as f32;
    p.iter_mut().for_each(|x| *x -= mean);
    let norm = p.iter().map(|x| x * x).sum::<f32>().sqrt();
    // Below about 2 grey levels of standard deviation there is nothing to correlate.
    if norm < 2.0 * (p.len() as f32).sqrt() {
        return None;
    }
    p.iter_mut().for_each(|x| *x /= norm);
    Some(p)
}

/// The render's print points found in the photo near where `view`'s pose puts them,
/// strongest corners first. Points whose photo position is outside `mask` or inside
/// `hidden` (another detection, which may be in front) are not looked for.
pub fn print_points(view: &WindowRender<'_>, image: &RgbImage, mask: &GrayImage, hidden: Option<&GrayImage>, cfg: &PrintPointConfig) -> Vec<PrintPoint> {
    let r = cfg.patch_radius as i64;
    let s = cfg.search_px as i64;
    let (x0, y0, _, _) = view.window;
    let (w, h) = view.render.rgb.dimensions();
    let rendered = Grey::of(&view.render.rgb, (0, 0, w as i64, h as i64));
    // Only the photo the search can reach.
    let reach = r + s + 1;
    let photo = Grey::of(image, (x0 as i64 - reach, y0 as i64 - reach, w as i64 + 2 * reach, h as i64 + 2 * reach));
    // Corner candidates: the strongest per cell.
    let cell = cfg.cell_px.max(1) as i64;
    let mut best_per_cell: std::collections::HashMap<(i64, i64), (f32, i64, i64)> = std::collections::HashMap::new();
    for (c, x, y) in corners(view.render, &rendered, r as usize) {
        let slot = best_per_cell.entry((x / cell, y / cell)).or_insert((c, x, y));
        if c > slot.0 {
            *slot = (c, x, y);
        }
    }
    let mut corners: Vec<(f32, i64, i64)> = best_per_cell.into_values().collect();
    corners.sort_by(|a, b| b.0.total_cmp(&a.0).then((a.1, a.2).cmp(&(b.1, b.2))));
    // A corner needs gradients of some 10 grey levels per pixel in both directions over
    // its patch; weaker ones are noise or a gentle shading ramp.
    let floor = 100.0 * ((2 * r + 1) * (2 * r + 1)) as f32;
    let inverse = view.pose.inverse();
    let on = |m: &GrayImage, x: i64, y: i64| m.get_pixel(x as u32, y as u32)[0] > 0;
    let stats = PatchStats::of(&photo);
    corners
        .into_iter()
        .take_while(|c| c.0 >= floor)
        .take(3 * cfg.max_points)
        .filter_map(|(_, x, y)| {
            let (ix, iy) = (x0 as i64 + x, y0 as i64 + y);
            let template = normalised_patch(&rendered, x, y, r)?;
            let z = view.render.depth_at(x as u32, y as u32) as f64;
            if z <= 0.0 {
                return None;
            }
            let searchable = |u: i64, v: i64| (!cfg.within_mask || on(mask, u, v)) && !hidden.is_some_and(|h| on(h, u, v));
            let offset = best_match(&template, &photo, &stats, (ix, iy), searchable, cfg)?;
            let object_point = inverse.transform_point(&view.camera.back_project(x as f64, y as f64, z)).coords;
            Some(PrintPoint { object_point, observed: Vector2::new(ix as f64, iy as f64) + offset, offset_px: offset.norm() })
        })
        .take(cfg.max_points)
        .collect()
}

/// Sums of the photo's grey levels and of their squares, for every patch's mean and norm
/// in constant time (normalised cross-correlation at many offsets).
struct PatchStats {
    sum: Integral,
    squares: Integral,
}

impl PatchStats {
    fn of(g: &Grey) -> Self {
        let at = |x: usize, y: usize| g.at(g.x0 + x as i64, g.y0 + y as i64) as f64;
        Self { sum: Integral::new(g.w as usize, g.h as usize, at), squares: Integral::new(g.w as usize, g.h as usize, |x, y| at(x, y).powi(2)) }
    }
}

/// Where the zero-mean, unit-norm (2·r + 1)² `template` correlates best with the photo
/// within `search_px` of `(ix, iy)`, as the offset to the peak of the correlation surface,
/// placed to a fraction of a pixel; only photo positions that are `searchable` count.
/// `None` unless the peak is clear: at least `min_ncc`, better by `min_margin` than any
/// position 2 px or more from it, and not on the search's border (the true peak may lie
/// beyond it).
fn best_match(template: &[f32], photo: &Grey, stats: &PatchStats, (ix, iy): (i64, i64), searchable: impl Fn(i64, i64) -> bool, cfg: &PrintPointConfig) -> Option<Vector2<f64>> {
    let (r, s) = (cfg.patch_radius as i64, cfg.search_px as i64);
    let n = ((2 * r + 1) * (2 * r + 1)) as f64;
    let side = 2 * s + 1;
    let mut scores = vec![f64::NEG_INFINITY; (side * side) as usize];
    for dy in -s..=s {
        for dx in -s..=s {
            let (u, v) = (ix + dx, iy + dy);
            if !photo.inside(u, v, r) || !searchable(u, v) {
                continue;
            }
            let (gx, gy) = ((u - photo.x0) as usize, (v - photo.y0) as usize);
            let sum = stats.sum.around(gx, gy, r as usize);
            let norm = (stats.squares.around(gx, gy, r as usize) - sum * sum / n).max(0.0).sqrt();
            // Below about 2 grey levels of standard deviation there is nothing to correlate.
            if norm < 2.0 * n.sqrt() {
                continue;
            }
            // The template has zero mean, so the photo patch's mean drops out of the product.
            let mut dot = 0.0f32;
            for (row, t) in (v - r..=v + r).zip(template.chunks_exact((2 * r + 1) as usize)) {
                for (col, tv) in (u - r..=u + r).zip(t) {
                    dot += tv * photo.at(col, row);
                }
            }
            scores[((dy + s) * side + dx + s) as usize] = dot as f64 / norm;
        }
    }
    let at = |dx: i64, dy: i64| scores[((dy + s) * side + dx + s) as usize];
    let (mut bx, mut by) = (0, 0);
    for dy in -s..=s {
        for dx in -s..=s {
            if at(dx, dy) > at(bx, by) {
                (bx, by) = (dx, dy);
            }
        }
    }
    let best = at(bx, by);
    if best < cfg.min_ncc || bx.abs() == s || by.abs() == s {
        return None;
    }
    let rival = (-s..=s).flat_map(|dy| (-s..=s).map(move |dx| (dx, dy))).filter(|&(dx, dy)| (dx - bx).abs().max((dy - by).abs()) >= 2).map(|(dx, dy)| at(dx, dy)).fold(f64::NEG_INFINITY, f64::max);
    if best - rival < cfg.min_margin {
        return None;
    }
    // A parabola through the peak and its neighbours, each way: the sub-pixel peak.
    let vertex = |m: f64, c: f64, p: f64| {
        let d = m - 2.0 * c + p;
        if m.is_finite() && p.is_finite() && d < 0.0 {
            (0.5 * (m - p) / d).clamp(-0.5, 0.5)
        } else {
            0.0
        }
    };
    Some(Vector2::new(bx as f64 + vertex(at(bx - 1, by), best, at(bx + 1, by)), by as f64 + vertex(at(bx, by - 1), best, at(bx, by + 1))))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, Rotation3};

    /// A print of random grey blobs about 3 px across (value noise: a hashed grey level
    /// every 3 px, bilinear between), grey 30–230: no repeats within the search's reach.
    fn print(x: f64, y: f64) -> u8 {
        let level = |i: i64, j: i64| {
            // splitmix64 of the cell's index
            let mut h = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (j as u64).wrapping_add(0x632B_E59B_D9B4_E019);
            h = (h ^ (h >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            h = (h ^ (h >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            30.0 + ((h ^ (h >> 31)) % 200) as f64
        };
        let (u, v) = (x / 3.0, y / 3.0);
        let (i, j) = (u.floor() as i64, v.floor() as i64);
        let (fu, fv) = (u - u.floor(), v - v.floor());
        let top = level(i, j) * (1.0 - fu) + level(i + 1, j) * fu;
        let bottom = level(i, j + 1) * (1.0 - fu) + level(i + 1, j + 1) * fu;
        (top * (1.0 - fv) + bottom * fv).round() as u8
    }

    /// A 64² render of the print at depth 1 m with `mask`, and the photo (96², the window at
    /// (16, 16)) showing the print moved by `shift`, area-averaged over 4×4 samples.
    fn pair(shift: (f64, f64), render_mask: impl Fn(u32, u32) -> bool) -> (RenderOutput, RgbImage, Intrinsics) {
        let sampled = |x: f64, y: f64| {
            let mut sum = 0.0;
            for i in 0..4 {
                for j in 0..4 {
                    sum += print(x + (i as f64 - 1.5) / 4.0, y + (j as f64 - 1.5) / 4.0) as f64;
                }
            }
            (sum / 16.0).round() as u8
        };
        let rgb = RgbImage::from_fn(64, 64, |x, y| if render_mask(x, y) { image::Rgb([sampled(x as f64, y as f64); 3]) } else { image::Rgb([0; 3]) });
        let mask = GrayImage::from_fn(64, 64, |x, y| image::Luma([if render_mask(x, y) { 255 } else { 0 }]));
        let depth = mask.pixels().map(|p| if p[0] > 0 { 1.0 } else { 0.0 }).collect();
        let photo = RgbImage::from_fn(96, 96, |x, y| image::Rgb([sampled(x as f64 - 16.0 - shift.0, y as f64 - 16.0 - shift.1); 3]));
        let k = Intrinsics { fx: 500.0, fy: 500.0, cx: 48.0, cy: 48.0, width: 96, height: 96 };
        (RenderOutput { rgb, depth, mask }, photo, k)
    }

    /// The print points found with the photo's print moved by `shift`, and how many of them
    /// are more than 0.6 px from where the print went.
    fn found(shift: (f64, f64), hidden: Option<&GrayImage>) -> (Vec<PrintPoint>, usize) {
        let (render, photo, k) = pair(shift, |_, _| true);
        let window = (16, 16, 64, 64);
        let camera = k.window(16, 16, 64, 64).unwrap();
        let pose = Pose::new(Rotation3::from_euler_angles(0.1, 0.2, 0.3), Vector3::new(0.01, 0.0, 1.0));
        let view = WindowRender { render: &render, pose: &pose, window, camera: &camera };
        let mask = GrayImage::from_pixel(96, 96, image::Luma([255]));
        let points = print_points(&view, &photo, &mask, hidden, &PrintPointConfig::default());
        // Each point's offset is from where the pose's own render put it.
        let projected = |p: &PrintPoint| k.project(&Point3::from(pose.rotation * p.object_point + pose.translation)).unwrap();
        assert!(points.iter().all(|p| ((projected(p) - p.observed).norm() - p.offset_px).abs() < 1e-6));
        let wrong = points.iter().filter(|p| (projected(p) + Vector2::new(shift.0, shift.1) - p.observed).norm() > 0.6).count();
        (points, wrong)
    }

    /// The print moved by a fraction of a pixel is found where it went, to about a tenth of
    /// a pixel, at many points; unmoved, where the render has it.
    #[test]
    fn a_moved_print_is_found_where_it_went() {
        for shift in [(0.0, 0.0), (2.0, -1.0), (1.5, 0.25), (-3.4, 2.6)] {
            let (points, wrong) = found(shift, None);
            assert_eq!(wrong, 0, "at {shift:?}");
            assert!(points.len() >= 40, "{} points at {shift:?}", points.len());
            let expected = (shift.0 * shift.0 + shift.1 * shift.1).sqrt();
            let mut errors: Vec<f64> = points.iter().map(|p| (p.offset_px - expected).abs()).collect();
            errors.sort_by(f64::total_cmp);
            assert!(errors[errors.len() / 2] < 0.12, "median error {} px at {shift:?}", errors[errors.len() / 2]);
        }
        // Beyond the search's reach a few points are claimed, a tenth or so of those found
        // within it: chance likenesses of 7² patches in a random print (measured: 13 of
        // about 130). The refiner's robust weights and its check on the result are the
        // guard against those, not this search.
        let (beyond, _) = found((9.0, 0.0), None);
        assert!(beyond.len() < 20, "{} points", beyond.len());
    }

    /// No print, no points; the render's outline is not taken for print; pixels another
    /// detection covers are not looked at.
    #[test]
    fn flat_surfaces_outlines_and_hidden_pixels_give_no_points() {
        let flat = RenderOutput { rgb: RgbImage::from_pixel(64, 64, image::Rgb([128; 3])), depth: vec![1.0; 64 * 64], mask: GrayImage::from_pixel(64, 64, image::Luma([255])) };
        let k = Intrinsics { fx: 500.0, fy: 500.0, cx: 32.0, cy: 32.0, width: 64, height: 64 };
        let pose = Pose::new(Rotation3::identity(), Vector3::new(0.0, 0.0, 1.0));
        let view = WindowRender { render: &flat, pose: &pose, window: (0, 0, 64, 64), camera: &k };
        let photo = RgbImage::from_fn(64, 64, |x, y| image::Rgb([print(x as f64, y as f64); 3]));
        assert!(print_points(&view, &photo, &flat.mask, None, &PrintPointConfig::default()).is_empty());

        // A plain disc on black: its outline is a strong edge, but every patch across it
        // leaves the silhouette.
        let disc = |x: u32, y: u32| (x as f64 - 31.5).powi(2) + (y as f64 - 31.5).powi(2) < 400.0;
        let (mut render, photo, k) = pair((0.0, 0.0), disc);
        for (p, m) in render.rgb.pixels_mut().zip(render.mask.pixels()) {
            if m[0] > 0 {
                *p = image::Rgb([200; 3]);
            }
        }
        let camera = k.window(16, 16, 64, 64).unwrap();
        let view = WindowRender { render: &render, pose: &pose, window: (16, 16, 64, 64), camera: &camera };
        assert!(print_points(&view, &photo, &GrayImage::from_pixel(96, 96, image::Luma([255])), None, &PrintPointConfig::default()).is_empty());

        let all = found((1.0, 0.0), None).0.len();
        let left_half_hidden = GrayImage::from_fn(96, 96, |x, _| image::Luma([if x < 48 { 255 } else { 0 }]));
        let (some, _) = found((1.0, 0.0), Some(&left_half_hidden));
        assert!(some.len() < all * 3 / 4 && !some.is_empty(), "{} of {all}", some.len());
        assert!(some.iter().all(|p| p.observed.x >= 48.0 - 0.5));
    }
}
