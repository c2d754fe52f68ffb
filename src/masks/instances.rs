//! Groups one object's detections in one image into instances. A detector (or `bop synth`)
//! often proposes several masks of the same instance; the paper's multi-mask selection
//! wants them together as one instance's candidates, while masks of different instances
//! must each get their own estimate.

use image::GrayImage;

/// Intersection over union of two same-sized masks (non-zero = inside).
pub fn mask_iou(a: &GrayImage, b: &GrayImage) -> f64 {
    let (both, in_a, in_b) = overlap_counts(a, b);
    let union = in_a + in_b - both;
    if union == 0 {
        0.0
    } else {
        both as f64 / union as f64
    }
}

/// Pixels inside both of two same-sized masks, inside `a`, inside `b`.
pub(super) fn overlap_counts(a: &GrayImage, b: &GrayImage) -> (u64, u64, u64) {
    let (mut both, mut in_a, mut in_b) = (0u64, 0u64, 0u64);
    for (&x, &y) in a.as_raw().iter().zip(b.as_raw()) {
        both += (x > 0 && y > 0) as u64;
        in_a += (x > 0) as u64;
        in_b += (y > 0) as u64;
    }
    (both, in_a, in_b)
}

/// Greedy grouping in descending score: each mask joins the first group whose leader (its
/// best-scoring mask) it overlaps with IoU ≥ `min_iou`, or leads a new group. Groups come
/// out best leader first, each listing indices into `masks` best first.
pub fn group_instances(masks: &[(&GrayImage, f64)], min_iou: f64) -> Vec<Vec<usize>> {
    let mut order: Vec<usize> = (0..masks.len()).collect();
    order.sort_by(|&a, &b| masks[b].1.total_cmp(&masks[a].1));
    let mut groups: Vec<Vec<usize>> = Vec::new();
    for i in order {
        match groups.iter_mut().find(|g| mask_iou(masks[g[0]].0, masks[i].0) >= min_iou) {
            Some(g) => g.push(i),
            None => groups.push(vec![i]),
        }
    }
    groups
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::Luma;

    fn rect(x0: u32, x1: u32) -> GrayImage {
        GrayImage::from_fn(20, 10, |x, y| Luma([if (x0..x1).contains(&x) && (2..8).contains(&y) { 255 } else { 0 }]))
    }

    #[test]
    fn overlapping_masks_group_and_separate_ones_do_not() {
        let (a, a2, b) = (rect(0, 6), rect(1, 6), rect(10, 16));
        assert!((mask_iou(&a, &a2) - 5.0 / 6.0).abs() < 1e-12);
        assert_eq!(mask_iou(&a, &b), 0.0);
        let groups = group_instances(&[(&a2, 0.5), (&b, 0.9), (&a, 1.0)], 0.5);
        assert_eq!(groups, vec![vec![2, 0], vec![1]]);
        assert!(group_instances(&[], 0.5).is_empty());
    }
}
