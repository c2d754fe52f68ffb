//! A request's inputs as the estimator takes them: checked (`validate`), its masks chosen
//! (`candidate_masks`, with the depth's proposals beside boxes where asked for), cropped and
//! encoded by the backbone (`queries`). The estimate and the screen
//! (`Estimator::screen_scores`) both start here.

use super::{per_mask, EstimateConfig, EstimateError, Estimator, StageTimings};
use crate::estimate::candidates::Detection;
use crate::estimate::query::{crop_all, encode, QueryView};
use crate::geometry::Intrinsics;
use crate::onboard::ObjectModel;
use crate::telemetry::ms_since;
use image::{GrayImage, RgbImage};
use std::borrow::Cow;
use std::time::Instant;

/// A request's masks as the estimator takes them (`Estimator::queries`).
pub(super) struct Queries<'d> {
    /// The detections, followed by the depth proposals of boxes where asked for.
    pub(super) detections: Cow<'d, [Detection]>,
    /// The masks estimated (`Estimator::candidate_masks`), indices into `detections`.
    pub(super) chosen: Vec<usize>,
    /// Their crops encoded, in `chosen`'s order.
    pub(super) views: Vec<QueryView>,
}

impl Estimator {
    /// Checks the inputs; every problem is an `EstimateError` naming what is wrong.
    pub(super) fn validate(&self, model: &ObjectModel, image: &RgbImage, k: &Intrinsics, detections: &[Detection]) -> Result<(), EstimateError> {
        let ours = self.backbone.identity();
        if ours != model.backbone {
            return Err(EstimateError::BackboneMismatch {
                object: model.object_id.clone(),
                model: format!("{} ({})", model.backbone.name, model.backbone.weights_hash),
                ours: format!("{} ({})", ours.name, ours.weights_hash),
            });
        }
        Intrinsics::new(k.fx, k.fy, k.cx, k.cy, k.width, k.height).map_err(|e| EstimateError::BadInput(e.to_string()))?;
        if (k.width, k.height) != image.dimensions() {
            return Err(EstimateError::BadInput(format!("camera resolution {}×{} differs from the image's {}×{}", k.width, k.height, image.width(), image.height())));
        }
        if detections.is_empty() {
            return Err(EstimateError::BadInput("no detection (mask) given".into()));
        }
        for (i, d) in detections.iter().enumerate() {
            if d.mask.dimensions() != image.dimensions() {
                return Err(EstimateError::BadInput(format!("mask {i} is {}×{}, the image {}×{}", d.mask.width(), d.mask.height(), image.width(), image.height())));
            }
            if !d.score.is_finite() {
                return Err(EstimateError::BadInput(format!("mask {i} has a non-finite score")));
            }
            if crate::features::mask_bbox(&d.mask).is_none() {
                return Err(EstimateError::BadInput(format!("mask {i} is empty (no object pixel)")));
            }
        }
        Ok(())
    }

    /// Indices of the masks to try: score ≥ threshold, best first, at most `max_masks`
    /// (the proposals of one box count once, and all of them are tried); the best one
    /// when none passes.
    pub(super) fn candidate_masks(detections: &[Detection], cfg: &EstimateConfig) -> Vec<usize> {
        let mut order: Vec<usize> = (0..detections.len()).collect();
        order.sort_by(|&a, &b| detections[b].score.total_cmp(&detections[a].score));
        let mut kept: Vec<usize> = Vec::new();
        let mut sources = 0;
        for i in order {
            let d = &detections[i];
            if d.from_box.is_some() && kept.iter().any(|&j| detections[j].from_box == d.from_box) {
                kept.push(i);
            } else if sources < cfg.max_masks.max(1) && (d.score >= cfg.min_mask_score || sources == 0) {
                kept.push(i);
                sources += 1;
            }
        }
        kept
    }

    /// The masks a request's detections give (`candidate_masks`; with depth proposals where
    /// the configuration asks for them), each cropped and encoded by the backbone: the
    /// detections as estimated (extended), the chosen masks' indices and their queries.
    pub(super) fn queries<'d>(&self, req: &per_mask::MaskInputs<'_>, detections: &'d [Detection], timings: &mut StageTimings) -> Result<Queries<'d>, EstimateError> {
        let per_mask::MaskInputs { model, image, depth, k, cfg, .. } = *req;
        self.validate(model, image, k, detections)?;
        // With depth, each box may gain a proposal from the depth beside its colour cuts.
        let detections: Cow<'d, [Detection]> = match depth.filter(|_| cfg.depth_proposals) {
            Some(d) => Cow::Owned(crate::estimate::candidates::with_depth_proposals(detections, d, k)),
            None => Cow::Borrowed(detections),
        };
        let chosen = Self::candidate_masks(&detections, cfg);
        let masks: Vec<&GrayImage> = chosen.iter().map(|&i| &detections[i].mask).collect();
        let queries = self.encode_masks(model, image, &masks, timings)?;
        Ok(Queries { detections, chosen, views: queries })
    }

    /// Each of `masks` (non-empty) cropped from `image` and encoded by the backbone, the
    /// time added to `timings`' crop and features.
    pub(super) fn encode_masks(&self, model: &ObjectModel, image: &RgbImage, masks: &[&GrayImage], timings: &mut StageTimings) -> Result<Vec<QueryView>, EstimateError> {
        let size = model.grid.n * model.grid.patch;
        // Spans mark the stages the timings measure (exported traces, log context); the
        // loops inside the stages have none.
        let t = Instant::now();
        let span = tracing::info_span!("crop", masks = masks.len()).entered();
        let crops: Vec<_> = crop_all(image, masks, model.config.crop_padding, size).into_iter().map(|c| c.expect("validated non-empty")).collect();
        drop(span);
        timings.crop += ms_since(t);
        let t = Instant::now();
        let queries = tracing::info_span!("features").in_scope(|| encode(self.backbone.as_ref(), crops, model.config.min_coverage))?;
        timings.features += ms_since(t);
        Ok(queries)
    }
}
