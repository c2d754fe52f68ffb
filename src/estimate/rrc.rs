//! Render-guided Re-Correspondence: render the object at the estimate and at its nine
//! 90°/180°/270° axis flips, encode all renders in one batched call, back-project their
//! foreground patches into a fresh patch pool, and match the query against it.

use super::correspond::PatchPool;
use crate::features::{crop_query, Backbone, CropInput};
use crate::geometry::{CropBox, Intrinsics, Pose};
use crate::onboard::ObjectModel;
use crate::render::{RenderOptions, RenderPool};
use nalgebra::{Rotation3, Vector3};
use rayon::prelude::*;

/// Identity plus rotations by 90°, 180°, 270° about the object's x, y and z axes.
pub fn variant_rotations() -> Vec<Rotation3<f64>> {
    let mut out = vec![Rotation3::identity()];
    for axis in [Vector3::x_axis(), Vector3::y_axis(), Vector3::z_axis()] {
        for quarter in 1..=3 {
            out.push(Rotation3::from_axis_angle(&axis, quarter as f64 * std::f64::consts::FRAC_PI_2));
        }
    }
    out
}

/// `[R·ΔR | t']`, turning about the object's bounding-box centre `c` so the object stays
/// where it was seen (the paper's `[R·ΔR | t]` assumes the model origin is its centre;
/// BOP models mostly have it there, CAD files often do not).
pub fn variant_pose(pose: &Pose, delta: &Rotation3<f64>, centre: &Vector3<f64>) -> Pose {
    let r = pose.rotation * delta;
    Pose::new(r, pose.translation + pose.rotation * centre - r * centre)
}

/// Bounding-box centre and half-diagonal: a sphere that contains the whole mesh.
pub fn bounding_sphere(model: &ObjectModel) -> (Vector3<f64>, f64) {
    let (lo, hi) = model.mesh.bbox();
    let c = Vector3::from(model.mesh.bbox_center());
    let r = 0.5 * Vector3::new((hi[0] - lo[0]) as f64, (hi[1] - lo[1]) as f64, (hi[2] - lo[2]) as f64).norm();
    (c, r)
}

/// A square window of the image around the projected bounding sphere, `None` when the
/// sphere reaches behind the camera.
pub fn sphere_window(pose: &Pose, centre: &Vector3<f64>, radius: f64, k: &Intrinsics, size: u32) -> Option<CropBox> {
    let c = pose.rotation * centre + pose.translation;
    if c.z <= radius * 1.05 {
        return None;
    }
    let uv = k.project(&nalgebra::Point3::from(c))?;
    // Image radius of the sphere's silhouette (f·tan of its half-angle), 10 % margin.
    let r_px = k.fx.max(k.fy) * radius / (c.z * c.z - radius * radius).sqrt() * 1.1;
    Some(CropBox { origin_u: uv.x - r_px, origin_v: uv.y - r_px, side: 2.0 * r_px, size })
}

/// Side in pixels of a render of a window `side` image pixels wide: `scale` render pixels
/// per image pixel, but no more than `cap` unless the window itself is wider (then one
/// render pixel per image pixel: never coarser than the photo), between 64 and `crop`
/// (the backbone's crop, which every render is resized to); `crop` itself where `scale`
/// is 0 or less.
pub fn render_side(side: f64, scale: f64, cap: u32, crop: u32) -> u32 {
    if scale <= 0.0 || !side.is_finite() {
        return crop;
    }
    ((side * scale).ceil().min((cap as f64).max(side.ceil())).min(crop as f64) as u32).max(64.min(crop))
}

/// The RRC patch pool around `pose`; empty if no variant rendered visibly. Each variant is
/// rendered at `render_scale` pixels per image pixel of its window, at most `render_cap`
/// pixels a side where the window is narrower than that (`render_side`).
pub fn rrc_pool(model: &ObjectModel, pose: &Pose, k: &Intrinsics, backbone: &dyn Backbone, renderer: &RenderPool, render_scale: f64, render_cap: u32) -> Result<PatchPool, super::EstimateError> {
    let (centre, radius) = bounding_sphere(model);
    let size = model.grid.n * model.grid.patch;
    let mut views = Vec::new();
    for delta in variant_rotations() {
        let p = variant_pose(pose, &delta, &centre);
        if let Some(w) = sphere_window(&p, &centre, radius, k, size) {
            let w = CropBox { size: render_side(w.side, render_scale, render_cap, size), ..w };
            views.push((p, w.intrinsics(k)));
        }
    }
    let renders = renderer.render_batch(&model.mesh, &views, &RenderOptions::default())?;
    let cropped: Vec<Option<(CropInput, CropBox)>> = renders.par_iter().map(|r| crop_query(&r.rgb, &r.mask, model.config.crop_padding, size)).collect();
    let (crops, meta): (Vec<CropInput>, Vec<(usize, CropBox)>) = cropped.into_iter().enumerate().filter_map(|(i, c)| c.map(|(crop, bx)| (crop, (i, bx)))).unzip();
    let maps = backbone.extract(&crops)?;
    // Fresh backbone descriptors: the backbone's size, whether or not the templates are PCA-compressed.
    let mut pool = PatchPool { dim: backbone.identity().local_dim as usize, ..Default::default() };
    for (fm, (i, bx)) in maps.iter().zip(&meta) {
        let (pose_i, kw) = &views[*i];
        let inv = pose_i.inverse();
        let search = (model.grid.patch as f64 * bx.scale() * 0.5).ceil() as i64;
        for patch in fm.foreground(model.config.min_coverage) {
            let (cu, cv) = fm.grid.centre_of(patch);
            let (wu, wv) = bx.to_image(cu, cv);
            let Some(z) = renders[*i].depth_near(wu, wv, search) else { continue };
            let p = inv.transform_point(&kw.back_project(wu, wv, z as f64));
            pool.points.push([p.x as f32, p.y as f32, p.z as f32]);
            pool.descriptors.extend_from_slice(fm.descriptor(patch));
        }
    }
    Ok(pool)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn renders_follow_the_object_size_in_the_photo_up_to_the_crop() {
        assert_eq!(render_side(100.0, 2.0, 512, 512), 200);
        assert_eq!(render_side(100.4, 2.0, 512, 512), 201);
        assert_eq!(render_side(300.0, 2.0, 512, 512), 512);
        assert_eq!(render_side(10.0, 2.0, 512, 512), 64);
        assert_eq!(render_side(100.0, 0.0, 512, 512), 512);
        assert_eq!(render_side(f64::NAN, 2.0, 512, 512), 512);
        assert_eq!(render_side(10.0, 2.0, 512, 32), 32);
        // The cap holds the render below twice the window, never below the window itself.
        assert_eq!(render_side(100.0, 2.0, 256, 512), 200);
        assert_eq!(render_side(200.0, 2.0, 256, 512), 256);
        assert_eq!(render_side(300.4, 2.0, 256, 512), 301);
        assert_eq!(render_side(600.0, 2.0, 256, 512), 512);
    }

    #[test]
    fn ten_distinct_variants_keep_the_centre_in_place() {
        let v = variant_rotations();
        assert_eq!(v.len(), 10);
        for i in 0..10 {
            for j in i + 1..10 {
                assert!(crate::geometry::geodesic_distance(&v[i], &v[j]) > 1.0);
            }
        }
        let pose = Pose::new(Rotation3::from_euler_angles(0.3, -0.2, 1.0), Vector3::new(0.01, 0.02, 0.5));
        let c = Vector3::new(0.02, -0.01, 0.03);
        for d in &v {
            let p = variant_pose(&pose, d, &c);
            let a = pose.rotation * c + pose.translation;
            let b = p.rotation * c + p.translation;
            assert!((a - b).norm() < 1e-12);
        }
    }
}
