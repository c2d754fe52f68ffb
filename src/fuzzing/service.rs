//! The service's request decoding without a server: HTTP JSON bodies (serde), multipart
//! onboarding bodies (axum's parser and ours), and gRPC messages (prost, then the
//! conversion), each followed by what the core decodes before any model is needed.

use crate::masks::BoxMask;
use crate::service::detect_requests::DetectRequest;
use crate::service::requests::{EstimateRequest, OnboardRequest};
use crate::service::{grpc_convert, proto as pb};
use axum::extract::FromRequest;
use prost::Message;

/// What `Core::estimate` decodes before it looks up objects: limits, intrinsics, image,
/// then every detection's mask (segmenting boxes only on small images, to keep the fuzzer
/// fast; larger ones are filled).
fn decode_estimate(req: &EstimateRequest) {
    if req.check_limits().is_err() || req.intrinsics.decode().is_err() {
        return;
    }
    let Ok(image) = req.image.decode() else { return };
    let how = if image.width() as u64 * image.height() as u64 <= 65_536 { BoxMask::Segment } else { BoxMask::Fill };
    for (i, d) in req.detections.iter().enumerate() {
        if let Ok(mask) = d.mask(i, &image, how) {
            assert_eq!(mask.dimensions(), image.dimensions());
        }
    }
}

/// What `Core::detect` decodes before it looks up objects: limits, options, intrinsics,
/// image (and their agreement).
fn decode_detect(req: &DetectRequest) {
    if req.check_limits().is_err() || crate::detect::check_options(&req.options).is_err() {
        return;
    }
    let _ = crate::service::wire::decode_image(&req.image, &req.intrinsics);
}

/// What `Core::start_onboard` checks before it stages the upload (the mesh itself has its
/// own targets).
fn check_onboard(req: &OnboardRequest) {
    let _ = crate::store::validate_id(&req.object_id);
    let _ = crate::geometry::ViewSampling { level: req.options.level, in_plane_steps: req.options.in_plane }.validate();
    let _ = req.options.pca.check(384);
    let _ = crate::limits::check_count("mesh.resources", req.mesh.resources.len(), crate::limits::MAX_MESH_RESOURCES);
}

/// First byte 2 mod 4: a detect body; else even: an estimate body; odd: an onboarding body.
pub fn http_json(data: &[u8]) {
    let Some(([mode], body)) = super::header::<1>(data) else { return };
    if mode % 4 == 2 {
        if let Ok(req) = serde_json::from_slice::<DetectRequest>(body) {
            decode_detect(&req);
        }
        return;
    }
    match mode % 2 {
        0 => {
            if let Ok(req) = serde_json::from_slice::<EstimateRequest>(body) {
                decode_estimate(&req);
            }
        }
        _ => {
            if let Ok(req) = serde_json::from_slice::<OnboardRequest>(body) {
                check_onboard(&req);
            }
        }
    }
}

/// First byte 2 mod 4: a `DetectRequest` message; else even: an `EstimateRequest`; odd:
/// an `OnboardRequest`.
pub fn grpc_request(data: &[u8]) {
    let Some(([mode], message)) = super::header::<1>(data) else { return };
    if mode % 4 == 2 {
        if let Ok(Ok(req)) = pb::DetectRequest::decode(message).map(grpc_convert::detect_request) {
            decode_detect(&req);
        }
        return;
    }
    match mode % 2 {
        0 => {
            if let Ok(Ok(req)) = pb::EstimateRequest::decode(message).map(grpc_convert::estimate_request) {
                decode_estimate(&req);
            }
        }
        _ => {
            if let Ok(Ok(req)) = pb::OnboardRequest::decode(message).map(grpc_convert::onboard_request) {
                check_onboard(&req);
            }
        }
    }
}

/// A multipart/form-data onboarding body with the boundary `BOUNDARY`.
pub fn multipart(data: &[u8]) {
    static RUNTIME: std::sync::OnceLock<tokio::runtime::Runtime> = std::sync::OnceLock::new();
    let runtime = RUNTIME.get_or_init(|| tokio::runtime::Builder::new_current_thread().build().expect("a tokio runtime"));
    let request = axum::http::Request::builder().header("content-type", "multipart/form-data; boundary=BOUNDARY").body(axum::body::Body::from(data.to_vec())).expect("a valid request");
    runtime.block_on(async {
        let Ok(form) = axum::extract::Multipart::from_request(request, &()).await else { return };
        if let Ok(req) = crate::service::multipart::onboard_request(form).await {
            check_onboard(&req);
        }
    });
}
