//! Reads BOP datasets (ours or a downloaded one) into the library's units: poses in
//! metres, intrinsics with the image size. Errors name the file and the entry.

use super::format::*;
use super::rotation::{check_rotation, pose_as_given, LooseRotations};
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
    /// `T_cam_obj`, metres. The rotation is the file's matrix unchanged (see `rotation.rs`):
    /// the toolkit scores with it as written, which real ground truth leaves up to 10⁻²
    /// from orthonormal.
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
/// What was accepted but is worth a look (rotations that are not quite rotations) is
/// added to `warnings`, one line per file.
pub fn load_split_gt(dataset: &Path, split: &str, warnings: &mut Vec<String>) -> Result<Vec<ImageGt>, DatasetError> {
    let dir = dataset.join(split);
    let io = |source| DatasetError::Io { path: dir.clone(), source };
    let mut scenes: Vec<PathBuf> = std::fs::read_dir(&dir).map_err(io)?.map(|e| e.map(|e| e.path())).collect::<Result<_, _>>().map_err(io)?;
    scenes.retain(|p| p.join(SCENE_GT).is_file());
    scenes.sort();
    let mut out = Vec::new();
    for s in scenes {
        out.extend(load_scene_gt(&s, warnings)?);
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

/// The annotated images of one scene folder (`…/<scene_id:06>/`), by image id; warnings as
/// for [`load_split_gt`].
pub fn load_scene_gt(scene: &Path, warnings: &mut Vec<String>) -> Result<Vec<ImageGt>, DatasetError> {
    let scene_id = scene_id_of(scene)?;
    let gt_path = scene.join(SCENE_GT);
    let cam_path = scene.join(SCENE_CAMERA);
    let info_path = scene.join(SCENE_GT_INFO);
    let gt = read_images(&gt_path)?;
    let mut cams = load_scene_cameras(scene)?;
    let infos = if info_path.exists() { Some(read_images(&info_path)?) } else { None };
    let mut out = Vec::with_capacity(gt.len());
    let mut loose = LooseRotations::default();
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
                let deviation = check_rotation("cam_R_m2c", &r.cam_r_m2c).map_err(|m| invalid(&gt_path, format!("image {im_id}, instance {i}: {m}")))?;
                loose.note(deviation, || format!("image {im_id}, instance {i}"));
                Ok(GtInstance {
                    obj_id: r.obj_id,
                    pose: pose_as_given(&r.cam_r_m2c, r.cam_t_m2c.map(|v| v * 1e-3)),
                    visib_fract,
                    mask_path: mask_path(scene, im_id, i),
                    mask_visib_path: mask_visib_path(scene, im_id, i),
                })
            })
            .collect::<Result<_, DatasetError>>()?;
        out.push(ImageGt { scene_id, im_id, cam: camera.cam, depth_scale: camera.depth_scale, rgb_path: camera.rgb_path, depth_path: camera.depth_path, instances });
    }
    warnings.extend(loose.warning(&gt_path, "cam_R_m2c"));
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
    candidates.into_iter().find(|p| p.is_file()).ok_or_else(|| invalid(&png, format!("missing colour image of image {im_id} (nor .jpg, nor gray/{im_id:06}.png|jpg exists)")))
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

/// An image's depth PNG as the estimator takes it (metres, checked against the colour
/// image's `size` and for plausible values).
pub fn load_depth(camera: &ImageCamera, size: (u32, u32)) -> Result<crate::depth::DepthImage, DatasetError> {
    let path = &camera.depth_path;
    crate::depth::DepthImage::read_png_for(path, camera.depth_scale, size, &format!("depth_scale {} from scene_camera.json", camera.depth_scale)).map_err(|e| invalid(path, e))
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

#[cfg(test)]
mod tests {
    //! Hand-written scenes, so that the reader is tested without a GPU.

    use super::*;

    /// A scene with one 40×30 image (id 4) whose `scene_gt.json` is `gt`.
    fn write_scene(root: &Path, gt: &str) -> PathBuf {
        let scene = root.join("test/000003");
        std::fs::create_dir_all(scene.join("rgb")).unwrap();
        image::RgbImage::new(40, 30).save(scene.join("rgb/000004.png")).unwrap();
        std::fs::write(scene.join("scene_camera.json"), r#"{"4": {"cam_K": [50, 0, 19.5, 0, 51, 14.5, 0, 0, 1], "depth_scale": 0.1}}"#).unwrap();
        std::fs::write(scene.join("scene_gt.json"), gt).unwrap();
        scene
    }

    fn gt_with_rotation(r: &str) -> String {
        format!(r#"{{"4": [{{"obj_id": 7, "cam_R_m2c": [{r}], "cam_t_m2c": [10, -20, 500]}}]}}"#)
    }

    const IDENTITY: &str = "1, 0, 0, 0, 1, 0, 0, 0, 1";

    /// LM-O scene 2, image 804, object 5 as the toolkit's tests ship it: R·Rᵀ is 9.4·10⁻³
    /// off the identity and the determinant is 1.0137.
    const LMO: [f64; 9] = [-0.4265835, -0.90545594, 0.08228724, -0.2176405, 0.01298762, -0.98068271, 0.88320192, -0.43448076, -0.20156121];

    fn load(scene: &Path) -> Result<(Vec<ImageGt>, Vec<String>), DatasetError> {
        let mut warnings = Vec::new();
        load_scene_gt(scene, &mut warnings).map(|images| (images, warnings))
    }

    #[test]
    fn reads_a_hand_written_scene() {
        let dir = tempfile::tempdir().unwrap();
        let scene = write_scene(dir.path(), &gt_with_rotation(IDENTITY));
        let (images, warnings) = load(&scene).unwrap();
        assert_eq!((images.len(), warnings.len()), (1, 0));
        let im = &images[0];
        assert_eq!((im.scene_id, im.im_id, im.cam.width, im.cam.height, im.cam.fy), (3, 4, 40, 30, 51.0));
        assert_eq!(im.instances[0].pose.translation, nalgebra::Vector3::new(0.01, -0.02, 0.5));
        assert_eq!(im.instances[0].visib_fract, None);
        assert!(im.instances[0].mask_visib_path.ends_with("mask_visib/000004_000000.png"));
    }

    #[test]
    fn gt_info_needs_only_visib_fract() {
        // The toolkit's evaluation reads nothing else; some datasets lack the other fields.
        let dir = tempfile::tempdir().unwrap();
        let scene = write_scene(dir.path(), &gt_with_rotation(IDENTITY));
        std::fs::write(scene.join(SCENE_GT_INFO), r#"{"4": [{"visib_fract": 0.25, "px_count_all": 100}]}"#).unwrap();
        assert_eq!(load(&scene).unwrap().0[0].instances[0].visib_fract, Some(0.25));
        std::fs::write(scene.join(SCENE_GT_INFO), r#"{"4": [{"bbox_obj": [1, 2, 3, 4]}]}"#).unwrap();
        let err = load(&scene).unwrap_err().to_string();
        assert!(err.contains("scene_gt_info.json: image 4, instance 0: missing field `visib_fract`"), "{err}");
    }

    #[test]
    fn a_rough_rotation_is_kept_as_written_with_a_warning() {
        let dir = tempfile::tempdir().unwrap();
        let lmo = LMO.map(|v| v.to_string()).join(", ");
        let scene = write_scene(dir.path(), &gt_with_rotation(&lmo));
        let (images, warnings) = load(&scene).unwrap();
        assert_eq!(images[0].instances[0].pose.rotation_row_major(), LMO);
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        let gt_path = scene.join(SCENE_GT).display().to_string();
        assert!(warnings[0].starts_with(&gt_path) && warnings[0].contains("1 of 1 cam_R_m2c matrices") && warnings[0].contains("(image 4, instance 0)"), "{}", warnings[0]);
    }

    #[test]
    fn broken_entries_are_refused_naming_file_entry_and_field() {
        let dir = tempfile::tempdir().unwrap();
        let scene = write_scene(dir.path(), "{}");
        let cases = [
            (r#"{"4": [{"obj_id": 7, "cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1]}]}"#.to_string(), "image 4, instance 0: missing field `cam_t_m2c`"),
            (gt_with_rotation("2, 0, 0, 0, 1, 0, 0, 0, 1"), "image 4, instance 0: cam_R_m2c: not a rotation: determinant is 2"),
            (gt_with_rotation("1, 0, 0, 0, 1, 0, 0, 0, -1"), "image 4, instance 0: cam_R_m2c: not a rotation: determinant is -1"),
            (gt_with_rotation("1, 0.5, 0, 0, 1, 0, 0, 0, 1"), "image 4, instance 0: cam_R_m2c: not a rotation: R·Rᵀ differs from the identity by up to 0.5"),
            (gt_with_rotation("1, 0, 0, 0, 1, 0, 0, 0"), "image 4, instance 0: cam_R_m2c: expected 9 numbers (a row-major 3×3 matrix), got 8"),
            (gt_with_rotation(r#"1, "0", 0, 0, 1, 0, 0, 0, 1"#), "image 4, instance 0: cam_R_m2c: value 2 is \"0\", not a number"),
            (r#"{"4": [{"obj_id": 7, "cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0]}]}"#.into(), "cam_t_m2c: expected 3 numbers (x, y, z in mm), got 2"),
            (r#"{"4": [{"obj_id": 7, "cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, NaN], "cam_t_m2c": [0, 0, 1]}]}"#.into(), "not a JSON object keyed by id"),
            (r#"{"4": {"obj_id": 7}}"#.into(), "image 4: expected a list"),
            (r#"{"four": []}"#.into(), "key \"four\" is not a numeric id"),
            (r#"{"4": [ "#.into(), "not a JSON object"),
            (r#"{"5": []}"#.into(), "scene_camera.json: no entry for image 5"),
        ];
        for (text, needle) in cases {
            std::fs::write(scene.join(SCENE_GT), &text).unwrap();
            let err = load(&scene).unwrap_err().to_string();
            let file = if needle.starts_with("scene_camera") { SCENE_CAMERA } else { SCENE_GT };
            assert!(err.starts_with(&scene.join(file).display().to_string()), "{err}");
            assert!(err.contains(needle), "{err:?} lacks {needle:?}");
        }
    }
}
