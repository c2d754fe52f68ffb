//! Patch re-identification: does a patch's nearest descriptor in another image of the same
//! object sit on the same surface point (within one patch)? Measured (a) between
//! neighbouring rendered views and (b) across a simulated render-to-real gap. This is how
//! the embedded backbone's design was chosen (docs/backbone.md).

use super::degrade::{add_noise, clutter_background, color_shift, composite, dilate, gaussian_blur};
use crate::features::{crop_query, Backbone, CropInput, FeatureMap};
use crate::geometry::views::{fitted_distance, view_pose};
use crate::geometry::{CropBox, Intrinsics, Pose};
use crate::mesh::procedural::Rng;
use crate::mesh::Mesh;
use crate::render::{RenderOptions, RenderOutput, RenderPool};
use anyhow::{anyhow, Result};
use nalgebra::{Rotation3, Unit, Vector3};

/// Share of query patches whose nearest template patch is the right one, per setting.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct ReidScore {
    pub neighbour_views: f64,
    pub render_to_real: f64,
    /// Both at once: a degraded photo-like query against an untextured neighbouring view.
    pub neighbour_across_gap: f64,
    pub patches_neighbour: usize,
    pub patches_gap: usize,
}

/// One image of the object as the backbone sees it, with what is needed to locate patches.
#[derive(Clone)]
struct View {
    crop: CropInput,
    bx: CropBox,
    render: RenderOutput,
    pose: Pose,
}

const PADDING: f64 = 0.1;

fn camera(size: u32) -> Intrinsics {
    let c = (size as f64 - 1.0) * 0.5;
    Intrinsics { fx: size as f64 * 1.2, fy: size as f64 * 1.2, cx: c, cy: c, width: size, height: size }
}

/// Pairs of (query, template) views for both settings, rendered once and shared by every
/// backbone under test.
pub struct ReidSet {
    neighbour: Vec<(View, View)>,
    gap: Vec<(View, View)>,
    neighbour_gap: Vec<(View, View)>,
    k: Intrinsics,
}

impl ReidSet {
    pub fn build(mesh: &Mesh, pool: &RenderPool, pairs: usize, seed: u64) -> Result<Self> {
        let size = 480;
        let k = camera(size);
        let centre = Vector3::from(mesh.bbox_center());
        let dist = fitted_distance(mesh.diameter() * 0.5, k.fx, size as f64 * 0.5, 0.7);
        let mut rng = Rng::new(seed);
        let mut neighbour = Vec::new();
        let mut gap = Vec::new();
        let mut neighbour_gap = Vec::new();
        // Template look: what a CAD mesh gives — vertex colours if it has them, else grey.
        let template_opts = if mesh.colors().is_some() { RenderOptions { use_texture: false, ..RenderOptions::default() } } else { RenderOptions { use_texture: false, ..RenderOptions::grey() } };
        for _ in 0..pairs {
            let dir = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
            let roll = rng.range(0.0, std::f64::consts::TAU);
            let pose = view_pose(&dir, roll, &centre, dist);
            // (a) a second view about 15° away: a neighbour on the level-2 template sphere.
            let axis = Unit::new_normalize(dir.cross(&Vector3::new(rng.normal(), rng.normal(), rng.normal())));
            let dir2 = Rotation3::from_axis_angle(&axis, 15f64.to_radians()) * dir;
            let pose2 = view_pose(&dir2, roll, &centre, dist);
            let a = render_view(mesh, pool, &pose, &k, &RenderOptions::default(), None)?;
            let b = render_view(mesh, pool, &pose2, &k, &RenderOptions::default(), None)?;
            neighbour.push((a, b));
            // (b) the same pose: textured, relit, cluttered, blurred, noisy, colour-shifted
            // query against the untextured template render.
            let light = [rng.range(-1.0, 1.0) as f32, rng.range(-1.0, 1.0) as f32, -1.0];
            let query_opts = RenderOptions { light_dir: light, light_intensity: rng.range(0.5, 0.9) as f32, ambient: rng.range(0.15, 0.4) as f32, ..RenderOptions::default() };
            let q = render_view(mesh, pool, &pose, &k, &query_opts, Some(&mut rng))?;
            let t = render_view(mesh, pool, &pose, &k, &template_opts, None)?;
            let t2 = render_view(mesh, pool, &pose2, &k, &template_opts, None)?;
            neighbour_gap.push((q.clone(), t2));
            gap.push((q, t));
        }
        Ok(Self { neighbour, gap, neighbour_gap, k })
    }

    pub fn score(&self, backbone: &dyn Backbone, min_coverage: f32) -> Result<ReidScore> {
        let (n_ok, n_all) = self.score_pairs(&self.neighbour, backbone, min_coverage)?;
        let (g_ok, g_all) = self.score_pairs(&self.gap, backbone, min_coverage)?;
        let (c_ok, c_all) = self.score_pairs(&self.neighbour_gap, backbone, min_coverage)?;
        Ok(ReidScore {
            neighbour_views: n_ok as f64 / n_all.max(1) as f64,
            render_to_real: g_ok as f64 / g_all.max(1) as f64,
            neighbour_across_gap: c_ok as f64 / c_all.max(1) as f64,
            patches_neighbour: n_all,
            patches_gap: g_all,
        })
    }

    fn score_pairs(&self, pairs: &[(View, View)], backbone: &dyn Backbone, min_cov: f32) -> Result<(usize, usize)> {
        let crops: Vec<CropInput> = pairs.iter().flat_map(|(a, b)| [a.crop.clone(), b.crop.clone()]).collect();
        let feats = backbone.extract(&crops)?;
        let (mut ok, mut all) = (0, 0);
        for (i, (a, b)) in pairs.iter().enumerate() {
            let (fa, fb) = (&feats[2 * i], &feats[2 * i + 1]);
            let (o, n) = self.reidentify(a, fa, b, fb, min_cov);
            ok += o;
            all += n;
        }
        Ok((ok, all))
    }

    /// For each foreground patch of `a` whose surface point is visible in `b`: is the
    /// nearest foreground patch of `b` within one patch of where that point lands?
    fn reidentify(&self, a: &View, fa: &FeatureMap, b: &View, fb: &FeatureMap, min_cov: f32) -> (usize, usize) {
        let grid = fa.grid;
        let fg_b = fb.foreground(min_cov);
        let k = &self.k;
        let (mut ok, mut all) = (0, 0);
        let inv_a = a.pose.inverse();
        for pa in fa.foreground(min_cov) {
            let (cu, cv) = grid.centre_of(pa);
            let (u, v) = a.bx.to_image(cu, cv);
            let Some(z) = depth_at(&a.render, u, v) else { continue };
            let obj = inv_a.transform_point(&k.back_project(u, v, z));
            let cam_b = b.pose.transform_point(&obj);
            let Some(uv) = k.project(&cam_b) else { continue };
            // Visible in b: its depth there agrees with the point's (else it is occluded).
            match depth_at(&b.render, uv.x, uv.y) {
                Some(zb) if (zb - cam_b.z).abs() < 0.02 * cam_b.z => {}
                _ => continue,
            }
            let (bu, bv) = b.bx.to_crop(uv.x, uv.y);
            let Some((ti, tj)) = grid.patch_at(bu, bv) else { continue };
            let da = fa.descriptor(pa);
            let best = fg_b.iter().map(|&pb| (pb, fb.descriptor(pb).iter().zip(da).map(|(x, y)| x * y).sum::<f32>())).max_by(|x, y| x.1.total_cmp(&y.1));
            let Some((pb, _)) = best else { continue };
            let (bi, bj) = (pb as u32 / grid.n, pb as u32 % grid.n);
            all += 1;
            if bi.abs_diff(ti) <= 1 && bj.abs_diff(tj) <= 1 {
                ok += 1;
            }
        }
        (ok, all)
    }
}

fn depth_at(r: &RenderOutput, u: f64, v: f64) -> Option<f64> {
    let (x, y) = (u.round(), v.round());
    if x < 0.0 || y < 0.0 || x >= r.width() as f64 || y >= r.height() as f64 {
        return None;
    }
    let z = r.depth_at(x as u32, y as u32);
    (z > 0.0).then_some(z as f64)
}

/// Renders a view and crops it like a query; with `degrade`, the photo-like degradations
/// are applied first and the mask dilated by 2 px (segmentations overshoot).
fn render_view(mesh: &Mesh, pool: &RenderPool, pose: &Pose, k: &Intrinsics, opts: &RenderOptions, degrade: Option<&mut Rng>) -> Result<View> {
    let render = pool.render(mesh, pose, k, opts)?;
    let (rgb, mask) = match degrade {
        Some(rng) => {
            let bg = clutter_background(k.width, k.height, rng);
            let img = composite(&render.rgb, &render.mask, &bg);
            let img = gaussian_blur(&img, rng.range(0.5, 1.5));
            let gains = [rng.range(0.8, 1.2), rng.range(0.8, 1.2), rng.range(0.8, 1.2)];
            let img = color_shift(&img, gains, [rng.range(-15.0, 15.0), rng.range(-15.0, 15.0), rng.range(-15.0, 15.0)]);
            (add_noise(&img, 4.0, rng), dilate(&render.mask, 2))
        }
        None => (render.rgb.clone(), render.mask.clone()),
    };
    let (crop, bx) = crop_query(&rgb, &mask, PADDING, 512).ok_or_else(|| anyhow!("object rendered outside the view at {pose:?}"))?;
    Ok(View { crop, bx, render, pose: *pose })
}
