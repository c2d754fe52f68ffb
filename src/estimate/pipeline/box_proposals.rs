//! The hypotheses of a request's candidates, a box's mask proposals estimated only as far
//! as they are needed.
//!
//! A box's proposals come in their sources' order (`masks::propose_first`). Where the
//! first one's pose fits it (`EstimateConfig::sure_proposal_iou`), the box's other
//! proposals are answered unestimated and the sources not yet cut (`Detection::later`) are
//! never cut; otherwise those are cut, encoded and estimated after the caller's masks, each
//! answered as its box's (`candidates::box_owner`). A box proposal's poses are held to
//! cover the box where the object's prior holds (`box_prior::covering_box`).

use super::per_mask::MaskInputs;
use super::{EstimateError, EstimateResult, Estimator, Hypothesis, QueryView, RefineContext, StageTimings};
use crate::estimate::box_prior::BoxPrior;
use crate::estimate::candidates::Detection;
use crate::geometry::Pose;
use crate::masks::PixelBox;
use image::{GrayImage, RgbImage};
use std::borrow::Cow;

/// The candidates a request estimates, and what was estimated of them.
pub(super) struct Estimated<'d> {
    /// The caller's detections (with any depth proposals), then the later proposals cut.
    pub(super) detections: Cow<'d, [Detection]>,
    /// The masks estimated, indices into `detections`, in `views`' and `hypotheses`' order.
    pub(super) chosen: Vec<usize>,
    pub(super) views: Vec<QueryView>,
    pub(super) hypotheses: Vec<Hypothesis>,
}

impl Estimator {
    /// One hypothesis per chosen candidate (`views` encodes `chosen`, indices into
    /// `detections`), with the later proposals of the boxes whose first pose did not fit
    /// them appended to all four.
    pub(super) fn hypotheses_by_box<'d>(
        &self,
        req: &MaskInputs<'_>,
        detections: Cow<'d, [Detection]>,
        mut chosen: Vec<usize>,
        mut views: Vec<QueryView>,
        timings: &mut StageTimings,
    ) -> Result<Estimated<'d>, EstimateError> {
        let MaskInputs { model, k, others, cfg, .. } = *req;
        let mut hypotheses = Vec::with_capacity(chosen.len());
        let (mut seen, mut sure, mut unsure): (Vec<PixelBox>, Vec<PixelBox>, Vec<usize>) = (Vec::new(), Vec::new(), Vec::new());
        for (q, &mi) in views.iter().zip(&chosen) {
            let _mask_span = tracing::info_span!("mask", index = mi).entered();
            let d = &detections[mi];
            if d.from_box.is_some_and(|b| sure.contains(&b)) {
                let why = format!("not estimated: the first proposal of its box fits its pose (IoU ≥ {})", cfg.sure_proposal_iou);
                hypotheses.push(Hypothesis { failure: Some(why), ..Hypothesis::unscored(mi, d.score) });
                continue;
            }
            let mut h = self.hypothesis_for_mask(req, q, (mi, d), timings)?;
            if let Some(b) = d.from_box.filter(|b| !seen.contains(b)) {
                seen.push(b);
                if cfg.sure_proposal_iou > 0.0 && self.kept_iou(model, k, &mut h, d, others, cfg)?.is_some_and(|iou| iou >= cfg.sure_proposal_iou) {
                    sure.push(b);
                } else if d.later.is_some() {
                    unsure.push(mi);
                }
            }
            hypotheses.push(h);
        }
        let later = later_proposals(req.image, &detections, &unsure);
        let mut detections = detections;
        if !later.is_empty() {
            let masks: Vec<&GrayImage> = later.iter().map(|d| &d.mask).collect();
            let encoded = self.encode_masks(model, req.image, &masks, timings)?;
            for (j, (q, d)) in encoded.iter().zip(&later).enumerate() {
                let mi = detections.len() + j;
                let _mask_span = tracing::info_span!("mask", index = mi).entered();
                hypotheses.push(self.hypothesis_for_mask(req, q, (mi, d), timings)?);
                chosen.push(mi);
            }
            views.extend(encoded);
            detections.to_mut().extend(later);
        }
        Ok(Estimated { detections, chosen, views, hypotheses })
    }
}

/// The masks of the proposal sources still to try (`Detection::later`) for the boxes whose
/// first proposals are `unsure` (indices into `detections`), each a candidate of its box;
/// one within the sources' `same_iou` of a mask the box already has is dropped.
fn later_proposals(image: &RgbImage, detections: &[Detection], unsure: &[usize]) -> Vec<Detection> {
    let mut out = Vec::new();
    for &mi in unsure {
        let d = &detections[mi];
        let (Some(b), Some(rest)) = (d.from_box, d.later.as_ref()) else { continue };
        let earlier: Vec<&GrayImage> = detections.iter().filter(|e| e.from_box == Some(b)).map(|e| &e.mask).collect();
        out.extend(crate::masks::more_proposals(image, &b, rest, &earlier).into_iter().map(|p| Detection { mask: p.mask, score: d.score, from_box: Some(b), later: None }));
    }
    out
}

/// A box proposal's pose brought back to cover the caller's box where the proposal pulled
/// it too far and the prior holds for the object (`box_prior`); true where it moved.
pub(super) fn held_to_box(ctx: &RefineContext<'_>, prior: BoxPrior, pose: &mut Pose) -> bool {
    match ctx.from_box.filter(|_| prior.holds(&ctx.model.mesh)).and_then(|b| crate::estimate::box_prior::covering_box(&ctx.model.mesh, pose, &b, ctx.intrinsics)) {
        Some(p) => {
            *pose = p;
            true
        }
        None => false,
    }
}

/// The selected pose, where it came from a box cut by the image's border and the prior
/// holds, brought nearer until its outline reaches the box's free edge
/// (`box_prior::to_free_edge`); the winning hypothesis takes the same pose and says so
/// (`RefineReport::moved_to_free_edge`). Only the winner: held so during refinement, every
/// hypothesis came nearer, and selection then chose half-turns (docs/estimation.md, "Boxes
/// cut by the image's border"). Not with depth, which measures the distance.
pub(super) fn winner_to_free_edge(req: &MaskInputs<'_>, detections: &[Detection], result: &mut EstimateResult) {
    let MaskInputs { model, k, depth, cfg, .. } = *req;
    if depth.is_some() {
        return;
    }
    let Some(m) = result.mask_index else { return };
    let Some(b) = detections[m].from_box.filter(|_| cfg.box_prior.holds(&model.mesh)) else { return };
    let Some(nearer) = result.pose.as_ref().and_then(|pose| crate::estimate::box_prior::to_free_edge(&model.mesh, pose, &b, k)) else { return };
    result.pose = Some(nearer);
    if let Some(h) = result.hypotheses.iter_mut().find(|h| h.mask_index == m) {
        h.pose = Some(nearer);
        h.refinement.get_or_insert_with(Default::default).moved_to_free_edge = true;
    }
}
