//! A cheap look at a candidate mask before the costly stages, for callers that hold many
//! candidates per image of which most are not the object (the depth detector offers each
//! surface of an object's size to every object of that size). The best retrieved
//! templates are placed at the mask, fitted to the measured depth, and scored by a
//! `CoarseCheck` (the depth detector's callers give `DepthScreen`, the confirmation an
//! answer gets); a mask none of them passes is not matched, solved or refined.
//! Matching, PnP, RRC and refinement are about 0.9 of a mask's time (docs/benchmarks.md,
//! the profile), the screen a few renders.

use super::per_mask::MaskInputs;
use super::{EstimateConfig, EstimateError, Estimator, Hypothesis, Queries, QueryView, StageTimings};
use crate::depth::DepthImage;
use crate::detect::confirm::{confirm, confirmation_needed};
use crate::estimate::candidates::Detection;
use crate::estimate::hypotheses::place_template;
use crate::geometry::{Intrinsics, Pose};
use crate::mesh::Mesh;
use crate::onboard::ObjectModel;
use crate::render::{RenderError, RenderPool};
use image::{GrayImage, RgbImage};

/// What the caller holds a candidate to: a score of the object at a pose for a mask
/// (0–1, higher is likelier the object there) and the least score worth estimating.
pub trait CoarseCheck: Sync {
    /// The object at `pose` for candidate `mask` (image-sized).
    fn score(&self, mask: &GrayImage, pose: &Pose) -> Result<f32, RenderError>;
    /// Masks whose best placed template scores less are dropped.
    fn needed(&self) -> f32;
}

/// How a candidate's masks are screened before they are estimated.
#[derive(Clone, Copy)]
pub enum Screen<'a> {
    /// Not screened: every mask is estimated.
    Off,
    /// Each mask checked as it comes (`Estimator::best_placed`, stopping at the first
    /// placed template that passes).
    Check(&'a dyn CoarseCheck),
    /// Scored by the caller beforehand (`Estimator::screen_scores`, in the masks' order):
    /// a mask scored below `needed` is not estimated.
    Scored { scores: &'a [f32], needed: f32 },
}

impl Screen<'_> {
    /// Whether the masks are screened (and so estimated with the candidates' effort).
    pub fn is_on(&self) -> bool {
        !matches!(self, Screen::Off)
    }

    /// The best of the masks' scores where they were scored beforehand (`Scored`), else
    /// `None`: what the screen thought of the candidate, for the logs.
    pub fn best_score(&self) -> Option<f32> {
        match self {
            Screen::Scored { scores, .. } => Some(crate::detect::rivals::best_score(scores)),
            _ => None,
        }
    }
}

/// Retrieved templates placed and scored, best retrieval first. On the real YCB-V frames
/// with 8 objects searched (docs/detection.md, "Screening"), the best of the first three
/// kept every right candidate; the first alone lost two of twenty.
const SCREENED_TEMPLATES: usize = 3;

impl Estimator {
    /// The best score under `check` of the first retrieved templates (`ranked`), each placed
    /// at the mask and fitted to the depth; with `enough`, the look ends at the first that
    /// reaches it.
    pub(super) fn best_placed(&self, req: &MaskInputs<'_>, q: &QueryView, detection: &Detection, ranked: &[usize], check: &dyn CoarseCheck, enough: Option<f32>) -> Result<f32, EstimateError> {
        let ctx = req.context(detection);
        let mut best = 0.0f32;
        for &t in ranked.iter().take(SCREENED_TEMPLATES) {
            let Some(mut pose) = place_template(req.model, t, &q.crop_box, req.k) else { continue };
            let mut report = crate::estimate::RefineReport::default();
            self.fit_to_depth(&ctx, &mut pose, &mut report)?;
            best = best.max(check.score(&detection.mask, &pose)?);
            if enough.is_some_and(|enough| best >= enough) {
                break;
            }
        }
        Ok(best)
    }

    /// Each candidate mask's screen score under `check` (`Estimator::best_placed`: the
    /// best of the first retrieved templates placed at the mask and fitted to the depth), in
    /// the order of `detections` (followed by the depth proposals of boxes where `cfg` asks
    /// for them, as the estimate makes them), 0 for a mask the estimate would not take (`candidate_masks`),
    /// without depth every mask 1 (not screened). For callers that compare one place's
    /// candidates of several objects before estimating any (`detect::rivals`); they then
    /// estimate with `Screen::Scored`.
    pub fn screen_scores(
        &self,
        model: &ObjectModel,
        (image, depth): (&RgbImage, Option<&DepthImage>),
        k: &Intrinsics,
        detections: &[Detection],
        check: &dyn CoarseCheck,
        cfg: &EstimateConfig,
    ) -> Result<Vec<f32>, EstimateError> {
        let req = MaskInputs { model, image, depth, k, others: None, hints: &[], screen: Screen::Check(check), cfg };
        if depth.is_none() {
            self.validate(model, image, k, detections)?;
            return Ok(vec![1.0; detections.len()]);
        }
        let mut timings = StageTimings::default();
        let Queries { detections: extended, chosen, views } = self.queries(&req, detections, &mut timings)?;
        let mut scores = vec![0.0; extended.len()];
        for (q, &mi) in views.iter().zip(&chosen) {
            let mut h = Hypothesis::default();
            let retrieved = self.retrieve_for_mask(model, q, cfg, &mut h, &mut timings);
            scores[mi] = self.best_placed(&req, q, &extended[mi], &retrieved, check, None)?;
        }
        Ok(scores)
    }

    /// Whether mask `mi` passes the request's screen (always without one, or without depth
    /// to fit to): the best of the first retrieved templates (`ranked`), each placed at the
    /// mask and fitted to the depth, must score what the screen needs. A mask that does not
    /// pass gets its hypothesis's `failure`.
    pub(super) fn passes_screen(&self, req: &MaskInputs<'_>, q: &QueryView, (mi, detection): (usize, &Detection), ranked: &[usize], h: &mut Hypothesis) -> Result<bool, EstimateError> {
        if req.depth.is_none() {
            return Ok(true);
        }
        let (best, needed) = match req.screen {
            Screen::Off => return Ok(true),
            Screen::Check(check) => (self.best_placed(req, q, detection, ranked, check, Some(check.needed()))?, check.needed()),
            // A mask the caller did not score (none should be) is estimated.
            Screen::Scored { scores, needed } => (scores.get(mi).copied().unwrap_or(needed), needed),
        };
        if best >= needed {
            return Ok(true);
        }
        tracing::debug!(best, needed, "screened out");
        h.failure = Some(format!("screened out: the best placed template scores {best:.2}, {needed:.2} needed"));
        Ok(false)
    }
}

/// The depth detector's candidates of one object, screened before they are estimated
/// (`Estimator::estimate_screened`): the best retrieved templates placed at a candidate's
/// mask and fitted to the depth are confirmed as an estimate would be
/// (`detect::confirm::confirm`), and a mask whose best confirms below `SCREEN_SHARE` of
/// what an answer needs is not estimated.
pub struct DepthScreen<'a> {
    pub image: &'a RgbImage,
    pub depth: &'a DepthImage,
    pub k: &'a Intrinsics,
    pub mesh: &'a Mesh,
    pub renderer: &'a RenderPool,
    /// The caller's `min_score`.
    pub min_score: f32,
}

/// Share of the confirmation an answer needs (`detect::confirm::confirmation_needed` with
/// depth) that a candidate's placed templates must reach to be estimated. Measured (docs/detection.md,
/// "Screening"): on the real YCB-V frames the candidates later answered right reached 0.167
/// or more (of the 0.5 needed), but on generated scenes of bare HOPE meshes over real
/// frames right ones reached only 0.08–0.11 (a bare box's outline at a template's coarse
/// pose is weak evidence): needing 0.11 lost two of their answers there, 0.08 and 0.05
/// none. 0.06 keeps a margin below that.
const SCREEN_SHARE: f32 = 0.12;

impl<'a> DepthScreen<'a> {
    /// The screen of `mesh`'s candidates in a frame with `depth`; `None` without depth.
    pub fn of(image: &'a RgbImage, depth: Option<&'a DepthImage>, k: &'a Intrinsics, mesh: &'a Mesh, renderer: &'a RenderPool, min_score: f32) -> Option<Self> {
        depth.map(|depth| Self { image, depth, k, mesh, renderer, min_score })
    }

    /// As the estimator takes it: each mask checked as it comes (`Screen::Off` without one).
    pub fn as_screen(screen: &Option<Self>) -> Screen<'_> {
        screen.as_ref().map_or(Screen::Off, |s| Screen::Check(s))
    }

    /// As the estimator takes it when the masks were scored beforehand
    /// (`Estimator::screen_scores`; `Screen::Off` without a screen or scores).
    pub fn scored<'s>(screen: &Option<Self>, scores: Option<&'s [f32]>) -> Screen<'s> {
        match (screen, scores) {
            (Some(check), Some(scores)) => Screen::Scored { scores, needed: check.needed() },
            _ => Screen::Off,
        }
    }
}

impl CoarseCheck for DepthScreen<'_> {
    fn score(&self, mask: &GrayImage, pose: &Pose) -> Result<f32, RenderError> {
        confirm(self.image, Some(self.depth), self.k, self.mesh, mask, pose, self.renderer)
    }

    fn needed(&self) -> f32 {
        SCREEN_SHARE * confirmation_needed(self.min_score, true)
    }
}
