//! The square crop around a mask and its exact affine map back to image pixels, and the
//! patch grid on a crop. Pixel centres sit at integer coordinates in both spaces.

/// A square window of the image, resampled to `size`×`size` crop pixels.
///
/// Crop pixel `c` (centre at integer `c`) covers image coordinates whose centre is
/// `u = origin_u + (c + 0.5)·scale`, where `origin` is the window's top-left pixel
/// *edge* (a centre minus 0.5) in image coordinates and `scale = side / size` image pixels per crop pixel.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CropBox {
    /// Top-left corner (pixel edge, not centre) of the window, image pixels.
    pub origin_u: f64,
    pub origin_v: f64,
    /// Window side in image pixels.
    pub side: f64,
    /// Output crop side in crop pixels.
    pub size: u32,
}

impl CropBox {
    /// Square window centred on the box `[min, max]` of mask pixel centres (inclusive),
    /// whose side is the box's longer side times `1 + padding`.
    pub fn around(min_u: u32, min_v: u32, max_u: u32, max_v: u32, padding: f64, size: u32) -> Self {
        // Pixel edges of the box: centre ± 0.5.
        Self::around_edges(min_u as f64 - 0.5, min_v as f64 - 0.5, max_u as f64 + 0.5, max_v as f64 + 0.5, padding, size)
    }

    /// Square window centred on the box with edges left `l`, top `t`, right `r`, bottom `b`.
    pub fn around_edges(l: f64, t: f64, r: f64, b: f64, padding: f64, size: u32) -> Self {
        let side = (r - l).max(b - t) * (1.0 + padding);
        let (cu, cv) = ((l + r) * 0.5, (t + b) * 0.5);
        Self { origin_u: cu - side * 0.5, origin_v: cv - side * 0.5, side, size }
    }

    pub fn scale(&self) -> f64 {
        self.side / self.size as f64
    }

    /// [`to_image`](Self::to_image) as a scale and a shift, for code that maps crops to
    /// images in other ways too (`estimate::placement` fits such maps to matches).
    pub fn to_image_map(&self) -> ScaleShift {
        let s = self.scale();
        ScaleShift { scale: s, shift: [self.origin_u + 0.5 * s, self.origin_v + 0.5 * s] }
    }

    /// Crop pixel coordinates → image pixel coordinates (both centre-at-integer).
    pub fn to_image(&self, cu: f64, cv: f64) -> (f64, f64) {
        let s = self.scale();
        (self.origin_u + (cu + 0.5) * s, self.origin_v + (cv + 0.5) * s)
    }

    /// The camera `k` seen through this window: intrinsics whose pixel grid is the crop's,
    /// so that rendering with them draws exactly what `to_image` maps back to `k`'s image.
    pub fn intrinsics(&self, k: &super::Intrinsics) -> super::Intrinsics {
        let s = self.scale();
        super::Intrinsics { fx: k.fx / s, fy: k.fy / s, cx: (k.cx - self.origin_u) / s - 0.5, cy: (k.cy - self.origin_v) / s - 0.5, width: self.size, height: self.size }
    }

    /// Image pixel coordinates → crop pixel coordinates.
    pub fn to_crop(&self, u: f64, v: f64) -> (f64, f64) {
        let s = self.scale();
        ((u - self.origin_u) / s - 0.5, (v - self.origin_v) / s - 0.5)
    }
}

/// A scale and a shift in the plane, `p ↦ scale·p + shift`: a map from crop pixels to
/// image pixels without rotation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScaleShift {
    pub scale: f64,
    pub shift: [f64; 2],
}

impl ScaleShift {
    pub fn apply(&self, p: [f64; 2]) -> [f64; 2] {
        [self.scale * p[0] + self.shift[0], self.scale * p[1] + self.shift[1]]
    }
}

/// The `n`×`n` grid of `patch`-pixel patches covering a crop (32×32 of 16 px on 512).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct PatchGrid {
    pub n: u32,
    pub patch: u32,
}

impl PatchGrid {
    pub fn for_crop(crop_size: u32, patch: u32) -> Result<Self, String> {
        if patch == 0 || crop_size == 0 || !crop_size.is_multiple_of(patch) {
            return Err(format!("crop size {crop_size} is not a positive multiple of the patch size {patch}"));
        }
        Ok(Self { n: crop_size / patch, patch })
    }

    /// `n²`, in `usize`: a grid read from a stored manifest may have any `n`.
    pub fn len(&self) -> usize {
        self.n as usize * self.n as usize
    }

    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// Centre of patch (row `i`, column `j`) in crop pixels: (16j + 7.5, 16i + 7.5) for 16 px.
    pub fn centre(&self, i: u32, j: u32) -> (f64, f64) {
        let h = (self.patch as f64 - 1.0) * 0.5;
        ((j * self.patch) as f64 + h, (i * self.patch) as f64 + h)
    }

    /// Centre of the patch with linear index `k = i·n + j`.
    pub fn centre_of(&self, k: usize) -> (f64, f64) {
        self.centre(k as u32 / self.n, k as u32 % self.n)
    }

    /// Patch containing crop pixel coordinates, if inside the crop.
    pub fn patch_at(&self, cu: f64, cv: f64) -> Option<(u32, u32)> {
        let (j, i) = ((cu + 0.5) / self.patch as f64, (cv + 0.5) / self.patch as f64);
        (j >= 0.0 && i >= 0.0 && j < self.n as f64 && i < self.n as f64).then_some((i as u32, j as u32))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crop_map_round_trips_and_keeps_pixel_centres() {
        let b = CropBox::around(100, 50, 199, 99, 0.0, 100);
        // 100 px wide box, no padding: crop scale 1, crop pixel 0 is image pixel 100.
        assert!((b.scale() - 1.0).abs() < 1e-12);
        let (u, v) = b.to_image(0.0, 25.0);
        assert!((u - 100.0).abs() < 1e-12 && (v - 50.0).abs() < 1e-12, "{u} {v}");
        let b = CropBox::around(10, 20, 73, 40, 0.2, 512);
        for (cu, cv) in [(0.0, 0.0), (511.0, 3.0), (255.5, 255.5)] {
            let (u, v) = b.to_image(cu, cv);
            let (a, c) = b.to_crop(u, v);
            assert!((a - cu).abs() < 1e-9 && (c - cv).abs() < 1e-9);
            // The same map as a scale and a shift.
            let [mu, mv] = b.to_image_map().apply([cu, cv]);
            assert!((mu - u).abs() < 1e-9 && (mv - v).abs() < 1e-9, "{mu} {mv} against {u} {v}");
        }
        // The box centre maps to the crop centre.
        let (cu, cv) = b.to_crop(41.5, 30.0);
        assert!((cu - 255.5).abs() < 1e-9 && (cv - 255.5).abs() < 1e-9, "{cu} {cv}");
    }

    #[test]
    fn window_intrinsics_project_like_the_crop_map() {
        let k = crate::geometry::Intrinsics::new(600.0, 610.0, 320.0, 240.0, 640, 480).unwrap();
        let b = CropBox::around(100, 80, 260, 200, 0.1, 512);
        let kw = b.intrinsics(&k);
        let p = nalgebra::Point3::new(0.03, -0.02, 0.5);
        let (u, v) = {
            let q = k.project(&p).unwrap();
            (q.x, q.y)
        };
        let w = kw.project(&p).unwrap();
        let (cu, cv) = b.to_crop(u, v);
        assert!((w.x - cu).abs() < 1e-9 && (w.y - cv).abs() < 1e-9);
    }

    #[test]
    fn patch_centres_follow_the_convention() {
        let g = PatchGrid::for_crop(512, 16).unwrap();
        assert_eq!(g.n, 32);
        assert_eq!(g.centre(0, 0), (7.5, 7.5));
        assert_eq!(g.centre(2, 3), (55.5, 39.5));
        assert_eq!(g.patch_at(55.5, 39.5), Some((2, 3)));
        assert_eq!(g.patch_at(-1.0, 3.0), None);
        assert!(PatchGrid::for_crop(500, 16).is_err());
    }
}
