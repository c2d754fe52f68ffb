//! OpenCV pinhole → wgpu clip space, so that rasterisation reproduces `Intrinsics::project`
//! exactly. Pure math; no GPU.
//!
//! wgpu's framebuffer has its origin at the top-left corner of pixel (0, 0), so that pixel's
//! centre is at framebuffer (0.5, 0.5), whereas OpenCV puts pixel centres at integers. A
//! point projecting to (u, v) must therefore land at framebuffer (u + 0.5, v + 0.5):
//!   ndc_x = 2(u + 0.5)/W − 1,   ndc_y = 1 − 2(v + 0.5)/H   (NDC y points up).
//! Depth is reversed (near → 1, far → 0) because float depth has its precision near 0,
//! which reversal spends on far surfaces where perspective compresses them most.

use nalgebra::{Matrix4, Point3};

use super::RenderError;
use crate::geometry::{Intrinsics, Pose};

/// Camera frame (x right, y down, z forward, metres) → clip space for a `width × height`
/// target, with reversed depth between `near` and `far` (camera z).
pub fn clip_from_camera(k: &Intrinsics, near: f64, far: f64) -> Matrix4<f64> {
    let (w, h) = (k.width as f64, k.height as f64);
    let a = near / (far - near);
    #[rustfmt::skip]
    let m = Matrix4::new(
        2.0 * k.fx / w, 0.0,            2.0 * (k.cx + 0.5) / w - 1.0, 0.0,
        0.0,            -2.0 * k.fy / h, 1.0 - 2.0 * (k.cy + 0.5) / h, 0.0,
        0.0,            0.0,            -a,                            a * far,
        0.0,            0.0,            1.0,                           0.0,
    );
    m
}

/// Near and far planes that enclose a sphere (object-frame `center`, `radius`) at `pose`,
/// with a small margin. Still valid (near < far) when the sphere is behind the camera; then
/// nothing is drawn, which is the right answer.
pub fn clip_range_for_sphere(pose: &Pose, center: [f64; 3], radius: f64) -> (f64, f64) {
    let z = pose.transform_point(&Point3::from(center)).z;
    let margin = radius * 1.01 + 1e-6;
    // A floor on near keeps the depth mapping finite when the camera is inside the sphere.
    let near = (z - margin).max(1e-5);
    let far = (z + margin).max(near * 1.001);
    (near, far)
}

/// Rejects intrinsics the rasteriser cannot honour: `Intrinsics` has public fields, so its
/// validated constructor may have been bypassed.
pub fn check_intrinsics(k: &Intrinsics, max_side: u32) -> Result<(), RenderError> {
    if k.width == 0 || k.height == 0 {
        return Err(RenderError::InvalidIntrinsics(format!("image size {}x{} is empty", k.width, k.height)));
    }
    if k.width > max_side || k.height > max_side {
        return Err(RenderError::TooLarge { width: k.width, height: k.height, max: max_side });
    }
    if !(k.fx.is_finite() && k.fy.is_finite() && k.fx > 0.0 && k.fy > 0.0) {
        return Err(RenderError::InvalidIntrinsics(format!("focal lengths fx={}, fy={} must be positive", k.fx, k.fy)));
    }
    if !(k.cx.is_finite() && k.cy.is_finite()) {
        return Err(RenderError::InvalidIntrinsics(format!("principal point ({}, {}) is not finite", k.cx, k.cy)));
    }
    Ok(())
}

pub fn check_pose(p: &Pose) -> Result<(), RenderError> {
    let finite = p.translation.iter().chain(p.rotation.matrix().iter()).all(|x| x.is_finite());
    if finite {
        Ok(())
    } else {
        Err(RenderError::InvalidPose(format!("non-finite pose {p:?}")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector4;

    /// What the rasteriser does after the vertex shader: divide by w, then map NDC to the
    /// framebuffer (y flipped, origin top-left).
    fn to_framebuffer(clip: Vector4<f64>, w: f64, h: f64) -> (f64, f64, f64) {
        let ndc = clip.xyz() / clip.w;
        ((ndc.x + 1.0) * 0.5 * w, (1.0 - ndc.y) * 0.5 * h, ndc.z)
    }

    #[test]
    fn projected_point_lands_on_its_pixel_centre() {
        let k = Intrinsics::new(612.3, 598.7, 311.2, 247.9, 640, 480).unwrap();
        let m = clip_from_camera(&k, 0.1, 5.0);
        for p in [[0.0, 0.0, 1.0], [0.13, -0.07, 0.4], [-0.3, 0.2, 2.5], [0.01, 0.02, 4.9]] {
            let p = Point3::from(p);
            let uv = k.project(&p).unwrap();
            let (x, y, d) = to_framebuffer(m * p.to_homogeneous(), 640.0, 480.0);
            assert!((x - (uv.x + 0.5)).abs() < 1e-9 && (y - (uv.y + 0.5)).abs() < 1e-9, "{p:?}: {x},{y} vs {uv:?}");
            assert!((0.0..=1.0).contains(&d));
        }
    }

    #[test]
    fn depth_is_reversed_between_near_and_far() {
        let k = Intrinsics::new(500.0, 500.0, 320.0, 240.0, 640, 480).unwrap();
        let m = clip_from_camera(&k, 0.2, 3.0);
        let depth = |z: f64| to_framebuffer(m * Point3::new(0.0, 0.0, z).to_homogeneous(), 640.0, 480.0).2;
        assert!((depth(0.2) - 1.0).abs() < 1e-12);
        assert!(depth(3.0).abs() < 1e-12);
        assert!(depth(1.0) > depth(1.1));
    }

    #[test]
    fn sphere_range_encloses_the_sphere() {
        let pose = Pose::new(nalgebra::Rotation3::identity(), nalgebra::Vector3::new(0.0, 0.0, 0.8));
        let (n, f) = clip_range_for_sphere(&pose, [0.0, 0.0, 0.1], 0.2);
        assert!(n < 0.7 && n > 0.6 && f > 1.1 && f < 1.2, "{n} {f}");
        let behind = Pose::new(nalgebra::Rotation3::identity(), nalgebra::Vector3::new(0.0, 0.0, -3.0));
        let (n, f) = clip_range_for_sphere(&behind, [0.0; 3], 0.2);
        assert!(n > 0.0 && f > n);
    }

    #[test]
    fn rejects_empty_or_huge_images() {
        let mut k = Intrinsics::new(500.0, 500.0, 320.0, 240.0, 640, 480).unwrap();
        assert!(check_intrinsics(&k, 8192).is_ok());
        k.width = 0;
        assert!(matches!(check_intrinsics(&k, 8192), Err(RenderError::InvalidIntrinsics(_))));
        k.width = 100_000;
        assert!(matches!(check_intrinsics(&k, 8192), Err(RenderError::TooLarge { .. })));
        k.width = 640;
        k.fx = f64::NAN;
        assert!(check_intrinsics(&k, 8192).is_err());
    }
}
