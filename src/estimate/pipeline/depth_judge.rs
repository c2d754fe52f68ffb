//! Verification with depth: each rendered hypothesis fitted to the measured surface
//! (`estimate::depth_fit`) and scored on what the depth says of it.
//!
//! A pose at the wrong depth, or half-turned so that its surface bulges where the
//! measured one recedes, cannot fit; one behind the measured surface is seen through
//! (free space), the strongest evidence against it. The fit moves each pose to the depth,
//! so its render no longer shows it: selection renders the winner again.

use super::{EstimateError, Estimator, RefineContext, Verified};
use crate::depth::DepthImage;
use crate::estimate::depth_fit::{fit, visible_samples, DepthFit, DepthFitConfig};
use crate::estimate::select::window_camera;
use crate::geometry::{Intrinsics, Pose};
use crate::render::RenderOutput;
use rayon::prelude::*;

/// Weight of the depth score ([-1, 1]: inlier share less free-space share) added to a
/// rendered hypothesis's verification score (about [0, 1]). On the real YCB-V frames
/// (AR masks / boxes): 0.5 gave 0.605 / 0.534, 1 0.618 / 0.536, 2 0.579 / 0.558, 4 0.600 /
/// 0.557 (docs/estimation.md, "Depth"): flat within the noise of 35 instances.
const DEPTH_WEIGHT: f64 = 1.0;

impl Estimator {
    /// `pose` (verification off) fitted to `ctx.depth` from its render over the mask's
    /// window; the fit's report goes into `report`. Unchanged without depth.
    pub(super) fn fit_to_depth(&self, ctx: &RefineContext<'_>, pose: &mut Pose, report: &mut crate::estimate::RefineReport) -> Result<(), EstimateError> {
        let Some(depth) = ctx.depth else { return Ok(()) };
        let window = crate::estimate::select::mask_window(ctx.mask).expect("validated non-empty");
        let render = crate::estimate::select::render_window(&self.renderer, &ctx.model.mesh, pose, ctx.intrinsics, window)?;
        let (fitted, fit_report) = fit_rendered(ctx, depth, &render, pose, &window_camera(ctx.intrinsics, window)?);
        *pose = fitted;
        report.depth_fit = Some(fit_report);
        Ok(())
    }

    /// Fits every rendered hypothesis of `verified` to `ctx.depth`, adds its depth score
    /// to its own, and sorts best first again. Unrendered ones are left as they are (they
    /// rank below every rendered one).
    pub(super) fn judge_on_depth(ctx: &RefineContext<'_>, verified: &mut [Verified], window: (u32, u32, u32, u32)) -> Result<(), EstimateError> {
        let Some(depth) = ctx.depth else { return Ok(()) };
        let camera = window_camera(ctx.intrinsics, window)?;
        verified.par_iter_mut().filter(|v| v.render.is_some()).for_each(|v| {
            let render = v.render.take().expect("filtered on a render");
            let (pose, report) = fit_rendered(ctx, depth, &render, &v.pose, &camera);
            v.pose = pose;
            v.score += DEPTH_WEIGHT * report.score();
            v.refinement.depth_fit = Some(report);
        });
        verified.sort_by(|a, b| b.score.total_cmp(&a.score));
        Ok(())
    }
}

/// `pose` fitted to `depth` over the surface its `render` (taken with `camera`) shows.
fn fit_rendered(ctx: &RefineContext<'_>, depth: &DepthImage, render: &RenderOutput, pose: &Pose, camera: &Intrinsics) -> (Pose, DepthFit) {
    let samples = visible_samples(render, pose, camera);
    fit(&samples, pose, depth, ctx.intrinsics, ctx.model.diameter(), &DepthFitConfig::default())
}
