//! `b2tf bop eval`: the errors of a results CSV against a dataset's ground truth, computed
//! as `bop_toolkit/scripts/eval_calc_errors.py` does, then scored by `scoring.rs`.
//!
//! Everything is in mm here, as in the toolkit: model vertices, translations, depth. Per
//! target, only the estimates the toolkit evaluates (the top `inst_count` by score) get
//! errors, against every GT instance of the object in the image: MSSD (∞ when the bounding
//! spheres do not overlap), MSPD, and VSD from depth renders of the model at both poses
//! (all 1.0 when the spheres' projections do not overlap).

use super::dataset::{load_depth_mm, load_models_info, load_split_gt, load_targets, model_path, ImageGt};
use super::format::MODELS_INFO;
use super::pose_errors::{mspd, mssd, sphere_projections_overlap, spheres_overlap, vsd, DepthMap, Intrinsics as K4, VsdCost};
use super::results_csv::ResultRow;
use super::scoring::{evaluate_bop19, select_estimates, ArReport, Bop19Params, GtInstance, TargetEval};
use super::symmetry::{parse_models_info, ObjectSymmetries};
use crate::geometry::Pose;
use crate::mesh::{load_mesh, Mesh, Units};
use crate::render::{RenderOptions, RenderPool};
use anyhow::{anyhow, Context, Result};
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

/// One object as the metrics see it.
struct EvalModel {
    mesh: Mesh,
    /// Vertices, mm.
    points: Vec<[f64; 3]>,
    /// Symmetry transforms with mm translations, identity first.
    symmetries: Vec<Pose>,
    diameter_mm: f64,
}

fn mm(p: &Pose) -> Pose {
    Pose::new(p.rotation, p.translation * 1000.0)
}

fn load_models(dataset: &Path, ids: impl IntoIterator<Item = u32>, step: f64) -> Result<BTreeMap<u32, EvalModel>> {
    let info = load_models_info(dataset)?;
    let info_path = dataset.join(MODELS_INFO);
    let text = std::fs::read_to_string(&info_path).with_context(|| format!("reading {}", info_path.display()))?;
    let symmetries = parse_models_info(&text).with_context(|| info_path.display().to_string())?;
    let mut out = BTreeMap::new();
    for id in ids {
        let diameter_mm = info.get(&id).ok_or_else(|| anyhow!("{}: no entry for object {id}, which the targets list", info_path.display()))?.diameter;
        let mesh = load_mesh(&model_path(dataset, id), Some(Units::Mm))?;
        let points = mesh.positions().iter().map(|v| v.map(|c| c as f64 * 1000.0)).collect();
        let symmetries = symmetries.get(&id).cloned().unwrap_or_else(ObjectSymmetries::default).transformations(step).with_context(|| format!("object {id}"))?;
        out.insert(id, EvalModel { mesh, points, symmetries, diameter_mm });
    }
    Ok(out)
}

/// Depth of `model` rendered alone at `pose` (metres) through the image's camera, mm.
fn render_depth_mm(pool: &RenderPool, model: &EvalModel, pose: &Pose, img: &ImageGt) -> Result<DepthMap> {
    let r = pool.render(&model.mesh, pose, &img.cam, &RenderOptions::default())?;
    Ok(DepthMap::new(img.cam.width as usize, img.cam.height as usize, r.depth.iter().map(|&z| z * 1000.0).collect())?)
}

/// Scores `results` against the dataset's `split`; `progress(done, total)` per target.
pub fn evaluate(dataset: &Path, split: &str, results: &[ResultRow], pool: &RenderPool, params: &Bop19Params, progress: &dyn Fn(usize, usize)) -> Result<ArReport> {
    let targets = load_targets(dataset)?;
    let images: HashMap<(u32, u32), ImageGt> = load_split_gt(dataset, split)?.into_iter().map(|g| ((g.scene_id, g.im_id), g)).collect();
    let models = load_models(dataset, targets.iter().map(|t| t.obj_id).collect::<std::collections::BTreeSet<_>>(), params.max_sym_disc_step)?;
    let mut estimates: HashMap<(u32, u32, u32), Vec<&ResultRow>> = HashMap::new();
    for r in results {
        estimates.entry((r.scene_id, r.im_id, r.obj_id)).or_default().push(r);
    }
    let mut evals = Vec::with_capacity(targets.len());
    for (n, t) in targets.iter().enumerate() {
        progress(n, targets.len());
        let img = images.get(&(t.scene_id, t.im_id)).ok_or_else(|| anyhow!("target scene {} image {}: no ground truth for this image in {split}", t.scene_id, t.im_id))?;
        let model = &models[&t.obj_id];
        let gts: Vec<(&Pose, f64)> = img.instances.iter().filter(|g| g.obj_id == t.obj_id).map(|g| (&g.pose, g.visib_fract.unwrap_or(1.0))).collect();
        let ests = estimates.get(&(t.scene_id, t.im_id, t.obj_id)).map(Vec::as_slice).unwrap_or(&[]);
        let scores: Vec<f64> = ests.iter().map(|e| e.score).collect();
        let (n_est, n_gt) = (ests.len(), gts.len());
        let mut vsd_tables = vec![vec![vec![f64::NAN; n_gt]; n_est]; params.vsd_taus.len()];
        let (mut mssd_table, mut mspd_table) = (vec![vec![f64::NAN; n_gt]; n_est], vec![vec![f64::NAN; n_gt]; n_est]);
        let selected = select_estimates(&scores, t.inst_count as usize, params.n_top);
        let k: K4 = [img.cam.fx, img.cam.fy, img.cam.cx, img.cam.cy];
        let test_depth = if selected.is_empty() || n_gt == 0 {
            None
        } else {
            let (w, h, d) = load_depth_mm(&img.depth_path, img.depth_scale)?;
            Some(DepthMap::new(w as usize, h as usize, d).with_context(|| img.depth_path.display().to_string())?)
        };
        let gt_depths: Vec<DepthMap> = if test_depth.is_some() { gts.iter().map(|(p, _)| render_depth_mm(pool, model, p, img)).collect::<Result<_>>()? } else { Vec::new() };
        for &e in &selected {
            let est = mm(&ests[e].pose);
            let est_depth = test_depth.as_ref().map(|_| render_depth_mm(pool, model, &ests[e].pose, img)).transpose()?;
            for (g, (gt_pose, _)) in gts.iter().enumerate() {
                let gt = mm(gt_pose);
                mssd_table[e][g] = if spheres_overlap(&est.translation, &gt.translation, model.diameter_mm) { mssd(&est, &gt, &model.points, &model.symmetries)? } else { f64::INFINITY };
                mspd_table[e][g] = mspd(&est, &gt, &model.points, k, &model.symmetries)?;
                let errs = if sphere_projections_overlap(model.diameter_mm / 2.0, &est.translation, &gt.translation) {
                    let (ed, td) = (est_depth.as_ref().expect("rendered"), test_depth.as_ref().expect("loaded"));
                    vsd(ed, &gt_depths[g], td, k, params.vsd_delta, &params.vsd_taus, params.vsd_normalized_by_diameter, model.diameter_mm, VsdCost::Step)?
                } else {
                    vec![1.0; params.vsd_taus.len()]
                };
                for (tau, v) in errs.into_iter().enumerate() {
                    vsd_tables[tau][e][g] = v;
                }
            }
        }
        evals.push(TargetEval {
            scene_id: t.scene_id,
            im_id: t.im_id,
            obj_id: t.obj_id,
            inst_count: t.inst_count as usize,
            gts: gts.iter().map(|&(_, visib_fract)| GtInstance { visib_fract }).collect(),
            est_scores: scores,
            vsd: vsd_tables,
            mssd: mssd_table,
            mspd: mspd_table,
            diameter: model.diameter_mm,
            image_width: img.cam.width,
        });
    }
    progress(targets.len(), targets.len());
    Ok(evaluate_bop19(&evals, params)?)
}
