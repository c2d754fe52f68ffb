//! A training-free refiner for the weakest direction of RGB-only PnP, the depth along the
//! viewing ray: it scales the translation (which keeps the object's projected centre
//! fixed and changes only its apparent size) to the value whose rendered silhouette best
//! overlaps the detection mask, by a shrinking-step search over a few window renders.

use super::refine::{RefineContext, RefineReport, Refined, Refiner};
use super::select::{mask_window, render_window, window_iou};
use crate::geometry::Pose;
use crate::render::RenderPool;
use std::sync::Arc;

pub struct SilhouetteDepthRefiner {
    renderer: Arc<RenderPool>,
    /// First relative step of the depth search and how many times it is halved.
    pub initial_step: f64,
    pub rounds: usize,
}

impl SilhouetteDepthRefiner {
    pub fn new(renderer: Arc<RenderPool>) -> Self {
        Self { renderer, initial_step: 0.04, rounds: 3 }
    }

    fn iou_at(&self, ctx: &RefineContext<'_>, pose: &Pose, window: (u32, u32, u32, u32)) -> Result<f32, String> {
        let r = render_window(&self.renderer, &ctx.model.mesh, pose, ctx.intrinsics, window).map_err(|e| e.to_string())?;
        Ok(window_iou(&r, ctx.mask, ctx.unknown, window))
    }
}

impl Refiner for SilhouetteDepthRefiner {
    fn name(&self) -> &str {
        "silhouette-depth"
    }

    fn refine(&self, ctx: &RefineContext<'_>, pose: Pose) -> Result<Refined, String> {
        let window = mask_window(ctx.mask).ok_or("empty mask")?;
        let mut best = (self.iou_at(ctx, &pose, window)?, 1.0f64);
        let mut step = self.initial_step;
        for _ in 0..self.rounds {
            let centre = best.1;
            for s in [centre * (1.0 - step), centre * (1.0 + step)] {
                let candidate = Pose::new(pose.rotation, pose.translation * s);
                let iou = self.iou_at(ctx, &candidate, window)?;
                if iou > best.0 {
                    best = (iou, s);
                }
            }
            step *= 0.5;
        }
        let report = RefineReport { moved: best.1 != 1.0, residual_px: f64::NAN, agreement: best.0 as f64, ..Default::default() };
        Ok(Refined { pose: Pose::new(pose.rotation, pose.translation * best.1), report })
    }
}
