//! `b2tf bop eval`: the errors of a results CSV against a dataset's ground truth, computed
//! as `bop_toolkit/scripts/eval_calc_errors.py` does, then scored by `scoring.rs`.
//!
//! Everything is in mm here, as in the toolkit: model vertices, translations, depth. Per
//! target, only the estimates the toolkit evaluates (the top `inst_count` by score) get
//! errors, against every GT instance of the object in the image: MSSD (∞ when the bounding
//! spheres do not overlap), MSPD, and VSD from depth renders of the model at both poses
//! (all 1.0 when the spheres' projections do not overlap).
//!
//! Where the toolkit's conventions differ from the product's, its are followed: rotations
//! are the files' matrices unchanged (`rotation.rs`), MSSD and MSPD use the PLY's vertices
//! in f64 (`eval_models.rs`), and VSD's depth renders put pixel centres where OpenGL does
//! (`vsd_render.rs`).
//!
//! Beside BOP's metrics it counts the half-turns ([`half_turn`]): the failure depth cannot
//! see on objects whose shape is nearly symmetric, counted so that it can be followed.

use super::dataset::{load_depth_mm, load_split_gt, load_targets, ImageGt};
use super::eval_models::{load_models, mm};
use super::pose_errors::{mspd, mssd, sphere_projections_overlap, spheres_overlap, vsd, DepthMap, Intrinsics as K4, VsdCost};
use super::results_csv::ResultRow;
use super::scoring::{evaluate_bop19, select_estimates, ArReport, Bop19Params, GtInstance, TargetEval};
use super::vsd_render::render_depth_mm;
use crate::geometry::Pose;
use crate::render::RenderPool;
use anyhow::{anyhow, Context, Result};
use std::collections::HashMap;
use std::path::Path;

/// Scores `results` against the dataset's `split`; `progress(done, total)` per target.
/// What the ground truth holds that was accepted but is worth a look is added to
/// `warnings`, one line per file.
pub fn evaluate(dataset: &Path, split: &str, results: &[ResultRow], pool: &RenderPool, params: &Bop19Params, progress: &dyn Fn(usize, usize), warnings: &mut Vec<String>) -> Result<ArReport> {
    let targets = load_targets(dataset)?;
    let images: HashMap<(u32, u32), ImageGt> = load_split_gt(dataset, split, warnings)?.into_iter().map(|g| ((g.scene_id, g.im_id), g)).collect();
    let models = load_models(dataset, targets.iter().map(|t| t.obj_id).collect::<std::collections::BTreeSet<_>>(), params.max_sym_disc_step, params.symmetries)?;
    let mut estimates: HashMap<(u32, u32, u32), Vec<&ResultRow>> = HashMap::new();
    for r in results {
        estimates.entry((r.scene_id, r.im_id, r.obj_id)).or_default().push(r);
    }
    let mut evals = Vec::with_capacity(targets.len());
    let mut half_turns: HashMap<u32, usize> = HashMap::new();
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
        let gt_depths: Vec<DepthMap> = if test_depth.is_some() { gts.iter().map(|(p, _)| render_depth_mm(pool, &model.mesh, p, &img.cam)).collect::<Result<_>>()? } else { Vec::new() };
        for &e in &selected {
            let est = mm(&ests[e].pose);
            if half_turn(&est, gts.iter().map(|(p, _)| mm(p)), &model.symmetries, model.diameter_mm) {
                *half_turns.entry(t.obj_id).or_default() += 1;
            }
            let est_depth = test_depth.as_ref().map(|_| render_depth_mm(pool, &model.mesh, &ests[e].pose, &img.cam)).transpose()?;
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
    let mut report = evaluate_bop19(&evals, params)?;
    for (obj, o) in report.per_object.iter_mut() {
        o.half_turns = half_turns.get(obj).copied().unwrap_or(0);
    }
    report.half_turns = report.per_object.values().map(|o| o.half_turns).sum();
    Ok(report)
}

/// Largest rotation error of a placed estimate that is not counted a half-turn, degrees.
pub const HALF_TURN_DEGREES: f64 = 90.0;

/// Whether `est` (mm) is placed right but turned: its centre within 0.1·`diameter` of the
/// nearest true instance's, and its rotation more than [`HALF_TURN_DEGREES`] from that
/// instance's under every symmetry transform (identity first, as `EvalModel` holds them).
/// A pose far from every instance is a miss, not a turn.
pub fn half_turn(est: &Pose, gts: impl IntoIterator<Item = Pose>, symmetries: &[Pose], diameter: f64) -> bool {
    let nearest = gts.into_iter().map(|g| ((g.translation - est.translation).norm(), g)).min_by(|a, b| a.0.total_cmp(&b.0));
    let Some((distance, gt)) = nearest else {
        return false;
    };
    if distance > 0.1 * diameter {
        return false;
    }
    let least = std::iter::once(gt.rotation).chain(symmetries.iter().map(|s| gt.rotation * s.rotation)).map(|r| angle_deg(&r, &est.rotation)).fold(f64::INFINITY, f64::min);
    least > HALF_TURN_DEGREES
}

/// The angle between two rotations, degrees; clamped, since the files' matrices are kept
/// as given (`rotation.rs`) and a trace a hair above 3 would give no angle at all.
fn angle_deg(a: &nalgebra::Rotation3<f64>, b: &nalgebra::Rotation3<f64>) -> f64 {
    let m = a.matrix().transpose() * b.matrix();
    ((m.trace() - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Vector3};

    fn pose(axis: Vector3<f64>, degrees: f64, t: [f64; 3]) -> Pose {
        Pose::new(Rotation3::from_scaled_axis(axis * degrees.to_radians()), Vector3::from(t))
    }

    #[test]
    fn a_half_turn_is_placed_right_and_turned_past_ninety_degrees_up_to_the_symmetries() {
        let gt = pose(Vector3::x(), 0.0, [0.0, 0.0, 500.0]);
        let turned = pose(Vector3::z(), 180.0, [3.0, 0.0, 502.0]);
        assert!(half_turn(&turned, [gt], &[], 100.0));
        // Turned less, or placed wrong: not a half-turn.
        assert!(!half_turn(&pose(Vector3::z(), 60.0, [3.0, 0.0, 502.0]), [gt], &[], 100.0));
        assert!(!half_turn(&pose(Vector3::z(), 180.0, [40.0, 0.0, 500.0]), [gt], &[], 100.0));
        // A declared half-turn symmetry about z forgives it; one about x does not.
        assert!(!half_turn(&turned, [gt], &[pose(Vector3::z(), 180.0, [0.0; 3])], 100.0));
        assert!(half_turn(&turned, [gt], &[pose(Vector3::x(), 180.0, [0.0; 3])], 100.0));
        // The nearest of several instances is the one compared with; none: nothing to turn from.
        let other = pose(Vector3::z(), 180.0, [200.0, 0.0, 500.0]);
        assert!(half_turn(&turned, [other, gt], &[], 100.0));
        assert!(!half_turn(&turned, std::iter::empty(), &[], 100.0));
    }
}
