//! Overlap of a 2D detection with a ground-truth instance as pycocotools measures it
//! (cocoapi `common/maskApi.c`, `bbIou` and `rleIou`, non-crowd ground truth; BOP marks
//! none as crowd): boxes are continuous `[x, y, w, h]` rectangles, masks are compared
//! pixel by pixel on their column-major runs, without decoding either.

use crate::masks::rle::Rle;

/// IoU of two `[x, y, w, h]` boxes. No `+ 1` on the sides: COCO boxes are continuous, so
/// `[0, 0, 10, 10]` covers 100 units. Boxes that only touch overlap by nothing.
pub fn box_iou(dt: [f64; 4], gt: [f64; 4]) -> f64 {
    crate::detect::nms::box_iou(&dt, &gt)
}

/// IoU of two masks of the same size, `None` when the sizes differ (pycocotools then
/// returns −1, which never reaches a threshold; the caller says which entry is wrong).
/// Masks that do not intersect have IoU 0, two empty masks included.
pub fn rle_iou(dt: &Rle, gt: &Rle) -> Option<f64> {
    if dt.size != gt.size {
        return None;
    }
    let inter = intersection(dt, gt);
    if inter == 0 {
        return Some(0.0);
    }
    Some(inter as f64 / (dt.area() + gt.area() - inter) as f64)
}

/// Object pixels common to both masks: a merge of the two lists of runs. Each list covers
/// every pixel once (checked when the RLE was read), so they advance in step.
fn intersection(a: &Rle, b: &Rle) -> u64 {
    let (mut ia, mut ib) = (0usize, 0usize);
    // Pixels left in the current run of each; run i is object when i is odd.
    let (mut left_a, mut left_b) = (0u64, 0u64);
    let mut inter = 0u64;
    loop {
        while left_a == 0 {
            let Some(&c) = a.counts.get(ia) else { return inter };
            left_a = c as u64;
            ia += 1;
        }
        while left_b == 0 {
            let Some(&c) = b.counts.get(ib) else { return inter };
            left_b = c as u64;
            ib += 1;
        }
        let step = left_a.min(left_b);
        // `ia` and `ib` point one past the current runs.
        if ia % 2 == 0 && ib % 2 == 0 {
            inter += step;
        }
        left_a -= step;
        left_b -= step;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::{GrayImage, Luma};

    fn rect(w: u32, h: u32, x0: u32, y0: u32, rw: u32, rh: u32) -> Rle {
        Rle::encode(&GrayImage::from_fn(w, h, |x, y| Luma([u8::from((x0..x0 + rw).contains(&x) && (y0..y0 + rh).contains(&y)) * 255])))
    }

    #[test]
    fn boxes_by_hand() {
        assert_eq!(box_iou([0.0, 0.0, 10.0, 10.0], [0.0, 0.0, 10.0, 10.0]), 1.0);
        // 5×10 overlap of two 10×10 boxes: 50 / 150.
        assert_eq!(box_iou([5.0, 0.0, 10.0, 10.0], [0.0, 0.0, 10.0, 10.0]), 50.0 / 150.0);
        // A 6×10 box inside a 10×10 one: 60 / 100.
        assert_eq!(box_iou([0.0, 0.0, 6.0, 10.0], [0.0, 0.0, 10.0, 10.0]), 0.6);
        // Touching is no overlap; nor is a zero-size box.
        assert_eq!(box_iou([10.0, 0.0, 10.0, 10.0], [0.0, 0.0, 10.0, 10.0]), 0.0);
        assert_eq!(box_iou([2.0, 2.0, 0.0, 0.0], [0.0, 0.0, 10.0, 10.0]), 0.0);
        // Fractional coordinates are kept: 0.5 × 10 of 10 × 10 + 10 × 10 − 5.
        assert!((box_iou([9.5, 0.0, 10.0, 10.0], [0.0, 0.0, 10.0, 10.0]) - 5.0 / 195.0).abs() < 1e-15);
    }

    #[test]
    fn masks_by_hand() {
        let a = rect(20, 10, 2, 1, 6, 4); // 24 px
        let b = rect(20, 10, 5, 3, 6, 4); // 24 px, overlap x 5..8, y 3..5: 3×2 = 6
        assert_eq!(rle_iou(&a, &b), Some(6.0 / 42.0));
        assert_eq!(rle_iou(&b, &a), Some(6.0 / 42.0));
        assert_eq!(rle_iou(&a, &a), Some(1.0));
        // Runs crossing column boundaries: a full-height stripe against a full image.
        let full = rect(20, 10, 0, 0, 20, 10);
        assert_eq!(rle_iou(&rect(20, 10, 3, 0, 4, 10), &full), Some(40.0 / 200.0));
        let empty = rect(20, 10, 0, 0, 0, 0);
        assert_eq!(rle_iou(&empty, &a), Some(0.0));
        assert_eq!(rle_iou(&empty, &empty), Some(0.0));
        assert_eq!(rle_iou(&rect(10, 20, 2, 1, 6, 4), &a), None);
    }

    #[test]
    fn mask_iou_agrees_with_pixel_counting() {
        // Irregular masks with zero-length runs at the start (object at pixel 0).
        let m = |seed: u32| GrayImage::from_fn(13, 7, |x, y| Luma([u8::from((x * 7 + y * 3 + seed) % 5 < 2 || (x + y + seed).is_multiple_of(7)) * 255]));
        for (s1, s2) in [(0, 1), (2, 2), (3, 4)] {
            let (ma, mb) = (m(s1), m(s2));
            let inter = ma.pixels().zip(mb.pixels()).filter(|(p, q)| p[0] > 0 && q[0] > 0).count() as f64;
            let union = ma.pixels().zip(mb.pixels()).filter(|(p, q)| p[0] > 0 || q[0] > 0).count() as f64;
            assert_eq!(rle_iou(&Rle::encode(&ma), &Rle::encode(&mb)), Some(inter / union), "{s1} {s2}");
        }
    }
}
