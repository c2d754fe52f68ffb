//! Reads BOP datasets (ours or a downloaded one) into the library's units: poses in
//! metres, intrinsics with the image size. Errors name the file and the entry.

use super::format::*;
use crate::geometry::{Intrinsics, Pose};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Every error names the file, and the image / instance entry when it is about one.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
}

fn invalid(path: &Path, message: impl Into<String>) -> DatasetError {
    DatasetError::Invalid { path: path.to_path_buf(), message: message.into() }
}

/// One annotated object instance.
#[derive(Clone, Debug, PartialEq)]
pub struct GtInstance {
    pub obj_id: u32,
    /// `T_cam_obj`, metres.
    pub pose: Pose,
    /// From `scene_gt_info.json`; `None` when the scene has no such file.
    pub visib_fract: Option<f64>,
    pub mask_path: PathBuf,
    pub mask_visib_path: PathBuf,
}

/// One annotated image.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageGt {
    pub scene_id: u32,
    pub im_id: u32,
    /// With the image size read from the colour image's header.
    pub cam: Intrinsics,
    /// Depth PNG value × `depth_scale` = mm.
    pub depth_scale: f64,
    pub rgb_path: PathBuf,
    pub depth_path: PathBuf,
    pub instances: Vec<GtInstance>,
}

/// Every annotated image of every scene of `DATASET/<split>/`, by scene then image id.
pub fn load_split_gt(dataset: &Path, split: &str) -> Result<Vec<ImageGt>, DatasetError> {
    let dir = dataset.join(split);
    let io = |source| DatasetError::Io { path: dir.clone(), source };
    let mut scenes: Vec<PathBuf> = std::fs::read_dir(&dir).map_err(io)?.map(|e| e.map(|e| e.path())).collect::<Result<_, _>>().map_err(io)?;
    scenes.retain(|p| p.join(SCENE_GT).is_file());
    scenes.sort();
    let mut out = Vec::new();
    for s in scenes {
        out.extend(load_scene_gt(&s)?);
    }
    Ok(out)
}

/// What estimation needs of one image, all of which BOP publishes even for test sets whose
/// ground truth is withheld: the camera and where the pixels are.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageCamera {
    /// With the image size read from the colour image's header.
    pub cam: Intrinsics,
    /// Depth PNG value × `depth_scale` = mm.
    pub depth_scale: f64,
    pub rgb_path: PathBuf,
    pub depth_path: PathBuf,
}

fn scene_id_of(scene: &Path) -> Result<u32, DatasetError> {
    let id = scene.file_name().and_then(|n| n.to_str()).and_then(|n| n.parse::<u32>().ok());
    id.ok_or_else(|| invalid(scene, "a scene folder's name must be its numeric id"))
}

/// `scene_camera.json` of one scene folder, by image id.
pub fn load_scene_cameras(scene: &Path) -> Result<BTreeMap<u32, ImageCamera>, DatasetError> {
    let cam_path = scene.join(SCENE_CAMERA);
    read_images(&cam_path)?
        .into_iter()
        .map(|(im_id, entry)| {
            let cam: CameraRecord = serde_json::from_value(entry).map_err(|e| invalid(&cam_path, format!("image {im_id}: {e}")))?;
            let rgb_path = colour_image(scene, im_id)?;
            let (width, height) = image::image_dimensions(&rgb_path).map_err(|e| invalid(&rgb_path, e.to_string()))?;
            let k = intrinsics(&cam, width, height).map_err(|m| invalid(&cam_path, format!("image {im_id}: {m}")))?;
            Ok((im_id, ImageCamera { cam: k, depth_scale: cam.depth_scale, rgb_path, depth_path: depth_path(scene, im_id) }))
        })
        .collect()
}

/// The annotated images of one scene folder (`…/<scene_id:06>/`), by image id.
pub fn load_scene_gt(scene: &Path) -> Result<Vec<ImageGt>, DatasetError> {
    let scene_id = scene_id_of(scene)?;
    let gt_path = scene.join(SCENE_GT);
    let cam_path = scene.join(SCENE_CAMERA);
    let info_path = scene.join(SCENE_GT_INFO);
    let gt = read_images(&gt_path)?;
    let mut cams = load_scene_cameras(scene)?;
    let infos = if info_path.exists() { Some(read_images(&info_path)?) } else { None };
    let mut out = Vec::with_capacity(gt.len());
    for (im_id, entry) in gt {
        let records: Vec<GtRecord> = parse_list(&gt_path, im_id, entry)?;
        let camera = cams.remove(&im_id).ok_or_else(|| invalid(&cam_path, format!("no entry for image {im_id}, which {SCENE_GT} annotates")))?;
        let visib: Vec<Option<f64>> = match &infos {
            None => vec![None; records.len()],
            Some(infos) => {
                let entry = infos.get(&im_id).ok_or_else(|| invalid(&info_path, format!("no entry for image {im_id}, which {SCENE_GT} annotates")))?;
                let list: Vec<GtInfoRecord> = parse_list(&info_path, im_id, entry.clone())?;
                if list.len() != records.len() {
                    return Err(invalid(&info_path, format!("image {im_id}: {} instances, but {SCENE_GT} has {}", list.len(), records.len())));
                }
                list.iter().map(|i| Some(i.visib_fract)).collect()
            }
        };
        let instances = records
            .iter()
            .zip(visib)
            .enumerate()
            .map(|(i, (r, visib_fract))| {
                Ok(GtInstance {
                    obj_id: r.obj_id,
                    pose: pose_from_record(r).map_err(|m| invalid(&gt_path, format!("image {im_id}, instance {i}: {m}")))?,
                    visib_fract,
                    mask_path: mask_path(scene, im_id, i),
                    mask_visib_path: mask_visib_path(scene, im_id, i),
                })
            })
            .collect::<Result<_, DatasetError>>()?;
        out.push(ImageGt { scene_id, im_id, cam: camera.cam, depth_scale: camera.depth_scale, rgb_path: camera.rgb_path, depth_path: camera.depth_path, instances });
    }
    Ok(out)
}

/// `models/models_info.json` of a dataset (mm), by object id.
pub fn load_models_info(dataset: &Path) -> Result<BTreeMap<u32, ModelInfo>, DatasetError> {
    let path = dataset.join(MODELS_INFO);
    read_images(&path)?.into_iter().map(|(id, v)| serde_json::from_value(v).map(|m| (id, m)).map_err(|e| invalid(&path, format!("object {id}: {e}")))).collect()
}

/// A JSON object keyed by numeric ids (images, or objects in models_info).
fn read_images(path: &Path) -> Result<BTreeMap<u32, Value>, DatasetError> {
    let text = std::fs::read_to_string(path).map_err(|source| DatasetError::Io { path: path.to_path_buf(), source })?;
    let map: serde_json::Map<String, Value> = serde_json::from_str(&text).map_err(|e| invalid(path, format!("not a JSON object keyed by id: {e}")))?;
    map.into_iter().map(|(k, v)| k.parse::<u32>().map(|id| (id, v)).map_err(|_| invalid(path, format!("key {k:?} is not a numeric id")))).collect()
}

/// A per-image list whose items are parsed one by one, so an error names the instance.
fn parse_list<T: serde::de::DeserializeOwned>(path: &Path, im_id: u32, entry: Value) -> Result<Vec<T>, DatasetError> {
    let Value::Array(items) = entry else {
        return Err(invalid(path, format!("image {im_id}: expected a list of instances")));
    };
    items.into_iter().enumerate().map(|(i, v)| serde_json::from_value(v).map_err(|e| invalid(path, format!("image {im_id}, instance {i}: {e}")))).collect()
}

fn pose_from_record(r: &GtRecord) -> Result<Pose, String> {
    if !r.cam_r_m2c.iter().chain(&r.cam_t_m2c).all(|v| v.is_finite()) {
        return Err("non-finite pose".into());
    }
    let det = nalgebra::Matrix3::from_row_slice(&r.cam_r_m2c).determinant();
    // BOP files round rotations to a few digits, so only reject what is not near a rotation.
    if (det - 1.0).abs() > 1e-2 {
        return Err(format!("cam_R_m2c has determinant {det}, not a rotation"));
    }
    Ok(Pose::from_row_major(&r.cam_r_m2c, r.cam_t_m2c.map(|v| v * 1e-3)))
}

fn intrinsics(c: &CameraRecord, width: u32, height: u32) -> Result<Intrinsics, String> {
    let k = &c.cam_k;
    if k[1] != 0.0 || k[3] != 0.0 || k[6] != 0.0 || k[7] != 0.0 || k[8] != 1.0 {
        return Err(format!("cam_K {k:?} is not a pinhole matrix without skew"));
    }
    if !(c.depth_scale.is_finite() && c.depth_scale > 0.0) {
        return Err(format!("depth_scale {} must be positive", c.depth_scale));
    }
    Intrinsics::new(k[0], k[4], k[2], k[5], width, height).map_err(|e| e.to_string())
}

/// BOP colour images are PNG (some datasets JPEG) in `rgb/`; grey-only datasets (ITODD)
/// have `gray/` instead.
fn colour_image(scene: &Path, im_id: u32) -> Result<PathBuf, DatasetError> {
    let png = rgb_path(scene, im_id);
    let gray = scene.join("gray").join(format!("{im_id:06}.png"));
    let candidates = [png.clone(), png.with_extension("jpg"), gray.clone(), gray.with_extension("jpg")];
    candidates
        .into_iter()
        .find(|p| p.is_file())
        .ok_or_else(|| invalid(&png, format!("missing colour image of image {im_id} (nor .jpg, nor gray/{im_id:06}.png|jpg exists)")))
}

/// `test_targets_bop19.json`: which objects to estimate in which images, and how many
/// instances of each. Each entry is checked, and an error names its index.
pub fn load_targets(dataset: &Path) -> Result<Vec<TargetRecord>, DatasetError> {
    let path = dataset.join(TEST_TARGETS);
    let text = std::fs::read_to_string(&path).map_err(|source| DatasetError::Io { path: path.clone(), source })?;
    let Value::Array(items) = serde_json::from_str(&text).map_err(|e| invalid(&path, format!("not JSON: {e}")))? else {
        return Err(invalid(&path, "expected a list of {scene_id, im_id, obj_id, inst_count}"));
    };
    items
        .into_iter()
        .enumerate()
        .map(|(i, v)| {
            let t: TargetRecord = serde_json::from_value(v).map_err(|e| invalid(&path, format!("entry {i}: {e}")))?;
            if t.inst_count == 0 || t.obj_id == 0 {
                return Err(invalid(&path, format!("entry {i}: obj_id and inst_count must be positive")));
            }
            Ok(t)
        })
        .collect()
}

/// The colour image as RGB (grey images are expanded), with the file named on failure.
pub fn load_rgb(path: &Path) -> Result<image::RgbImage, DatasetError> {
    Ok(image::open(path).map_err(|e| invalid(path, e.to_string()))?.to_rgb8())
}

/// A BOP depth PNG (16 bit) as depth in mm (value × `depth_scale`), 0 where unknown.
pub fn load_depth_mm(path: &Path, depth_scale: f64) -> Result<(u32, u32, Vec<f32>), DatasetError> {
    let img = image::open(path).map_err(|e| invalid(path, e.to_string()))?;
    let depth = img.to_luma16();
    let (w, h) = depth.dimensions();
    Ok((w, h, depth.into_raw().into_iter().map(|v| (v as f64 * depth_scale) as f32).collect()))
}

/// `models/obj_<id:06>.ply`: BOP models are PLY in mm.
pub fn model_path(dataset: &Path, obj_id: u32) -> PathBuf {
    dataset.join("models").join(format!("obj_{obj_id:06}.ply"))
}
