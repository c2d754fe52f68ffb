//! Model depth for VSD, rendered the way the BOP toolkit renders it.
//!
//! The toolkit's renderers (`renderer_vispy`, the default, and `bop_renderer` behind
//! `renderer_cpp`) turn K into an OpenGL projection that puts a point projecting to (u, v)
//! at window coordinates (u, v); OpenGL samples pixel (i, j) at its centre, window
//! (i + ½, j + ½). So the toolkit's pixel (i, j) shows the ray through (i + ½, j + ½) of K,
//! half a pixel from the OpenCV convention (pixel centres at integers) that our renderer and
//! the rest of the product follow, rightly. Moving the principal point to (cx − ½, cy − ½)
//! for the render makes our pixel (i, j) show that same ray: the toolkit's depth map, pixel
//! for pixel. Without it, `bop eval`'s VSD differed from the toolkit's by up to 0.07 in
//! recall for an object with small pose errors, the silhouettes being half a pixel apart.
//!
//! Only these renders move: the test depth image and the distance images use K as given
//! (the toolkit's `depth_im_to_dist_im_fast` takes integer pixel coordinates with the
//! unshifted K), and nothing outside `bop eval` renders this way.

use super::pose_errors::DepthMap;
use crate::geometry::{Intrinsics, Pose};
use crate::mesh::Mesh;
use crate::render::{RenderOptions, RenderPool};
use anyhow::Result;

/// The camera whose OpenCV-convention render equals the toolkit's render through `k`.
pub fn toolkit_camera(k: &Intrinsics) -> Intrinsics {
    Intrinsics { cx: k.cx - 0.5, cy: k.cy - 0.5, ..*k }
}

/// Depth in mm of `mesh` alone at `pose` (metres), as the toolkit renders it through `cam`;
/// 0 off the object.
pub fn render_depth_mm(pool: &RenderPool, mesh: &Mesh, pose: &Pose, cam: &Intrinsics) -> Result<DepthMap> {
    let r = pool.render(mesh, pose, &toolkit_camera(cam), &RenderOptions::default())?;
    Ok(DepthMap::new(cam.width as usize, cam.height as usize, r.depth.iter().map(|&z| z * 1000.0).collect())?)
}

#[cfg(test)]
mod tests {
    //! Depth maps worked out by hand with the toolkit's convention: pixel (i, j) sees the
    //! ray ((i + ½ − cx)/fx, (j + ½ − cy)/fy, 1). Rendered on whatever adapter there is
    //! (lavapipe on CPU); skipped without one unless B2TF_REQUIRE_GPU=1.

    use super::*;
    use crate::mesh::{MeshData, Units};
    use nalgebra::{Rotation3, Vector3};

    fn pool() -> Option<RenderPool> {
        crate::render::tests::test_pool()
    }

    /// A square of side 2·`half` metres in the object's z = 0 plane.
    fn square(half: f32) -> Mesh {
        let positions = vec![[-half, -half, 0.0], [half, -half, 0.0], [half, half, 0.0], [-half, half, 0.0]];
        Mesh::new("square", Units::M, MeshData { positions, triangles: vec![[0, 1, 2], [0, 2, 3]], ..MeshData::default() }).unwrap()
    }

    fn camera() -> Intrinsics {
        Intrinsics::new(100.0, 100.0, 32.0, 24.0, 64, 48).unwrap()
    }

    #[test]
    fn the_principal_point_moves_half_a_pixel_and_nothing_else() {
        let k = Intrinsics::new(572.4114, 573.57043, 325.2611, 242.04899, 640, 480).unwrap();
        let t = toolkit_camera(&k);
        assert_eq!((t.fx, t.fy, t.cx, t.cy, t.width, t.height), (k.fx, k.fy, k.cx - 0.5, k.cy - 0.5, 640, 480));
    }

    #[test]
    fn silhouette_covers_the_pixels_whose_centres_the_toolkit_samples() {
        // A 165 mm square facing the camera 1 m away spans u, v ∈ 32 ± 8.25 and 24 ± 8.25:
        // [23.75, 40.25] × [15.75, 32.25]. The toolkit's pixel i is covered when i + ½ is in
        // the span: columns 24..=39, rows 16..=31 (16 × 16). OpenCV's centres (i in the span)
        // would give columns 24..=40 and rows 16..=32 instead.
        let Some(pool) = pool() else { return };
        let pose = Pose::new(Rotation3::identity(), Vector3::new(0.0, 0.0, 1.0));
        let d = render_depth_mm(&pool, &square(0.0825), &pose, &camera()).unwrap();
        let covered = |x: usize, y: usize| d.data[y * d.width + x] > 0.0;
        for y in 0..48 {
            for x in 0..64 {
                let inside = (24..=39).contains(&x) && (16..=31).contains(&y);
                assert_eq!(covered(x, y), inside, "pixel ({x}, {y})");
                if inside {
                    assert!((d.data[y * d.width + x] - 1000.0).abs() < 1e-3, "{}", d.data[y * d.width + x]);
                }
            }
        }
    }

    #[test]
    fn tilted_plane_depth_is_the_depth_at_half_integer_centres() {
        // The plane through (0, 0, 1 m) with normal n = (sin 30°, 0, cos 30°) (turned about
        // y): along the ray r = (x̃, ỹ, 1) the depth is (n·t) / (n·r). Across the image the
        // depth grows by 4 to 9 mm per pixel column, so half a pixel is worth 2 mm or more.
        let Some(pool) = pool() else { return };
        let k = camera();
        let pose = Pose::new(Rotation3::from_axis_angle(&Vector3::y_axis(), 30f64.to_radians()), Vector3::new(0.0, 0.0, 1.0));
        let n = pose.rotation * Vector3::z();
        let depth_on_ray = |u: f64, v: f64| 1000.0 * n.dot(&pose.translation) / n.dot(&Vector3::new((u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0));
        let d = render_depth_mm(&pool, &square(0.8), &pose, &k).unwrap();
        let (mut worst_toolkit, mut least_opencv) = (0f64, f64::INFINITY);
        for y in 0..48 {
            for x in 0..64 {
                let z = f64::from(d.data[y * d.width + x]);
                assert!(z > 0.0, "pixel ({x}, {y}) not covered");
                let (u, v) = (x as f64, y as f64);
                worst_toolkit = worst_toolkit.max((z - depth_on_ray(u + 0.5, v + 0.5)).abs());
                least_opencv = least_opencv.min((z - depth_on_ray(u, v)).abs());
            }
        }
        eprintln!("tilted plane: rendered depth within {worst_toolkit:.4} mm of the toolkit's centres, at least {least_opencv:.2} mm from OpenCV's");
        assert!(worst_toolkit < 0.01, "rendered depth is {worst_toolkit} mm off the toolkit's");
        assert!(least_opencv > 1.5, "rendered depth is within {least_opencv} mm of OpenCV's centres");
    }
}
