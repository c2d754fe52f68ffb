//! Non-maximum suppression over boxes, across objects and instances: the best detection
//! keeps its place, any other overlapping it by IoU above the threshold goes.

/// Box IoU of [x, y, w, h] boxes.
pub fn box_iou(a: &[f64; 4], b: &[f64; 4]) -> f64 {
    let ix = (a[0] + a[2]).min(b[0] + b[2]) - a[0].max(b[0]);
    let iy = (a[1] + a[3]).min(b[1] + b[3]) - a[1].max(b[1]);
    if ix <= 0.0 || iy <= 0.0 {
        return 0.0;
    }
    let inter = ix * iy;
    inter / (a[2] * a[3] + b[2] * b[3] - inter)
}

pub fn area(b: &[f64; 4]) -> f64 {
    b[2] * b[3]
}

/// Share of box `a` inside box `b`.
pub fn inside_share(a: &[f64; 4], b: &[f64; 4]) -> f64 {
    let ix = (a[0] + a[2]).min(b[0] + b[2]) - a[0].max(b[0]);
    let iy = (a[1] + a[3]).min(b[1] + b[3]) - a[1].max(b[1]);
    if ix <= 0.0 || iy <= 0.0 || area(a) <= 0.0 {
        return 0.0;
    }
    ix * iy / area(a)
}

/// For each box, whether it is a part of a larger one in the same group: mostly (≥ 80 %)
/// inside a box of at least 1.5× its area whose score reaches `ratio` × its own. A textured
/// object's print answers smaller views of it, and one instance cannot sit inside the box
/// of another instance of the same object (it would be hidden behind it), so such a match
/// gives way to the whole object around it.
pub fn parts_of_larger(boxes: &[[f64; 4]], scores: &[f32], groups: &[usize], ratio: f32) -> Vec<bool> {
    (0..boxes.len())
        .map(|i| (0..boxes.len()).any(|j| j != i && groups[j] == groups[i] && scores[j] >= ratio * scores[i] && area(&boxes[j]) > 1.5 * area(&boxes[i]) && inside_share(&boxes[i], &boxes[j]) >= 0.8))
        .collect()
}

/// Indices of the kept boxes, best score first.
pub fn suppress(boxes: &[[f64; 4]], scores: &[f32], max_iou: f64) -> Vec<usize> {
    let mut order: Vec<usize> = (0..boxes.len()).collect();
    order.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]));
    let mut kept: Vec<usize> = Vec::new();
    for i in order {
        if kept.iter().all(|&k| box_iou(&boxes[k], &boxes[i]) <= max_iou) {
            kept.push(i);
        }
    }
    kept
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn iou_of_known_boxes() {
        assert_eq!(box_iou(&[0.0, 0.0, 10.0, 10.0], &[0.0, 0.0, 10.0, 10.0]), 1.0);
        assert!((box_iou(&[0.0, 0.0, 10.0, 10.0], &[5.0, 0.0, 10.0, 10.0]) - 50.0 / 150.0).abs() < 1e-12);
        assert_eq!(box_iou(&[0.0, 0.0, 10.0, 10.0], &[10.0, 0.0, 10.0, 10.0]), 0.0);
    }

    #[test]
    fn inside_share_is_the_part_of_the_first_box_covered() {
        assert_eq!(inside_share(&[2.0, 2.0, 2.0, 2.0], &[0.0, 0.0, 10.0, 10.0]), 1.0);
        assert_eq!(inside_share(&[0.0, 0.0, 10.0, 10.0], &[2.0, 2.0, 2.0, 2.0]), 0.04);
        assert_eq!(inside_share(&[8.0, 0.0, 4.0, 2.0], &[0.0, 0.0, 10.0, 10.0]), 0.5);
        assert_eq!(inside_share(&[20.0, 0.0, 4.0, 2.0], &[0.0, 0.0, 10.0, 10.0]), 0.0);
    }

    #[test]
    fn overlapping_weaker_boxes_go_separate_ones_stay() {
        let boxes = [[0.0, 0.0, 10.0, 10.0], [1.0, 1.0, 10.0, 10.0], [50.0, 50.0, 10.0, 10.0], [2.0, 0.0, 10.0, 10.0]];
        let scores = [0.7, 0.9, 0.5, 0.8];
        assert_eq!(suppress(&boxes, &scores, 0.5), vec![1, 2]);
    }

    #[test]
    fn a_part_gives_way_to_the_whole_of_the_same_object_only() {
        let whole = [0.0, 0.0, 40.0, 40.0];
        let part = [5.0, 5.0, 15.0, 15.0];
        let boxes = [whole, part];
        // The part scores a little better than the whole: still a part.
        assert_eq!(parts_of_larger(&boxes, &[0.5, 0.55], &[0, 0], 0.8), vec![false, true]);
        // Much better than the whole: kept (the whole may be the mistake).
        assert_eq!(parts_of_larger(&boxes, &[0.3, 0.55], &[0, 0], 0.8), vec![false, false]);
        // Another object in front of a larger one is not a part of it.
        assert_eq!(parts_of_larger(&boxes, &[0.5, 0.55], &[0, 1], 0.8), vec![false, false]);
    }
}
