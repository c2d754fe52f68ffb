//! The shapes every request and answer shares, estimate, detect and track alike: an
//! image, the camera's intrinsics, a run-length mask and a pose, with their decoding into
//! library inputs (each bad input a clear error naming its field).

use super::base64_bytes::Base64Bytes;
use super::error::ServiceError;
use crate::geometry::Intrinsics;
use crate::limits;
use image::RgbImage;

/// An image: encoded PNG/JPEG bytes, or raw 8-bit RGB rows with their size.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ImageInput {
    /// PNG or JPEG file bytes, base64 (JSON) or raw (gRPC).
    #[serde(default)]
    pub encoded: Option<Base64Bytes>,
    /// Raw RGB8, row-major, `width × height × 3` bytes, base64 (JSON) or raw (gRPC).
    #[serde(default)]
    pub raw_rgb8: Option<Base64Bytes>,
    #[serde(default)]
    pub width: Option<u32>,
    #[serde(default)]
    pub height: Option<u32>,
}

impl ImageInput {
    pub fn decode(&self) -> Result<RgbImage, ServiceError> {
        match (&self.encoded, &self.raw_rgb8) {
            (Some(bytes), None) => Ok(limits::REQUEST_IMAGE.decode(bytes.as_slice()).map_err(|e| ServiceError::invalid(format!("image.encoded: {e}")))?.to_rgb8()),
            (None, Some(r)) => {
                let (Some(w), Some(h)) = (self.width, self.height) else {
                    return Err(ServiceError::invalid("image.raw_rgb8 needs image.width and image.height"));
                };
                limits::REQUEST_IMAGE.check(w, h).map_err(|e| ServiceError::invalid(format!("image.width × image.height: {e}")))?;
                let bytes = r.0.clone();
                let expected = w as u64 * h as u64 * 3;
                if w == 0 || h == 0 || bytes.len() as u64 != expected {
                    return Err(ServiceError::invalid(format!("image.raw_rgb8 has {} bytes; {w}×{h} RGB8 needs {expected}", bytes.len())));
                }
                RgbImage::from_raw(w, h, bytes).ok_or_else(|| ServiceError::invalid("image.raw_rgb8: size mismatch"))
            }
            _ => Err(ServiceError::invalid("image: give exactly one of encoded or raw_rgb8")),
        }
    }
}

/// Pinhole intrinsics in pixels, with the image size they belong to. The API's own type,
/// field for field `geometry::Intrinsics` today: kept apart so that the wire contract
/// (and its OpenAPI schema) does not move when the domain type does; checked on the way in.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
pub struct IntrinsicsInput {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: u32,
    pub height: u32,
}

impl IntrinsicsInput {
    pub fn decode(&self) -> Result<Intrinsics, ServiceError> {
        Intrinsics::new(self.fx, self.fy, self.cx, self.cy, self.width, self.height).map_err(|e| ServiceError::invalid(format!("intrinsics: {e}")))
    }
}

/// A binary mask as run-length encoding (BOP/COCO: column-major counts, first run
/// background, `size` = [height, width]).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct RleInput {
    #[serde(deserialize_with = "limits::bounded_vec::<_, _, { limits::MAX_RLE_RUNS }>")]
    pub counts: Vec<u32>,
    pub size: [u32; 2],
}

/// A pose `T_cam_obj`: rotation row-major and as a unit quaternion (w, x, y, z), translation
/// in metres.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PoseOutput {
    #[serde(rename = "R")]
    pub r: [f64; 9],
    pub t: [f64; 3],
    pub quaternion_wxyz: [f64; 4],
}

impl From<&crate::geometry::Pose> for PoseOutput {
    fn from(p: &crate::geometry::Pose) -> Self {
        let q = nalgebra::UnitQuaternion::from_rotation_matrix(&p.rotation);
        Self { r: p.rotation_row_major(), t: [p.translation.x, p.translation.y, p.translation.z], quaternion_wxyz: [q.w, q.i, q.j, q.k] }
    }
}

/// The image and its intrinsics, which must agree on the size.
pub fn decode_image(image: &ImageInput, intrinsics: &IntrinsicsInput) -> Result<(RgbImage, Intrinsics), ServiceError> {
    let k = intrinsics.decode()?;
    let image = tracing::info_span!("decode").in_scope(|| image.decode())?;
    if image.dimensions() != (k.width, k.height) {
        return Err(ServiceError::invalid(format!("image is {}×{} but intrinsics say {}×{}", image.width(), image.height(), k.width, k.height)));
    }
    Ok((image, k))
}
