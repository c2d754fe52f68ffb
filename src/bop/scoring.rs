//! BOP'19 recall / Average Recall aggregation, following
//! `scripts/eval_calc_errors.py` (estimate selection), `scripts/eval_calc_scores.py`
//! (GT validity, error normalisation), `bop_toolkit_lib/pose_matching.py`
//! (greedy matching), `bop_toolkit_lib/score.py::calc_localization_scores`
//! (recall) and `scripts/eval_bop19_pose.py` (averaging).
//!
//! What the toolkit does, and this module reproduces:
//! * **Estimates**: per target (scene, image, object) the estimates are sorted by
//!   descending score (stable: ties keep input order) and, with `n_top = -1`
//!   (BOP19), only the top `inst_count` are evaluated (`0` = all, `k > 0` = top k).
//! * **Valid GTs**: with `visib_gt_min < 0` (BOP19 uses `-1`), the `inst_count`
//!   most visible GT instances of the target object (stable sort by descending
//!   `visib_fract`, ties by GT order) are valid; with `visib_gt_min ≥ 0`, every
//!   GT of the target object with `visib_fract ≥ visib_gt_min` is valid.
//! * **Normalisation** (before thresholding): MSSD is divided by the object
//!   diameter; MSPD is multiplied by `640 / image_width` (the toolkit scales the
//!   *errors*, not the 5..50 px thresholds); VSD is not (its taus are already
//!   diameter fractions).
//! * **Matching**, separately for every threshold (and every tau for VSD): in
//!   descending-score order each estimate takes the valid, still unmatched GT
//!   with the smallest error *strictly below* the threshold (first GT on ties).
//! * **Recall** per threshold = matched valid GTs / valid GTs, **pooled over all
//!   targets of all objects** (not the mean of per-object recalls); 0 when there
//!   are no targets. With `n_top > 0` each image/object counts at most `n_top`
//!   targets.
//! * **AR_VSD** = mean over taus × thresholds (tau outer), **AR_MSSD** /
//!   **AR_MSPD** = mean over thresholds, **AR** = mean of the three. Means use
//!   numpy's summation order.
//!
//! Per-object ARs (same formulas restricted to one object) are our addition; the
//! toolkit only logs per-object recalls.

use std::collections::{BTreeMap, HashSet};
use std::fmt::Write as _;

use serde::Serialize;

use crate::bop::pose_errors::numpy_sum;

/// Errors of every estimate w.r.t. every GT instance of the target: `table[est][gt]`.
pub type ErrorTable = Vec<Vec<f64>>;

/// Evaluation parameters, defaulting to the BOP'19 protocol (`eval_bop19_pose.py`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Bop19Params {
    /// VSD visibility tolerance passed to [`crate::bop::pose_errors::vsd`]:
    /// 15 mm (5 mm for ITODD). Not used by the scorer itself.
    pub vsd_delta: f64,
    /// VSD misalignment tolerances (fractions of the diameter): 0.05..=0.50 step 0.05.
    pub vsd_taus: Vec<f64>,
    /// BOP19: true.
    pub vsd_normalized_by_diameter: bool,
    /// VSD correctness thresholds: 0.05..=0.50 step 0.05.
    pub vsd_correct_th: Vec<f64>,
    /// MSSD thresholds as fractions of the diameter: 0.05..=0.50 step 0.05.
    pub mssd_correct_th: Vec<f64>,
    /// MSPD thresholds in px at the reference width: 5..=50 step 5.
    pub mspd_correct_th: Vec<f64>,
    /// MSPD errors are multiplied by `mspd_reference_width / image_width` (640).
    pub mspd_reference_width: f64,
    /// BOP19: -1 (use the `inst_count` most visible GTs).
    pub visib_gt_min: f64,
    /// BOP19: -1 (top `inst_count` estimates); 0 = all; k > 0 = top k.
    pub n_top: i64,
    /// For [`crate::geometry::symmetry::symmetry_transformations`]: 0.01.
    pub max_sym_disc_step: f64,
    /// Where the symmetries come from. Not BOP: `Mesh` scores up to the symmetries the
    /// product finds in each mesh's shape and colours (`mesh::symmetry_finder`) beside
    /// those `models_info.json` declares. On
    /// meshes without their textures it says how much of what is lost is turns the shape
    /// cannot tell (a bare box's half-turns). BOP: `Declared`.
    pub symmetries: crate::bop::eval_models::SymmetriesFrom,
}

impl Default for Bop19Params {
    fn default() -> Self {
        Self {
            vsd_delta: 15.0,
            vsd_taus: np_arange(0.05, 0.51, 0.05),
            vsd_normalized_by_diameter: true,
            vsd_correct_th: np_arange(0.05, 0.51, 0.05),
            mssd_correct_th: np_arange(0.05, 0.51, 0.05),
            mspd_correct_th: np_arange(5.0, 51.0, 5.0),
            mspd_reference_width: 640.0,
            visib_gt_min: -1.0,
            n_top: -1,
            max_sym_disc_step: 0.01,
            symmetries: crate::bop::eval_models::SymmetriesFrom::Declared,
        }
    }
}

/// `np.arange(start, stop, step)` for floats: `ceil((stop−start)/step)` values
/// `start + i·((start+step) − start)` — bit-identical to numpy's fill.
pub fn np_arange(start: f64, stop: f64, step: f64) -> Vec<f64> {
    let len = ((stop - start) / step).ceil();
    if !(len.is_finite() && len > 0.0) {
        return Vec::new();
    }
    let delta = (start + step) - start;
    (0..len as usize).map(|i| start + i as f64 * delta).collect()
}

/// One GT instance of the target object in the target image (in `scene_gt` order).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct GtInstance {
    /// `visib_fract` from `scene_gt_info.json`.
    pub visib_fract: f64,
}

/// Everything the scorer needs about one target of `test_targets_bop19.json`.
///
/// Error tables are indexed `[est][gt]` with rows aligned with `est_scores` (all
/// estimates submitted for this scene/image/object, in submission order) and
/// columns aligned with `gts` (all GT instances of `obj_id` in the image, in
/// `scene_gt` order). Errors are *raw*: MSSD in the unit of `diameter`, MSPD in
/// pixels, VSD as returned by `vsd`. Rows of estimates outside the top selection
/// are never read; use [`select_estimates`] to compute only the needed rows (the
/// others may hold anything, e.g. `f64::NAN`).
#[derive(Debug, Clone, PartialEq)]
pub struct TargetEval {
    pub scene_id: u32,
    pub im_id: u32,
    pub obj_id: u32,
    /// `inst_count` of the target.
    pub inst_count: usize,
    pub gts: Vec<GtInstance>,
    /// Confidence score of every submitted estimate.
    pub est_scores: Vec<f64>,
    /// One table per VSD tau, in `Bop19Params::vsd_taus` order.
    pub vsd: Vec<ErrorTable>,
    pub mssd: ErrorTable,
    pub mspd: ErrorTable,
    /// Object diameter (`models_info.json`, mm), in the unit of the MSSD errors.
    pub diameter: f64,
    /// Width of the test image in pixels.
    pub image_width: u32,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ScoringError {
    #[error("target scene {0} im {1} obj {2} is listed twice")]
    DuplicateTarget(u32, u32, u32),
    #[error("target scene {scene_id} im {im_id} obj {obj_id}: {message}")]
    BadTarget { scene_id: u32, im_id: u32, obj_id: u32, message: String },
    #[error("invalid parameters: {0}")]
    BadParams(String),
}

/// Per-object Average Recalls.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ObjectAr {
    pub ar: f64,
    pub ar_vsd: f64,
    pub ar_mssd: f64,
    pub ar_mspd: f64,
    /// Number of valid GT instances (targets) of this object.
    pub targets: usize,
    /// Evaluated estimates of this object placed right but turned: not part of BOP's
    /// metrics (`evaluate::half_turn`; 0 where the caller computes none).
    pub half_turns: usize,
}

/// Pooled recall for every threshold, in evaluation order.
#[derive(Debug, Clone, PartialEq, Serialize, Default)]
pub struct RecallCurves {
    /// `[tau][threshold]`.
    pub vsd: Vec<Vec<f64>>,
    pub mssd: Vec<f64>,
    pub mspd: Vec<f64>,
}

/// BOP'19 result: `ar = mean(ar_vsd, ar_mssd, ar_mspd)`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ArReport {
    pub ar: f64,
    pub ar_vsd: f64,
    pub ar_mssd: f64,
    pub ar_mspd: f64,
    pub per_object: BTreeMap<u32, ObjectAr>,
    /// Valid GT instances over all targets (the recall denominator).
    pub targets: usize,
    /// The objects' `half_turns` summed.
    pub half_turns: usize,
    /// Estimates actually evaluated (after the top-`n` selection).
    pub estimates: usize,
    pub recalls: RecallCurves,
}

/// Indices of the estimates the toolkit evaluates, best first: stable sort by
/// descending score, then the top `inst_count` (`n_top = -1`), all (`0`) or the
/// top `n_top` (`> 0`). NaN scores sort last (the scorer rejects them).
pub fn select_estimates(scores: &[f64], inst_count: usize, n_top: i64) -> Vec<usize> {
    let mut order: Vec<usize> = (0..scores.len()).collect();
    order.sort_by(|&a, &b| desc_nan_last(scores[a], scores[b]));
    let keep = match n_top {
        0 => order.len(),
        n if n < 0 => inst_count,
        n => usize::try_from(n).unwrap_or(usize::MAX),
    };
    order.truncate(keep);
    order
}

/// Descending order with NaN last — a total order, so the stable sort keeps
/// equal keys in input order like Python's `sorted(..., reverse=True)`.
fn desc_nan_last(a: f64, b: f64) -> std::cmp::Ordering {
    b.partial_cmp(&a).unwrap_or_else(|| a.is_nan().cmp(&b.is_nan()))
}

/// Valid GT mask (see the module docs).
pub fn valid_gts(gts: &[GtInstance], inst_count: usize, visib_gt_min: f64) -> Vec<bool> {
    if visib_gt_min >= 0.0 {
        return gts.iter().map(|g| g.visib_fract >= visib_gt_min).collect();
    }
    let mut order: Vec<usize> = (0..gts.len()).collect();
    order.sort_by(|&a, &b| desc_nan_last(gts[a].visib_fract, gts[b].visib_fract));
    let mut valid = vec![false; gts.len()];
    for &g in order.iter().take(inst_count) {
        valid[g] = true;
    }
    valid
}

/// `pose_matching.match_poses` for one target and one threshold: returns
/// `(estimate, gt)` pairs. `est_order` is best-first; `normalize` maps a raw
/// error to the thresholded quantity.
pub fn greedy_match(est_order: &[usize], errors: &[Vec<f64>], gt_valid: &[bool], threshold: f64, normalize: impl Fn(f64) -> f64) -> Vec<(usize, usize)> {
    let mut matched = vec![false; gt_valid.len()];
    let mut out = Vec::new();
    for &est in est_order {
        let mut best = threshold;
        let mut best_gt = None;
        for (gt, (&valid, &err)) in gt_valid.iter().zip(&errors[est]).enumerate() {
            if valid && !matched[gt] {
                let e = normalize(err);
                if e < best {
                    best = e;
                    best_gt = Some(gt);
                }
            }
        }
        if let Some(gt) = best_gt {
            matched[gt] = true;
            out.push((est, gt));
        }
    }
    out
}

/// Runs the whole BOP'19 aggregation over `targets`.
pub fn evaluate_bop19(targets: &[TargetEval], params: &Bop19Params) -> Result<ArReport, ScoringError> {
    check_params(params)?;
    let mut seen = HashSet::new();
    for t in targets {
        if !seen.insert((t.scene_id, t.im_id, t.obj_id)) {
            return Err(ScoringError::DuplicateTarget(t.scene_id, t.im_id, t.obj_id));
        }
        check_target(t, params)?;
    }

    let prepared: Vec<Prepared> = targets.iter().map(|t| Prepared::new(t, params)).collect();
    let obj_ids: Vec<u32> = {
        let mut v: Vec<u32> = targets.iter().map(|t| t.obj_id).collect();
        v.sort_unstable();
        v.dedup();
        v
    };
    let total_targets: usize = prepared.iter().map(|p| p.n_targets).sum();
    let estimates: usize = prepared.iter().map(|p| p.order.len()).sum();

    // One Tally per evaluated (table, threshold) pair, in the toolkit's order.
    let mut vsd_tallies = Vec::new();
    for (tau_idx, _) in params.vsd_taus.iter().enumerate() {
        let row: Vec<Tally> = params.vsd_correct_th.iter().map(|&th| tally(targets, &prepared, th, |t| &t.vsd[tau_idx], |_, e| e)).collect();
        vsd_tallies.push(row);
    }
    let mssd_tallies: Vec<Tally> = params.mssd_correct_th.iter().map(|&th| tally(targets, &prepared, th, |t| &t.mssd, |t, e| e / t.diameter)).collect();
    let mspd_tallies: Vec<Tally> = params
        .mspd_correct_th
        .iter()
        .map(|&th| {
            let w = params.mspd_reference_width;
            tally(targets, &prepared, th, |t| &t.mspd, move |t, e| w / f64::from(t.image_width) * e)
        })
        .collect();

    let pooled = |t: &Tally| recall(t.tps, total_targets);
    let recalls = RecallCurves {
        vsd: vsd_tallies.iter().map(|row| row.iter().map(pooled).collect()).collect(),
        mssd: mssd_tallies.iter().map(pooled).collect(),
        mspd: mspd_tallies.iter().map(pooled).collect(),
    };
    let ar_vsd = numpy_mean(&recalls.vsd.concat());
    let ar_mssd = numpy_mean(&recalls.mssd);
    let ar_mspd = numpy_mean(&recalls.mspd);

    let mut per_object = BTreeMap::new();
    for &obj in &obj_ids {
        let n: usize = targets.iter().zip(&prepared).filter(|(t, _)| t.obj_id == obj).map(|(_, p)| p.n_targets).sum();
        let obj_recall = |t: &Tally| recall(t.obj_tps.get(&obj).copied().unwrap_or(0), n);
        let vsd: Vec<f64> = vsd_tallies.iter().flatten().map(obj_recall).collect();
        let mssd: Vec<f64> = mssd_tallies.iter().map(obj_recall).collect();
        let mspd: Vec<f64> = mspd_tallies.iter().map(obj_recall).collect();
        let (v, s, p) = (numpy_mean(&vsd), numpy_mean(&mssd), numpy_mean(&mspd));
        per_object.insert(obj, ObjectAr { ar: numpy_mean(&[v, s, p]), ar_vsd: v, ar_mssd: s, ar_mspd: p, targets: n, half_turns: 0 });
    }

    Ok(ArReport { ar: numpy_mean(&[ar_vsd, ar_mssd, ar_mspd]), ar_vsd, ar_mssd, ar_mspd, per_object, targets: total_targets, half_turns: 0, estimates, recalls })
}

/// Renders a report as a Markdown table (overall first, then one row per object).
pub fn format_report(r: &ArReport) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "| scope | targets | AR | AR_VSD | AR_MSSD | AR_MSPD | half-turns |");
    let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|---:|");
    let _ = writeln!(s, "| all | {} | {:.4} | {:.4} | {:.4} | {:.4} | {} |", r.targets, r.ar, r.ar_vsd, r.ar_mssd, r.ar_mspd, r.half_turns);
    for (obj, o) in &r.per_object {
        let _ = writeln!(s, "| obj {} | {} | {:.4} | {:.4} | {:.4} | {:.4} | {} |", obj, o.targets, o.ar, o.ar_vsd, o.ar_mssd, o.ar_mspd, o.half_turns);
    }
    let _ = writeln!(s, "\nhalf-turns: estimates whose centre is within 0.1·d of a true instance's and whose rotation is more than 90° from it, up to the symmetries scored with (not a BOP metric)");
    let _ = writeln!(s, "\nestimates evaluated: {}", r.estimates);
    s
}

impl std::fmt::Display for ArReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&format_report(self))
    }
}

/// Per-target data shared by every threshold.
struct Prepared {
    order: Vec<usize>,
    valid: Vec<bool>,
    n_targets: usize,
}

impl Prepared {
    fn new(t: &TargetEval, p: &Bop19Params) -> Self {
        let valid = valid_gts(&t.gts, t.inst_count, p.visib_gt_min);
        let n_valid = valid.iter().filter(|&&v| v).count();
        let n_targets = match usize::try_from(p.n_top) {
            Ok(n) if n > 0 => n_valid.min(n),
            _ => n_valid,
        };
        Self { order: select_estimates(&t.est_scores, t.inst_count, p.n_top), valid, n_targets }
    }
}

/// True positives of one (error table, threshold) evaluation.
struct Tally {
    tps: usize,
    obj_tps: BTreeMap<u32, usize>,
}

fn tally<'a>(targets: &'a [TargetEval], prepared: &[Prepared], threshold: f64, table: impl Fn(&'a TargetEval) -> &'a ErrorTable, normalize: impl Fn(&TargetEval, f64) -> f64) -> Tally {
    let mut out = Tally { tps: 0, obj_tps: BTreeMap::new() };
    for (t, p) in targets.iter().zip(prepared) {
        let n = greedy_match(&p.order, table(t), &p.valid, threshold, |e| normalize(t, e)).len();
        out.tps += n;
        *out.obj_tps.entry(t.obj_id).or_insert(0) += n;
    }
    out
}

/// `score.calc_recall`.
fn recall(tps: usize, targets: usize) -> f64 {
    if targets == 0 {
        0.0
    } else {
        tps as f64 / targets as f64
    }
}

/// `np.mean` (pairwise sum / n); 0 for an empty slice is never reached (params checked).
fn numpy_mean(v: &[f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    numpy_sum(v) / v.len() as f64
}

fn check_params(p: &Bop19Params) -> Result<(), ScoringError> {
    let lists = [("vsd_taus", &p.vsd_taus), ("vsd_correct_th", &p.vsd_correct_th), ("mssd_correct_th", &p.mssd_correct_th), ("mspd_correct_th", &p.mspd_correct_th)];
    for (name, l) in lists {
        if l.is_empty() || l.iter().any(|v| v.is_nan()) {
            return Err(ScoringError::BadParams(format!("{name} must be non-empty and free of NaN")));
        }
    }
    if !(p.mspd_reference_width.is_finite() && p.mspd_reference_width > 0.0) {
        return Err(ScoringError::BadParams("mspd_reference_width must be finite and > 0".into()));
    }
    if p.visib_gt_min.is_nan() {
        return Err(ScoringError::BadParams("visib_gt_min is NaN".into()));
    }
    Ok(())
}

fn check_target(t: &TargetEval, p: &Bop19Params) -> Result<(), ScoringError> {
    let bad = |message: String| ScoringError::BadTarget { scene_id: t.scene_id, im_id: t.im_id, obj_id: t.obj_id, message };
    if t.est_scores.iter().any(|s| s.is_nan()) {
        return Err(bad("an estimate score is NaN".into()));
    }
    if t.gts.iter().any(|g| g.visib_fract.is_nan()) {
        return Err(bad("a GT visib_fract is NaN".into()));
    }
    if !(t.diameter.is_finite() && t.diameter > 0.0) {
        return Err(bad(format!("diameter must be finite and > 0, got {}", t.diameter)));
    }
    if t.image_width == 0 {
        return Err(bad("image_width is 0".into()));
    }
    if t.vsd.len() != p.vsd_taus.len() {
        return Err(bad(format!("{} VSD tables for {} taus", t.vsd.len(), p.vsd_taus.len())));
    }
    let (rows, cols) = (t.est_scores.len(), t.gts.len());
    let tables = t.vsd.iter().map(|v| ("vsd", v)).chain([("mssd", &t.mssd), ("mspd", &t.mspd)]);
    for (name, table) in tables {
        if table.len() != rows || table.iter().any(|r| r.len() != cols) {
            return Err(bad(format!("{name} table must be {rows} estimates x {cols} GTs")));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A target whose every metric table is `err` (VSD: same table for every tau).
    fn target(obj_id: u32, im_id: u32, inst: usize, visib: &[f64], scores: &[f64], err: ErrorTable) -> TargetEval {
        TargetEval {
            scene_id: 1,
            im_id,
            obj_id,
            inst_count: inst,
            gts: visib.iter().map(|&v| GtInstance { visib_fract: v }).collect(),
            est_scores: scores.to_vec(),
            vsd: vec![err.clone(); 10],
            mssd: err.clone(),
            mspd: err,
            diameter: 100.0,
            image_width: 640,
        }
    }

    #[test]
    fn default_thresholds_match_numpy_arange() {
        let p = Bop19Params::default();
        assert_eq!(p.vsd_taus.len(), 10);
        assert_eq!(p.vsd_taus[0], 0.05);
        assert_eq!(p.vsd_taus[2], 0.15000000000000002); // numpy: 0.05 + 2*0.05
        assert_eq!(p.vsd_taus[9], 0.5);
        assert_eq!(p.mspd_correct_th, vec![5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 40.0, 45.0, 50.0]);
        assert_eq!(p.mssd_correct_th, p.vsd_correct_th);
    }

    #[test]
    fn true_poses_give_ar_one() {
        let p = Bop19Params::default();
        let t = vec![target(1, 0, 1, &[0.9], &[0.5], vec![vec![0.0]]), target(2, 0, 2, &[0.9, 0.4], &[0.5, 0.7], vec![vec![0.0, 9.0], vec![9.0, 0.0]])];
        let r = evaluate_bop19(&t, &p).unwrap();
        assert_eq!((r.ar, r.ar_vsd, r.ar_mssd, r.ar_mspd), (1.0, 1.0, 1.0, 1.0));
        assert_eq!(r.targets, 3);
        assert_eq!(r.estimates, 3);
        assert_eq!(r.per_object[&2].targets, 2);
        assert_eq!(r.per_object[&2].ar, 1.0);
    }

    #[test]
    fn no_estimates_give_zero() {
        let p = Bop19Params::default();
        let t = vec![target(1, 0, 1, &[0.9], &[], vec![])];
        let r = evaluate_bop19(&t, &p).unwrap();
        assert_eq!((r.ar, r.targets, r.estimates), (0.0, 1, 0));
        // No targets at all: recall is defined as 0.
        let r = evaluate_bop19(&[], &p).unwrap();
        assert_eq!((r.ar, r.targets), (0.0, 0));
    }

    #[test]
    fn error_between_thresholds_gives_fractional_recall() {
        let p = Bop19Params::default();
        let mut t = target(1, 0, 1, &[0.9], &[1.0], vec![vec![0.0]]);
        // VSD 0.32 < th only for th ∈ {0.35, 0.40, 0.45, 0.50} → 4/10 for each tau.
        t.vsd = vec![vec![vec![0.32]]; 10];
        // MSSD 22 mm / 100 mm = 0.22 < th for {0.25, ..., 0.50} → 6/10.
        t.mssd = vec![vec![22.0]];
        // MSPD 12 px at width 640 < th for {15, ..., 50} → 8/10.
        t.mspd = vec![vec![12.0]];
        let r = evaluate_bop19(&[t.clone()], &p).unwrap();
        assert!((r.ar_vsd - 0.4).abs() < 1e-15);
        assert!((r.ar_mssd - 0.6).abs() < 1e-15);
        assert!((r.ar_mspd - 0.8).abs() < 1e-15);
        assert!((r.ar - 0.6).abs() < 1e-15);
        assert_eq!(r.recalls.mssd[3], 0.0); // th 0.20: 0.22 is not below
        assert_eq!(r.recalls.mssd[4], 1.0); // th 0.25
                                            // Width 1280: the error is scaled by 640/1280 → 6 px → {10, ..., 50} → 9/10.
        t.image_width = 1280;
        let r = evaluate_bop19(&[t], &p).unwrap();
        assert!((r.ar_mspd - 0.9).abs() < 1e-15);
    }

    #[test]
    fn only_top_inst_count_estimates_count() {
        let p = Bop19Params::default();
        // inst_count 1: the best-scored estimate is wrong, the perfect one is ignored.
        let t = target(1, 0, 1, &[0.9], &[0.2, 0.9], vec![vec![0.0], vec![1e9]]);
        let r = evaluate_bop19(&[t], &p).unwrap();
        assert_eq!((r.ar, r.estimates), (0.0, 1));
        // Swap the scores: the perfect one is now on top.
        let t = target(1, 0, 1, &[0.9], &[0.9, 0.2], vec![vec![0.0], vec![1e9]]);
        assert_eq!(evaluate_bop19(&[t], &p).unwrap().ar, 1.0);
        // Ties keep submission order (stable sort).
        assert_eq!(select_estimates(&[0.5, 0.7, 0.5, 0.7], 3, -1), vec![1, 3, 0]);
        assert_eq!(select_estimates(&[0.5, 0.7], 1, 0), vec![1, 0]);
        assert_eq!(select_estimates(&[0.5, 0.7, 0.9], 1, 2), vec![2, 1]);
    }

    #[test]
    fn two_gts_are_matched_one_to_one() {
        let p = Bop19Params::default();
        // Both estimates are closest to GT 0. The better-scored one takes it; the other
        // can only take GT 1 (normalised error 0.30), which is correct for th > 0.30.
        // Recall: th 0.05..0.30 (6 values) → 1/2, th 0.35..0.50 (4) → 2/2 → AR = 0.7.
        let err = vec![vec![0.01, 0.20], vec![0.02, 0.30]];
        let mut t = target(1, 0, 2, &[0.9, 0.8], &[0.9, 0.8], err.clone());
        t.mssd = err.iter().map(|r| r.iter().map(|e| e * 100.0).collect()).collect();
        let r = evaluate_bop19(&[t], &p).unwrap();
        assert!((r.ar_vsd - 0.7).abs() < 1e-15, "{}", r.ar_vsd);
        assert!((r.ar_mssd - 0.7).abs() < 1e-15, "{}", r.ar_mssd);
        assert_eq!(r.recalls.mssd[0], 0.5);
        assert_eq!(r.recalls.mssd[9], 1.0);
        assert_eq!(greedy_match(&[0, 1], &err, &[true, true], 0.5, |e| e), vec![(0, 0), (1, 1)]);
    }

    #[test]
    fn only_the_most_visible_gts_are_valid() {
        let p = Bop19Params::default();
        // inst_count 1 with two GTs: only the more visible GT 1 is a target. The estimate
        // is perfect on GT 0 and far from GT 1 → recall 0, one target.
        let t = target(1, 0, 1, &[0.3, 0.8], &[1.0], vec![vec![0.0, 1e9]]);
        let r = evaluate_bop19(&[t], &p).unwrap();
        assert_eq!((r.ar, r.targets), (0.0, 1));
        // With visib_gt_min = 0.1 both GTs are valid (2 targets, 1 found).
        let p2 = Bop19Params { visib_gt_min: 0.1, ..Bop19Params::default() };
        let t = target(1, 0, 1, &[0.3, 0.8], &[1.0], vec![vec![0.0, 1e9]]);
        let r = evaluate_bop19(&[t], &p2).unwrap();
        assert_eq!((r.ar, r.targets), (0.5, 2));
    }

    #[test]
    fn overall_recall_is_pooled_not_mean_of_objects() {
        let p = Bop19Params::default();
        // Object 1: three images, all correct. Object 2: one image, wrong.
        let mut t: Vec<TargetEval> = (0..3).map(|im| target(1, im, 1, &[0.9], &[1.0], vec![vec![0.0]])).collect();
        t.push(target(2, 0, 1, &[0.9], &[1.0], vec![vec![1e9]]));
        let r = evaluate_bop19(&t, &p).unwrap();
        assert_eq!(r.ar, 0.75); // 3 / 4, not (1 + 0) / 2
        assert_eq!(r.per_object[&1].ar, 1.0);
        assert_eq!(r.per_object[&2].ar, 0.0);
        let text = format_report(&r);
        assert!(text.contains("| all | 4 | 0.7500 |"), "{text}");
        assert!(serde_json::to_string(&r).unwrap().contains("\"ar\":0.75"));
    }

    #[test]
    fn bad_input_is_rejected() {
        let p = Bop19Params::default();
        let good = target(1, 0, 1, &[0.9], &[1.0], vec![vec![0.0]]);
        assert!(matches!(evaluate_bop19(&[good.clone(), good.clone()], &p), Err(ScoringError::DuplicateTarget(1, 0, 1))));
        let mut bad = good.clone();
        bad.mssd = vec![vec![0.0, 1.0]];
        assert!(evaluate_bop19(&[bad], &p).unwrap_err().to_string().contains("obj 1"));
        let mut bad = good.clone();
        bad.vsd.pop();
        assert!(evaluate_bop19(&[bad], &p).is_err());
        let mut bad = good.clone();
        bad.est_scores = vec![f64::NAN];
        assert!(evaluate_bop19(&[bad], &p).is_err());
        let mut bad = good;
        bad.image_width = 0;
        assert!(evaluate_bop19(&[bad], &p).is_err());
        let p = Bop19Params { mssd_correct_th: vec![], ..Bop19Params::default() };
        assert!(evaluate_bop19(&[], &p).is_err());
    }
}
