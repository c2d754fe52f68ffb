//! `b2tf bop eval --detections`: the BOP'22 2D detection (bbox) and segmentation (segm)
//! scores of a detections file, as `bop_toolkit/scripts/eval_bop22_coco.py` computes them:
//! ground truth from `detection_gt.rs`, COCO AP from `coco_ap.rs`.
//!
//! Which detections count, as the toolkit decides: those of target images only (others
//! are dropped), of the dataset's objects only (COCOeval evaluates the ground truth's
//! categories; an unknown one could not change a score, having no ground truth), and for
//! segm only those with a segmentation. Each drop is reported once as a warning. A
//! detection's area (for small / medium / large) is its box's w·h even for segm, as
//! pycocotools' `loadRes` sets it when results carry boxes.

use super::coco_ap::{summarize, CocoSummary, Dt, Gt, ImageCategory, ABSENT};
use super::coco_iou::{box_iou, rle_iou};
use super::detection_gt::{BoxType, DetectionImage};
use super::detections::DetectionRecord;
use anyhow::{bail, Result};
use serde::Serialize;
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::fmt::Write;

/// Both scores of one detections file.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DetectionReport {
    /// Entries in the file.
    pub detections: usize,
    /// Those scored by the bbox AP (target images, known objects).
    pub evaluated: usize,
    /// Target images.
    pub images: usize,
    pub bbox_type: BoxType,
    pub bbox: CocoSummary,
    /// Absent when no scored detection has a segmentation.
    pub segm: Option<CocoSummary>,
    /// Mean of the per-image `time` over the file's images, −1 when a time is negative
    /// (the toolkit's `average_time_per_image`).
    pub average_time_per_image: f64,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum IouType {
    Bbox,
    Segm,
}

/// Scores `dets` (as read, in file order: errors and warnings name entries by index)
/// against `images`; `objects` are the dataset's object ids.
pub fn evaluate_detections(images: &[DetectionImage], objects: &BTreeSet<u32>, dets: &[DetectionRecord], box_type: BoxType, warnings: &mut Vec<String>) -> Result<DetectionReport> {
    let image_index: HashMap<(u32, u32), usize> = images.iter().enumerate().map(|(i, im)| ((im.scene_id, im.im_id), i)).collect();
    let mut kept: Vec<(usize, usize)> = Vec::new(); // (entry, image)
    let mut not_target: Vec<usize> = Vec::new();
    let mut unknown: Vec<usize> = Vec::new();
    for (entry, d) in dets.iter().enumerate() {
        match image_index.get(&(d.scene_id, d.image_id)) {
            None => not_target.push(entry),
            Some(_) if !objects.contains(&d.obj_id) => unknown.push(entry),
            Some(&i) => kept.push((entry, i)),
        }
    }
    if let Some(&first) = not_target.first() {
        let d = &dets[first];
        warnings.push(format!(
            "{} detections are for images that are not test targets (first: entry {first}, scene {} image {}); skipped, as the BOP toolkit does",
            not_target.len(),
            d.scene_id,
            d.image_id
        ));
    }
    if let Some(&first) = unknown.first() {
        warnings.push(format!("{} detections name objects the dataset does not have (first: entry {first}, category_id {}); skipped, as the BOP toolkit does", unknown.len(), dets[first].obj_id));
    }
    if kept.is_empty() {
        bail!("no detection is for a target image and object of the dataset: nothing to score (the BOP toolkit scores such a file −1)");
    }
    for &(entry, i) in &kept {
        if let Some(seg) = &dets[entry].segmentation {
            let im = &images[i];
            if seg.size != [im.height, im.width] {
                bail!("entry {entry}: segmentation is {}×{} (h×w) but image {} of scene {} is {}×{}", seg.size[0], seg.size[1], im.im_id, im.scene_id, im.height, im.width);
            }
        }
    }
    let with_mask = kept.iter().filter(|&&(e, _)| dets[e].segmentation.is_some()).count();
    if with_mask > 0 && with_mask < kept.len() {
        warnings.push(format!("{} of {} detections have no segmentation; the segm AP scores the {with_mask} that do, as the BOP toolkit does", kept.len() - with_mask, kept.len()));
    }
    let bbox = summarize(&by_category(images, objects, dets, &kept, IouType::Bbox));
    let segm = (with_mask > 0).then(|| summarize(&by_category(images, objects, dets, &kept, IouType::Segm)));
    Ok(DetectionReport { detections: dets.len(), evaluated: kept.len(), images: images.len(), bbox_type: box_type, bbox, segm, average_time_per_image: mean_time(dets) })
}

/// For each object, each image holding it (as ground truth or detection) in image order.
fn by_category(images: &[DetectionImage], objects: &BTreeSet<u32>, dets: &[DetectionRecord], kept: &[(usize, usize)], kind: IouType) -> BTreeMap<u32, Vec<ImageCategory>> {
    let mut per_image: BTreeMap<(u32, usize), Vec<&DetectionRecord>> = BTreeMap::new();
    for &(entry, i) in kept {
        let d = &dets[entry];
        if kind == IouType::Bbox || d.segmentation.is_some() {
            per_image.entry((d.obj_id, i)).or_default().push(d);
        }
    }
    objects
        .iter()
        .map(|&obj| {
            let list = images
                .iter()
                .enumerate()
                .filter_map(|(i, im)| {
                    let gts: Vec<_> = im.objects.iter().filter(|g| g.obj_id == obj).collect();
                    let ds = per_image.get(&(obj, i)).map_or(&[][..], Vec::as_slice);
                    if gts.is_empty() && ds.is_empty() {
                        return None;
                    }
                    let gt_items = gts.iter().map(|g| Gt { area: g.area, ignore: g.ignore }).collect();
                    let dt_items = ds.iter().map(|d| Dt { score: d.score, area: d.bbox[2] * d.bbox[3] }).collect();
                    Some(ImageCategory::new(gt_items, dt_items, |di, gi| match kind {
                        IouType::Bbox => box_iou(ds[di].bbox, gts[gi].bbox),
                        // Sizes were checked above; −1 (never a match) is pycocotools' value otherwise.
                        IouType::Segm => ds[di].segmentation.as_ref().and_then(|m| rle_iou(m, &gts[gi].mask)).unwrap_or(-1.0),
                    }))
                })
                .collect();
            (obj, list)
        })
        .collect()
}

/// One time per image (the first given; the toolkit checks they agree), averaged.
fn mean_time(dets: &[DetectionRecord]) -> f64 {
    if dets.iter().any(|d| d.time < 0.0) {
        return ABSENT;
    }
    let mut per_image: BTreeMap<(u32, u32), f64> = BTreeMap::new();
    for d in dets {
        per_image.entry((d.scene_id, d.image_id)).or_insert(d.time);
    }
    if per_image.is_empty() {
        ABSENT
    } else {
        per_image.values().sum::<f64>() / per_image.len() as f64
    }
}

fn cell(v: f64) -> String {
    if v == ABSENT {
        "-".into()
    } else {
        format!("{v:.4}")
    }
}

fn format_summary(s: &mut String, title: &str, c: &CocoSummary) {
    let _ = writeln!(s, "{title}");
    let _ = writeln!(s, "| AP | AP50 | AP75 | AP_small | AP_medium | AP_large | AR1 | AR10 | AR100 | AR_small | AR_medium | AR_large |");
    let _ = writeln!(s, "|{}", "---:|".repeat(12));
    let row = [c.ap, c.ap50, c.ap75, c.ap_small, c.ap_medium, c.ap_large, c.ar1, c.ar10, c.ar100, c.ar_small, c.ar_medium, c.ar_large];
    let _ = writeln!(s, "| {} |", row.map(cell).join(" | "));
    let _ = writeln!(s, "\n| object | AP |\n|---|---:|");
    for (obj, ap) in &c.per_category {
        let _ = writeln!(s, "| obj {obj} | {} |", cell(*ap));
    }
}

/// The bbox table, then the segm one; "-" where nothing could be counted.
pub fn format_detection_report(r: &DetectionReport) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "{} of {} detections scored over {} target images; mean {} s per image", r.evaluated, r.detections, r.images, cell(r.average_time_per_image));
    format_summary(&mut s, &format!("\nbbox AP ({} boxes; COCO AP@[.5:.95], BOP'22):", r.bbox_type), &r.bbox);
    if let Some(segm) = &r.segm {
        format_summary(&mut s, "\nsegm AP (visible masks; COCO AP@[.5:.95], BOP'22):", segm);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bop::detection_gt::GtObject;
    use crate::masks::rle::Rle;
    use image::{GrayImage, Luma};

    fn rect(x0: u32, y0: u32, w: u32, h: u32) -> Rle {
        Rle::encode(&GrayImage::from_fn(40, 30, |x, y| Luma([u8::from((x0..x0 + w).contains(&x) && (y0..y0 + h).contains(&y)) * 255])))
    }

    /// Scene 1 image 2 (40×30) holding object 5 at x 0..10, y 0..10.
    fn images() -> Vec<DetectionImage> {
        let mask = rect(0, 0, 10, 10);
        vec![DetectionImage { scene_id: 1, im_id: 2, width: 40, height: 30, objects: vec![GtObject { obj_id: 5, bbox: [0.0, 0.0, 10.0, 10.0], area: 100.0, mask, ignore: false }] }]
    }

    fn det(scene_id: u32, image_id: u32, obj_id: u32, bbox: [f64; 4], segmentation: Option<Rle>) -> DetectionRecord {
        DetectionRecord { scene_id, image_id, obj_id, bbox, score: 0.9, time: 0.25, segmentation }
    }

    #[test]
    fn scores_boxes_and_masks_and_reports_what_it_skipped() {
        let objects = BTreeSet::from([5, 6]);
        // The box is exact; the mask covers 60 of the 100 pixels: segm IoU 0.6 → 3/10.
        let dets = vec![det(1, 2, 5, [0.0, 0.0, 10.0, 10.0], Some(rect(0, 0, 6, 10))), det(1, 3, 5, [0.0, 0.0, 10.0, 10.0], None), det(1, 2, 9, [0.0, 0.0, 10.0, 10.0], None)];
        let mut warnings = Vec::new();
        let r = evaluate_detections(&images(), &objects, &dets, BoxType::Amodal, &mut warnings).unwrap();
        assert_eq!((r.detections, r.evaluated, r.images, r.average_time_per_image), (3, 1, 1, 0.25));
        // A lone true positive: 1 / (1 + ε), as pycocotools gives it (see coco_ap).
        assert!((r.bbox.ap - 1.0).abs() < 1e-15 && r.bbox.per_category[&6] == ABSENT, "{r:?}");
        let segm = r.segm.unwrap();
        assert!((segm.ap - 0.3).abs() < 1e-12, "{segm:?}");
        assert_eq!(warnings.len(), 2, "{warnings:?}");
        assert!(warnings[0].starts_with("1 detections are for images that are not test targets (first: entry 1, scene 1 image 3)"), "{}", warnings[0]);
        assert!(warnings[1].starts_with("1 detections name objects the dataset does not have (first: entry 2, category_id 9)"), "{}", warnings[1]);
        let table = format_detection_report(&evaluate_detections(&images(), &objects, &dets, BoxType::Modal, &mut Vec::new()).unwrap());
        assert!(table.contains("bbox AP (modal boxes") && table.contains("| 1.0000 | 1.0000 | 1.0000 | 1.0000 | - | - |") && table.contains("| obj 6 | - |"), "{table}");
        assert!(table.contains("segm AP") && table.contains("| obj 5 | 0.3000 |"), "{table}");
    }

    #[test]
    fn box_only_detections_have_no_segm_score_and_bad_input_is_refused() {
        let objects = BTreeSet::from([5]);
        let r = evaluate_detections(&images(), &objects, &[det(1, 2, 5, [0.0, 0.0, 10.0, 5.0], None)], BoxType::Amodal, &mut Vec::new()).unwrap();
        assert!(r.segm.is_none() && (r.bbox.ap - 0.1).abs() < 1e-12, "{r:?}");
        let wrong_size = Rle::encode(&GrayImage::new(30, 40));
        let err = evaluate_detections(&images(), &objects, &[det(1, 2, 5, [0.0; 4], None), det(1, 2, 5, [0.0; 4], Some(wrong_size))], BoxType::Amodal, &mut Vec::new()).unwrap_err().to_string();
        assert!(err.contains("entry 1: segmentation is 40×30 (h×w) but image 2 of scene 1 is 30×40"), "{err}");
        let err = evaluate_detections(&images(), &objects, &[det(7, 2, 5, [0.0; 4], None)], BoxType::Amodal, &mut Vec::new()).unwrap_err().to_string();
        assert!(err.contains("nothing to score"), "{err}");
    }
}
