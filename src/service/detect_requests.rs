//! The Detect call's messages (HTTP JSON bodies; gRPC maps onto the same) and the
//! detector's report turned into them. A detection in the answer carries the same
//! `object_id`, `bbox`, `score` and `mask_rle` fields as an Estimate detection, so a client
//! may pass it back to Estimate as it is.

use super::error::ServiceError;
use super::wire::{ImageInput, IntrinsicsInput, PoseOutput, RleInput};
use crate::detect::{DetectOptions, DetectReport, Detection, MaskSource, Searched};
use crate::limits;

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct DetectRequest {
    pub image: ImageInput,
    pub intrinsics: IntrinsicsInput,
    /// Objects to look for; empty: every object in the store.
    #[serde(default, deserialize_with = "limits::bounded_vec::<_, _, { limits::MAX_DETECT_OBJECTS }>")]
    pub objects: Vec<String>,
    #[serde(default)]
    pub options: DetectOptions,
    /// The depth camera's image registered to `image` (RGB-D): the objects are then looked
    /// for among the surfaces the depth shows (`detect::depth_detector`).
    #[serde(default)]
    pub depth: Option<super::depth_input::DepthInput>,
}

impl DetectRequest {
    /// Refuses what is over the limits from what the request announces, before decoding.
    pub fn check_limits(&self) -> Result<(), ServiceError> {
        check_objects(&self.objects)?;
        check_image_size(&self.intrinsics)
    }
}

/// The object list of a Detect (or an Estimate by detection): within the limit, each a
/// valid id.
pub fn check_objects(objects: &[String]) -> Result<(), ServiceError> {
    limits::check_count("objects", objects.len(), limits::MAX_DETECT_OBJECTS).map_err(ServiceError::invalid)?;
    for (i, id) in objects.iter().enumerate() {
        crate::store::validate_id(id).map_err(|e| ServiceError::invalid(format!("objects[{i}]: {e}")))?;
    }
    Ok(())
}

pub fn check_image_size(k: &IntrinsicsInput) -> Result<(), ServiceError> {
    limits::REQUEST_IMAGE.check(k.width, k.height).map_err(|e| ServiceError::invalid(format!("intrinsics.width × intrinsics.height: {e}")))
}

/// The score's parts: the template match and what the render at the coarse pose says.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ScoreTerms {
    /// Template match, share of the best possible response, 0–1.
    pub shape: f32,
    /// Share of the rendered outline with an image edge of its orientation, above chance, 0–1.
    pub outline: f32,
    /// Chromaticity overlap of render and image, 0–1; absent for meshes without colours.
    pub colour: Option<f32>,
    /// Share of the render's interior edges (print, creases) the image answers, above
    /// chance, 0–1; absent where the render shows too few.
    pub texture: Option<f32>,
}

/// One found object instance.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct DetectionOutput {
    pub object_id: String,
    /// [x, y, w, h], pixels.
    pub bbox: [f64; 4],
    /// 0–1; detections under the request's `min_score` are not returned.
    pub score: f32,
    /// The object's pixels (BOP/COCO uncompressed RLE: column-major, first run background).
    pub mask_rle: RleInput,
    /// Where the mask came from: "silhouette" (the render at the coarse pose) or
    /// "graph_cut" (the photo segmented inside the box, where it agreed with the render).
    pub mask_source: MaskSource,
    /// The matched template's pose placed where it was found, `T_cam_obj`: a coarse
    /// hypothesis (tens of degrees, a few per cent of depth).
    pub coarse_pose: PoseOutput,
    pub terms: ScoreTerms,
}

impl From<&Detection> for DetectionOutput {
    fn from(d: &Detection) -> Self {
        let rle = crate::masks::Rle::encode(&d.mask);
        Self {
            object_id: d.object_id.clone(),
            bbox: d.bbox,
            score: d.score,
            mask_rle: RleInput { counts: rle.counts, size: rle.size },
            mask_source: d.mask_source,
            coarse_pose: PoseOutput::from(&d.pose),
            terms: ScoreTerms { shape: d.shape_score, outline: d.evidence.outline, colour: d.evidence.colour, texture: d.evidence.texture },
        }
    }
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct DetectResponse {
    /// Best first, across objects and instances.
    pub detections: Vec<DetectionOutput>,
    /// Why nothing was found, when nothing was (not an error).
    pub reason: Option<String>,
    /// Per object: the distances and scales searched, candidates examined.
    pub searched: Vec<Searched>,
    /// The detector's stages (responses, search, verify, masks, total), milliseconds.
    pub timings_ms: std::collections::BTreeMap<String, f64>,
    /// The whole request on the server, decoding included, milliseconds.
    pub total_ms: f64,
}

impl DetectResponse {
    pub fn new(report: DetectReport, started: std::time::Instant) -> Self {
        Self {
            detections: report.detections.iter().map(DetectionOutput::from).collect(),
            reason: report.reason,
            searched: report.searched,
            timings_ms: report.timings.by_stage(),
            total_ms: started.elapsed().as_secs_f64() * 1e3,
        }
    }
}

/// The detector's timings by stage name, without the unit suffix the map's name carries.
#[cfg(test)]
mod tests {
    use super::*;

    fn request(objects: serde_json::Value) -> serde_json::Value {
        serde_json::json!({"image": {"raw_rgb8": "", "width": 64, "height": 48},
            "intrinsics": {"fx": 1, "fy": 1, "cx": 0, "cy": 0, "width": 64, "height": 48},
            "objects": objects})
    }

    fn refusal(v: serde_json::Value) -> String {
        match serde_json::from_value::<DetectRequest>(v) {
            Ok(r) => r.check_limits().unwrap_err().message,
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn object_lists_over_the_limit_or_with_bad_ids_are_refused() {
        let max = limits::MAX_DETECT_OBJECTS;
        let ids: Vec<String> = (0..max).map(|i| format!("o{i}")).collect();
        assert!(serde_json::from_value::<DetectRequest>(request(serde_json::json!(ids))).unwrap().check_limits().is_ok());
        let ids: Vec<String> = (0..=max).map(|i| format!("o{i}")).collect();
        assert!(refusal(request(serde_json::json!(ids))).contains(&format!("more than {max} items, over the limit")));
        assert!(refusal(request(serde_json::json!(["ok", "../etc"]))).starts_with("objects[1]: "));
        let mut v = request(serde_json::json!([]));
        v["intrinsics"]["width"] = serde_json::json!(20_000);
        assert!(refusal(v).starts_with("intrinsics.width × intrinsics.height: 20000×48 is over the limit"));
    }

    #[test]
    fn options_default_to_the_detectors() {
        let r: DetectRequest = serde_json::from_value(request(serde_json::json!([]))).unwrap();
        assert_eq!(r.options, DetectOptions::default());
        let mut v = request(serde_json::json!(["a"]));
        v["options"] = serde_json::json!({"min_score": 0.5, "max_distance_m": 2.0});
        let r: DetectRequest = serde_json::from_value(v).unwrap();
        assert_eq!((r.options.min_score, r.options.max_distance_m, r.options.max_detections), (0.5, Some(2.0), DetectOptions::default().max_detections));
    }
}
