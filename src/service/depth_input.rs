//! The depth image of an RGB-D request (`EstimateRequest::depth`), as both adapters carry
//! it: a 16-bit PNG or raw little-endian uint16 rows with a scale (value × `scale_mm` =
//! millimetres, BOP's `depth_scale`), or raw little-endian float32 metres. Registered to the
//! colour image: the same size and intrinsics. 0 = no measurement.

use super::base64_bytes::Base64Bytes;
use super::error::ServiceError;
use crate::depth::DepthImage;
use crate::limits;

#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct DepthInput {
    /// A 16-bit greyscale PNG's bytes, base64 (JSON) or raw (gRPC).
    #[serde(default)]
    pub png16: Option<Base64Bytes>,
    /// Little-endian uint16, row-major, `width × height × 2` bytes.
    #[serde(default)]
    pub raw_u16: Option<Base64Bytes>,
    /// Little-endian float32 metres, row-major, `width × height × 4` bytes.
    #[serde(default)]
    pub raw_f32: Option<Base64Bytes>,
    /// Pixels; required with the raw forms.
    #[serde(default)]
    pub width: Option<u32>,
    #[serde(default)]
    pub height: Option<u32>,
    /// Millimetres per unit of `png16` and `raw_u16` (1 for millimetres, 0.1 for tenths);
    /// not used with `raw_f32`.
    #[serde(default)]
    pub scale_mm: Option<f64>,
}

impl DepthInput {
    /// The depth, checked against the colour image (`width × height`): its size, its values
    /// (finite, non-negative, some measured) and their units (a plausible median).
    pub fn decode(&self, width: u32, height: u32) -> Result<DepthImage, ServiceError> {
        let invalid = |field: &str, e: crate::depth::DepthError| ServiceError::invalid(format!("depth.{field}: {e}"));
        let scale = || self.scale_mm.ok_or_else(|| ServiceError::invalid("depth.scale_mm is needed with png16 and raw_u16 (millimetres per unit: 1 for millimetres, 0.1 for tenths)"));
        let (depth, field, hint) = match (&self.png16, &self.raw_u16, &self.raw_f32) {
            (Some(png), None, None) => {
                let scale = scale()?;
                let decoded = limits::REQUEST_IMAGE.decode(png.as_slice()).map_err(|e| ServiceError::invalid(format!("depth.png16: {e}")))?;
                (DepthImage::from_decoded(decoded, scale).map_err(|e| invalid("png16", e))?, "png16", format!("scale_mm {scale}"))
            }
            (None, Some(raw), None) => {
                let scale = scale()?;
                let (w, h) = self.raw_size(raw.as_slice().len(), 2, "raw_u16")?;
                let values: Vec<u16> = raw.as_slice().chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])).collect();
                (DepthImage::from_u16(w, h, &values, scale).map_err(|e| invalid("raw_u16", e))?, "raw_u16", format!("scale_mm {scale}"))
            }
            (None, None, Some(raw)) => {
                let (w, h) = self.raw_size(raw.as_slice().len(), 4, "raw_f32")?;
                let values: Vec<f32> = raw.as_slice().chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
                (DepthImage::from_metres(w, h, values).map_err(|e| invalid("raw_f32", e))?, "raw_f32", "raw_f32 is metres".to_string())
            }
            _ => return Err(ServiceError::invalid("depth: give exactly one of png16, raw_u16 or raw_f32")),
        };
        depth.check_for(width, height, &hint).map_err(|e| invalid(field, e))?;
        Ok(depth)
    }

    /// The raw form's size: given, within the limits, and matching its byte count.
    fn raw_size(&self, bytes: usize, per_pixel: usize, field: &str) -> Result<(u32, u32), ServiceError> {
        let (Some(w), Some(h)) = (self.width, self.height) else {
            return Err(ServiceError::invalid(format!("depth.{field} needs depth.width and depth.height")));
        };
        limits::REQUEST_IMAGE.check(w, h).map_err(|e| ServiceError::invalid(format!("depth.width × depth.height: {e}")))?;
        let expected = w as usize * h as usize * per_pixel;
        if bytes != expected {
            return Err(ServiceError::invalid(format!("depth.{field} has {bytes} bytes; {w}×{h} needs {expected}")));
        }
        Ok((w, h))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn u16_input(values: &[u16], w: u32, h: u32, scale: Option<f64>) -> DepthInput {
        DepthInput { raw_u16: Some(values.iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>().into()), width: Some(w), height: Some(h), scale_mm: scale, ..Default::default() }
    }

    fn f32_input(values: &[f32], w: u32, h: u32) -> DepthInput {
        DepthInput { raw_f32: Some(values.iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>().into()), width: Some(w), height: Some(h), ..Default::default() }
    }

    #[test]
    fn every_form_decodes_to_metres() {
        let d = u16_input(&[0, 8000, 8000, 8000], 2, 2, Some(0.1)).decode(2, 2).unwrap();
        assert!((d.at(1, 0) - 0.8).abs() < 1e-6 && d.at(0, 0) == 0.0);
        let d = f32_input(&[0.0, 0.7, 0.7, 0.7], 2, 2).decode(2, 2).unwrap();
        assert!((d.at(1, 1) - 0.7).abs() < 1e-6);
        let mut png = std::io::Cursor::new(Vec::new());
        image::DynamicImage::ImageLuma16(image::ImageBuffer::from_pixel(2, 2, image::Luma([900u16]))).write_to(&mut png, image::ImageFormat::Png).unwrap();
        let d = DepthInput { png16: Some(png.into_inner().into()), scale_mm: Some(1.0), ..Default::default() }.decode(2, 2).unwrap();
        assert!((d.at(0, 1) - 0.9).abs() < 1e-6);
    }

    #[test]
    fn bad_depth_is_refused_naming_the_field() {
        let cases: Vec<(DepthInput, &str)> = vec![
            (DepthInput::default(), "depth: give exactly one of png16, raw_u16 or raw_f32"),
            (u16_input(&[800; 4], 2, 2, None), "depth.scale_mm is needed"),
            (u16_input(&[800; 4], 2, 2, Some(0.0)), "depth.raw_u16: depth scale must be finite and positive"),
            (u16_input(&[800; 4], 2, 2, Some(f64::NAN)), "depth.raw_u16: depth scale must be finite and positive"),
            (u16_input(&[800; 3], 3, 1, Some(1.0)), "depth.raw_u16: depth is 3×1 but the image is 2×2"),
            (u16_input(&[800; 4], 2, 3, Some(1.0)), "depth.raw_u16 has 8 bytes; 2×3 needs 12"),
            (DepthInput { width: None, ..u16_input(&[800; 4], 2, 2, Some(1.0)) }, "depth.raw_u16 needs depth.width and depth.height"),
            (u16_input(&[0; 4], 2, 2, Some(1.0)), "depth.raw_u16: depth holds no measurement"),
            (u16_input(&[800; 4], 2, 2, Some(1000.0)), "depth.raw_u16: depth's median is 800 m"),
            (f32_input(&[0.5, f32::NAN, 0.5, 0.5], 2, 2), "depth.raw_f32: depth value at pixel (1, 0) is NaN"),
            (f32_input(&[0.5, f32::INFINITY, 0.5, 0.5], 2, 2), "depth.raw_f32: depth value at pixel (1, 0) is inf"),
            (f32_input(&[800.0; 4], 2, 2), "raw_f32 is metres"),
            (DepthInput { png16: Some(vec![1, 2, 3].into()), scale_mm: Some(1.0), ..Default::default() }, "depth.png16:"),
            (DepthInput { width: Some(100_000), height: Some(2), ..u16_input(&[800; 4], 2, 2, Some(1.0)) }, "depth.width × depth.height: 100000×2 is over the limit"),
        ];
        for (input, needle) in cases {
            let e = input.decode(2, 2).unwrap_err();
            assert!(e.message.contains(needle), "{needle:?} not in {:?}", e.message);
            assert_eq!(e.kind, super::super::error::ErrorKind::InvalidArgument);
        }
        // An 8-bit PNG is not depth.
        let mut png = std::io::Cursor::new(Vec::new());
        image::DynamicImage::ImageLuma8(image::ImageBuffer::from_pixel(2, 2, image::Luma([9u8]))).write_to(&mut png, image::ImageFormat::Png).unwrap();
        let e = DepthInput { png16: Some(png.into_inner().into()), scale_mm: Some(1.0), ..Default::default() }.decode(2, 2).unwrap_err();
        assert!(e.message.contains("depth.png16: depth is not a 16-bit"), "{}", e.message);
    }
}
