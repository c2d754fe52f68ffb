//! Occluders: flat coloured ellipses and star-shaped polygons drawn in front of part of an
//! object, standing in for the clutter that hides objects in real scenes; over real
//! backgrounds, cut from a real photo instead of flat colour.

use crate::mesh::procedural::Rng;
use image::{Rgb, RgbImage};

#[derive(Clone, Debug)]
pub(super) enum Shape {
    Ellipse {
        cx: f64,
        cy: f64,
        rx: f64,
        ry: f64,
    },
    /// Vertices in order around a centre, so the polygon is simple.
    Polygon(Vec<(f64, f64)>),
}

#[derive(Clone, Debug)]
pub(super) struct Occluder {
    pub shape: Shape,
    pub color: [u8; 3],
}

impl Shape {
    pub fn contains(&self, x: f64, y: f64) -> bool {
        match self {
            Shape::Ellipse { cx, cy, rx, ry } => ((x - cx) / rx).powi(2) + ((y - cy) / ry).powi(2) < 1.0,
            Shape::Polygon(v) => {
                // Even-odd rule: count edges crossed by a ray towards +x.
                let mut inside = false;
                for (i, &(x1, y1)) in v.iter().enumerate() {
                    let (x0, y0) = v[(i + v.len() - 1) % v.len()];
                    if (y0 > y) != (y1 > y) && x < x0 + (y - y0) / (y1 - y0) * (x1 - x0) {
                        inside = !inside;
                    }
                }
                inside
            }
        }
    }

    /// Pixel range `[x0, y0, x1, y1)` that can hold covered pixel centres, clipped to w × h.
    pub fn pixel_bounds(&self, w: u32, h: u32) -> [u32; 4] {
        let (lo, hi) = match self {
            Shape::Ellipse { cx, cy, rx, ry } => ((cx - rx, cy - ry), (cx + rx, cy + ry)),
            Shape::Polygon(v) => v.iter().fold(((f64::MAX, f64::MAX), (f64::MIN, f64::MIN)), |((ax, ay), (bx, by)), &(x, y)| ((ax.min(x), ay.min(y)), (bx.max(x), by.max(y)))),
        };
        let clip = |v: f64, n: u32| v.clamp(0.0, n as f64) as u32;
        [clip(lo.0.floor(), w), clip(lo.1.floor(), h), clip(hi.0.ceil() + 1.0, w), clip(hi.1.ceil() + 1.0, h)]
    }
}

/// An occluder 20–50 % of `object_size` (pixels) across, centred within one radius of
/// `anchor` (a pixel of the object): it may cover an edge or the middle, and so a varying
/// share of the object (the caller keeps it only if every instance stays visible enough).
pub(super) fn sample_occluder(anchor: (f64, f64), object_size: f64, rng: &mut Rng) -> Occluder {
    let radius = rng.range(0.1, 0.25) * object_size;
    let cx = anchor.0 + rng.range(-radius, radius);
    let cy = anchor.1 + rng.range(-radius, radius);
    let color = std::array::from_fn(|_| rng.range(0.0, 255.0) as u8);
    let shape = if rng.uniform() < 0.5 {
        Shape::Ellipse { cx, cy, rx: radius * rng.range(0.6, 1.4), ry: radius * rng.range(0.6, 1.4) }
    } else {
        let n = 3 + (rng.next_u64() % 4) as usize;
        // Sorted angles around the centre make a star-shaped, hence simple, polygon.
        let mut angles: Vec<f64> = (0..n).map(|_| rng.range(0.0, std::f64::consts::TAU)).collect();
        angles.sort_by(f64::total_cmp);
        Shape::Polygon(
            angles
                .into_iter()
                .map(|a| {
                    let r = radius * rng.range(0.6, 1.4);
                    (cx + r * a.cos(), cy + r * a.sin())
                })
                .collect(),
        )
    };
    Occluder { shape, color }
}

/// Real photo for the occluders to be cut from: occluder `j` shows `photo` shifted by
/// `offsets[j]` (wrapping), so each is a different piece of real clutter.
pub(super) struct OccluderPhoto {
    pub photo: RgbImage,
    pub offsets: Vec<(u32, u32)>,
}

impl OccluderPhoto {
    /// A piece of `photo` for each of `count` occluders, at offsets drawn from `rng`.
    pub fn new(photo: RgbImage, count: usize, rng: &mut Rng) -> Self {
        let (w, h) = photo.dimensions();
        let offsets = (0..count).map(|_| ((rng.next_u64() % w as u64) as u32, (rng.next_u64() % h as u64) as u32)).collect();
        Self { photo, offsets }
    }

    /// Occluder `j`'s colour at pixel (`x`, `y`).
    pub fn pixel(&self, j: usize, x: u32, y: u32) -> Rgb<u8> {
        let (w, h) = self.photo.dimensions();
        let (dx, dy) = self.offsets[j];
        *self.photo.get_pixel((x + dx) % w, (y + dy) % h)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shapes_contain_their_inside_only() {
        let e = Shape::Ellipse { cx: 10.0, cy: 5.0, rx: 4.0, ry: 2.0 };
        assert!(e.contains(13.0, 5.0) && !e.contains(10.0, 7.5));
        let square = Shape::Polygon(vec![(0.0, 0.0), (4.0, 0.0), (4.0, 4.0), (0.0, 4.0)]);
        assert!(square.contains(2.0, 3.0) && !square.contains(5.0, 2.0) && !square.contains(2.0, -1.0));
        assert_eq!(square.pixel_bounds(3, 100), [0, 0, 3, 5]);
        let mut rng = Rng::new(5);
        for _ in 0..50 {
            let o = sample_occluder((40.0, 40.0), 40.0, &mut rng);
            let [x0, y0, x1, y1] = o.shape.pixel_bounds(200, 200);
            let covered = (y0..y1).flat_map(|y| (x0..x1).map(move |x| (x, y))).filter(|&(x, y)| o.shape.contains(x as f64, y as f64)).count();
            assert!(covered > 0, "{o:?} covers nothing");
        }
    }

    #[test]
    fn occluders_cut_from_a_photo_take_its_pixels_shifted() {
        let photo = RgbImage::from_fn(4, 3, |x, y| Rgb([x as u8, y as u8, 0]));
        let p = OccluderPhoto { photo, offsets: vec![(0, 0), (3, 2)] };
        assert_eq!(p.pixel(0, 1, 2), Rgb([1, 2, 0]));
        // Shifted and wrapped around the photo's edges.
        assert_eq!(p.pixel(1, 1, 2), Rgb([0, 1, 0]));
        let drawn = OccluderPhoto::new(RgbImage::new(640, 480), 3, &mut Rng::new(1));
        assert_eq!(drawn.offsets.len(), 3);
        assert!(drawn.offsets.iter().all(|&(x, y)| x < 640 && y < 480));
    }
}
