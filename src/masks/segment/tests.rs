//! Segmentation on synthetic images: a coloured blob on a textured background, the box
//! around it; the mask must match the blob, at the border and when downsampled too.

use super::*;
use crate::masks::instances::mask_iou;
use image::Rgb;

/// Deterministic noise so the tests need no `rand`.
fn hash(x: u32, y: u32, salt: u32) -> u32 {
    let mut h = x.wrapping_mul(0x9E37_79B1) ^ y.wrapping_mul(0x85EB_CA77) ^ salt.wrapping_mul(0xC2B2_AE3D);
    h ^= h >> 15;
    h = h.wrapping_mul(0x2C1B_3C6D);
    h ^ (h >> 12)
}

/// Two overlapping ellipses: not convex, so a box-shaped answer cannot pass.
fn blob(cx: f64, cy: f64, r: f64) -> impl Fn(u32, u32) -> bool {
    let shape = blob_shape(cx, cy, r);
    move |x, y| shape(x as f64, y as f64)
}

/// `blob` at any point of the image plane.
fn blob_shape(cx: f64, cy: f64, r: f64) -> impl Fn(f64, f64) -> bool {
    move |x, y| {
        let (u, v) = (x - cx, y - cy);
        (u / r).powi(2) + (v / (0.6 * r)).powi(2) <= 1.0 || ((u - 0.5 * r) / (0.45 * r)).powi(2) + ((v + 0.5 * r) / (0.5 * r)).powi(2) <= 1.0
    }
}

/// Grey-green-brown stripes and checks with noise behind an orange blob with shading.
fn scene(width: u32, height: u32, inside: &dyn Fn(u32, u32) -> bool) -> (RgbImage, GrayImage) {
    let palette = [[90u8, 110, 80], [140, 140, 130], [70, 60, 50], [160, 170, 150], [40, 80, 110]];
    let image = RgbImage::from_fn(width, height, |x, y| {
        let noise = (hash(x, y, 1) % 21) as i32 - 10;
        let base = if inside(x, y) {
            let shade = (x % 37) as i32 - 18;
            [230 + shade / 3, 120 + shade, 40]
        } else {
            palette[((x / 13 + y / 9 + (x / 29) * (y / 17)) % 5) as usize].map(i32::from)
        };
        Rgb(base.map(|c| (c + noise).clamp(0, 255) as u8))
    });
    let truth = GrayImage::from_fn(width, height, |x, y| Luma([if inside(x, y) { OBJECT } else { 0 }]));
    (image, truth)
}

fn tight_box(truth: &GrayImage, grow: u32) -> PixelBox {
    let on: Vec<(u32, u32)> = truth.enumerate_pixels().filter(|p| p.2[0] != 0).map(|p| (p.0, p.1)).collect();
    let (x0, x1) = (on.iter().map(|p| p.0).min().unwrap(), on.iter().map(|p| p.0).max().unwrap());
    let (y0, y1) = (on.iter().map(|p| p.1).min().unwrap(), on.iter().map(|p| p.1).max().unwrap());
    PixelBox { x0: x0.saturating_sub(grow), y0: y0.saturating_sub(grow), x1: (x1 + 1 + grow).min(truth.width()), y1: (y1 + 1 + grow).min(truth.height()) }
}

#[test]
fn blob_on_texture_is_recovered() {
    let inside = blob(100.0, 80.0, 45.0);
    let (image, truth) = scene(220, 170, &inside);
    for grow in [0, 6] {
        let b = tight_box(&truth, grow);
        let s = segment_box(&image, &b, &SegmentConfig::default());
        let iou = mask_iou(&s.mask, &truth);
        let filled = mask_iou(&b.filled(220, 170), &truth);
        eprintln!("grow {grow}: IoU {iou:.3} (filled box {filled:.3}), {:.1} ms", s.ms);
        assert_eq!(s.method, Method::GraphCut, "{:?}", s.note);
        assert!(iou > 0.85, "IoU {iou}");
        assert!(iou > filled + 0.1);
    }
}

#[test]
fn box_touching_the_image_border_works() {
    // The blob runs off the left and top edges; its box starts at 0.
    let inside = blob(20.0, 25.0, 50.0);
    let (image, truth) = scene(160, 120, &inside);
    let b = tight_box(&truth, 0);
    assert_eq!((b.x0, b.y0), (0, 0));
    let s = segment_box(&image, &b, &SegmentConfig::default());
    let iou = mask_iou(&s.mask, &truth);
    assert_eq!(s.method, Method::GraphCut, "{:?}", s.note);
    assert!(iou > 0.85, "IoU {iou}");
}

#[test]
fn large_boxes_are_downsampled_and_upsampled_back() {
    let inside = blob(330.0, 250.0, 200.0);
    let (image, truth) = scene(640, 480, &inside);
    let b = tight_box(&truth, 4);
    let s = segment_box(&image, &b, &SegmentConfig::default());
    let iou = mask_iou(&s.mask, &truth);
    eprintln!("{}×{} box: IoU {iou:.3}, {:.1} ms", b.width(), b.height(), s.ms);
    assert!(iou > 0.85, "IoU {iou}");
}

#[test]
fn collapse_falls_back_to_the_inscribed_ellipse() {
    // Nothing distinguishes the box from its surroundings.
    let image = RgbImage::from_fn(100, 80, |x, y| Rgb([120 + (hash(x, y, 2) % 5) as u8; 3]));
    let b = PixelBox { x0: 30, y0: 20, x1: 70, y1: 60 };
    let s = segment_box(&image, &b, &SegmentConfig::default());
    assert_eq!(s.method, Method::EllipseFallback);
    assert!(s.note.as_deref().unwrap().contains("inscribed ellipse"), "{:?}", s.note);
    assert!((s.fill - std::f64::consts::FRAC_PI_4).abs() < 0.05, "fill {}", s.fill);
    // A box over the whole image leaves no background to learn from.
    let all = PixelBox { x0: 0, y0: 0, x1: 100, y1: 80 };
    let s = segment_box(&image, &all, &SegmentConfig::default());
    assert!(s.note.unwrap().contains("no background"));
    // A one-pixel box still gives a non-empty mask.
    let tiny = PixelBox { x0: 5, y0: 5, x1: 6, y1: 6 };
    assert_eq!(segment_box(&image, &tiny, &SegmentConfig::default()).mask.get_pixel(5, 5)[0], OBJECT);
}

#[test]
fn cleaning_keeps_the_largest_region_and_fills_its_holes() {
    // 8×6 grid, box = columns 1..7, rows 1..5; a ring with a hole, plus a stray cell.
    let (w, h) = (8, 6);
    let in_box: Vec<bool> = (0..w * h).map(|i| (1..7).contains(&(i % w)) && (1..5).contains(&(i / w))).collect();
    let grid = Grid { w, h, colour: vec![[0.0; 3]; w * h], in_box, origin: (0, 0), scale: (1.0, 1.0) };
    let rows = ["........", ".###..#.", ".#.#....", ".###....", "........", "........"];
    let labels: Vec<bool> = rows.iter().flat_map(|r| r.bytes().map(|b| b == b'#')).collect();
    let cleaned = clean(&grid, labels);
    let shown: Vec<String> = cleaned.chunks(w).map(|r| r.iter().map(|&l| if l { '#' } else { '.' }).collect()).collect();
    assert_eq!(shown, ["........", ".###....", ".###....", ".###....", "........", "........"]);
}

/// A camera's pixels on the outline blend the object with what is behind it: the cut
/// alone takes most such pixels into the mask, settling them by coverage
/// (`outline_matte`) puts the outline where half of a pixel is the object's.
#[test]
fn blended_outline_pixels_are_settled_by_coverage() {
    let inside = blob_shape(60.3, 50.6, 28.0);
    // 4×4 samples per pixel: the share each pixel's colour takes from the blob.
    let coverage = |x: u32, y: u32| (0..16).filter(|s| inside(x as f64 + (s % 4) as f64 / 4.0 + 0.125, y as f64 + (s / 4) as f64 / 4.0 + 0.125)).count() as f64 / 16.0;
    let (object, back) = ([225.0, 110.0, 40.0], [70.0, 90.0, 120.0]);
    let image = RgbImage::from_fn(130, 110, |x, y| {
        let a = coverage(x, y);
        Rgb(std::array::from_fn(|i| (object[i] * a + back[i] * (1.0 - a)).round() as u8))
    });
    let truth = GrayImage::from_fn(130, 110, |x, y| Luma([if coverage(x, y) >= 0.5 { OBJECT } else { 0 }]));
    let b = tight_box(&GrayImage::from_fn(130, 110, |x, y| Luma([if coverage(x, y) > 0.0 { OBJECT } else { 0 }])), 0);
    let wrong = |settle_outline: bool| {
        let s = segment_box(&image, &b, &SegmentConfig { settle_outline, ..SegmentConfig::default() });
        let count = |extra: bool| s.mask.pixels().zip(truth.pixels()).filter(|(m, t)| (m[0] > 0 && t[0] == 0) == extra && m[0] != t[0]).count();
        (count(true), count(false))
    };
    let (raw, settled) = (wrong(false), wrong(true));
    eprintln!("pixels too many / missed: cut alone {raw:?}, settled {settled:?}");
    assert!(raw.0 > 3 * raw.1 + 10, "the cut alone should lean outward: {raw:?}");
    assert!(settled.0 + settled.1 <= (raw.0 + raw.1) / 4, "{raw:?} -> {settled:?}");
}
