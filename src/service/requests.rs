//! The API's messages as plain serde types (the HTTP JSON bodies; the gRPC adapter maps
//! its protobuf messages onto the same), and their decoding into library inputs with a
//! clear error for every kind of bad input. Units: metres, pixels (OpenCV: pixel centres
//! at integer coordinates), `T_cam_obj`.

use super::base64_bytes::Base64Bytes;
use super::error::ServiceError;
use crate::geometry::symmetry::KnownSymmetries;
use crate::limits;
use crate::masks::{box_to_mask, mask_from_png, mask_from_rle, require_nonempty, BoxMask, MaskError, Rle};
use image::{GrayImage, RgbImage};

pub use super::wire::{ImageInput, IntrinsicsInput, PoseOutput, RleInput};

/// One detection of one object: a mask (PNG, base64, non-zero = object; or RLE) and/or a
/// box `[x, y, w, h]` in pixels (a box alone is segmented: the object inside the box).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct DetectionInput {
    pub object_id: String,
    #[serde(default)]
    pub mask_png: Option<Base64Bytes>,
    #[serde(default)]
    pub mask_rle: Option<RleInput>,
    #[serde(default)]
    pub bbox: Option<[f64; 4]>,
    #[serde(default = "one")]
    pub score: f32,
}

fn one() -> f32 {
    1.0
}

impl DetectionInput {
    /// The estimator's candidates for this detection: its mask, or for a box alone the
    /// box's mask proposals (`masks::proposals`), each carrying the box; `index` names the
    /// detection in errors.
    pub fn candidates(&self, index: usize, image: &RgbImage) -> Result<Vec<crate::estimate::Detection>, ServiceError> {
        match (self.bbox, self.mask_png.is_none() && self.mask_rle.is_none()) {
            (Some(b), true) => {
                let proposed = crate::masks::box_masks(image, b, BoxMask::Propose, &Default::default()).map_err(|e| ServiceError::invalid(format!("detections[{index}].bbox: {e}")))?;
                Ok(crate::estimate::Detection::from_box_masks(proposed, self.score))
            }
            _ => Ok(vec![crate::estimate::Detection::new(self.mask(index, image, BoxMask::Segment)?, self.score)]),
        }
    }

    /// The mask on `image`; `index` names the detection in errors. A box alone is
    /// segmented inside the box (`how`), which is why the image is needed.
    pub fn mask(&self, index: usize, image: &RgbImage, how: BoxMask) -> Result<GrayImage, ServiceError> {
        let (width, height) = image.dimensions();
        let bad = |f: &'static str| move |e: MaskError| ServiceError::invalid(format!("detections[{index}].{f}: {e}"));
        let (mask, field) = if let Some(png) = &self.mask_png {
            (mask_from_png(png.as_slice(), width, height).map_err(bad("mask_png"))?, "mask_png")
        } else if let Some(rle) = &self.mask_rle {
            let r = Rle::new(rle.size, rle.counts.clone()).map_err(|e| bad("mask_rle")(e.into()))?;
            (mask_from_rle(&r, width, height).map_err(bad("mask_rle"))?, "mask_rle")
        } else if let Some(b) = self.bbox {
            let s = box_to_mask(image, b, how).map_err(bad("bbox"))?;
            if let Some(note) = &s.note {
                tracing::info!("detections[{index}].bbox: {note}");
            }
            (s.mask, "bbox")
        } else {
            return Err(ServiceError::invalid(format!("detections[{index}]: give a mask_png, a mask_rle or a bbox")));
        };
        require_nonempty(mask).map_err(bad(field))
    }
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct EstimateOptions {
    /// Render-guided re-correspondence.
    pub rrc: bool,
    /// RRC also where the first PnP's inliers are sure enough to skip it
    /// (`EstimateConfig::rrc_sure_share`).
    pub rrc_always: bool,
    /// Templates kept by retrieval.
    pub k: usize,
    /// Candidate masks per instance (multi-mask selection).
    pub max_masks: usize,
    /// Instances estimated per object (its detections grouped by mask overlap).
    pub instances_per_object: usize,
    /// Refinement after PnP/RRC.
    pub refiner: crate::estimate::RefinerKind,
    /// Hypothesis verification: also refine the pose's axis flips and the best templates
    /// placed at the mask, and keep the best verified one (default on).
    pub verify: bool,
    /// Retrieved templates placed at the mask as hypotheses in verification.
    pub verify_templates: usize,
    /// Spins of the pose about each object axis verified: steps of a whole turn.
    pub spin_steps: usize,
    /// Templates with the most matches, placed where their matches put them, verified.
    pub verify_matched: usize,
    /// The winner tilted this many degrees each way across the line of sight, verified
    /// (0: off).
    pub nudge_degrees: f64,
    /// With depth: the best this many template views found on the measured surface under
    /// the mask, fitted there and judged beside the estimate's hypotheses; with the depth
    /// detector's candidates also the views every answer is reviewed against (0: off).
    pub depth_views: usize,
    /// Whether a box-only detection's poses are moved back until their outline covers the
    /// box (`estimate::box_prior`): `"auto"` (the default), for meshes without colours;
    /// `"tight"` or true, always; `"off"` or false, never (boxes drawn loose bring the
    /// object nearer by their looseness).
    #[serde(deserialize_with = "crate::estimate::box_prior::deserialize")]
    pub box_prior: crate::estimate::BoxPrior,
    /// Also answer the photo with each pose drawn on it (`overlay_png`): tinted
    /// silhouette, outline and object axes, for people to check by eye. Default off.
    pub overlay: bool,
}

impl Default for EstimateOptions {
    fn default() -> Self {
        let v = crate::estimate::VerifyConfig::default();
        Self {
            rrc: true,
            rrc_always: false,
            k: 125,
            max_masks: 2,
            instances_per_object: 1,
            refiner: crate::estimate::RefinerKind::default(),
            verify: true,
            verify_templates: v.templates,
            spin_steps: v.spin_steps,
            verify_matched: v.matched_templates,
            nudge_degrees: v.nudge_degrees,
            depth_views: v.depth_views,
            box_prior: crate::estimate::BoxPrior::default(),
            overlay: false,
        }
    }
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct EstimateRequest {
    pub image: ImageInput,
    pub intrinsics: IntrinsicsInput,
    /// The masks or boxes of the objects; or leave empty and name `objects` to have the
    /// server's detector find them.
    #[serde(default, deserialize_with = "limits::bounded_vec::<_, _, { limits::MAX_DETECTIONS }>")]
    pub detections: Vec<DetectionInput>,
    /// Objects to detect, then estimate (instead of `detections`).
    #[serde(default, deserialize_with = "limits::bounded_vec::<_, _, { limits::MAX_DETECT_OBJECTS }>")]
    pub objects: Vec<String>,
    /// The detector's settings when `objects` are named.
    #[serde(default)]
    pub detect: crate::detect::DetectOptions,
    #[serde(default)]
    pub options: EstimateOptions,
    /// The depth camera's image registered to `image` (RGB-D): each hypothesis is then
    /// fitted to the measured surface and judged on it.
    #[serde(default)]
    pub depth: Option<super::depth_input::DepthInput>,
}

impl EstimateRequest {
    /// Refuses a request over the input limits (src/limits.rs) from what it announces,
    /// before its image and masks are decoded: both adapters' requests pass here.
    pub fn check_limits(&self) -> Result<(), ServiceError> {
        let invalid = |m: String| ServiceError::invalid(m);
        limits::check_count("detections", self.detections.len(), limits::MAX_DETECTIONS).map_err(invalid)?;
        super::detect_requests::check_objects(&self.objects)?;
        match (self.detections.is_empty(), self.objects.is_empty()) {
            (true, true) => return Err(invalid("detections: at least one is needed (or name objects to detect)".into())),
            (false, false) => return Err(invalid("give detections or objects, not both".into())),
            _ => {}
        }
        for (i, d) in self.detections.iter().enumerate() {
            if let Some(rle) = &d.mask_rle {
                limits::check_count(&format!("detections[{i}].mask_rle.counts"), rle.counts.len(), limits::MAX_RLE_RUNS).map_err(invalid)?;
            }
        }
        let (w, h) = (self.intrinsics.width, self.intrinsics.height);
        limits::REQUEST_IMAGE.check(w, h).map_err(|e| invalid(format!("intrinsics.width × intrinsics.height: {e}")))?;
        let mask_pixels = self.detections.len() as u64 * w as u64 * h as u64;
        if mask_pixels > limits::MAX_MASK_PIXELS_PER_REQUEST {
            return Err(invalid(format!(
                "detections: {} masks of {w}×{h} are {mask_pixels} mask pixels, over the limit of {} per request",
                self.detections.len(),
                limits::MAX_MASK_PIXELS_PER_REQUEST
            )));
        }
        let o = &self.options;
        for (name, value, max) in [
            ("options.k", o.k, limits::MAX_RETRIEVAL_K),
            ("options.max_masks", o.max_masks, limits::MAX_MASKS_PER_INSTANCE),
            ("options.instances_per_object", o.instances_per_object, limits::MAX_MASKS_PER_INSTANCE),
            ("options.verify_templates", o.verify_templates, limits::MAX_VERIFY_TEMPLATES),
            ("options.verify_matched", o.verify_matched, limits::MAX_VERIFY_TEMPLATES),
            ("options.spin_steps", o.spin_steps, limits::MAX_SPIN_STEPS),
            ("options.depth_views", o.depth_views, crate::estimate::depth_search::MOST_VIEWS),
        ] {
            if value > max {
                return Err(invalid(format!("{name} is {value}, over the limit of {max}")));
            }
        }
        crate::estimate::verify::nudge_in_range(o.nudge_degrees).map_err(|e| invalid(format!("options.nudge_degrees: {e}")))?;
        Ok(())
    }
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct InstanceResult {
    pub object_id: String,
    /// Instance number within the object, best detection first.
    pub instance: usize,
    /// Absent when no pose was found (then `reason` says why).
    pub pose: Option<PoseOutput>,
    pub score: f32,
    /// When the server detected the object: the detector's evidence at this pose
    /// (`detect::confirm`), which decided that the instance is there; 0–1.
    #[serde(default)]
    pub confirmation_score: Option<f32>,
    /// Index into the request's `detections` (or the response's, when the server
    /// detected) of the mask the pose came from.
    pub detection_index: Option<usize>,
    pub reason: Option<String>,
    /// Per candidate mask: retrieval, matches, inliers, RRC, IoU, selection scores.
    pub diagnostics: serde_json::Value,
    /// Stage times of this instance, milliseconds.
    pub timings_ms: std::collections::BTreeMap<String, f64>,
    /// The object's symmetries (metres), as its `ObjectInfo` has them; `None`: unknown (an
    /// object stored before model format 5). The pose is as right as `pose ∘ S` for each
    /// discrete `S`, and as any turn about a continuous axis.
    #[serde(default)]
    pub symmetries: Option<KnownSymmetries>,
    /// The object has a continuous symmetry: the pose's rotation about that axis is
    /// arbitrary (any turn about it is equally right).
    #[serde(default)]
    pub arbitrary_rotation_about_axis: bool,
    /// The best pose judged on the photo that is another answer, and by how much it lost
    /// (`estimate::runner_up`); absent when there was none.
    #[serde(default)]
    pub runner_up: Option<RunnerUpOutput>,
}

/// A pose the evidence nearly chose instead of the answer.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct RunnerUpOutput {
    pub pose: PoseOutput,
    /// The answer's verification score minus this pose's (≥ 0).
    pub margin: f32,
    /// Symmetry-aware largest surface distance from the answer, share of the diameter.
    pub distance_over_diameter: f32,
    /// The margin is below the server's close-call threshold (`estimate::runner_up::CLOSE_CALL`):
    /// the photo could hardly tell the two poses apart.
    #[serde(default)]
    pub close_call: bool,
}

impl From<&crate::estimate::RunnerUp> for RunnerUpOutput {
    fn from(u: &crate::estimate::RunnerUp) -> Self {
        Self { pose: PoseOutput::from(&u.pose), margin: u.margin as f32, distance_over_diameter: u.distance as f32, close_call: u.close_call() }
    }
}

impl InstanceResult {
    /// `arbitrary_rotation_about_axis` of an object with these symmetries.
    pub fn arbitrary_rotation(symmetries: Option<&KnownSymmetries>) -> bool {
        symmetries.is_some_and(KnownSymmetries::arbitrary_rotation_about_axis)
    }
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct EstimateResponse {
    pub results: Vec<InstanceResult>,
    /// What the detector found when the request named `objects` (`detection_index` points
    /// here then); empty when the request gave its detections.
    #[serde(default)]
    pub detections: Vec<super::detect_requests::DetectionOutput>,
    /// Why there is no result, when the detector found nothing.
    #[serde(default)]
    pub reason: Option<String>,
    /// With `options.overlay`: the photo with the poses drawn on it, PNG (base64 in JSON).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub overlay_png: Option<Base64Bytes>,
    /// Whole request, milliseconds (decoding included).
    pub total_ms: f64,
}

/// A mesh upload: the file's bytes, its format and length unit, and the files it refers to
/// (MTL, textures, glTF buffers) by the names it uses.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct MeshInput {
    /// File bytes (base64 in JSON).
    pub data: Base64Bytes,
    /// ply | obj | gltf | glb
    pub format: String,
    /// mm | cm | m (PLY and OBJ need it; glTF is metres).
    #[serde(default)]
    pub units: Option<String>,
    #[serde(default, deserialize_with = "limits::bounded_vec::<_, _, { limits::MAX_MESH_RESOURCES }>")]
    pub resources: Vec<ResourceInput>,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ResourceInput {
    /// File name as the mesh refers to it (no folders).
    pub name: String,
    /// File bytes (base64 in JSON).
    pub data: Base64Bytes,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct OnboardOptions {
    /// Icosphere level 0–3 and in-plane steps (defaults: 2 and 12, 1944 templates).
    pub level: u32,
    pub in_plane: u32,
    /// PCA of the patch descriptors: "auto" (default: compress only descriptors wider than
    /// 256), null/"off" (keep all) or a component count.
    pub pca: crate::onboard::PcaSetting,
    /// How the patch descriptors are stored: "f16" (default), "i8", "pq2" or "pq4".
    pub descriptors: crate::onboard::DescriptorCoding,
    /// Which templates keep patch rows: "auto" (default: per view with the embedded
    /// backbone, per template with an ONNX one), "per-view" or "per-template".
    pub patch_rows: crate::onboard::PatchRows,
}

impl Default for OnboardOptions {
    fn default() -> Self {
        Self { level: 2, in_plane: 12, pca: crate::onboard::PcaSetting::Auto, descriptors: crate::onboard::DescriptorCoding::F16, patch_rows: crate::onboard::PatchRows::Auto }
    }
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct OnboardRequest {
    pub object_id: String,
    pub mesh: MeshInput,
    #[serde(default)]
    pub options: OnboardOptions,
    #[serde(default)]
    pub replace: bool,
}

impl MeshInput {
    /// Writes the mesh and its resources into `dir` and loads it.
    pub fn load(&self, dir: &std::path::Path) -> Result<crate::mesh::Mesh, ServiceError> {
        let ext = match self.format.to_ascii_lowercase().as_str() {
            f @ ("ply" | "obj" | "gltf" | "glb") => f.to_string(),
            other => return Err(ServiceError::invalid(format!("mesh.format {other:?}: expected ply, obj, gltf or glb"))),
        };
        let units = match &self.units {
            None => None,
            Some(u) => Some(u.parse::<crate::mesh::Units>().map_err(|e| ServiceError::invalid(format!("mesh.units: {e}")))?),
        };
        limits::check_count("mesh.resources", self.resources.len(), limits::MAX_MESH_RESOURCES).map_err(ServiceError::invalid)?;
        let write =
            |name: &str, data: &Base64Bytes| -> Result<(), ServiceError> { std::fs::write(dir.join(name), data.as_slice()).map_err(|e| ServiceError::internal(format!("staging {name}: {e}"))) };
        for (i, r) in self.resources.iter().enumerate() {
            let ok = !r.name.is_empty() && !r.name.contains(['/', '\\']) && r.name != "." && r.name != ".." && !r.name.starts_with("mesh.");
            if !ok {
                return Err(ServiceError::invalid(format!("mesh.resources[{i}].name {:?}: a plain file name is required", r.name)));
            }
            write(&r.name, &r.data)?;
        }
        let path = dir.join(format!("mesh.{ext}"));
        write(path.file_name().and_then(|n| n.to_str()).unwrap_or("mesh"), &self.data)?;
        crate::mesh::load_mesh_with(&path, units, &crate::mesh::Folder::confined(dir))
            .map_err(|e| ServiceError::invalid(format!("mesh: {}", e.to_string().replace(&dir.display().to_string(), "<upload>"))))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn estimate(detections: usize, width: u32, height: u32) -> serde_json::Value {
        let d = serde_json::json!({"object_id": "a", "bbox": [0, 0, 1, 1]});
        serde_json::json!({"image": {"raw_rgb8": "", "width": width, "height": height},
            "intrinsics": {"fx": 1, "fy": 1, "cx": 0, "cy": 0, "width": width, "height": height},
            "detections": vec![d; detections]})
    }

    fn refusal(v: serde_json::Value) -> String {
        match serde_json::from_value::<EstimateRequest>(v) {
            Ok(r) => r.check_limits().unwrap_err().message,
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn requests_over_the_limits_are_refused_before_decoding() {
        let max = limits::MAX_DETECTIONS;
        assert!(serde_json::from_value::<EstimateRequest>(estimate(max, 64, 48)).unwrap().check_limits().is_ok());
        assert!(refusal(estimate(max + 1, 64, 48)).contains(&format!("more than {max} items, over the limit")));
        assert!(refusal(estimate(1, 20_000, 10)).starts_with("intrinsics.width × intrinsics.height: 20000×10 is over the limit"));
        assert!(refusal(estimate(200, 8_000, 5_000)).contains("mask pixels, over the limit of 1000000000 per request"));
        let mut v = estimate(1, 64, 48);
        v["options"] = serde_json::json!({"k": 1_000_000_000});
        assert_eq!(refusal(v), "options.k is 1000000000, over the limit of 100000");
        let mut v = estimate(1, 64, 48);
        v["options"] = serde_json::json!({"verify_templates": 65});
        assert_eq!(refusal(v), "options.verify_templates is 65, over the limit of 64");
        let mut v = estimate(1, 64, 48);
        v["options"] = serde_json::json!({"verify_matched": 65});
        assert_eq!(refusal(v), "options.verify_matched is 65, over the limit of 64");
        let mut v = estimate(1, 64, 48);
        v["options"] = serde_json::json!({"spin_steps": 360});
        assert_eq!(refusal(v), "options.spin_steps is 360, over the limit of 72");
        let mut v = estimate(1, 64, 48);
        v["options"] = serde_json::json!({"depth_views": 13});
        assert_eq!(refusal(v), "options.depth_views is 13, over the limit of 12");
        for degrees in [90.0, -1.0] {
            let mut v = estimate(1, 64, 48);
            v["options"] = serde_json::json!({ "nudge_degrees": degrees });
            assert_eq!(refusal(v), format!("options.nudge_degrees: {degrees} is outside 0–45 degrees"));
        }
        let mut v = estimate(1, 64, 48);
        v["detections"][0]["mask_rle"] = serde_json::json!({"counts": vec![0; limits::MAX_RLE_RUNS + 1], "size": [48, 64]});
        assert!(refusal(v).contains("over the limit"));
    }

    #[test]
    fn raw_images_over_the_limits_are_refused_before_their_length_is_checked() {
        let raw = |w, h| ImageInput { encoded: None, raw_rgb8: Some(vec![0; 12].into()), width: Some(w), height: Some(h) };
        assert_eq!(raw(2, 2).decode().unwrap().dimensions(), (2, 2));
        let e = raw(100_000, 100_000).decode().unwrap_err().message;
        assert!(e.starts_with("image.width × image.height: 100000×100000 is over the limit of 16384 pixels a side"), "{e}");
        let png = crate::limits::tests::png_header_only(20_000, 20_000);
        let e = ImageInput { encoded: Some(png.into()), raw_rgb8: None, width: None, height: None }.decode().unwrap_err().message;
        assert!(e.starts_with("image.encoded: 20000×20000 is over the limit"), "{e}");
    }

    #[test]
    fn uploads_with_too_many_files_are_refused() {
        let resources: Vec<_> = (0..=limits::MAX_MESH_RESOURCES).map(|i| serde_json::json!({"name": format!("{i}.png"), "data": ""})).collect();
        let v = serde_json::json!({"object_id": "a", "mesh": {"data": "", "format": "obj", "resources": resources}});
        let e = serde_json::from_value::<OnboardRequest>(v).unwrap_err().to_string();
        assert!(e.contains(&format!("more than {} items, over the limit", limits::MAX_MESH_RESOURCES)), "{e}");
        let many = MeshInput { data: vec![].into(), format: "obj".into(), units: None, resources: vec![ResourceInput { name: "a".into(), data: vec![].into() }; limits::MAX_MESH_RESOURCES + 1] };
        let e = many.load(std::path::Path::new("/nonexistent")).unwrap_err().message;
        assert_eq!(e, format!("mesh.resources has {} items, over the limit of {}", limits::MAX_MESH_RESOURCES + 1, limits::MAX_MESH_RESOURCES));
    }
}
