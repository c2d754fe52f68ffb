//! Writes generated images as one BOP scene: images, masks, depth and the three per-scene
//! JSON files, plus the dataset's test targets and models info. Metres become mm here.

use super::format::*;
use crate::eval::scenes::SceneImage;
use crate::mesh::Mesh;
use anyhow::{bail, Context, Result};
use image::{GrayImage, ImageBuffer, Luma};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// BOP targets are the instances at least this visible (BOP'19 rules).
const TARGET_MIN_VISIB: f64 = 0.1;

/// Collects one scene's records while its images are written, then writes the JSON files.
pub(crate) struct SceneWriter {
    dir: PathBuf,
    scene_id: u32,
    camera: BTreeMap<u32, CameraRecord>,
    gt: BTreeMap<u32, Vec<GtRecord>>,
    info: BTreeMap<u32, Vec<GtInfoRecord>>,
}

impl SceneWriter {
    pub fn create(dataset: &Path, scene_id: u32) -> Result<Self> {
        let dir = scene_dir(dataset, TEST_SPLIT, scene_id);
        for sub in ["rgb", "depth", "mask", "mask_visib"] {
            let d = dir.join(sub);
            std::fs::create_dir_all(&d).with_context(|| format!("creating {}", d.display()))?;
        }
        Ok(Self { dir, scene_id, camera: BTreeMap::new(), gt: BTreeMap::new(), info: BTreeMap::new() })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    pub fn add(&mut self, im_id: u32, img: &SceneImage) -> Result<()> {
        let (w, h) = (img.cam.width, img.cam.height);
        save(&img.rgb, &rgb_path(&self.dir, im_id))?;
        let max_mm = img.depth.iter().fold(0f32, |a, &z| a.max(z)) as f64 * 1000.0;
        let depth_scale = depth_scale_for(max_mm).with_context(|| format!("image {im_id}"))?;
        let depth: ImageBuffer<Luma<u16>, Vec<u16>> = ImageBuffer::from_raw(w, h, img.depth.iter().map(|&z| (z as f64 * 1000.0 / depth_scale).round() as u16).collect()).expect("depth is w × h");
        save(&depth, &depth_path(&self.dir, im_id))?;
        let k = &img.cam;
        self.camera.insert(im_id, CameraRecord { cam_k: [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0], depth_scale });
        let (mut gts, mut infos) = (Vec::new(), Vec::new());
        for (i, inst) in img.instances.iter().enumerate() {
            save(&inst.mask, &mask_path(&self.dir, im_id, i))?;
            save(&inst.mask_visib, &mask_visib_path(&self.dir, im_id, i))?;
            let t = inst.pose.translation * 1000.0;
            gts.push(GtRecord { obj_id: inst.obj_id, cam_r_m2c: inst.pose.rotation_row_major(), cam_t_m2c: [t.x, t.y, t.z] });
            let valid = inst.mask.as_raw().iter().zip(&img.depth).filter(|&(&m, &z)| m > 0 && z > 0.0).count();
            infos.push(GtInfoRecord {
                bbox_obj: Some(bbox_xywh(&inst.mask)),
                bbox_visib: Some(bbox_xywh(&inst.mask_visib)),
                px_count_all: Some(inst.px_count_all as u64),
                px_count_valid: Some(valid as u64),
                px_count_visib: Some(inst.px_count_visib as u64),
                visib_fract: inst.visib_fract(),
            });
        }
        self.gt.insert(im_id, gts);
        self.info.insert(im_id, infos);
        Ok(())
    }

    /// Writes the scene's JSON files; returns its test targets, for
    /// [`write_test_targets`] to write with those of the dataset's other scenes.
    pub fn finish(self) -> Result<Vec<TargetRecord>> {
        write_json(&self.dir.join(SCENE_CAMERA), &self.camera)?;
        write_json(&self.dir.join(SCENE_GT), &self.gt)?;
        write_json(&self.dir.join(SCENE_GT_INFO), &self.info)?;
        let mut targets = Vec::new();
        for (&im_id, gts) in &self.gt {
            let mut counts: BTreeMap<u32, u32> = BTreeMap::new();
            for (g, info) in gts.iter().zip(&self.info[&im_id]) {
                if info.visib_fract >= TARGET_MIN_VISIB {
                    *counts.entry(g.obj_id).or_default() += 1;
                }
            }
            targets.extend(counts.into_iter().map(|(obj_id, inst_count)| TargetRecord { im_id, inst_count, obj_id, scene_id: self.scene_id }));
        }
        Ok(targets)
    }
}

/// The dataset's `test_targets_bop19.json`.
pub(crate) fn write_test_targets(dataset: &Path, targets: &[TargetRecord]) -> Result<()> {
    write_json(&dataset.join(TEST_TARGETS), &targets)
}

/// `models/models_info.json`: evaluation needs each object's diameter (mm). Entries
/// already in the file are kept as they are (a copied BOP models folder carries its
/// symmetries there); objects without one get their measured diameter and box.
pub(crate) fn write_models_info(dataset: &Path, objects: &[(u32, Mesh)]) -> Result<()> {
    let path = dataset.join(MODELS_INFO);
    let mut info: BTreeMap<u32, serde_json::Value> = if path.exists() {
        let text = std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
        let map: BTreeMap<String, serde_json::Value> = serde_json::from_str(&text).with_context(|| format!("{}: not a JSON object keyed by object id", path.display()))?;
        map.into_iter().filter_map(|(k, v)| k.parse().ok().map(|id| (id, v))).collect()
    } else {
        BTreeMap::new()
    };
    for (id, m) in objects {
        info.entry(*id).or_insert_with(|| {
            let (lo, hi) = m.bbox();
            let mm = |v: f32| v as f64 * 1000.0;
            let measured =
                ModelInfo { diameter: m.diameter() * 1000.0, min_x: mm(lo[0]), min_y: mm(lo[1]), min_z: mm(lo[2]), size_x: mm(hi[0] - lo[0]), size_y: mm(hi[1] - lo[1]), size_z: mm(hi[2] - lo[2]) };
            serde_json::to_value(measured).expect("serialisable")
        });
    }
    let dir = path.parent().expect("has a folder");
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    write_json(&path, &info)
}

/// BOP's usual 0.1 mm steps while the farthest depth fits 16 bits (6.5 m), else coarser.
fn depth_scale_for(max_mm: f64) -> Result<f64> {
    for scale in [0.1, 1.0, 10.0] {
        if max_mm / scale <= u16::MAX as f64 {
            return Ok(scale);
        }
    }
    bail!("depth {max_mm:.0} mm does not fit a 16-bit depth image even at 10 mm steps")
}

/// `[x, y, width, height]` of the non-zero pixels, BOP's `[-1, -1, -1, -1]` if none.
fn bbox_xywh(mask: &GrayImage) -> [i64; 4] {
    let mut b: Option<[u32; 4]> = None;
    for (x, y, p) in mask.enumerate_pixels() {
        if p[0] > 0 {
            let r = b.get_or_insert([x, y, x, y]);
            *r = [r[0].min(x), r[1].min(y), r[2].max(x), r[3].max(y)];
        }
    }
    match b {
        Some([x0, y0, x1, y1]) => [x0 as i64, y0 as i64, (x1 - x0 + 1) as i64, (y1 - y0 + 1) as i64],
        None => [-1; 4],
    }
}

fn save<P, C>(img: &ImageBuffer<P, C>, path: &Path) -> Result<()>
where
    P: image::PixelWithColorType,
    [P::Subpixel]: image::EncodableLayout,
    C: std::ops::Deref<Target = [P::Subpixel]>,
{
    img.save(path).with_context(|| format!("writing {}", path.display()))
}

fn write_json<T: serde::Serialize>(path: &Path, value: &T) -> Result<()> {
    let text = serde_json::to_string_pretty(value).expect("records serialise");
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn boxes_and_depth_scales() {
        let mut m = GrayImage::new(8, 6);
        assert_eq!(bbox_xywh(&m), [-1; 4]);
        m.put_pixel(2, 1, Luma([255]));
        m.put_pixel(5, 3, Luma([255]));
        assert_eq!(bbox_xywh(&m), [2, 1, 4, 3]);
        assert_eq!(depth_scale_for(2000.0).unwrap(), 0.1);
        assert_eq!(depth_scale_for(20_000.0).unwrap(), 1.0);
        assert!(depth_scale_for(1e7).is_err());
    }
}
