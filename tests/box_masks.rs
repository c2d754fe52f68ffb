//! Box-only detections on generated scenes: the mask segmented inside each instance's
//! box against the true visible mask, next to what the filled box scores.

use b2tfpose::eval::scenes::{generate_image, SceneConfig};
use b2tfpose::features::mask_bbox;
use b2tfpose::masks::{box_to_mask, mask_iou, BoxMask, Method};
use b2tfpose::mesh::procedural::textured_box;
use b2tfpose::render::{RenderPool, RendererConfig};

#[test]
fn segmented_boxes_match_the_visible_masks_far_better_than_filled_boxes() {
    let pool = RenderPool::new(1, RendererConfig::default()).unwrap();
    let objects = [(1, textured_box([0.10, 0.06, 0.16], 3)), (2, textured_box([0.05, 0.05, 0.08], 9))];
    let cfg = SceneConfig { images: 4, objects_per_image: 2, image_size: (320, 240), seed: 7, ..Default::default() };
    let (mut segmented, mut filled, mut fallbacks, mut n) = (0.0, 0.0, 0, 0);
    for im in 0..cfg.images as u32 {
        let scene = generate_image(&objects, &cfg, &pool, im).unwrap();
        for inst in &scene.instances {
            let (x0, y0, x1, y1) = mask_bbox(&inst.mask_visib).unwrap();
            let bbox = [x0 as f64, y0 as f64, (x1 - x0 + 1) as f64, (y1 - y0 + 1) as f64];
            let s = box_to_mask(&scene.rgb, bbox, BoxMask::Segment).unwrap();
            let f = box_to_mask(&scene.rgb, bbox, BoxMask::Fill).unwrap();
            let (iou_s, iou_f) = (mask_iou(&s.mask, &inst.mask_visib), mask_iou(&f.mask, &inst.mask_visib));
            eprintln!("image {im} object {}: segmented IoU {iou_s:.3}, filled {iou_f:.3}, {:?}, {:.0} ms", inst.obj_id, s.method, s.ms);
            segmented += iou_s;
            filled += iou_f;
            fallbacks += (s.method == Method::EllipseFallback) as usize;
            n += 1;
        }
    }
    let (segmented, filled) = (segmented / n as f64, filled / n as f64);
    eprintln!("{n} instances: mean IoU segmented {segmented:.3}, filled box {filled:.3}, {fallbacks} fallbacks");
    assert!(n >= 6, "only {n} instances");
    assert!(segmented > filled + 0.1, "segmented {segmented:.3} vs filled {filled:.3}");
    assert!(segmented > 0.75, "segmented {segmented:.3}");
}
