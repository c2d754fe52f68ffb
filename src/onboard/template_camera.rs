//! The camera templates are rendered with: square, fx = fy, so that turning a base render
//! about its principal point makes every in-plane template exactly. Shared by onboarding
//! (`pipeline`), the stored model (`model`, which maps template pixels back) and the
//! contour model (`contour`).

use crate::geometry::Intrinsics;

/// Base-render intrinsics: square, fx = fy (so in-plane rotation of the image is exact),
/// principal point at the image centre.
pub fn base_intrinsics(size: u32) -> Intrinsics {
    let c = (size as f64 - 1.0) * 0.5;
    Intrinsics { fx: size as f64, fy: size as f64, cx: c, cy: c, width: size, height: size }
}

/// How the template of in-plane angle `angle` is made from its base render: turned about
/// the principal point (exact for the square, fx = fy base camera).
pub fn in_plane_turn(k: &Intrinsics, angle: f64) -> crate::geometry::Turn {
    crate::geometry::Turn::new(angle, [k.cx, k.cy])
}
