//! One candidate mask's way through the estimator: retrieval, the caller's screen where it
//! gives one, matching and PnP, then the start refined, and verified against its
//! alternatives (or, without verification, refined alone), then refined again on its
//! print. `Estimator::estimate_hinted` runs it for each mask before selection chooses
//! among them.

use super::{Detection, EstimateConfig, EstimateError, Estimator, Hypothesis, QueryView, RefineContext, RefinerKind, StageTimings};
use crate::depth::DepthImage;
use crate::estimate::hypotheses::Source;
use crate::geometry::{Intrinsics, Pose};
use crate::onboard::ObjectModel;
use crate::telemetry::ms_since;
use image::{GrayImage, RgbImage};
use std::time::Instant;

/// What each candidate mask of one request is estimated against.
pub(super) struct MaskInputs<'a> {
    pub(super) model: &'a ObjectModel,
    pub(super) image: &'a RgbImage,
    pub(super) depth: Option<&'a DepthImage>,
    pub(super) k: &'a Intrinsics,
    /// Where other detections may hide the object (see `Estimator::estimate_among`).
    pub(super) others: Option<&'a GrayImage>,
    pub(super) hints: &'a [Pose],
    /// Masks that fail it are not estimated (`Estimator::passes_screen`).
    pub(super) screen: super::Screen<'a>,
    pub(super) cfg: &'a EstimateConfig,
}

impl<'a> MaskInputs<'a> {
    /// What the refiners and the depth fit take for `detection`'s mask.
    pub(super) fn context(&self, detection: &'a Detection) -> RefineContext<'a> {
        RefineContext {
            model: self.model,
            image: self.image,
            intrinsics: self.k,
            mask: &detection.mask,
            unknown: self.others,
            mask_is_probability: false,
            from_box: detection.from_box,
            depth: self.depth,
        }
    }
}

impl Estimator {
    /// One candidate mask's hypothesis: retrieval, the screen, matching and PnP
    /// (`pose_for_mask`), then its start (PnP's pose, or with verification a template's
    /// where PnP found none) refined and verified.
    pub(super) fn hypothesis_for_mask(&self, req: &MaskInputs<'_>, q: &QueryView, (mi, detection): (usize, &Detection), timings: &mut StageTimings) -> Result<Hypothesis, EstimateError> {
        let cfg = req.cfg;
        let mut h = Hypothesis::unscored(mi, detection.score);
        let retrieved = self.retrieve_for_mask(req.model, q, cfg, &mut h, timings);
        let t = Instant::now();
        let passed = self.passes_screen(req, q, (mi, detection), &retrieved, &mut h)?;
        if req.screen.is_on() && req.depth.is_some() {
            timings.screen += ms_since(t);
        }
        if !passed {
            return Ok(h);
        }
        let matched = self.pose_for_mask(req.model, q, (req.image, &detection.mask), req.k, &retrieved, cfg, &mut h, timings)?;
        let start = match h.pose {
            Some(p) => Some((Source::Pipeline, p)),
            None if cfg.verify.enabled => crate::estimate::hypotheses::start_without_pnp(req.model, &matched, &retrieved, &q.crop_box, req.k),
            None => None,
        };
        if let Some(start) = start {
            let ctx = req.context(detection);
            let t = Instant::now();
            let _span = tracing::info_span!("refine", refiner = cfg.refiner.name(), verify = cfg.verify.enabled).entered();
            if cfg.verify.enabled {
                self.verify_into(req, &ctx, start, (&retrieved, &matched), q, &mut h, timings)?;
            } else {
                self.refine_into(&ctx, start.1, cfg, &mut h, timings)?;
            }
            // A pose fitted to the depth is not moved again along the image alone.
            if cfg.refiner == RefinerKind::Contour && req.depth.is_none() {
                self.refine_on_print(&ctx, &mut h, cfg);
            }
            timings.refine += ms_since(t);
        }
        Ok(h)
    }

    /// The start and its alternatives verified (`verify`); the best becomes the hypothesis's pose.
    #[allow(clippy::too_many_arguments)]
    fn verify_into(
        &self,
        req: &MaskInputs<'_>,
        ctx: &RefineContext<'_>,
        (source, pose): (Source, Pose),
        (retrieved, matched): (&[usize], &[Pose]),
        q: &QueryView,
        h: &mut Hypothesis,
        timings: &mut StageTimings,
    ) -> Result<(), EstimateError> {
        let (verified, depth_ms) = self.verify(ctx, (source, pose), retrieved, (matched, req.hints), q, req.cfg)?;
        h.verified = verified;
        timings.depth += depth_ms;
        if let Some(best) = h.verified.first_mut() {
            h.pose = Some(best.pose);
            h.refinement = Some(best.refinement.clone());
            h.render = best.render.take();
            // PnP's failure (kept in the trace) no longer leaves the mask without a pose.
            if let Some(why) = h.failure.take() {
                tracing::debug!(%why, start = %source, "verified from a template where PnP found no pose");
            }
        }
        Ok(())
    }

    /// Without verification: the start refined by the configured refiner, held to the box
    /// and fitted to the depth where there is one.
    fn refine_into(&self, ctx: &RefineContext<'_>, start: Pose, cfg: &EstimateConfig, h: &mut Hypothesis, timings: &mut StageTimings) -> Result<(), EstimateError> {
        match self.refiner(cfg.refiner).refine(ctx, start) {
            Ok(mut r) => {
                r.report.moved_to_box = super::held_to_box(ctx, cfg.box_prior, &mut r.pose);
                let t = Instant::now();
                self.fit_to_depth(ctx, &mut r.pose, &mut r.report)?;
                if ctx.depth.is_some() {
                    timings.depth += ms_since(t);
                }
                h.pose = Some(r.pose);
                h.refinement = Some(r.report);
            }
            Err(e) => h.failure = Some(format!("refiner {} failed: {e}", cfg.refiner.name())),
        }
        Ok(())
    }
}
