//! Depth images from RGB-D cameras, registered to the colour image (same size, same
//! intrinsics): camera-frame z in metres per pixel, 0 where the sensor measured nothing
//! (holes are normal: dark, shiny and grazing surfaces, shadows at depth edges).
//!
//! Two encodings come in: 16-bit PNGs with a scale (BOP's `depth_scale`: value × scale =
//! millimetres; Kinect-class and RealSense cameras write 1 mm or 0.1 mm steps) and float32
//! metres (what Open3D and pyrealsense2 give after scaling). Both are checked here, once,
//! so that estimation can trust what it reads.

pub mod sensor;
pub mod surfaces;

use image::{DynamicImage, ImageFormat};

/// Depth in metres, row-major, `width × height`; 0 = no measurement.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthImage {
    width: u32,
    height: u32,
    metres: Vec<f32>,
}

/// Plausible scene depths: a median outside this range says the scale is wrong.
pub const PLAUSIBLE_METRES: (f32, f32) = (0.05, 20.0);

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum DepthError {
    #[error("depth scale must be finite and positive (millimetres per unit), got {0}")]
    BadScale(f64),
    #[error("depth is not a 16-bit single-channel PNG: {0}")]
    NotSixteenBit(String),
    #[error("depth holds {got} values, {width}×{height} needs {want}")]
    WrongLength { got: usize, want: usize, width: u32, height: u32 },
    #[error("depth value at pixel ({x}, {y}) is {value}: it must be finite and non-negative (0 = no measurement)")]
    NotFinite { x: u32, y: u32, value: f32 },
    #[error("depth is {width}×{height} but the image is {image_width}×{image_height}: it must be registered to the colour image")]
    WrongSize { width: u32, height: u32, image_width: u32, image_height: u32 },
    #[error("depth holds no measurement (every pixel is 0)")]
    Empty,
    #[error("depth's median is {median_m} m, outside {lo}–{hi} m: is the scale right (value × scale = millimetres; {scale_hint})?")]
    Implausible { median_m: f32, lo: f32, hi: f32, scale_hint: String },
}

impl DepthImage {
    /// Float depth in metres (0 = no measurement); NaN, infinities and negatives refused.
    pub fn from_metres(width: u32, height: u32, metres: Vec<f32>) -> Result<Self, DepthError> {
        let want = width as usize * height as usize;
        if metres.len() != want {
            return Err(DepthError::WrongLength { got: metres.len(), want, width, height });
        }
        if let Some(i) = metres.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
            return Err(DepthError::NotFinite { x: i as u32 % width.max(1), y: i as u32 / width.max(1), value: metres[i] });
        }
        Ok(Self { width, height, metres })
    }

    /// 16-bit values × `scale_mm` = millimetres (BOP's `depth_scale`).
    pub fn from_u16(width: u32, height: u32, values: &[u16], scale_mm: f64) -> Result<Self, DepthError> {
        if !(scale_mm.is_finite() && scale_mm > 0.0) {
            return Err(DepthError::BadScale(scale_mm));
        }
        let to_m = (scale_mm / 1000.0) as f32;
        Self::from_metres(width, height, values.iter().map(|&v| v as f32 * to_m).collect())
    }

    /// A 16-bit greyscale PNG's bytes, values × `scale_mm` = millimetres.
    pub fn from_png(bytes: &[u8], scale_mm: f64) -> Result<Self, DepthError> {
        let decoded = image::load_from_memory_with_format(bytes, ImageFormat::Png).map_err(|e| DepthError::NotSixteenBit(e.to_string()))?;
        Self::from_decoded(decoded, scale_mm)
    }

    /// A decoded image (decoded under the caller's size limits), which must be 16-bit
    /// greyscale; values × `scale_mm` = millimetres.
    pub fn from_decoded(decoded: DynamicImage, scale_mm: f64) -> Result<Self, DepthError> {
        if !(scale_mm.is_finite() && scale_mm > 0.0) {
            return Err(DepthError::BadScale(scale_mm));
        }
        match decoded {
            DynamicImage::ImageLuma16(img) => Self::from_u16(img.width(), img.height(), img.as_raw(), scale_mm),
            other => Err(DepthError::NotSixteenBit(format!("it is {:?}", other.color()))),
        }
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    /// (width, height), as `image`'s `dimensions()`.
    pub fn dimensions(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// Metres at pixel (x, y); 0 = no measurement (and outside the image).
    pub fn at(&self, x: u32, y: u32) -> f32 {
        if x < self.width && y < self.height {
            self.metres[(y * self.width + x) as usize]
        } else {
            0.0
        }
    }

    /// Metres at the pixel nearest (u, v) (pixel centres at integers); 0 outside.
    pub fn nearest(&self, u: f64, v: f64) -> f32 {
        let (x, y) = (u.round(), v.round());
        if x < 0.0 || y < 0.0 {
            return 0.0;
        }
        self.at(x as u32, y as u32)
    }

    /// Checks the depth against the colour image it must be registered to, and that its
    /// values are depths in metres (median of the measured pixels within
    /// [`PLAUSIBLE_METRES`]). `scale_hint` names the scale the caller gave, for the error.
    pub fn check_for(&self, image_width: u32, image_height: u32, scale_hint: &str) -> Result<(), DepthError> {
        if (self.width, self.height) != (image_width, image_height) {
            return Err(DepthError::WrongSize { width: self.width, height: self.height, image_width, image_height });
        }
        let mut measured: Vec<f32> = self.metres.iter().copied().filter(|&v| v > 0.0).collect();
        if measured.is_empty() {
            return Err(DepthError::Empty);
        }
        let mid = measured.len() / 2;
        let median = *measured.select_nth_unstable_by(mid, f32::total_cmp).1;
        let (lo, hi) = PLAUSIBLE_METRES;
        if !(lo..=hi).contains(&median) {
            return Err(DepthError::Implausible { median_m: median, lo, hi, scale_hint: scale_hint.to_string() });
        }
        Ok(())
    }

    /// A 16-bit depth PNG file read and checked against the `size` of the image it is
    /// registered to; the error names the file (and `scale_hint`, where the scale came from).
    pub fn read_png_for(path: &std::path::Path, scale_mm: f64, size: (u32, u32), scale_hint: &str) -> Result<Self, String> {
        let in_file = |e: &dyn std::fmt::Display| format!("depth {}: {e}", path.display());
        let bytes = std::fs::read(path).map_err(|e| in_file(&e))?;
        let depth = Self::from_png(&bytes, scale_mm).map_err(|e| in_file(&e))?;
        depth.check_for(size.0, size.1, scale_hint).map_err(|e| in_file(&e))?;
        Ok(depth)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::{ImageBuffer, Luma};

    fn png16(w: u32, h: u32, value: u16) -> Vec<u8> {
        let img: ImageBuffer<Luma<u16>, Vec<u16>> = ImageBuffer::from_fn(w, h, |x, _| Luma([if x == 0 { 0 } else { value }]));
        let mut out = std::io::Cursor::new(Vec::new());
        DynamicImage::ImageLuma16(img).write_to(&mut out, ImageFormat::Png).unwrap();
        out.into_inner()
    }

    #[test]
    fn a_sixteen_bit_png_reads_as_metres_with_its_scale_and_keeps_its_holes() {
        let d = DepthImage::from_png(&png16(4, 3, 8000), 0.1).unwrap();
        assert_eq!((d.width(), d.height()), (4, 3));
        assert!((d.at(2, 1) - 0.8).abs() < 1e-6, "{}", d.at(2, 1));
        assert_eq!(d.at(0, 1), 0.0, "a hole stays a hole");
        assert_eq!(d.at(9, 9), 0.0);
        assert!((d.nearest(1.6, 0.4) - 0.8).abs() < 1e-6);
        d.check_for(4, 3, "depth_scale 0.1").unwrap();
    }

    #[test]
    fn bad_depth_is_refused_naming_what_is_wrong() {
        let eight_bit = {
            let mut out = std::io::Cursor::new(Vec::new());
            DynamicImage::ImageLuma8(ImageBuffer::from_pixel(4, 3, Luma([9u8]))).write_to(&mut out, ImageFormat::Png).unwrap();
            out.into_inner()
        };
        assert!(matches!(DepthImage::from_png(&eight_bit, 1.0), Err(DepthError::NotSixteenBit(m)) if m.contains("L8")));
        assert!(matches!(DepthImage::from_png(b"not a png", 1.0), Err(DepthError::NotSixteenBit(_))));
        for scale in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(matches!(DepthImage::from_png(&png16(4, 3, 1), scale), Err(DepthError::BadScale(_))), "{scale}");
        }
        assert!(matches!(DepthImage::from_metres(2, 2, vec![0.5; 3]), Err(DepthError::WrongLength { got: 3, want: 4, .. })));
        for bad in [f32::NAN, f32::INFINITY, -0.5] {
            let e = DepthImage::from_metres(2, 2, vec![0.5, 0.5, bad, 0.5]).unwrap_err();
            assert!(matches!(e, DepthError::NotFinite { x: 0, y: 1, .. }), "{e}");
        }
        let d = DepthImage::from_png(&png16(4, 3, 800), 1.0).unwrap();
        assert!(matches!(d.check_for(5, 3, ""), Err(DepthError::WrongSize { .. })));
        assert_eq!(DepthImage::from_metres(2, 1, vec![0.0, 0.0]).unwrap().check_for(2, 1, ""), Err(DepthError::Empty));
        // Millimetres sent as metres, and a 16-bit image read with scale 1 that was 0.1 mm.
        let mm_as_m = DepthImage::from_metres(2, 1, vec![800.0, 810.0]).unwrap();
        let e = mm_as_m.check_for(2, 1, "float metres").unwrap_err();
        assert!(e.to_string().contains("float metres") && e.to_string().contains("810"), "{e}");
        let tenth_mm = DepthImage::from_png(&png16(4, 3, 30000), 1.0).unwrap();
        assert!(matches!(tenth_mm.check_for(4, 3, "depth_scale 1"), Err(DepthError::Implausible { .. })));
    }
}
