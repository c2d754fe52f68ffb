//! The ground truth of BOP's 2D detection and segmentation tasks, built as the toolkit's
//! `scripts/calc_gt_coco.py` builds `scene_gt_coco.json` (which `eval_bop22_coco.py`
//! then scores):
//!
//! * images: those of `test_targets_bop19.json`, every GT instance in them (not only the
//!   target objects);
//! * mask: the visible mask `mask_visib/<im>_<gt>.png`; its pixel count is the area (for
//!   COCO's small / medium / large); an instance with an empty visible mask is left out;
//! * box: by default "amodal", the tight box of the full silhouette `mask/<im>_<gt>.png`
//!   (within the image; left out when empty); "modal" (`scene_gt_coco_modal.json`) the
//!   tight box of the visible mask;
//! * ignored: `visib_fract < 0.1`, from `scene_gt_info.json`.

use super::dataset::{load_split_gt, load_targets};
use super::format::SCENE_GT_INFO;
use crate::masks::rle::Rle;
use anyhow::{anyhow, bail, Context, Result};
use std::collections::BTreeSet;
use std::path::Path;

/// Instances less visible than this are ignored (`calc_gt_coco.py`: `visibility < 0.1`).
pub const IGNORE_BELOW_VISIB_FRACT: f64 = 0.1;

/// Which ground-truth box the bbox AP compares with (the toolkit's `--bbox_type`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum BoxType {
    /// The whole object's silhouette, occluded parts included (the toolkit's default).
    #[default]
    Amodal,
    /// The visible part only.
    Modal,
}

impl std::str::FromStr for BoxType {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "amodal" => Ok(BoxType::Amodal),
            "modal" => Ok(BoxType::Modal),
            other => Err(format!("box type {other:?}: expected amodal or modal")),
        }
    }
}

impl std::fmt::Display for BoxType {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            BoxType::Amodal => "amodal",
            BoxType::Modal => "modal",
        })
    }
}

/// One ground-truth instance as the detection metrics see it.
#[derive(Clone, Debug, PartialEq)]
pub struct GtObject {
    pub obj_id: u32,
    /// `[x, y, w, h]`, whole pixels.
    pub bbox: [f64; 4],
    /// Visible mask.
    pub mask: Rle,
    /// Visible pixels.
    pub area: f64,
    pub ignore: bool,
}

/// One target image: its size (detection masks must match it) and its instances.
#[derive(Clone, Debug, PartialEq)]
pub struct DetectionImage {
    pub scene_id: u32,
    pub im_id: u32,
    pub width: u32,
    pub height: u32,
    pub objects: Vec<GtObject>,
}

/// The target images of `DATASET/<split>/` with their instances, by scene then image.
pub fn load_detection_gt(dataset: &Path, split: &str, box_type: BoxType, warnings: &mut Vec<String>) -> Result<Vec<DetectionImage>> {
    let targets: BTreeSet<(u32, u32)> = load_targets(dataset)?.iter().map(|t| (t.scene_id, t.im_id)).collect();
    let mut found = BTreeSet::new();
    let mut out = Vec::new();
    for img in load_split_gt(dataset, split, warnings)? {
        if !targets.contains(&(img.scene_id, img.im_id)) {
            continue;
        }
        found.insert((img.scene_id, img.im_id));
        let (width, height) = (img.cam.width, img.cam.height);
        let mut objects = Vec::with_capacity(img.instances.len());
        for (i, inst) in img.instances.iter().enumerate() {
            let visib_fract = inst.visib_fract.ok_or_else(|| {
                let info = inst.mask_visib_path.parent().and_then(Path::parent).map(|s| s.join(SCENE_GT_INFO)).unwrap_or_default();
                anyhow!("{}: missing; it holds visib_fract, by which instances under 10 % visible are ignored (scene {}, image {}, instance {i})", info.display(), img.scene_id, img.im_id)
            })?;
            let visible = read_mask(&inst.mask_visib_path, width, height)?;
            let Some(visible_box) = visible.bbox() else { continue };
            let bbox = match box_type {
                BoxType::Modal => visible_box,
                BoxType::Amodal => match read_mask(&inst.mask_path, width, height)?.bbox() {
                    Some(b) => b,
                    None => continue,
                },
            };
            objects.push(GtObject { obj_id: inst.obj_id, bbox: bbox.map(f64::from), area: visible.area() as f64, mask: visible, ignore: visib_fract < IGNORE_BELOW_VISIB_FRACT });
        }
        out.push(DetectionImage { scene_id: img.scene_id, im_id: img.im_id, width, height, objects });
    }
    // The toolkit's ground truth lists only annotated images; a target without annotation
    // makes its evaluation fail.
    if let Some((s, im)) = targets.difference(&found).next() {
        bail!("{}: target image {im} of scene {s} has no ground truth in {}/{s:06}/scene_gt.json", dataset.join(super::format::TEST_TARGETS).display(), dataset.join(split).display());
    }
    Ok(out)
}

/// The dataset's object ids, those of `models/obj_*.ply` (the toolkit's categories are its
/// list of the dataset's models); the ground truth's own when there is no models folder.
pub fn dataset_objects(dataset: &Path, images: &[DetectionImage]) -> BTreeSet<u32> {
    match super::synth::model_ids(&dataset.join("models")) {
        Ok(ids) => ids.into_iter().collect(),
        Err(_) => images.iter().flat_map(|im| im.objects.iter().map(|o| o.obj_id)).collect(),
    }
}

/// A mask PNG (any non-zero pixel is object) as an RLE, checked to be the image's size.
fn read_mask(path: &Path, width: u32, height: u32) -> Result<Rle> {
    let mask = image::open(path).with_context(|| format!("reading {}", path.display()))?.to_luma8();
    if mask.dimensions() != (width, height) {
        bail!("{}: {}×{} mask for a {width}×{height} image", path.display(), mask.width(), mask.height());
    }
    Ok(Rle::encode(&mask))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bop::format::{mask_path, mask_visib_path, SCENE_GT_INFO, TEST_TARGETS};
    use image::{GrayImage, Luma};
    use std::path::PathBuf;

    fn rect(x0: u32, y0: u32, w: u32, h: u32) -> GrayImage {
        GrayImage::from_fn(40, 30, |x, y| Luma([u8::from((x0..x0 + w).contains(&x) && (y0..y0 + h).contains(&y)) * 255]))
    }

    /// Scene 3, image 4 (40×30): instance 0 of object 7 half hidden, instance 1 of object 7
    /// 5 % visible, instance 2 of object 8 not visible at all.
    fn write_dataset(root: &Path) -> PathBuf {
        let scene = root.join("test/000003");
        for sub in ["rgb", "mask", "mask_visib"] {
            std::fs::create_dir_all(scene.join(sub)).unwrap();
        }
        image::RgbImage::new(40, 30).save(scene.join("rgb/000004.png")).unwrap();
        std::fs::write(scene.join("scene_camera.json"), r#"{"4": {"cam_K": [50, 0, 19.5, 0, 51, 14.5, 0, 0, 1], "depth_scale": 0.1}}"#).unwrap();
        let inst = |id: u32| format!(r#"{{"obj_id": {id}, "cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 500]}}"#);
        std::fs::write(scene.join("scene_gt.json"), format!(r#"{{"4": [{}, {}, {}]}}"#, inst(7), inst(7), inst(8))).unwrap();
        std::fs::write(scene.join(SCENE_GT_INFO), r#"{"4": [{"visib_fract": 0.5}, {"visib_fract": 0.05}, {"visib_fract": 0.0}]}"#).unwrap();
        for (i, full, visible) in [(0, rect(2, 3, 10, 7), rect(2, 3, 6, 7)), (1, rect(20, 10, 10, 10), rect(20, 10, 2, 2)), (2, rect(30, 0, 5, 5), rect(0, 0, 0, 0))] {
            full.save(mask_path(&scene, 4, i)).unwrap();
            visible.save(mask_visib_path(&scene, 4, i)).unwrap();
        }
        std::fs::write(root.join(TEST_TARGETS), r#"[{"scene_id": 3, "im_id": 4, "obj_id": 7, "inst_count": 1}]"#).unwrap();
        scene
    }

    #[test]
    fn boxes_masks_and_ignore_flags_as_the_toolkit_builds_them() {
        let dir = tempfile::tempdir().unwrap();
        write_dataset(dir.path());
        let gt = load_detection_gt(dir.path(), "test", BoxType::Amodal, &mut Vec::new()).unwrap();
        assert_eq!(gt.len(), 1);
        let im = &gt[0];
        assert_eq!((im.scene_id, im.im_id, im.width, im.height), (3, 4, 40, 30));
        // Every instance of a target image, not only the target's; the invisible one left out.
        assert_eq!(im.objects.len(), 2, "{:?}", im.objects);
        let (a, b) = (&im.objects[0], &im.objects[1]);
        assert_eq!((a.obj_id, a.bbox, a.area, a.ignore), (7, [2.0, 3.0, 10.0, 7.0], 42.0, false));
        assert_eq!((b.obj_id, b.bbox, b.area, b.ignore), (7, [20.0, 10.0, 10.0, 10.0], 4.0, true));
        assert_eq!(a.mask, Rle::encode(&rect(2, 3, 6, 7)));
        let modal = load_detection_gt(dir.path(), "test", BoxType::Modal, &mut Vec::new()).unwrap();
        assert_eq!((modal[0].objects[0].bbox, modal[0].objects[1].bbox), ([2.0, 3.0, 6.0, 7.0], [20.0, 10.0, 2.0, 2.0]));
    }

    #[test]
    fn missing_pieces_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let scene = write_dataset(dir.path());
        std::fs::write(dir.path().join(TEST_TARGETS), r#"[{"scene_id": 3, "im_id": 5, "obj_id": 7, "inst_count": 1}]"#).unwrap();
        let err = load_detection_gt(dir.path(), "test", BoxType::Amodal, &mut Vec::new()).unwrap_err().to_string();
        assert!(err.contains("target image 5 of scene 3 has no ground truth"), "{err}");
        std::fs::write(dir.path().join(TEST_TARGETS), r#"[{"scene_id": 3, "im_id": 4, "obj_id": 7, "inst_count": 1}]"#).unwrap();
        std::fs::remove_file(mask_path(&scene, 4, 0)).unwrap();
        let err = format!("{:#}", load_detection_gt(dir.path(), "test", BoxType::Amodal, &mut Vec::new()).unwrap_err());
        assert!(err.contains("mask/000004_000000.png"), "{err}");
        // Modal boxes do not need the full masks.
        assert!(load_detection_gt(dir.path(), "test", BoxType::Modal, &mut Vec::new()).is_ok());
        std::fs::remove_file(scene.join(SCENE_GT_INFO)).unwrap();
        let err = load_detection_gt(dir.path(), "test", BoxType::Modal, &mut Vec::new()).unwrap_err().to_string();
        assert!(err.contains("scene_gt_info.json: missing") && err.contains("instance 0"), "{err}");
    }
}
