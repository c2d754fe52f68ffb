//! Protobuf messages to and from the request types the core takes (the same ones the
//! HTTP JSON bodies deserialize into), so both adapters feed the core identical inputs.
//! Proto3 zero values stand for "default" where the proto says so.

use super::detect_requests::{DetectRequest, DetectResponse, DetectionOutput};
use super::error::ServiceError;
use super::operations::{OperationState, OperationStatus};
use super::proto as pb;
use super::requests::{self as rq, EstimateOptions, OnboardOptions};
use crate::detect::DetectOptions;
use crate::geometry::symmetry::KnownSymmetries;
use crate::onboard::PcaSetting;
use crate::store::ObjectInfo;

pub fn required<T>(v: Option<T>, field: &str) -> Result<T, ServiceError> {
    v.ok_or_else(|| ServiceError::invalid(format!("{field} is required")))
}

fn non_zero<T: Default + PartialEq>(v: T, default: T) -> T {
    if v == T::default() {
        default
    } else {
        v
    }
}

pub fn image(image: pb::Image) -> rq::ImageInput {
    let (encoded, raw_rgb8) = match image.data {
        Some(pb::image::Data::Encoded(b)) => (Some(b.into()), None),
        Some(pb::image::Data::RawRgb8(b)) => (None, Some(b.into())),
        None => (None, None),
    };
    let size = |v: u32| (v > 0).then_some(v);
    rq::ImageInput { encoded, raw_rgb8, width: size(image.width), height: size(image.height) }
}

pub fn depth(d: pb::Depth) -> crate::service::depth_input::DepthInput {
    let mut out = crate::service::depth_input::DepthInput::default();
    match d.data {
        Some(pb::depth::Data::Png16(b)) => out.png16 = Some(b.into()),
        Some(pb::depth::Data::RawU16(b)) => out.raw_u16 = Some(b.into()),
        Some(pb::depth::Data::RawF32(b)) => out.raw_f32 = Some(b.into()),
        None => {}
    }
    let size = |v: u32| (v > 0).then_some(v);
    out.width = size(d.width);
    out.height = size(d.height);
    out.scale_mm = (d.scale_mm != 0.0).then_some(d.scale_mm);
    out
}

pub fn intrinsics(k: pb::Intrinsics) -> rq::IntrinsicsInput {
    rq::IntrinsicsInput { fx: k.fx, fy: k.fy, cx: k.cx, cy: k.cy, width: k.width, height: k.height }
}

pub fn detections(d: Vec<pb::Detection>) -> Vec<rq::DetectionInput> {
    d.into_iter()
        .map(|d| {
            let (mask_png, mask_rle) = match d.mask {
                Some(pb::detection::Mask::MaskPng(b)) => (Some(b.into()), None),
                Some(pb::detection::Mask::MaskRle(rle)) => (None, Some(rq::RleInput { counts: rle.counts, size: [rle.height, rle.width] })),
                None => (None, None),
            };
            rq::DetectionInput { object_id: d.object_id, mask_png, mask_rle, bbox: d.bbox.map(|b| [b.x, b.y, b.width, b.height]), score: d.score.unwrap_or(1.0) }
        })
        .collect()
}

pub fn pose(p: rq::PoseOutput) -> pb::Pose {
    pb::Pose { r: p.r.to_vec(), t: p.t.to_vec(), quaternion_wxyz: p.quaternion_wxyz.to_vec() }
}

pub fn estimate_request(r: pb::EstimateRequest) -> Result<rq::EstimateRequest, ServiceError> {
    let image = image(required(r.image, "image")?);
    let intrinsics = intrinsics(required(r.intrinsics, "intrinsics")?);
    let detections = detections(r.detections);
    let defaults = EstimateOptions::default();
    let o = r.options.unwrap_or_default();
    let options = EstimateOptions {
        rrc: o.rrc.unwrap_or(defaults.rrc),
        rrc_always: o.rrc_always,
        k: non_zero(o.k as usize, defaults.k),
        max_masks: non_zero(o.max_masks as usize, defaults.max_masks),
        instances_per_object: non_zero(o.instances_per_object as usize, defaults.instances_per_object),
        verify: o.verify.unwrap_or(defaults.verify),
        verify_templates: o.verify_templates.map_or(defaults.verify_templates, |n| n as usize),
        spin_steps: o.spin_steps.map_or(defaults.spin_steps, |n| n as usize),
        verify_matched: o.verify_matched.map_or(defaults.verify_matched, |n| n as usize),
        nudge_degrees: o.nudge_degrees.unwrap_or(defaults.nudge_degrees),
        depth_views: o.depth_views.map_or(defaults.depth_views, |n| n as usize),
        box_prior: o.box_prior.map_or(defaults.box_prior, crate::estimate::BoxPrior::from_flag),
        overlay: o.overlay,
        refiner: if o.refiner.is_empty() { defaults.refiner } else { o.refiner.parse().map_err(|e: String| ServiceError::invalid(format!("options.refiner: {e}")))? },
    };
    Ok(rq::EstimateRequest { image, intrinsics, detections, objects: r.objects, detect: detect_options(r.detect), options, depth: r.depth.map(depth) })
}

/// Proto3 zero values and unset optionals are the detector's defaults.
pub fn detect_options(o: Option<pb::DetectOptions>) -> DetectOptions {
    let defaults = DetectOptions::default();
    let o = o.unwrap_or_default();
    DetectOptions {
        max_detections: non_zero(o.max_detections as usize, defaults.max_detections),
        min_score: o.min_score.unwrap_or(defaults.min_score),
        min_distance_m: o.min_distance_m,
        max_distance_m: o.max_distance_m,
        refine_masks: o.refine_masks.unwrap_or(defaults.refine_masks),
    }
}

pub fn detect_request(r: pb::DetectRequest) -> Result<DetectRequest, ServiceError> {
    let image = image(required(r.image, "image")?);
    let intrinsics = intrinsics(required(r.intrinsics, "intrinsics")?);
    Ok(DetectRequest { image, intrinsics, objects: r.objects, options: detect_options(r.options), depth: r.depth.map(depth) })
}

pub fn detected_object(d: DetectionOutput) -> pb::DetectedObject {
    let [x, y, width, height] = d.bbox;
    pb::DetectedObject {
        object_id: d.object_id,
        bbox: Some(pb::BBox { x, y, width, height }),
        score: d.score,
        mask_rle: Some(pb::Rle { counts: d.mask_rle.counts, height: d.mask_rle.size[0], width: d.mask_rle.size[1] }),
        mask_source: serde_json::to_value(d.mask_source).ok().and_then(|v| v.as_str().map(String::from)).unwrap_or_default(),
        coarse_pose: Some(pose(d.coarse_pose)),
        shape_score: d.terms.shape,
        outline_score: d.terms.outline,
        colour_score: d.terms.colour,
        texture_score: d.terms.texture,
    }
}

pub fn detect_response(r: DetectResponse) -> pb::DetectResponse {
    let searched = r
        .searched
        .into_iter()
        .map(|s| pb::SearchedObject { object_id: s.object_id, min_distance_m: s.distance_m[0], max_distance_m: s.distance_m[1], scales: s.scales as u32, candidates: s.candidates as u32 })
        .collect();
    pb::DetectResponse {
        detections: r.detections.into_iter().map(detected_object).collect(),
        reason: r.reason.unwrap_or_default(),
        searched,
        timings_ms: r.timings_ms.into_iter().collect(),
        total_ms: r.total_ms,
    }
}

pub fn estimate_response(r: rq::EstimateResponse) -> pb::EstimateResponse {
    let results = r
        .results
        .into_iter()
        .map(|i| pb::InstanceResult {
            object_id: i.object_id,
            instance: i.instance as u32,
            pose: i.pose.map(pose),
            score: i.score,
            confirmation_score: i.confirmation_score,
            detection_index: i.detection_index.map_or(-1, |d| d as i32),
            reason: i.reason.unwrap_or_default(),
            diagnostics_json: i.diagnostics.to_string(),
            timings_ms: i.timings_ms.into_iter().collect(),
            symmetries: i.symmetries.map(symmetries),
            arbitrary_rotation_about_axis: i.arbitrary_rotation_about_axis,
            runner_up: i.runner_up.map(|u| pb::RunnerUp { pose: Some(pose(u.pose)), margin: u.margin, distance_over_diameter: u.distance_over_diameter, close_call: u.close_call }),
        })
        .collect();
    pb::EstimateResponse {
        results,
        total_ms: r.total_ms,
        detections: r.detections.into_iter().map(detected_object).collect(),
        reason: r.reason.unwrap_or_default(),
        overlay_png: r.overlay_png.map(|b| b.0).unwrap_or_default(),
    }
}

pub fn onboard_request(r: pb::OnboardRequest) -> Result<rq::OnboardRequest, ServiceError> {
    let mesh = required(r.mesh, "mesh")?;
    let defaults = OnboardOptions::default();
    let o = r.options.unwrap_or_default();
    let pca = match (o.pca, o.full_descriptors) {
        (0, false) => PcaSetting::Auto,
        (0, true) => PcaSetting::Off,
        (k, false) => PcaSetting::Components(k as usize),
        (k, true) => return Err(ServiceError::invalid(format!("options: pca {k} and full_descriptors contradict each other; set one"))),
    };
    let descriptors = if o.descriptors.is_empty() { defaults.descriptors } else { o.descriptors.parse().map_err(|e: String| ServiceError::invalid(format!("options.descriptors: {e}")))? };
    let patch_rows = if o.patch_rows.is_empty() { defaults.patch_rows } else { o.patch_rows.parse().map_err(|e: String| ServiceError::invalid(format!("options.patch_rows: {e}")))? };
    let options = OnboardOptions { level: o.level.unwrap_or(defaults.level), in_plane: non_zero(o.in_plane, defaults.in_plane), pca, descriptors, patch_rows };
    let mesh = rq::MeshInput {
        data: mesh.data.into(),
        format: mesh.format,
        units: (!mesh.units.is_empty()).then_some(mesh.units),
        resources: mesh.resources.into_iter().map(|x| rq::ResourceInput { name: x.name, data: x.data.into() }).collect(),
    };
    Ok(rq::OnboardRequest { object_id: r.object_id, mesh, options, replace: r.replace })
}

pub fn object_info(o: ObjectInfo) -> pb::ObjectInfo {
    pb::ObjectInfo {
        id: o.id,
        templates: o.templates as u64,
        diameter_m: o.diameter_m,
        backbone: o.backbone.name,
        bytes: o.bytes,
        created_unix_s: o.created_at,
        mesh_units: o.units.as_str().to_string(),
        symmetries: o.symmetries.map(symmetries),
    }
}

/// An object's symmetries as the proto has them: the source by its JSON name ("mesh",
/// "models_info"), each discrete symmetry as its row-major 4×4 matrix.
pub fn symmetries(s: KnownSymmetries) -> pb::Symmetries {
    let source = serde_json::to_value(s.source).ok().and_then(|v| v.as_str().map(String::from)).unwrap_or_default();
    let discrete = s.symmetries.discrete.iter().map(|d| pb::DiscreteSymmetry { matrix: d.to_row_major_4x4().to_vec() }).collect();
    let continuous = s.symmetries.continuous.iter().map(|c| pb::ContinuousSymmetry { axis: c.axis.to_vec(), offset_m: c.offset.to_vec() }).collect();
    pb::Symmetries { source, discrete, continuous }
}

pub fn operation(s: OperationStatus) -> pb::Operation {
    let state = match s.state {
        OperationState::Running => pb::operation::State::Running,
        OperationState::Succeeded => pb::operation::State::Succeeded,
        OperationState::Failed => pb::operation::State::Failed,
        OperationState::Cancelled => pb::operation::State::Cancelled,
    };
    pb::Operation {
        id: s.id,
        object_id: s.object_id,
        state: state as i32,
        templates_done: s.templates_done,
        templates_total: s.templates_total,
        error: s.error.unwrap_or_default(),
        object: s.object.map(object_info),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn onboard_with(options: Option<pb::OnboardOptions>) -> OnboardOptions {
        let mesh = Some(pb::Mesh { data: vec![1], format: "obj".into(), units: "m".into(), resources: vec![] });
        onboard_request(pb::OnboardRequest { object_id: "x".into(), mesh, options, replace: false }).unwrap().options
    }

    /// The server's close-call verdict reaches the gRPC answer as HTTP's JSON has it, each way.
    #[test]
    fn the_runner_up_keeps_its_close_call_verdict() {
        for (margin, close) in [(0.01, true), (0.2, false)] {
            let u = crate::estimate::RunnerUp { pose: crate::geometry::Pose::identity(), source: crate::estimate::hypotheses::Source::Flip(1), margin, distance: 0.5 };
            let up = rq::RunnerUpOutput::from(&u);
            let result = serde_json::json!({"object_id": "x", "instance": 0, "pose": null, "score": 0.9, "detection_index": 0, "reason": null, "diagnostics": [], "timings_ms": {}, "runner_up": up});
            let r: rq::EstimateResponse = serde_json::from_value(serde_json::json!({"results": [result], "total_ms": 1.0})).unwrap();
            let pb_up = estimate_response(r).results[0].runner_up.clone().expect("runner-up kept");
            assert_eq!((pb_up.close_call, pb_up.margin), (close, margin as f32));
        }
    }

    #[test]
    fn unset_options_take_defaults_and_level_zero_is_kept() {
        let d = OnboardOptions::default();
        let o = onboard_with(None);
        assert_eq!((o.level, o.in_plane, o.pca), (d.level, d.in_plane, PcaSetting::Auto));
        let o = onboard_with(Some(pb::OnboardOptions { level: Some(0), in_plane: 1, pca: 16, full_descriptors: false, descriptors: "pq4".into(), patch_rows: "per-view".into() }));
        assert_eq!((o.level, o.in_plane, o.pca, o.descriptors, o.patch_rows), (0, 1, PcaSetting::Components(16), crate::onboard::DescriptorCoding::Pq4, crate::onboard::PatchRows::PerView));
        let o = onboard_with(Some(pb::OnboardOptions { level: None, in_plane: 0, pca: 0, full_descriptors: true, descriptors: String::new(), patch_rows: String::new() }));
        assert_eq!((o.pca, o.descriptors, o.patch_rows), (PcaSetting::Off, crate::onboard::DescriptorCoding::F16, crate::onboard::PatchRows::Auto));
        let mesh = Some(pb::Mesh { data: vec![1], format: "obj".into(), units: "m".into(), resources: vec![] });
        let both = pb::OnboardOptions { level: None, in_plane: 0, pca: 8, full_descriptors: true, ..Default::default() };
        let err = onboard_request(pb::OnboardRequest { object_id: "x".into(), mesh, options: Some(both), replace: false }).unwrap_err();
        assert!(err.message.contains("pca 8 and full_descriptors contradict"), "{}", err.message);
        let mesh = Some(pb::Mesh { data: vec![1], format: "obj".into(), units: "m".into(), resources: vec![] });
        let unknown = pb::OnboardOptions { descriptors: "pq8".into(), ..Default::default() };
        let err = onboard_request(pb::OnboardRequest { object_id: "x".into(), mesh, options: Some(unknown), replace: false }).unwrap_err();
        assert!(err.message.contains("options.descriptors: unknown descriptor coding \"pq8\""), "{}", err.message);
        let mesh = Some(pb::Mesh { data: vec![1], format: "obj".into(), units: "m".into(), resources: vec![] });
        let unknown = pb::OnboardOptions { patch_rows: "per-face".into(), ..Default::default() };
        let err = onboard_request(pb::OnboardRequest { object_id: "x".into(), mesh, options: Some(unknown), replace: false }).unwrap_err();
        assert!(err.message.contains("options.patch_rows: unknown patch rows \"per-face\""), "{}", err.message);
        assert!(onboard_request(pb::OnboardRequest { object_id: "x".into(), mesh: None, options: None, replace: false }).unwrap_err().message.contains("mesh is required"));
    }

    #[test]
    fn refiner_is_parsed_and_an_unknown_one_is_named() {
        let with = |refiner: &str| {
            let options = Some(pb::EstimateOptions { refiner: refiner.into(), ..Default::default() });
            estimate_request(pb::EstimateRequest { image: Some(pb::Image::default()), intrinsics: Some(pb::Intrinsics::default()), options, ..Default::default() })
        };
        assert_eq!(with("").unwrap().options.refiner, crate::estimate::RefinerKind::default());
        assert_eq!(with("silhouette-depth").unwrap().options.refiner, crate::estimate::RefinerKind::SilhouetteDepth);
        let e = with("magic").unwrap_err();
        assert!(e.message.contains("options.refiner") && e.message.contains("magic"), "{}", e.message);
    }

    #[test]
    fn verification_hypotheses_default_when_unset_and_zero_means_none() {
        let with = |verify_templates, spin_steps, verify_matched| {
            let options = Some(pb::EstimateOptions { verify_templates, spin_steps, verify_matched, ..Default::default() });
            let o = estimate_request(pb::EstimateRequest { image: Some(pb::Image::default()), intrinsics: Some(pb::Intrinsics::default()), options, ..Default::default() }).unwrap().options;
            (o.verify_templates, o.spin_steps, o.verify_matched)
        };
        let d = crate::estimate::VerifyConfig::default();
        assert_eq!(with(None, None, None), (d.templates, d.spin_steps, d.matched_templates));
        assert_eq!(with(Some(0), Some(0), Some(0)), (0, 0, 0));
        assert_eq!(with(Some(20), Some(12), Some(7)), (20, 12, 7));
    }

    /// A 64×48 request with one (empty) detection and these options, converted.
    fn one_detection_request(options: pb::EstimateOptions) -> rq::EstimateRequest {
        estimate_request(pb::EstimateRequest {
            image: Some(pb::Image::default()),
            intrinsics: Some(pb::Intrinsics { width: 64, height: 48, ..Default::default() }),
            detections: vec![pb::Detection::default()],
            options: Some(options),
            ..Default::default()
        })
        .unwrap()
    }

    #[test]
    fn the_nudge_defaults_when_unset_and_a_nan_is_refused() {
        let with = |nudge_degrees| one_detection_request(pb::EstimateOptions { nudge_degrees, ..Default::default() });
        assert_eq!(with(None).options.nudge_degrees, crate::estimate::VerifyConfig::default().nudge_degrees);
        assert_eq!(with(Some(0.0)).options.nudge_degrees, 0.0);
        let e = with(Some(f64::NAN)).check_limits().unwrap_err();
        assert!(e.message.contains("options.nudge_degrees: NaN is outside 0–45 degrees"), "{}", e.message);
    }

    #[test]
    fn the_depth_views_default_when_unset_and_too_many_are_refused() {
        let with = |depth_views| one_detection_request(pb::EstimateOptions { depth_views, ..Default::default() });
        assert_eq!(with(None).options.depth_views, crate::estimate::VerifyConfig::default().depth_views);
        assert_eq!(with(Some(0)).options.depth_views, 0, "0 turns them off");
        let e = with(Some(100)).check_limits().unwrap_err();
        assert_eq!(e.message, "options.depth_views is 100, over the limit of 12");
    }

    #[test]
    fn the_box_prior_is_the_default_unless_said() {
        let with = |box_prior| one_detection_request(pb::EstimateOptions { box_prior, ..Default::default() }).options.box_prior;
        use crate::estimate::BoxPrior;
        assert_eq!([None, Some(true), Some(false)].map(with), [BoxPrior::Auto, BoxPrior::Tight, BoxPrior::Off]);
    }

    #[test]
    fn rrc_is_skipped_where_sure_unless_always_is_said() {
        let with = |rrc_always| one_detection_request(pb::EstimateOptions { rrc_always, ..Default::default() }).options;
        assert_eq!([false, true].map(|a| (with(a).rrc, with(a).rrc_always)), [(true, false), (true, true)]);
    }

    #[test]
    fn symmetries_keep_their_source_matrices_and_axes() {
        use crate::geometry::symmetry::{ContinuousSymmetry, DiscreteSymmetry, ObjectSymmetries, SymmetrySource};
        // A cylinder along z, centred 5 cm up, and its flip about x through its centre.
        let flip = [1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.1, 0.0, 0.0, 0.0, 1.0];
        let cylinder = ContinuousSymmetry { axis: [0.0, 0.0, 1.0], offset: [0.0, 0.0, 0.05] };
        let known = KnownSymmetries { source: SymmetrySource::ModelsInfo, symmetries: ObjectSymmetries { discrete: vec![DiscreteSymmetry::from_row_major_4x4(&flip)], continuous: vec![cylinder] } };
        assert!(rq::InstanceResult::arbitrary_rotation(Some(&known)));
        let m = symmetries(known.clone());
        assert_eq!((m.source.as_str(), m.discrete.len(), m.discrete[0].matrix.as_slice()), ("models_info", 1, flip.as_slice()));
        assert_eq!((m.continuous[0].axis.as_slice(), m.continuous[0].offset_m.as_slice()), ([0.0, 0.0, 1.0].as_slice(), [0.0, 0.0, 0.05].as_slice()));
        // An object with discrete symmetries only, or unknown ones: the rotation is determined.
        let boxy = KnownSymmetries { source: SymmetrySource::Mesh, symmetries: ObjectSymmetries { discrete: known.symmetries.discrete.clone(), continuous: vec![] } };
        assert!(!rq::InstanceResult::arbitrary_rotation(Some(&boxy)) && !rq::InstanceResult::arbitrary_rotation(None));
        assert_eq!(symmetries(boxy).source, "mesh");
    }
}
