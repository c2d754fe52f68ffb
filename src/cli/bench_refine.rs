//! `b2tf bench refine`: the refiners alone, started from the true pose and from known
//! perturbations of it on generated scenes. It separates what the refiner can do (how far
//! it pulls a pose back, how much it drifts a right one, how its depth precision falls
//! with the object's apparent size) from the rest of the pipeline.

use super::bench_estimate::{bench_models, median};
use crate::estimate::{RefineContext, RefinerKind};
use crate::eval::pose_error::{mssd, rotation_error_deg};
use crate::eval::scenes::generate_image;
use crate::geometry::Pose;
use crate::mesh::Mesh;
use crate::render::RenderPool;
use anyhow::{bail, Result};
use nalgebra::{Rotation3, Unit, Vector3};
use std::sync::Arc;
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct BenchRefineArgs {
    #[command(flatten)]
    pub scenes: super::bench_scenes::BenchSceneArgs,
    /// Harsher scenes (lighting, blur, noise): the refiners read the mask, so this mostly
    /// changes what colour statistics would see.
    #[arg(long)]
    pub harsh_scenes: bool,
    /// Rotation of each perturbation, degrees (about three fixed axes in turn).
    #[arg(long, default_value_t = 10.0)]
    pub degrees: f64,
    /// Depth change of each perturbation, as a share of the distance (alternating sign).
    #[arg(long, default_value_t = 0.10)]
    pub depth: f64,
    /// Refiners to compare (default: contour and silhouette-depth). The contour refiner is
    /// also run without its occlusion model, for comparison.
    #[arg(long = "refiner", value_enum)]
    pub refiners: Vec<RefinerKind>,
}

/// Apparent sizes (mask box side, px) the results are split by: depth precision from an
/// outline scales with the square of the apparent size.
const SIZE_EDGES: [u32; 3] = [60, 100, 200];

fn size_class(side: u32) -> usize {
    SIZE_EDGES.iter().position(|&e| side < e).unwrap_or(SIZE_EDGES.len())
}

fn size_label(i: usize) -> String {
    match i {
        0 => format!("< {} px", SIZE_EDGES[0]),
        i if i == SIZE_EDGES.len() => format!("≥ {} px", SIZE_EDGES[i - 1]),
        i => format!("{}–{} px", SIZE_EDGES[i - 1], SIZE_EDGES[i]),
    }
}

/// Outcomes of one start (truth or perturbed) for one refiner, by apparent size.
#[derive(Default, Clone)]
struct Outcomes {
    n: usize,
    correct: usize,
    rot_deg: Vec<f64>,
    depth_rel: Vec<f64>,
    ms: Vec<f64>,
    /// |visible fraction the refiner assumed − the true one| where it reported one.
    visible_err: Vec<f64>,
}

impl Outcomes {
    fn cell(&mut self) -> String {
        if self.n == 0 {
            return "–".into();
        }
        format!("{:.0} % · {:.1}° · {:.2} %", 100.0 * self.correct as f64 / self.n as f64, median(&mut self.rot_deg), 100.0 * median(&mut self.depth_rel))
    }
}

/// `pose` turned by `degrees` about `axis` (object frame) around the object's centre, and
/// moved `depth_factor` times as far along the ray through that centre.
fn perturbed(pose: &Pose, centre: &Vector3<f64>, axis: Vector3<f64>, degrees: f64, depth_factor: f64) -> Pose {
    let d = Rotation3::from_axis_angle(&Unit::new_normalize(axis), degrees.to_radians());
    let turned = crate::estimate::rrc::variant_pose(pose, &d, centre);
    let c = turned.rotation * centre + turned.translation;
    Pose::new(turned.rotation, turned.translation + c * (depth_factor - 1.0))
}

pub fn run(a: BenchRefineArgs) -> Result<()> {
    let scene_cfg = a.scenes.scene_config(a.harsh_scenes)?;
    let backbone = a.scenes.backbone.open()?;
    let pool = Arc::new(super::open_renderer(RenderPool::DEFAULT_SIZE)?);
    let meshes = a.scenes.load_meshes()?;
    let models = bench_models(&meshes, false, &a.scenes.store, backbone.as_ref(), &pool)?;
    let objects: Vec<(u32, Mesh)> = meshes.iter().enumerate().map(|(i, (_, m))| (i as u32 + 1, m.clone())).collect();
    let kinds = if a.refiners.is_empty() { vec![RefinerKind::Contour, RefinerKind::SilhouetteDepth] } else { a.refiners.clone() };
    let estimator = crate::estimate::Estimator::new(backbone, pool.clone());
    let mut without_occlusion = crate::estimate::contour::ContourRefiner::new(pool.clone());
    without_occlusion.config.occlusion_model = false;
    let photo = |edges| {
        let mut r = crate::estimate::contour::ContourRefiner::new(pool.clone());
        r.config.photo_edges = edges;
        r
    };
    use crate::estimate::contour::PhotoEdges;
    let (photo_off, photo_plain, photo_all) = (photo(PhotoEdges::Off), photo(PhotoEdges::Plain), photo(PhotoEdges::All));
    let mut refiners: Vec<(String, &dyn crate::estimate::Refiner)> = Vec::new();
    for kind in &kinds {
        refiners.push((kind.name().to_string(), estimator.refiner(*kind)));
        if *kind == RefinerKind::Contour {
            refiners.push(("contour, no occlusion model".into(), &without_occlusion));
            refiners.push(("contour, photo edges off".into(), &photo_off));
            refiners.push(("contour, photo edges where the print is plain".into(), &photo_plain));
            refiners.push(("contour, photo edges on every line".into(), &photo_all));
        }
    }
    let axes = [Vector3::new(1.0, 0.3, 0.0), Vector3::new(-0.2, 1.0, 0.5), Vector3::new(0.3, -0.4, 1.0)];
    let buckets = SIZE_EDGES.len() + 1;
    // [refiner][start: 0 truth, 1 perturbed][size]
    let mut out = vec![[vec![Outcomes::default(); buckets], vec![Outcomes::default(); buckets]]; refiners.len()];
    let mut visible_true = Vec::new();
    let pb = super::progress::bar(a.scenes.images as u64, "refining");
    let mut instances = 0;
    for im in 0..a.scenes.images as u32 {
        let scene = generate_image(&objects, &scene_cfg, &pool, im)?;
        for inst in &scene.instances {
            instances += 1;
            let model = &models[inst.obj_id as usize - 1];
            let side = crate::features::mask_bbox(&inst.mask).map_or(0, |b| (b.2 - b.0).max(b.3 - b.1) + 1);
            let bucket = size_class(side);
            let others = crate::masks::union(scene.instances.iter().filter(|o| !std::ptr::eq(*o, inst)).map(|o| &o.mask_visib), scene.rgb.width(), scene.rgb.height());
            let ctx = RefineContext { model, image: &scene.rgb, intrinsics: &scene.cam, mask: &inst.mask_visib, unknown: others.as_ref(), mask_is_probability: false, from_box: None, depth: None };
            let centre = Vector3::from(model.mesh.bbox_center());
            let mut starts = vec![(0, inst.pose)];
            for (i, axis) in axes.iter().enumerate() {
                let factor = if i % 2 == 0 { 1.0 + a.depth } else { 1.0 - a.depth };
                starts.push((1, perturbed(&inst.pose, &centre, *axis, a.degrees, factor)));
            }
            visible_true.push(inst.visib_fract());
            for (r, (_, refiner)) in refiners.iter().enumerate() {
                for (kind, start) in &starts {
                    let t = Instant::now();
                    let refined = refiner.refine(&ctx, *start).map_err(anyhow::Error::msg)?;
                    let o = &mut out[r][*kind][bucket];
                    o.ms.push(t.elapsed().as_secs_f64() * 1e3);
                    o.n += 1;
                    let p = refined.pose;
                    o.correct += (mssd(&p, &inst.pose, model.mesh.positions()) < 0.1 * model.diameter()) as usize;
                    o.rot_deg.push(rotation_error_deg(&p, &inst.pose));
                    let z = (inst.pose.rotation * centre + inst.pose.translation).z;
                    o.depth_rel.push(((p.rotation * centre + p.translation).z - z).abs() / z);
                    if refined.report.visible_fraction.is_finite() {
                        o.visible_err.push((refined.report.visible_fraction - inst.visib_fract()).abs());
                    }
                }
            }
        }
        pb.inc(1);
    }
    pb.finish_and_clear();
    if instances == 0 {
        bail!("no instances generated");
    }
    println!(
        "{instances} instances in {} generated images (diameter {:.2}–{:.2} of the image height, {:.0}–{:.0} % occluded, median {:.0} % visible, seed {}); perturbed starts: {}° about 3 axes, depth ×(1 ± {}); cells: MSSD < 0.1·d · median rotation error · median |Δz|/z of the object centre",
        a.scenes.images,
        a.scenes.fill.0,
        a.scenes.fill.1,
        a.scenes.min_occlusion * 100.0,
        a.scenes.max_occlusion * 100.0,
        100.0 * median(&mut visible_true),
        a.scenes.seed,
        a.degrees,
        a.depth
    );
    let sizes: Vec<String> = (0..buckets).map(size_label).collect();
    println!("| refiner | start | {} | all | median ms | median \\|assumed − true visible fraction\\| |", sizes.join(" | "));
    println!("|---|---|{}---:|---:|---:|", "---:|".repeat(buckets));
    for (r, (name, _)) in refiners.iter().enumerate() {
        for (s, start) in ["truth", "perturbed"].iter().enumerate() {
            let cells = &mut out[r][s];
            let mut all = Outcomes::default();
            for c in cells.iter() {
                all.n += c.n;
                all.correct += c.correct;
                all.rot_deg.extend(&c.rot_deg);
                all.depth_rel.extend(&c.depth_rel);
                all.ms.extend(&c.ms);
                all.visible_err.extend(&c.visible_err);
            }
            let visible = if all.visible_err.is_empty() { "–".to_string() } else { format!("{:.2}", median(&mut all.visible_err)) };
            let by_size: Vec<String> = cells.iter_mut().map(|c| if c.n == 0 { "–".into() } else { format!("{} ({})", c.cell(), c.n) }).collect();
            println!("| {name} | {start} | {} | {} | {:.1} | {visible} |", by_size.join(" | "), all.cell(), median(&mut all.ms));
        }
    }
    Ok(())
}
