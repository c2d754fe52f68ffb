//! The public entry point: validate, RANSAC, re-estimate on the consensus set, refine.

use super::matches::Matches;
use super::mirror::mirrored;
use super::refine::{levenberg_marquardt, LmOptions};
use super::validate::{check_inputs, degenerate_spread, min_support};
use super::{ransac, PnpConfig, PnpError, PnpResult};
use crate::geometry::Intrinsics;

/// The consensus re-estimate: plain least squares from the best minimal pose, a few steps
/// (it starts close; this only has to pull in the inliers the noisy sample missed).
const REESTIMATE: LmOptions = LmOptions { max_iterations: 10, huber_px: None };

/// `T_cam_obj` from `image_points[i]` (pixels) ↔ `object_points[i]` (metres, object frame),
/// robust to outliers. Deterministic for a given `cfg.seed`.
pub fn solve_pnp_ransac(image_points: &[[f64; 2]], object_points: &[[f64; 3]], k: &Intrinsics, cfg: &PnpConfig) -> Result<PnpResult, PnpError> {
    check_inputs(image_points, object_points, k, cfg)?;
    let need = min_support(cfg);
    let m = Matches::new(image_points, object_points, k, cfg.reprojection_threshold_px);

    let consensus = ransac::search(&m, cfg);
    let best = match consensus.pose {
        Some(pose) if consensus.inliers >= need => pose,
        _ => return Err(PnpError::NoConsensus { best_inliers: consensus.inliers }),
    };

    let mut inliers = m.inliers(&best);
    // An inlier set on a line fits a family of poses equally well: refuse rather than pick one.
    if degenerate_spread(image_points, object_points, inliers.iter().copied()) {
        return Err(PnpError::Degenerate);
    }
    let mut pose = levenberg_marquardt(&m, &inliers, &best, &REESTIMATE);
    if let Some(mirror) = mirrored(&m, &inliers, &pose) {
        let mirror = levenberg_marquardt(&m, &inliers, &mirror, &REESTIMATE);
        if m.truncated_cost(&mirror) < m.truncated_cost(&pose) {
            pose = mirror;
        }
    }
    inliers = m.inliers(&pose);
    if cfg.refine {
        // Huber at half the threshold: the matches near the threshold are the likeliest
        // outliers that slipped in, so they pull linearly, not quadratically.
        let opt = LmOptions { max_iterations: 20, huber_px: Some(0.5 * cfg.reprojection_threshold_px) };
        pose = levenberg_marquardt(&m, &inliers, &pose, &opt);
        inliers = m.inliers(&pose);
    }
    if inliers.len() < need {
        return Err(PnpError::NoConsensus { best_inliers: inliers.len() });
    }
    Ok(PnpResult { mean_reprojection_error_px: m.mean_error_px(&pose, &inliers), pose, inliers, iterations: consensus.iterations })
}
