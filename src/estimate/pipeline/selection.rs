//! Step 10, selection: every hypothesis's kept pose rendered in its mask's window, gated by
//! its IoU with the mask and scored, z-normalised across the request's hypotheses, by its
//! rendered appearance, its silhouette (a box proposal's: its agreement with the box) and
//! its detector score.

use super::{EstimateConfig, EstimateError, EstimateResult, Estimator, Hypothesis, StageTimings};
use crate::estimate::candidates::Detection;
use crate::estimate::query::QueryView;
use crate::estimate::select::{box_agreement, combined_scores, mask_window, render_window, window_iou};
use crate::features::crop_query;
use crate::geometry::Intrinsics;
use crate::onboard::ObjectModel;
use image::GrayImage;

impl Estimator {
    /// The IoU of `h`'s kept pose, rendered in its mask's window, with the mask (the
    /// pixels under `others` left out where verification leaves them out), kept as `h.iou`
    /// with the render in `h.render` (verification's own where it made one); None without
    /// a pose.
    pub(super) fn kept_iou(&self, model: &ObjectModel, k: &Intrinsics, h: &mut Hypothesis, d: &Detection, others: Option<&GrayImage>, cfg: &EstimateConfig) -> Result<Option<f32>, EstimateError> {
        let Some(pose) = h.pose else { return Ok(None) };
        let window = mask_window(&d.mask).expect("validated non-empty");
        let render = match h.render.take() {
            Some(r) => r,
            None => render_window(&self.renderer, &model.mesh, &pose, k, window)?,
        };
        h.iou = window_iou(&render, &d.mask, others.filter(|_| cfg.verify.occlusion_aware_iou), window);
        h.render = Some(render);
        Ok(Some(h.iou))
    }

    /// Step 10: IoU gate and z-normalised scoring across hypotheses; `others` as for
    /// `estimate_among`.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn select(
        &self,
        model: &ObjectModel,
        queries: &[QueryView],
        chosen: &[usize],
        k: &Intrinsics,
        (detections, others): (&[Detection], Option<&GrayImage>),
        mut hyps: Vec<Hypothesis>,
        cfg: &EstimateConfig,
    ) -> Result<EstimateResult, EstimateError> {
        let size = model.grid.n * model.grid.patch;
        let mut crops = Vec::new();
        let mut owners = Vec::new();
        for (i, h) in hyps.iter_mut().enumerate() {
            if self.kept_iou(model, k, h, &detections[chosen[i]], others, cfg)?.is_none() {
                continue;
            }
            let render = h.render.take().expect("kept_iou rendered it");
            let window = mask_window(&detections[chosen[i]].mask).expect("validated non-empty");
            h.box_agreement = detections[chosen[i]].from_box.map(|b| box_agreement(&render, window, &b, others));
            if h.iou < cfg.selection.iou_gate {
                h.failure = Some(format!("rendered mask IoU {:.2} < gate {:.2}", h.iou, cfg.selection.iou_gate));
                continue;
            }
            if let Some((crop, _)) = crop_query(&render.rgb, &render.mask, model.config.crop_padding, size) {
                crops.push(crop);
                owners.push(i);
            }
        }
        let maps = self.backbone.extract(&crops)?;
        for (fm, &i) in maps.iter().zip(&owners) {
            hyps[i].cosine = fm.global.iter().zip(&queries[i].features.global).map(|(a, b)| a * b).sum();
        }
        let cos: Vec<f32> = owners.iter().map(|&i| hyps[i].cosine).collect();
        // A pose from a box's proposal is judged by how well it fills the box, not by its
        // own mask: every proposal's pose was fitted to that proposal, so agreeing with it
        // says nothing about which proposal was right.
        let iou: Vec<f32> = owners.iter().map(|&i| hyps[i].box_agreement.unwrap_or(hyps[i].iou)).collect();
        let det: Vec<f32> = owners.iter().map(|&i| hyps[i].detector_score).collect();
        let scores = combined_scores(&cos, &iou, &det, &cfg.selection.weights);
        for (&i, s) in owners.iter().zip(&scores) {
            hyps[i].score = *s;
        }
        let best = owners.iter().zip(&scores).max_by(|a, b| a.1.total_cmp(b.1)).map(|(&i, _)| i);
        let reason = match best {
            Some(_) => None,
            None => Some(hyps.iter().filter_map(|h| h.failure.clone()).collect::<Vec<_>>().join("; ")).filter(|s| !s.is_empty()).or(Some("no hypothesis".into())),
        };
        Ok(EstimateResult {
            pose: best.and_then(|i| hyps[i].pose),
            // Reported score: the winner's IoU-weighted confidence in [0, 1], not the
            // z-score (which only ranks within one image).
            score: best.map(|i| confidence(&hyps[i], &cfg.selection.weights)).unwrap_or(0.0),
            mask_index: best.map(|i| hyps[i].mask_index),
            hypotheses: hyps,
            timings: StageTimings::default(),
            reason,
            runner_up: None,
        })
    }
}

/// The silhouette term of a box proposal's hypothesis: the geometric mean of its IoU with
/// the proposal and its box agreement (`select::box_agreement`), so that it must satisfy
/// both. On the real frames: AR 0.231 → 0.280 from boxes; the arithmetic mean gave the
/// same, the box agreement alone 0.262 (docs/estimation.md, "Several proposals per box").
pub(super) fn box_blend(iou: f64, agreement: f32) -> f64 {
    (iou.max(0.0) * agreement as f64).sqrt()
}

/// A [0, 1] confidence from the raw selection inputs with the selection weights.
fn confidence(h: &Hypothesis, w: &[f32; 3]) -> f32 {
    let c = h.cosine.clamp(0.0, 1.0);
    let total = w.iter().sum::<f32>().max(1e-6);
    ((w[0] * c + w[1] * h.iou + w[2] * h.detector_score.clamp(0.0, 1.0)) / total).clamp(0.0, 1.0)
}
