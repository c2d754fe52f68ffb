//! Mesh → base-view renders → in-plane rotated crops → features + 3D points → ObjectModel.

use super::model::{pack_silhouette, ObjectModel, OnboardConfig, PatchRows, Template};
use super::profile::{timed, OnboardProfile, ViewClock, ViewStep};
use super::template_camera::{base_intrinsics, in_plane_turn};
use crate::features::{sample_crop, Backbone, CropInput, ToSource};
use crate::geometry::symmetry::{KnownSymmetries, SymmetrySource};
use crate::geometry::views::{fitted_distance, icosphere, view_pose};
use crate::geometry::{CropBox, Intrinsics, PatchGrid, Pose};
use crate::mesh::Mesh;
use crate::render::{RenderOptions, RenderOutput, RenderPool};
use half::f16;
use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

/// Where onboarding is; sent to the progress callback after every step.
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    pub templates_done: usize,
    pub templates_total: usize,
}

#[derive(Debug, thiserror::Error)]
pub enum OnboardError {
    #[error("invalid onboarding settings: {0}")]
    Config(String),
    #[error("object id {0:?} is invalid: use 1–64 characters from A–Z, a–z, 0–9, '-', '_', '.' (not starting with '.')")]
    BadId(String),
    #[error("rendering failed: {0}")]
    Render(#[from] crate::render::RenderError),
    #[error("feature extraction failed: {0}")]
    Features(#[from] crate::features::FeatureError),
    #[error("view {0} of the object rendered empty (is the mesh degenerate?)")]
    EmptyView(usize),
    #[error("onboarding was cancelled")]
    Cancelled,
}

/// Object ids become file and database names: keep them boring.
pub fn validate_object_id(id: &str) -> Result<(), OnboardError> {
    let ok = !id.is_empty() && id.len() <= 64 && !id.starts_with('.') && id.chars().all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'));
    if ok {
        Ok(())
    } else {
        Err(OnboardError::BadId(id.to_string()))
    }
}

/// Chunk of base views rendered at once: bounds memory (each 512² render is ~2 MB).
const VIEW_CHUNK: usize = 16;

pub fn onboard(object_id: &str, mesh: &Mesh, config: &OnboardConfig, backbone: &dyn Backbone, renderer: &RenderPool, progress: &(dyn Fn(Progress) + Sync)) -> Result<ObjectModel, OnboardError> {
    onboard_profiled(object_id, mesh, config, backbone, renderer, progress, &std::sync::atomic::AtomicBool::new(false)).map(|(model, _)| model)
}

/// `onboard` that stops with `OnboardError::Cancelled` at the next chunk of views once
/// `cancel` is set (a service cancelling a long-running onboarding), and tells where its
/// time went (`b2tf bench onboard` prints it, the service logs it).
pub fn onboard_profiled(
    object_id: &str,
    mesh: &Mesh,
    config: &OnboardConfig,
    backbone: &dyn Backbone,
    renderer: &RenderPool,
    progress: &(dyn Fn(Progress) + Sync),
    cancel: &std::sync::atomic::AtomicBool,
) -> Result<(ObjectModel, OnboardProfile), OnboardError> {
    validate_object_id(object_id)?;
    config.views.validate().map_err(OnboardError::Config)?;
    let identity = backbone.identity();
    let grid = PatchGrid::for_crop(identity.input_size, identity.patch_size).map_err(OnboardError::Config)?;
    if config.render_size < 64 || !(0.1..=1.0).contains(&config.render_fill) {
        return Err(OnboardError::Config(format!("render size {} / fill {} out of range", config.render_size, config.render_fill)));
    }
    let k = base_intrinsics(config.render_size);
    let (centre, radius) = (Vector3::from(mesh.bbox_center()), mesh.bounding_radius());
    let distance = fitted_distance(radius.max(1e-6), k.fx, config.render_size as f64 * 0.5, config.render_fill);
    let dirs = icosphere(config.views.level);
    let angles = config.views.in_plane_angles();
    let total = dirs.len() * angles.len();
    let opts = RenderOptions::default();
    let mut profile = OnboardProfile::default();
    let clock = ViewClock::default();

    let mut parts: Vec<ViewTemplates> = Vec::with_capacity(dirs.len());
    // One span for rendering and describing every template; none per view.
    let span = tracing::info_span!("templates", views = dirs.len(), templates = total).entered();
    for (chunk_idx, chunk) in dirs.chunks(VIEW_CHUNK).enumerate() {
        if cancel.load(std::sync::atomic::Ordering::Relaxed) {
            return Err(OnboardError::Cancelled);
        }
        let views: Vec<(Pose, Intrinsics)> = chunk.iter().map(|d| (view_pose(d, 0.0, &centre, distance), k)).collect();
        let renders = timed(&mut profile.renders_s, || renderer.render_batch(mesh, &views, &opts))?;
        let done: Vec<ViewTemplates> = timed(&mut profile.views_s, || {
            renders
                .par_iter()
                .zip(views.par_iter())
                .enumerate()
                .map(|(i, (render, (pose, _)))| {
                    let base = BaseView { index: chunk_idx * VIEW_CHUNK + i, render, pose, k: &k };
                    templates_of_view(&base, &angles, config, backbone, &grid, &clock)
                })
                .collect::<Result<_, _>>()
        })?;
        parts.extend(done);
        progress(Progress { templates_done: parts.len() * angles.len(), templates_total: total });
    }
    drop(span);
    profile.view_shares = clock.shares();
    // Templates are made with their own rows; sharing them per view is a step after.
    let mut model = assemble(object_id, mesh, &OnboardConfig { patch_rows: PatchRows::PerTemplate, ..config.clone() }, identity, k, grid, parts);
    if config.patch_rows.resolve(backbone) == PatchRows::PerView {
        timed(&mut profile.compress_s, || super::share_rows_per_view(&mut model)).map_err(OnboardError::Config)?;
    }
    if cancel.load(std::sync::atomic::Ordering::Relaxed) {
        return Err(OnboardError::Cancelled);
    }
    let contours = timed(&mut profile.contours_s, || tracing::info_span!("contours").in_scope(|| super::contour::ContourModel::build(mesh, renderer, &Default::default())))?;
    model.contours = std::sync::OnceLock::from(std::sync::Arc::new(contours));
    let shapes = timed(&mut profile.detector_s, || tracing::info_span!("detector").in_scope(|| crate::detect::ShapeModel::build(mesh, renderer, &Default::default())))?;
    model.detector = std::sync::OnceLock::from(std::sync::Arc::new(shapes));
    model.symmetries = Some(timed(&mut profile.symmetries_s, || tracing::info_span!("symmetries").in_scope(|| mesh_symmetries(mesh))));
    timed(&mut profile.compress_s, || {
        tracing::info_span!("pca").in_scope(|| apply_pca(&mut model, config.pca))?;
        tracing::info_span!("quantize").in_scope(|| apply_coding(&mut model, config.descriptors))
    })?;
    Ok((model, profile))
}

/// The mesh's symmetries as onboarding finds them (`objects upgrade` adds them to objects
/// stored before format 5 the same way).
pub fn mesh_symmetries(mesh: &Mesh) -> KnownSymmetries {
    KnownSymmetries { source: SymmetrySource::Mesh, symmetries: crate::mesh::symmetry_finder::find_symmetries(mesh, &Default::default()) }
}

/// Compresses an uncompressed model as `setting` asks (for its descriptor size and patch
/// count); leaves it as it is where the setting resolves to no PCA.
pub fn apply_pca(m: &mut ObjectModel, setting: crate::onboard::PcaSetting) -> Result<(), OnboardError> {
    match setting.resolve(m.local_dim, m.patch_count()) {
        Some(dim) => compress(m, dim),
        None => Ok(()),
    }
}

/// Fits the PCA on the model's own patch descriptors and stores them projected (what
/// onboarding does when its PCA setting resolves to a count; also usable on an
/// uncompressed model afterwards, as the benchmarks do).
pub fn compress(m: &mut ObjectModel, dim: usize) -> Result<(), OnboardError> {
    if m.pca.is_some() {
        return Err(OnboardError::Config("the model is already PCA-compressed".into()));
    }
    let rows = m.patch_descriptors.as_half().ok_or_else(|| OnboardError::Config("PCA needs the f16 descriptors; these are quantised".into()))?;
    let pca = super::pca::Pca::fit(rows, m.local_dim, dim).map_err(OnboardError::Config)?;
    m.patch_descriptors = super::PatchDescriptors::Half(pca.project_f16(rows).into());
    m.local_dim = dim;
    m.pca = Some(pca);
    Ok(())
}

/// Stores the model's f16 patch descriptors as `coding` asks (after any PCA: the codes
/// are learnt in the space they are matched in). A no-op for f16.
pub fn apply_coding(m: &mut ObjectModel, coding: super::model::DescriptorCoding) -> Result<(), OnboardError> {
    use super::model::DescriptorCoding;
    let per_code = match coding {
        DescriptorCoding::F16 => return Ok(()),
        DescriptorCoding::I8 => return m.patch_descriptors.to_int8(m.local_dim).map_err(OnboardError::Config),
        DescriptorCoding::Pq4 => 4,
        DescriptorCoding::Pq2 => 2,
    };
    if m.local_dim < per_code || !m.local_dim.is_multiple_of(per_code) {
        return Err(OnboardError::Config(format!("--descriptors {coding:?} needs descriptors of a multiple of {per_code} values, not {}: use --descriptors f16", m.local_dim)));
    }
    m.patch_descriptors.quantize(m.local_dim, m.local_dim / per_code).map_err(OnboardError::Config)
}

/// The templates of one base view (all its in-plane rotations).
struct ViewTemplates {
    templates: Vec<Template>,
    globals: Vec<f32>,
    descriptors: Vec<f16>,
    points: Vec<[f32; 3]>,
    cells: Vec<u16>,
    silhouettes: Vec<u64>,
}

/// One base view: its render, the camera pose it was rendered from, the intrinsics.
struct BaseView<'a> {
    index: usize,
    render: &'a RenderOutput,
    pose: &'a Pose,
    k: &'a Intrinsics,
}

/// A view's in-plane templates before their rows: the crop boxes and crops, in the
/// order of the view's angles.
struct TurnedCrops {
    boxes: Vec<CropBox>,
    crops: Vec<CropInput>,
}

fn templates_of_view(base: &BaseView, angles: &[f64], config: &OnboardConfig, backbone: &dyn Backbone, grid: &PatchGrid, clock: &ViewClock) -> Result<ViewTemplates, OnboardError> {
    let outline = crate::features::mask_row_ends(&base.render.mask);
    if outline.is_empty() {
        return Err(OnboardError::EmptyView(base.index));
    }
    let crop_size = grid.n * grid.patch;
    let turned = clock.time(ViewStep::Crops, || {
        let (boxes, crops) = angles
            .iter()
            .map(|&angle| {
                // Template pixel = the base pixel turned by `angle` about the principal point (fx = fy).
                let turn = in_plane_turn(base.k, angle);
                let [l, t, r, b] = turn.extents(outline.iter().copied()).expect("checked non-empty");
                let bx = CropBox::around_edges(l - 0.5, t - 0.5, r + 0.5, b + 0.5, config.crop_padding, crop_size);
                (bx, sample_crop(&base.render.rgb, &base.render.mask, &bx, ToSource::Turned(turn.inverse())))
            })
            .unzip();
        TurnedCrops { boxes, crops }
    });
    let features = clock.time(ViewStep::Features, || backbone.extract(&turned.crops))?;
    Ok(clock.time(ViewStep::Points, || view_rows(base, config, grid, angles, &turned, &features)))
}

/// A view's templates from their crops and descriptors: each foreground patch's 3D point
/// read from the base render's depth, its descriptor and cell, and the template's silhouette.
fn view_rows(base: &BaseView, config: &OnboardConfig, grid: &PatchGrid, angles: &[f64], turned: &TurnedCrops, features: &[crate::features::FeatureMap]) -> ViewTemplates {
    let inv_pose = base.pose.inverse();
    let mut out = ViewTemplates { templates: vec![], globals: vec![], descriptors: vec![], points: vec![], cells: vec![], silhouettes: vec![] };
    for (ai, (((&angle, bx), crop), fm)) in angles.iter().zip(&turned.boxes).zip(&turned.crops).zip(features).enumerate() {
        let to_base = in_plane_turn(base.k, angle).inverse();
        let start = out.points.len();
        for patch in fm.foreground(config.min_coverage) {
            let (cu, cv) = grid.centre_of(patch);
            let (tu, tv) = bx.to_image(cu, cv);
            let (bu, bv) = to_base.apply(tu, tv);
            let search = (grid.patch as f64 * bx.scale() * 0.5).ceil() as i64;
            let Some(z) = base.render.depth_near(bu, bv, search) else { continue };
            let p_cam = base.k.back_project(bu, bv, z as f64);
            let p_obj = inv_pose.transform_point(&Point3::from(p_cam.coords));
            out.points.push([p_obj.x as f32, p_obj.y as f32, p_obj.z as f32]);
            out.cells.push(patch as u16);
            out.descriptors.extend(fm.descriptor(patch).iter().map(|&x| f16::from_f32(x)));
        }
        let rot = crate::geometry::views::in_plane_rotation(angle);
        out.templates.push(Template {
            pose: Pose::new(rot * base.pose.rotation, rot * base.pose.translation),
            view: base.index as u32,
            in_plane: ai as u32,
            crop: *bx,
            patch_start: start as u32, // made global in `assemble`
            patch_count: (out.points.len() - start) as u32,
        });
        out.globals.extend_from_slice(&fm.global);
        out.silhouettes.extend(pack_silhouette(&crop.mask));
    }
    out
}

fn assemble(object_id: &str, mesh: &Mesh, config: &OnboardConfig, backbone: crate::features::BackboneIdentity, k: Intrinsics, grid: PatchGrid, parts: Vec<ViewTemplates>) -> ObjectModel {
    let mut m = ObjectModel {
        object_id: object_id.to_string(),
        global_dim: backbone.global_dim as usize,
        local_dim: backbone.local_dim as usize,
        backbone,
        config: config.clone(),
        render_intrinsics: k,
        grid,
        mesh: mesh.clone(),
        templates: vec![],
        global: vec![],
        patch_descriptors: Default::default(),
        patch_points: Default::default(),
        patch_cells: Default::default(),
        silhouettes: Default::default(),
        pca: None,
        contours: Default::default(),
        detector: Default::default(),
        symmetries: None,
    };
    let (mut descriptors, mut points) = (Vec::new(), Vec::new());
    for p in parts {
        let offset = points.len() as u32;
        m.templates.extend(p.templates.into_iter().map(|mut t| {
            t.patch_start += offset;
            t
        }));
        m.global.extend(p.globals);
        descriptors.extend(p.descriptors);
        points.extend(p.points);
        m.patch_cells.to_mut().extend(p.cells);
        m.silhouettes.to_mut().extend(p.silhouettes);
    }
    m.patch_descriptors = super::PatchDescriptors::Half(descriptors.into());
    m.patch_points = super::PatchPoints::Exact(points.into());
    m.patch_points.to_grid();
    m
}
