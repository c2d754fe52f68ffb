//! Hypotheses from the depth alone: every template's view of the object placed on the
//! surface the depth camera measured inside the mask, fitted there, the best kept.
//!
//! The image-driven hypotheses (PnP, the retrieved templates, flips and spins about them)
//! all start from what the photo's colours say; on an object whose print the mesh lacks,
//! in clutter, the right rotation can be among none of them, and the depth fit in
//! verification can only settle a pose near one. The measured surface says more than the
//! outline: a bottle's shoulder, a mug's handle, a box's edge. Each template already holds
//! the object points behind its patches (the surface seen from its viewpoint), so no
//! render is needed: each template is turned to look along the ray to the mask's measured
//! points, its points moved onto them (centre, then the median depth difference), and
//! scored by projective association (KinectFusion's: one depth lookup per point) on
//! points that agree inside the mask less points the camera sees through; the best few
//! are fitted by the point-to-plane ICP of `depth_fit` (normals from the template's patch
//! grid) and handed to verification, which refines, renders and judges them with the rest.

use super::depth_fit::{along_ray, depth_differences, fit, median, DepthFit, DepthFitConfig, SurfaceSample};
use crate::depth::DepthImage;
use crate::geometry::{geodesic_distance, Intrinsics, Pose};
use crate::onboard::ObjectModel;
use image::GrayImage;
use nalgebra::{Point3, Rotation3, Vector3};
use rayon::prelude::*;

/// Measured points taken from the mask at most (a grid over its box).
const MASK_POINTS: usize = 1500;
/// Every template is placed and fitted by a few ICP steps on a few of its points; the
/// best `FITTED` of those are fitted in full on all their points. (Placing every template
/// without ICP and fitting only the best 48 took a quarter of the time but found the right
/// view less often: under occlusion the measured centre is off the model's, and only the
/// fit brings a right rotation to its place.)
const FEW_POINTS: usize = 48;
const FEW_STEPS: usize = 6;
const FITTED: usize = 12;
/// The most views `searched` gives: the fitted ones.
pub const MOST_VIEWS: usize = FITTED;
/// Fitted poses closer than this in rotation (degrees) and a tenth of the diameter in
/// place are one pose: the better is kept.
const SAME_ROTATION_DEGREES: f64 = 10.0;

/// A pose found from the depth, with its fit.
#[derive(Clone, Debug)]
pub struct SearchedPose {
    pub pose: Pose,
    pub fit: DepthFit,
    /// What ranked it: the share of its measured points on the measured surface inside
    /// the mask, less the share the camera sees through, less the share of the mask it
    /// leaves uncovered (`Scene::score`).
    pub score: f64,
}

/// The surface each onboarded view shows, as object-frame samples with normals, from the
/// templates' patch points (no render). The surface a view shows is the same at every
/// in-plane turn, so it is sampled once per view.
struct ViewSurfaces {
    /// Per template, its view's index in `views`.
    view_of: Vec<usize>,
    views: Vec<ViewSurface>,
}

struct ViewSurface {
    /// The view's first template (in-plane turn 0), whose patches gave the samples.
    template: usize,
    /// Unit direction from the object's centre towards the view's camera, object frame.
    towards_camera: Vector3<f64>,
    all: Vec<SurfaceSample>,
    few: Vec<SurfaceSample>,
}

impl ViewSurfaces {
    fn of(model: &ObjectModel) -> Self {
        let owners: Vec<usize> = (0..model.templates.len()).map(|t| view_owner(model, t)).collect();
        let mut firsts = owners.clone();
        firsts.sort_unstable();
        firsts.dedup();
        let centre = Vector3::from(model.mesh.bbox_center());
        let views: Vec<ViewSurface> = firsts
            .par_iter()
            .map(|&t| {
                let all = view_samples(model, t);
                ViewSurface { template: t, towards_camera: towards_camera(&model.templates[t].pose, &centre), few: thinned(&all, FEW_POINTS), all }
            })
            .collect();
        let view_of = owners.iter().map(|o| firsts.binary_search(o).expect("every owner is listed")).collect();
        Self { view_of, views }
    }

    /// The view seen most nearly from where `pose` puts the camera: an ICP fit can turn a
    /// template's pose far from its view, and the surface the pose shows is then another
    /// view's.
    fn nearest(&self, pose: &Pose, centre: &Vector3<f64>) -> &ViewSurface {
        let d = towards_camera(pose, centre);
        self.views.iter().max_by(|a, b| a.towards_camera.dot(&d).total_cmp(&b.towards_camera.dot(&d))).expect("a model has views")
    }
}

/// Unit direction from the object's `centre` towards the camera of `pose`, object frame.
fn towards_camera(pose: &Pose, centre: &Vector3<f64>) -> Vector3<f64> {
    (pose.inverse().translation - centre).try_normalize(1e-12).unwrap_or_else(Vector3::z)
}

/// The `kept` best poses the depth alone gives for the object under `mask` (best first),
/// each a different rotation. Empty where the mask holds too few measured points (fewer
/// than 20) or `kept` is 0.
pub fn searched(model: &ObjectModel, depth: &DepthImage, k: &Intrinsics, mask: &GrayImage, kept: usize) -> Vec<SearchedPose> {
    let Some(centre) = measured_centre(depth, k, mask).filter(|_| kept > 0) else { return Vec::new() };
    // About 1 ms for 162 views; the search is about 10–15 ms on 2 cores.
    let surfaces = ViewSurfaces::of(model);
    let tol = super::depth_fit::tolerance(model.diameter());
    let mask_area = mask.pixels().filter(|p| p[0] > 0).count() as f64;
    let scene = Scene { model, surfaces: &surfaces, depth, k, mask, mask_area, tol };
    let mut coarse: Vec<(usize, Pose, f64)> = (0..model.templates.len())
        .into_par_iter()
        .filter_map(|t| {
            let few = &surfaces.views[surfaces.view_of[t]].few;
            let placed = placed_on(model, t, few, &centre, &scene)?;
            let (pose, _) = fit(few, &placed, depth, k, model.diameter(), &DepthFitConfig { iterations: FEW_STEPS, ..Default::default() });
            Some((t, pose, scene.score(&pose, |v| &v.few)))
        })
        .collect();
    coarse.sort_by(|a, b| b.2.total_cmp(&a.2).then(a.0.cmp(&b.0)));
    coarse.truncate(FITTED);
    let object_centre = Vector3::from(model.mesh.bbox_center());
    let mut fitted: Vec<SearchedPose> = coarse
        .par_iter()
        .filter_map(|&(_, pose, _)| {
            // Fitted on the surface the pose shows, twice: the first fit may turn it to
            // show another view's.
            let mut current = (pose, None);
            for _ in 0..2 {
                let samples = &surfaces.nearest(&current.0, &object_centre).all;
                if samples.len() < 12 {
                    return None;
                }
                let (p, f) = fit(samples, &current.0, depth, k, model.diameter(), &DepthFitConfig::default());
                current = (p, Some(f));
            }
            let (pose, fit) = (current.0, current.1?);
            Some(SearchedPose { score: scene.score(&pose, |v| &v.all), pose, fit })
        })
        .collect();
    fitted.sort_by(|a, b| b.score.total_cmp(&a.score));
    let mut out: Vec<SearchedPose> = Vec::new();
    for s in fitted {
        let same =
            |o: &SearchedPose| geodesic_distance(&o.pose.rotation, &s.pose.rotation).to_degrees() < SAME_ROTATION_DEGREES && (o.pose.translation - s.pose.translation).norm() < 0.1 * model.diameter();
        if !out.iter().any(same) {
            out.push(s);
        }
        if out.len() == kept {
            break;
        }
    }
    out
}

/// What the poses are scored against.
struct Scene<'a> {
    model: &'a ObjectModel,
    surfaces: &'a ViewSurfaces,
    depth: &'a DepthImage,
    k: &'a Intrinsics,
    mask: &'a GrayImage,
    /// The mask's pixels.
    mask_area: f64,
    /// Inlier tolerance along the ray (metres).
    tol: f64,
}

impl Scene<'_> {
    /// `pose` judged over the surface it shows (the nearest view's samples, those that
    /// `which` picks), at the points with a measurement at their pixel: the share on the
    /// measured surface (within the tolerance) inside the mask, less the share measured
    /// behind them (seen through), less the share of the mask the view leaves uncovered.
    /// Points on the surface outside the mask count neither way (the table under an
    /// object is at its depth too); without the cover, a view of one face inside the mask
    /// would score as well as the whole object. The view's cover is its patches' count
    /// times a patch's area in the image at that pose, times the share of its points
    /// inside the mask.
    fn score(&self, pose: &Pose, which: impl Fn(&ViewSurface) -> &[SurfaceSample]) -> f64 {
        let view = self.surfaces.nearest(pose, &Vector3::from(self.model.mesh.bbox_center()));
        let points = which(view);
        let (mut measured, mut agree, mut through, mut inside) = (0usize, 0usize, 0usize, 0usize);
        for s in points {
            let x = pose.rotation * s.point + pose.translation;
            let Some(uv) = self.k.project(&Point3::from(x)) else { continue };
            let masked = in_mask(self.mask, uv.x, uv.y);
            inside += usize::from(masked);
            let d = self.depth.nearest(uv.x, uv.y) as f64;
            if d <= 0.0 {
                continue;
            }
            measured += 1;
            let dz = d - x.z;
            if dz > self.tol {
                through += 1;
            } else if dz >= -self.tol && masked {
                agree += 1;
            }
        }
        if measured == 0 || points.is_empty() {
            return -2.0;
        }
        let covered = self.footprint(view.template, pose) * inside as f64 / points.len() as f64;
        let uncovered = 1.0 - (covered / self.mask_area.max(1.0)).min(1.0);
        (agree as f64 - through as f64) / measured as f64 - uncovered
    }

    /// Template `t`'s image area (pixels) seen at `pose`: its patches, each a patch of its
    /// crop, scaled from the template's camera and distance to this camera and distance.
    fn footprint(&self, t: usize, pose: &Pose) -> f64 {
        let (model, tp) = (self.model, &self.model.templates[t]);
        let centre = Vector3::from(model.mesh.bbox_center());
        let (z_template, z) = ((tp.pose.rotation * centre + tp.pose.translation).z, (pose.rotation * centre + pose.translation).z);
        if z <= 0.0 {
            return 0.0;
        }
        let side = model.grid.patch as f64 * tp.crop.scale() * (self.k.fx / model.render_intrinsics.fx) * (z_template / z);
        tp.patch_count as f64 * side * side
    }
}

fn in_mask(mask: &GrayImage, u: f64, v: f64) -> bool {
    let (x, y) = (u.round(), v.round());
    x >= 0.0 && y >= 0.0 && (x as u32) < mask.width() && (y as u32) < mask.height() && mask.get_pixel(x as u32, y as u32)[0] > 0
}

/// The median (per coordinate) of the measured points under the mask, camera frame;
/// `None` with fewer than 20.
fn measured_centre(depth: &DepthImage, k: &Intrinsics, mask: &GrayImage) -> Option<Vector3<f64>> {
    let (x0, y0, x1, y1) = crate::features::mask_bbox(mask)?;
    let area = ((x1 - x0 + 1) as usize) * ((y1 - y0 + 1) as usize);
    let step = ((area as f64 / MASK_POINTS as f64).sqrt().ceil() as u32).max(1);
    let mut coords: [Vec<f64>; 3] = Default::default();
    for y in (y0..=y1).step_by(step as usize) {
        for x in (x0..=x1).step_by(step as usize) {
            let z = depth.at(x, y);
            if mask.get_pixel(x, y)[0] == 0 || z <= 0.0 {
                continue;
            }
            let p = k.back_project(x as f64, y as f64, z as f64);
            for (c, v) in coords.iter_mut().zip([p.x, p.y, p.z]) {
                c.push(v);
            }
        }
    }
    if coords[0].len() < 20 {
        return None;
    }
    let [x, y, z] = coords.map(median);
    Some(Vector3::new(x, y, z))
}

/// Every n-th of `samples`, so that at most `at_most` are left.
fn thinned(samples: &[SurfaceSample], at_most: usize) -> Vec<SurfaceSample> {
    let step = samples.len().div_ceil(at_most.max(1)).max(1);
    samples.iter().step_by(step).copied().collect()
}

/// The template whose patch rows stand for `t`'s view: the view's first (in-plane turn
/// 0), where the templates are laid out view by view as onboarding writes them; else `t`.
fn view_owner(model: &ObjectModel, t: usize) -> usize {
    let tp = &model.templates[t];
    match t.checked_sub(tp.in_plane as usize) {
        Some(o) if model.templates[o].view == tp.view && model.templates[o].in_plane == 0 => o,
        _ => t,
    }
}

/// Template `t` turned to look along the ray to `centre` (the measured points' median),
/// its `points`' mean on it, then moved along the ray by the median depth difference:
/// the template as the camera would see it there. `None` where no point has a
/// measurement or the ray is degenerate.
fn placed_on(model: &ObjectModel, t: usize, samples: &[SurfaceSample], centre: &Vector3<f64>, scene: &Scene<'_>) -> Option<Pose> {
    if samples.is_empty() || centre.z <= 0.0 {
        return None;
    }
    let mean = samples.iter().map(|s| s.point).sum::<Vector3<f64>>() / samples.len() as f64;
    // The template's camera looks along +z at the object; turn it to look along the ray.
    let turn = Rotation3::rotation_between(&Vector3::z(), centre).unwrap_or_else(Rotation3::identity);
    let rotation = turn * model.templates[t].pose.rotation;
    let pose = Pose::new(rotation, centre - rotation * mean);
    let diffs = depth_differences(samples, &pose, scene.depth, scene.k);
    if diffs.is_empty() {
        return None;
    }
    // Deeper along the ray through the points' mean, so the image stays put.
    Some(along_ray(&pose, &mean, median(diffs)))
}

/// The patch points of template `t` (a view's first) with normals from their neighbours
/// on its patch grid (central differences in the template's camera, skipped across a
/// depth edge or where a neighbour is missing), object frame.
fn view_samples(model: &ObjectModel, t: usize) -> Vec<SurfaceSample> {
    let tp = &model.templates[t];
    let camera = &tp.pose;
    let n = model.grid.n as usize;
    let (start, count) = (tp.patch_start as usize, tp.patch_count as usize);
    let mut at: Vec<Option<Vector3<f64>>> = vec![None; n * n];
    for i in start..start + count {
        let p = Vector3::from(model.patch_points.point(i).map(f64::from));
        at[model.patch_cells[i] as usize] = Some(camera.rotation * p + camera.translation);
    }
    let cell = |r: usize, c: usize| if r < n && c < n { at[r * n + c] } else { None };
    let inverse = camera.inverse();
    let mut out = Vec::new();
    for r in 1..n.saturating_sub(1) {
        for c in 1..n.saturating_sub(1) {
            let (Some(p), Some(l), Some(rt), Some(u), Some(d)) = (cell(r, c), cell(r, c - 1), cell(r, c + 1), cell(r - 1, c), cell(r + 1, c)) else { continue };
            // Patches are 16 crop pixels apart, so a slanted face steps further in depth
            // between neighbours than a render's pixels do.
            let Some(normal) = super::depth_fit::grid_normal(&p, [l, rt, u, d], 0.05) else { continue };
            out.push(SurfaceSample { point: inverse.rotation * (p - camera.translation), normal: inverse.rotation * normal });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::RenderOptions;

    /// The smallest angle between `a` and `b` up to the half-turns about the object's axes
    /// that a plain box's surface cannot tell apart (degrees).
    fn degrees_up_to_half_turns(a: &Rotation3<f64>, b: &Rotation3<f64>) -> f64 {
        let turns = [Vector3::x_axis(), Vector3::y_axis(), Vector3::z_axis()].map(|axis| Rotation3::from_axis_angle(&axis, std::f64::consts::PI));
        std::iter::once(Rotation3::identity()).chain(turns).map(|t| geodesic_distance(&(a * t), b).to_degrees()).fold(f64::INFINITY, f64::min)
    }

    /// The test box onboarded at 42 views and 6 in-plane turns (252 templates at 128²): the
    /// crate's small test model's 24 templates are 60° and more apart, beyond an ICP's reach.
    fn onboarded_at_42_views(pool: &crate::render::RenderPool) -> ObjectModel {
        let backbone = crate::features::EmbeddedBackbone::new(crate::features::EmbeddedConfig::default()).unwrap();
        let mesh = crate::mesh::procedural::textured_box([0.1, 0.06, 0.16], 3);
        let config = crate::onboard::OnboardConfig { views: crate::geometry::ViewSampling { level: 1, in_plane_steps: 6 }, render_size: 128, ..Default::default() };
        crate::onboard::onboard("box", &mesh, &config, &backbone, pool, &|_| {}).unwrap()
    }

    /// The box seen from between its onboarded views, in front of a wall: the depth alone
    /// finds its pose to within the half-turns its surface cannot tell apart.
    #[test]
    fn a_box_between_its_views_is_found_from_the_depth_alone() {
        let Some(pool) = crate::render::tests::test_pool() else { return };
        let model = &onboarded_at_42_views(&pool);
        let k = Intrinsics::new(400.0, 400.0, 160.0, 120.0, 320, 240).unwrap();
        let truth = Pose::new(Rotation3::from_euler_angles(0.7, -0.35, 0.4), Vector3::new(0.02, -0.01, 0.55));
        let seen = pool.render_batch(&model.mesh, &[(truth, k)], &RenderOptions::default()).unwrap().remove(0);
        let wall: Vec<f32> = seen.depth.iter().map(|&z| if z > 0.0 { z } else { 0.8 }).collect();
        let depth = DepthImage::from_metres(320, 240, wall).unwrap();
        let found = searched(model, &depth, &k, &seen.mask, 4);
        assert!(!found.is_empty() && found.len() <= 4, "{}", found.len());
        let best = found.iter().map(|s| ((s.pose.translation - truth.translation).norm(), degrees_up_to_half_turns(&s.pose.rotation, &truth.rotation))).fold((f64::INFINITY, f64::INFINITY), |a, b| {
            if b.1 < a.1 {
                b
            } else {
                a
            }
        });
        assert!(best.0 < 0.01 && best.1 < 8.0, "nearest found pose {:.1} mm, {:.1}° off", best.0 * 1e3, best.1);
        assert!(found[0].fit.inlier_share > 0.9 && found[0].fit.free_space_share < 0.05, "{:?}", found[0].fit);
        // Each a different rotation, best first.
        for (i, a) in found.iter().enumerate() {
            assert!(found[..i].iter().all(|b| b.score >= a.score));
            assert!(found[..i]
                .iter()
                .all(|b| geodesic_distance(&a.pose.rotation, &b.pose.rotation).to_degrees() >= SAME_ROTATION_DEGREES || (a.pose.translation - b.pose.translation).norm() >= 0.1 * model.diameter()));
        }
    }

    /// Nothing to search from: no measurement under the mask, an empty mask, or no views asked.
    #[test]
    fn no_measured_surface_under_the_mask_finds_nothing() {
        let Some(model) = crate::onboard::test_model::small_model() else { return };
        let k = Intrinsics::new(400.0, 400.0, 160.0, 120.0, 320, 240).unwrap();
        let mut mask = GrayImage::new(320, 240);
        for y in 100..140 {
            for x in 140..180 {
                mask.put_pixel(x, y, image::Luma([255]));
            }
        }
        // Measured only outside the mask.
        let metres: Vec<f32> = (0..320 * 240).map(|i| if (140..180).contains(&(i % 320)) && (100..140).contains(&(i / 320)) { 0.0 } else { 0.6 }).collect();
        let depth = DepthImage::from_metres(320, 240, metres).unwrap();
        assert!(searched(model, &depth, &k, &mask, 4).is_empty());
        assert!(searched(model, &depth, &k, &GrayImage::new(320, 240), 4).is_empty());
        let flat = DepthImage::from_metres(320, 240, vec![0.6; 320 * 240]).unwrap();
        assert!(searched(model, &flat, &k, &mask, 0).is_empty());
        // A flat wall under the mask is a surface: something is found, and it says the
        // camera sees no free space where a pose lies on the wall.
        let on_wall = searched(model, &flat, &k, &mask, 2);
        assert!(on_wall.iter().all(|s| s.fit.free_space_share < 0.5), "{:?}", on_wall.iter().map(|s| &s.fit).collect::<Vec<_>>());
    }
}
