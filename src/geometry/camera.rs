//! OpenCV pinhole intrinsics: x right, y down, z forward; `u = fx·x/z + cx`, and pixel
//! (u, v)'s centre sits at integer coordinates (DESIGN.md, "Conventions").

use nalgebra::{Matrix3, Point3, Vector2};

/// Pinhole intrinsics with the image size they belong to. Pixels; no distortion.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: u32,
    pub height: u32,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum IntrinsicsError {
    #[error("focal lengths must be finite and positive, got fx={fx}, fy={fy}")]
    BadFocal { fx: f64, fy: f64 },
    #[error("principal point must be finite, got cx={cx}, cy={cy}")]
    BadPrincipalPoint { cx: f64, cy: f64 },
    #[error("image size must be positive, got {width}x{height}")]
    BadSize { width: u32, height: u32 },
}

impl Intrinsics {
    /// Validated constructor: every consumer may assume positive focals and a non-empty image.
    pub fn new(fx: f64, fy: f64, cx: f64, cy: f64, width: u32, height: u32) -> Result<Self, IntrinsicsError> {
        if !(fx.is_finite() && fy.is_finite() && fx > 0.0 && fy > 0.0) {
            return Err(IntrinsicsError::BadFocal { fx, fy });
        }
        if !(cx.is_finite() && cy.is_finite()) {
            return Err(IntrinsicsError::BadPrincipalPoint { cx, cy });
        }
        if width == 0 || height == 0 {
            return Err(IntrinsicsError::BadSize { width, height });
        }
        Ok(Self { fx, fy, cx, cy, width, height })
    }

    /// This camera cut down to the pixel window of `width` × `height` at (`x`, `y`): a render
    /// through it draws exactly those pixels of this camera's image. `None` for an empty
    /// window.
    pub fn window(&self, x: u32, y: u32, width: u32, height: u32) -> Option<Self> {
        (width > 0 && height > 0).then_some(Self { cx: self.cx - x as f64, cy: self.cy - y as f64, width, height, ..*self })
    }

    /// The same camera with `s`×`s` pixels in place of each pixel (pixel centres at
    /// integers in both): pixel u's area spans s·u … s·u + s − 1 there, centred on
    /// s·u + (s − 1)/2.
    pub fn supersampled(&self, s: u32) -> Self {
        let (f, half) = (s as f64, (s as f64 - 1.0) * 0.5);
        Self { fx: self.fx * f, fy: self.fy * f, cx: self.cx * f + half, cy: self.cy * f + half, width: self.width * s, height: self.height * s }
    }

    pub fn k(&self) -> Matrix3<f64> {
        Matrix3::new(self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)
    }

    /// Projects a camera-frame point to pixels; `None` behind or on the camera plane.
    pub fn project(&self, p: &Point3<f64>) -> Option<Vector2<f64>> {
        if p.z <= 0.0 {
            return None;
        }
        Some(Vector2::new(self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy))
    }

    /// Camera-frame point at pixel (u, v) and depth z (metres along the optical axis).
    pub fn back_project(&self, u: f64, v: f64, z: f64) -> Point3<f64> {
        Point3::new((u - self.cx) * z / self.fx, (v - self.cy) * z / self.fy, z)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_window_sees_the_same_pixels_shifted() {
        let k = Intrinsics::new(600.0, 610.0, 320.0, 240.0, 640, 480).unwrap();
        let w = k.window(100, 50, 200, 150).unwrap();
        assert_eq!((w.width, w.height, w.fx, w.fy), (200, 150, 600.0, 610.0));
        let p = Point3::new(0.05, -0.02, 0.8);
        let (full, cut) = (k.project(&p).unwrap(), w.project(&p).unwrap());
        assert!((full - cut - Vector2::new(100.0, 50.0)).norm() < 1e-12, "{full} vs {cut}");
        assert!(k.window(10, 10, 0, 5).is_none() && k.window(10, 10, 5, 0).is_none());
    }
}
