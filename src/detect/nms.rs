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
}
