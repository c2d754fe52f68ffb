//! The BOP dataset layout (bop_toolkit docs/bop_datasets_format.md), shared by the writer
//! and the reader: file names and the JSON records. Lengths in these files are mm.

use std::path::{Path, PathBuf};

/// Where a dataset's test images live: `DATASET/test/<scene_id:06>/`.
pub const TEST_SPLIT: &str = "test";
pub const SCENE_CAMERA: &str = "scene_camera.json";
pub const SCENE_GT: &str = "scene_gt.json";
pub const SCENE_GT_INFO: &str = "scene_gt_info.json";
pub const TEST_TARGETS: &str = "test_targets_bop19.json";
pub const MODELS_INFO: &str = "models/models_info.json";

pub fn scene_dir(dataset: &Path, split: &str, scene_id: u32) -> PathBuf {
    dataset.join(split).join(format!("{scene_id:06}"))
}

pub fn rgb_path(scene: &Path, im_id: u32) -> PathBuf {
    scene.join("rgb").join(format!("{im_id:06}.png"))
}

pub fn depth_path(scene: &Path, im_id: u32) -> PathBuf {
    scene.join("depth").join(format!("{im_id:06}.png"))
}

pub fn mask_path(scene: &Path, im_id: u32, instance: usize) -> PathBuf {
    scene.join("mask").join(format!("{im_id:06}_{instance:06}.png"))
}

pub fn mask_visib_path(scene: &Path, im_id: u32, instance: usize) -> PathBuf {
    scene.join("mask_visib").join(format!("{im_id:06}_{instance:06}.png"))
}

/// One image of `scene_camera.json`. BOP may add `cam_R_w2c`, `cam_t_w2c`, `view_level`,
/// which the reader ignores.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CameraRecord {
    /// Row-major 3×3 K.
    #[serde(rename = "cam_K")]
    pub cam_k: [f64; 9],
    /// Depth PNG value × depth_scale = depth in mm.
    pub depth_scale: f64,
}

/// One instance of `scene_gt.json`: `T_cam_obj` with the translation in mm. The rotation
/// is read as written; `rotation::check_rotation` judges it.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GtRecord {
    pub obj_id: u32,
    /// Row-major.
    #[serde(rename = "cam_R_m2c", deserialize_with = "numbers::rotation")]
    pub cam_r_m2c: [f64; 9],
    /// Millimetres.
    #[serde(deserialize_with = "numbers::translation")]
    pub cam_t_m2c: [f64; 3],
}

/// One instance of `scene_gt_info.json`. Boxes are `[x, y, width, height]`, all −1 when
/// the region is empty. Only `visib_fract` is required: it is all the toolkit's evaluation
/// reads (`eval_calc_errors.py`, `inout.get_im_targets`), and some datasets' files lack
/// the other fields, which are then not written back either.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GtInfoRecord {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bbox_obj: Option<[i64; 4]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bbox_visib: Option<[i64; 4]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub px_count_all: Option<u64>,
    /// Silhouette pixels with a non-zero depth value.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub px_count_valid: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub px_count_visib: Option<u64>,
    pub visib_fract: f64,
}

/// Fixed-length number lists whose errors name their field: serde's own message for a
/// `[f64; 9]` says "invalid length 8" without saying which list.
mod numbers {
    use serde::de::{Deserialize, Deserializer, Error};

    pub fn rotation<'de, D: Deserializer<'de>>(d: D) -> Result<[f64; 9], D::Error> {
        exactly(d, "cam_R_m2c", "a row-major 3×3 matrix")
    }

    pub fn translation<'de, D: Deserializer<'de>>(d: D) -> Result<[f64; 3], D::Error> {
        exactly(d, "cam_t_m2c", "x, y, z in mm")
    }

    fn exactly<'de, D: Deserializer<'de>, const N: usize>(d: D, field: &str, what: &str) -> Result<[f64; N], D::Error> {
        let values = Vec::<serde_json::Value>::deserialize(d).map_err(|e| D::Error::custom(format!("{field}: {e}")))?;
        if values.len() != N {
            return Err(D::Error::custom(format!("{field}: expected {N} numbers ({what}), got {}", values.len())));
        }
        let mut out = [0.0; N];
        for (i, (slot, v)) in out.iter_mut().zip(&values).enumerate() {
            *slot = v.as_f64().ok_or_else(|| D::Error::custom(format!("{field}: value {} is {v}, not a number", i + 1)))?;
        }
        Ok(out)
    }
}

/// One entry of `test_targets_bop19.json`: how many instances of an object to estimate.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct TargetRecord {
    pub im_id: u32,
    pub inst_count: u32,
    pub obj_id: u32,
    pub scene_id: u32,
}

/// One object of `models/models_info.json`, mm: the diameter (largest vertex distance),
/// and the model's axis-aligned box. Symmetries, when listed, are read by
/// `geometry::symmetry::parse_models_info`.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ModelInfo {
    pub diameter: f64,
    pub min_x: f64,
    pub min_y: f64,
    pub min_z: f64,
    pub size_x: f64,
    pub size_y: f64,
    pub size_z: f64,
}
