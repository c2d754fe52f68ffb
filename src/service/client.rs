//! Building blocks for Rust clients of the gRPC API (`b2tf demo --server`, `b2tf bench
//! serve`, the tests): PNG encoding, a one-mask estimate request, and the API key as
//! `authorization` metadata.

use super::proto as pb;
use crate::geometry::Intrinsics;
use tonic::metadata::{Ascii, MetadataValue};

/// PNG file bytes of an RGB or grey image.
pub fn png_bytes<P: image::PixelWithColorType>(img: &image::ImageBuffer<P, Vec<P::Subpixel>>) -> image::ImageResult<Vec<u8>>
where
    [P::Subpixel]: image::EncodableLayout,
{
    let mut out = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png)?;
    Ok(out)
}

impl From<&Intrinsics> for pb::Intrinsics {
    fn from(k: &Intrinsics) -> Self {
        Self { fx: k.fx, fy: k.fy, cx: k.cx, cy: k.cy, width: k.width, height: k.height }
    }
}

/// An estimate of one object from an encoded image and one PNG mask (score 1).
pub fn one_mask_request(object_id: &str, image_png: Vec<u8>, mask_png: Vec<u8>, k: &Intrinsics, rrc: bool) -> pb::EstimateRequest {
    pb::EstimateRequest {
        image: Some(pb::Image { data: Some(pb::image::Data::Encoded(image_png)), width: 0, height: 0 }),
        intrinsics: Some(k.into()),
        detections: vec![pb::Detection { object_id: object_id.into(), mask: Some(pb::detection::Mask::MaskPng(mask_png)), bbox: None, score: Some(1.0) }],
        options: Some(pb::EstimateOptions { rrc: Some(rrc), ..Default::default() }),
        ..Default::default()
    }
}

/// Adds `authorization: Bearer <key>` to every call when a key is set.
#[derive(Clone)]
pub struct BearerKey(Option<MetadataValue<Ascii>>);

impl BearerKey {
    pub fn new(key: Option<&str>) -> Result<Self, String> {
        key.map(|k| format!("Bearer {k}").parse().map_err(|_| "the API key is not a valid header value".to_string())).transpose().map(Self)
    }
}

impl tonic::service::Interceptor for BearerKey {
    fn call(&mut self, mut req: tonic::Request<()>) -> Result<tonic::Request<()>, tonic::Status> {
        if let Some(k) = &self.0 {
            req.metadata_mut().insert("authorization", k.clone());
        }
        Ok(req)
    }
}

/// A PoseService client that sends the API key.
pub type Client = pb::pose_service_client::PoseServiceClient<tonic::service::interceptor::InterceptedService<tonic::transport::Channel, BearerKey>>;
