//! The online stage end to end (DESIGN.md steps 4–10) for one object in one image.

use super::box_prior::BoxPrior;
use super::candidates::Detection;
use super::contour::{ContourRefiner, PrintRefineConfig};
use super::correspond::{correspond, Correspondences};
use super::hypotheses::Source;
use super::pnp::{solve_pnp_ransac, PnpConfig, PnpResult};
use super::query::QueryView;
use super::refine::{PassThrough, RefineContext, RefineReport, Refiner, RefinerKind};
use super::retrieve::{retrieve, RetrievalConfig};
use super::rrc::rrc_pool;
use super::select::{box_agreement, combined_scores, mask_window, render_window, window_iou, SelectionConfig};
use super::silhouette_refiner::SilhouetteDepthRefiner;
use super::verify::{render_evidence, score as verification_score, Verified, VerifyConfig};
use super::EstimateError;
use crate::depth::DepthImage;
use crate::features::{crop_query, Backbone};
use crate::geometry::{Intrinsics, Pose};
use crate::onboard::ObjectModel;
use crate::render::RenderPool;
use crate::telemetry::ms_since;
use image::{GrayImage, RgbImage};
use rayon::prelude::*;
use std::borrow::Cow;
use std::sync::Arc;
use std::time::Instant;

mod box_proposals;
mod coarse_cut;
mod depth_judge;
mod depth_review;
mod nudge;
mod per_mask;
mod queries;
mod screen;
mod second_look;
pub use depth_review::Reviewed;

use box_proposals::held_to_box;
use queries::Queries;

pub use super::candidate_effort::CandidateEffort;
pub use screen::{CoarseCheck, DepthScreen, Screen};

#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EstimateConfig {
    pub retrieval: RetrievalConfig,
    /// Nearest pool patches per query patch before the mutual filter.
    pub k_nn: usize,
    pub pnp: PnpConfig,
    /// Render-guided re-correspondence on or off.
    pub rrc: bool,
    /// RRC renders each variant at this many pixels per image pixel of the object in the
    /// photo (at most the backbone's crop; 0: at the crop's size, as the paper). 2 by
    /// measurement: the same MSSD as the crop's size over seven generated sets (one
    /// instance more in all) for 10–15 % less time per estimate
    /// (docs/benchmarks/estimation-outlines.md, "Each face drawn once, closed meshes
    /// one-sided").
    #[serde(default = "default_rrc_render_scale")]
    pub rrc_render_scale: f64,
    /// RRC's renders no wider than this many pixels, unless the object's window in the
    /// photo is wider still (then one render pixel per image pixel). 256 by measurement:
    /// against no cap (512, the backbone's crop) the same MSSD over seven generated sets
    /// (one instance gained, one lost) for 1–9 % less time per estimate (3–37 ms), most on
    /// larger objects (docs/benchmarks/estimation-occlusion-and-speed.md, "RRC's renders
    /// capped at 256 pixels").
    #[serde(default = "default_rrc_render_cap")]
    pub rrc_render_cap: u32,
    /// RRC is skipped where the first PnP's inliers are at least this share of the query's
    /// foreground patches: its correspondences are sure already, and RRC's renders would
    /// find the same pose (0: RRC always runs, as the paper). 0.15 by measurement: on 150
    /// generated HOPE instances every one RRC put right had a share of 0.11 or less, and
    /// 107 of them were skipped without a verdict changed; on the real YCB-V frames (bare
    /// meshes) the shares were 0.02–0.06, so RRC ran on every one
    /// (docs/benchmarks/estimation-occlusion-and-speed.md, "RRC where the first
    /// correspondences are weak").
    #[serde(default = "default_rrc_sure_share")]
    pub rrc_sure_share: f64,
    /// A box's first mask proposal (its `cut`) is enough where its pose, rendered, overlaps
    /// it by at least this IoU: the box's other proposals are neither made
    /// (`Detection::later`) nor estimated (0: every proposal is). 0.85 by measurement: on
    /// the real YCB-V frames, over the exact boxes and five jitters of them, estimating the
    /// others only below 0.8–0.9 kept the AR of estimating all (0.365 mean) where the first
    /// alone gave 0.355, and the others were estimated for 45 of 210 instances
    /// (docs/estimation.md, "The first proposal where its pose fits it").
    #[serde(default = "default_sure_proposal_iou")]
    pub sure_proposal_iou: f32,
    /// Candidate masks per object, and the detector score they need (the best one is kept
    /// regardless).
    pub max_masks: usize,
    pub min_mask_score: f32,
    pub selection: SelectionConfig,
    /// The refinement after PnP/RRC.
    #[serde(default)]
    pub refiner: RefinerKind,
    /// Hypothesis verification (flips and retrieved templates, refined and verified).
    #[serde(default)]
    pub verify: VerifyConfig,
    /// The kept pose refined again on its print as well as its outline (contour refiner,
    /// objects with colours): `contour::print_refine`.
    #[serde(default)]
    pub print: PrintRefineConfig,
    /// Whether a box proposal's refined poses are moved back until their outline covers
    /// the box (`box_prior`): for tight boxes; by default for meshes without colours.
    /// Configs written before it said true (tight) or false (off).
    #[serde(default, deserialize_with = "super::box_prior::deserialize")]
    pub box_prior: BoxPrior,
    /// With depth, each box gains a mask proposal from the depth (`masks::depth_proposal`)
    /// beside its colour cuts. Off by default: on the real YCB-V frames it changed the AR
    /// from boxes with depth from 0.536 to 0.531 for a quarter more time
    /// (docs/estimation.md, "Depth (RGB-D)").
    #[serde(default)]
    pub depth_proposals: bool,
    /// How the depth detector's candidates, screened against the depth, are estimated:
    /// light (fewer verification hypotheses refined) by default (`candidate_effort`).
    #[serde(default)]
    pub candidate_effort: CandidateEffort,
}

impl Default for EstimateConfig {
    fn default() -> Self {
        Self {
            retrieval: RetrievalConfig::default(),
            k_nn: 3,
            pnp: PnpConfig::default(),
            rrc: true,
            rrc_render_scale: default_rrc_render_scale(),
            rrc_render_cap: default_rrc_render_cap(),
            rrc_sure_share: default_rrc_sure_share(),
            sure_proposal_iou: default_sure_proposal_iou(),
            max_masks: 2,
            min_mask_score: 0.35,
            selection: SelectionConfig::default(),
            refiner: RefinerKind::default(),
            verify: VerifyConfig::default(),
            print: PrintRefineConfig::default(),
            box_prior: BoxPrior::default(),
            depth_proposals: false,
            candidate_effort: CandidateEffort::default(),
        }
    }
}

fn default_rrc_render_scale() -> f64 {
    2.0
}

fn default_rrc_render_cap() -> u32 {
    256
}

fn default_rrc_sure_share() -> f64 {
    0.15
}

fn default_sure_proposal_iou() -> f32 {
    0.85
}

impl EstimateConfig {
    /// With `always`, RRC runs on every instance, never skipped for sure first matches
    /// (`rrc_sure_share` 0): what `--rrc-always` and the API's `rrc_always` ask for.
    pub fn with_rrc_always(self, always: bool) -> Self {
        if always {
            Self { rrc_sure_share: 0.0, ..self }
        } else {
            self
        }
    }
}

/// Milliseconds per stage, summed over the masks of one estimate.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct StageTimings {
    pub crop: f64,
    pub features: f64,
    pub retrieval: f64,
    /// The caller's screen of each mask (`pipeline::screen`); absent without one.
    #[serde(skip_serializing_if = "is_zero")]
    pub screen: f64,
    pub matching: f64,
    pub pnp: f64,
    pub rrc: f64,
    pub refine: f64,
    /// The fits to the measured depth (`pipeline::depth_judge`), a part of `refine`;
    /// absent without depth.
    #[serde(skip_serializing_if = "is_zero")]
    pub depth: f64,
    pub selection: f64,
    pub total: f64,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

impl StageTimings {
    /// Stage name → milliseconds, as serialised (`depth` only where there was depth, `screen`
    /// where there was a screen): what the
    /// service answers and its metrics observe.
    pub fn by_stage(&self) -> std::collections::BTreeMap<String, f64> {
        let stages = [
            ("crop", self.crop),
            ("features", self.features),
            ("retrieval", self.retrieval),
            ("screen", self.screen),
            ("matching", self.matching),
            ("pnp", self.pnp),
            ("rrc", self.rrc),
            ("refine", self.refine),
            ("depth", self.depth),
            ("selection", self.selection),
            ("total", self.total),
        ];
        stages.into_iter().filter(|&(name, ms)| !["depth", "screen"].contains(&name) || !is_zero(&ms)).map(|(name, ms)| (name.to_string(), ms)).collect()
    }
}

/// What happened to one candidate mask.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Hypothesis {
    /// Index into the caller's detections.
    pub mask_index: usize,
    #[serde(skip)]
    pub pose: Option<Pose>,
    pub detector_score: f32,
    pub retrieved_templates: usize,
    /// Best template's retrieval cosine and silhouette IoU.
    pub top_template_cosine: f32,
    pub top_template_silhouette_iou: f32,
    pub matches: usize,
    pub inliers: usize,
    pub rrc_matches: usize,
    pub rrc_inliers: usize,
    /// Whether the RRC pose replaced the first one.
    pub rrc_used: bool,
    /// Whether RRC was left out because the first PnP's inliers were sure enough
    /// (`EstimateConfig::rrc_sure_share`).
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub rrc_skipped: bool,
    pub reprojection_error_px: f64,
    /// What the refiner did to the kept pose (absent when there was no pose to refine).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub refinement: Option<super::refine::RefineReport>,
    /// The kept pose rendered in the mask's window, when verification rendered it.
    #[serde(skip)]
    pub render: Option<crate::render::RenderOutput>,
    /// Every verified hypothesis of this mask, best first (empty without verification).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub verified: Vec<Verified>,
    /// Selection inputs and result (NaN until scored).
    pub cosine: f32,
    pub iou: f32,
    /// Where the mask was proposed from a box: the IoU of the box around the kept pose's
    /// visible render with that box (`select::box_agreement`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub box_agreement: Option<f32>,
    pub score: f32,
    /// Why this hypothesis has no pose or was dropped.
    pub failure: Option<String>,
}

impl Hypothesis {
    /// The hypothesis of candidate `mask_index` before anything is estimated: its selection
    /// inputs NaN until scored.
    pub(crate) fn unscored(mask_index: usize, detector_score: f32) -> Self {
        Hypothesis { mask_index, detector_score, cosine: f32::NAN, iou: f32::NAN, score: f32::NAN, ..Default::default() }
    }
}

/// The result for one object: the selected pose (if any) and every hypothesis.
#[derive(Clone, Debug, Default)]
pub struct EstimateResult {
    pub pose: Option<Pose>,
    pub score: f32,
    pub mask_index: Option<usize>,
    pub hypotheses: Vec<Hypothesis>,
    pub timings: StageTimings,
    /// Why there is no pose, when there is none.
    pub reason: Option<String>,
    /// The best verified pose that is another answer, and by how much it lost (absent
    /// without verification, or when every rendered hypothesis agreed with the answer).
    pub runner_up: Option<super::runner_up::RunnerUp>,
}

/// Runs the pipeline; holds the backbone, the renderer and the refiners it can use.
pub struct Estimator {
    backbone: Arc<dyn Backbone>,
    renderer: Arc<RenderPool>,
    /// One per `RefinerKind`, in `RefinerKind::ALL` order.
    refiners: Vec<Arc<dyn Refiner>>,
    /// Scores the outline of every hypothesis in verification, whichever refiner runs (the
    /// same instance as the `Contour` slot unless `with_refiner` replaced only that).
    contour: Arc<ContourRefiner>,
}

impl Estimator {
    pub fn new(backbone: Arc<dyn Backbone>, renderer: Arc<RenderPool>) -> Self {
        let contour = Arc::new(ContourRefiner::new(renderer.clone()));
        let refiners: Vec<Arc<dyn Refiner>> = RefinerKind::ALL
            .iter()
            .map(|k| -> Arc<dyn Refiner> {
                match k {
                    RefinerKind::None => Arc::new(PassThrough),
                    RefinerKind::SilhouetteDepth => Arc::new(SilhouetteDepthRefiner::new(renderer.clone())),
                    RefinerKind::Contour => contour.clone(),
                }
            })
            .collect();
        Self { backbone, renderer, refiners, contour }
    }

    /// Replaces the refiner run for `kind` (a pluggable refinement stage).
    pub fn with_refiner(mut self, kind: RefinerKind, refiner: Arc<dyn Refiner>) -> Self {
        self.refiners[Self::slot(kind)] = refiner;
        self
    }

    /// Replaces the contour refiner everywhere it runs: the `Contour` slot, the outline
    /// agreement of every hypothesis in verification, and the refinement on the print.
    pub fn with_contour(mut self, contour: Arc<ContourRefiner>) -> Self {
        self.refiners[Self::slot(RefinerKind::Contour)] = contour.clone();
        self.contour = contour;
        self
    }

    fn slot(kind: RefinerKind) -> usize {
        RefinerKind::ALL.iter().position(|&k| k == kind).expect("every kind has a slot")
    }

    /// The refiner this estimator runs for `kind`.
    pub fn refiner(&self, kind: RefinerKind) -> &dyn Refiner {
        self.refiners[Self::slot(kind)].as_ref()
    }

    pub fn backbone(&self) -> &dyn Backbone {
        self.backbone.as_ref()
    }

    pub fn estimate(&self, model: &ObjectModel, image: &RgbImage, k: &Intrinsics, detections: &[Detection], cfg: &EstimateConfig) -> Result<EstimateResult, EstimateError> {
        self.estimate_among(model, image, k, detections, None, cfg)
    }

    /// `estimate` when other detections in the image may hide this object: `others`
    /// (image-sized, non-zero where another detection is) tells the refiner that the
    /// mask's outline says nothing there, so an occluder's edge does not pull the pose.
    pub fn estimate_among(
        &self,
        model: &ObjectModel,
        image: &RgbImage,
        k: &Intrinsics,
        detections: &[Detection],
        others: Option<&GrayImage>,
        cfg: &EstimateConfig,
    ) -> Result<EstimateResult, EstimateError> {
        self.estimate_hinted(model, (image, None), k, detections, others, &[], cfg)
    }

    /// `estimate_among` with the depth camera's image registered to `image` (checked by
    /// the caller: `DepthImage::check_for`): verification fits each rendered hypothesis to
    /// it and weighs what it says (`pipeline::depth_judge`).
    #[allow(clippy::too_many_arguments)]
    pub fn estimate_rgbd(
        &self,
        model: &ObjectModel,
        image: &RgbImage,
        depth: Option<&DepthImage>,
        k: &Intrinsics,
        detections: &[Detection],
        others: Option<&GrayImage>,
        cfg: &EstimateConfig,
    ) -> Result<EstimateResult, EstimateError> {
        self.estimate_hinted(model, (image, depth), k, detections, others, &[], cfg)
    }

    /// `estimate_among` with `hints`: poses the caller holds possible (a previous estimate,
    /// a planned placement, or in a benchmark the truth, to tell a right pose that is never
    /// generated from one that loses the vote), verified with each mask's own hypotheses as
    /// source `hint` (ignored without verification).
    #[allow(clippy::too_many_arguments)]
    pub fn estimate_hinted(
        &self,
        model: &ObjectModel,
        (image, depth): (&RgbImage, Option<&DepthImage>),
        k: &Intrinsics,
        detections: &[Detection],
        others: Option<&GrayImage>,
        hints: &[Pose],
        cfg: &EstimateConfig,
    ) -> Result<EstimateResult, EstimateError> {
        self.estimate_inputs(&per_mask::MaskInputs { model, image, depth, k, others, hints, screen: Screen::Off, cfg }, detections)
    }

    /// `estimate_rgbd` for a candidate that is likely not the object (one of many the
    /// depth detector offers): each mask must first pass `screen` where there is one
    /// (`pipeline::screen`), and one that does not costs a few renders, not an estimate;
    /// one that does is estimated with `cfg.candidate_effort` (`candidate_effort`).
    #[allow(clippy::too_many_arguments)]
    pub fn estimate_screened(
        &self,
        model: &ObjectModel,
        (image, depth): (&RgbImage, Option<&DepthImage>),
        k: &Intrinsics,
        detections: &[Detection],
        others: Option<&GrayImage>,
        screen: Screen<'_>,
        cfg: &EstimateConfig,
    ) -> Result<EstimateResult, EstimateError> {
        // Screened against the depth, a candidate is estimated with the effort it is given;
        // without depth the screen is not asked and the estimate is a mask's.
        let cfg = if screen.is_on() && depth.is_some() { CandidateEffort::applied(cfg) } else { Cow::Borrowed(cfg) };
        self.estimate_inputs(&per_mask::MaskInputs { model, image, depth, k, others, hints: &[], screen, cfg: &cfg }, detections)
    }

    fn estimate_inputs(&self, req: &per_mask::MaskInputs<'_>, detections: &[Detection]) -> Result<EstimateResult, EstimateError> {
        let per_mask::MaskInputs { model, k, others, cfg, .. } = *req;
        let t_total = Instant::now();
        let given = detections.len();
        let mut timings = StageTimings::default();
        let Queries { detections: all, chosen, views } = self.queries(req, detections, &mut timings)?;
        let box_proposals::Estimated { detections, chosen, views: queries, hypotheses: hyps } = self.hypotheses_by_box(req, all, chosen, views, &mut timings)?;
        let detections: &[Detection] = &detections;

        let t = Instant::now();
        let mut result = tracing::info_span!("selection").in_scope(|| self.select(model, &queries, &chosen, k, (detections, others), hyps, cfg))?;
        if req.depth.is_none() {
            box_proposals::winner_to_free_edge(model, k, detections, &mut result, cfg.box_prior);
        }
        let winner = result.mask_index.and_then(|m| result.hypotheses.iter().find(|h| h.mask_index == m));
        result.runner_up = result.pose.as_ref().zip(winner).and_then(|(pose, h)| super::runner_up::runner_up(pose, &h.verified, model));
        timings.selection = ms_since(t);
        timings.total = ms_since(t_total);
        // Answered as the caller's detections: a depth proposal as its box's first.
        result.mask_index = result.mask_index.map(|i| super::candidates::box_owner(detections, given, i));
        for h in &mut result.hypotheses {
            h.mask_index = super::candidates::box_owner(detections, given, h.mask_index);
        }
        Ok(EstimateResult { timings, ..result })
    }

    /// The hypothesis's pose refined again on its print (`ContourRefiner::refine_on_print`),
    /// where that finds more of the print where it puts it; kept as it is otherwise.
    fn refine_on_print(&self, ctx: &RefineContext<'_>, h: &mut Hypothesis, cfg: &EstimateConfig) {
        let Some(pose) = h.pose else { return };
        let window = mask_window(ctx.mask).expect("validated non-empty");
        match self.contour.refine_on_print(ctx, &pose, window, h.render.as_ref(), &cfg.print) {
            Ok(Some(r)) => {
                let mut pose = r.pose;
                // Moved off its render, the pose is rendered again by selection.
                let held = held_to_box(ctx, cfg.box_prior, &mut pose);
                h.pose = Some(pose);
                h.refinement = Some(RefineReport { moved_to_box: held, ..r.report });
                h.render = (!held).then_some(r.render);
            }
            Ok(None) => {}
            // Only a render can fail here; the pose stays as verification left it.
            Err(e) => tracing::warn!("refining on the print failed: {e}"),
        }
    }

    /// Refines the pose, its axis flips and spins, the best templates placed at the mask
    /// and those placed by their matches (`matched`), and verifies them: contour agreement
    /// for all, then a render (IoU, appearance) for the best by contour and those the
    /// outline cannot tell from it (`verify::to_render`), then, where nothing the winner
    /// shows agrees with the photo's print, a second look (`second_look`). Best first.
    /// Also returns the milliseconds the depth fits took (0 without depth).
    fn verify(
        &self,
        ctx: &RefineContext<'_>,
        (start, pose): (Source, Pose),
        retrieved: &[usize],
        (matched, hints): (&[Pose], &[Pose]),
        query: &QueryView,
        cfg: &EstimateConfig,
    ) -> Result<(Vec<Verified>, f64), EstimateError> {
        // A box's proposals are placed at the box, which the caller drew, not at the
        // proposal's own extent, which may have taken in clutter.
        let place = ctx.from_box.map(|b| (b.x0, b.y0, b.x1 - 1, b.y1 - 1)).or_else(|| crate::features::mask_bbox(ctx.mask));
        let replaced = place.filter(|_| cfg.verify.replace_off_mask).and_then(|b| super::hypotheses::replaced_at_mask(&ctx.model.mesh, &pose, b, ctx.intrinsics));
        let mut candidates = super::hypotheses::candidates(ctx.model, (start, &pose), replaced.as_ref(), retrieved, &cfg.verify, &query.crop_box, ctx.intrinsics);
        candidates.extend(matched.iter().enumerate().map(|(i, &p)| (Source::Matched(i), p)).filter(|&(s, _)| s != start));
        candidates.extend(hints.iter().enumerate().map(|(i, &p)| (Source::Hint(i), p)));
        if let Some(depth) = ctx.depth.filter(|_| cfg.verify.depth_views > 0) {
            let t = Instant::now();
            let found = super::depth_search::searched(ctx.model, depth, ctx.intrinsics, ctx.mask, cfg.verify.depth_views);
            tracing::debug!(ms = ms_since(t), found = found.len(), "depth views searched");
            candidates.extend(found.into_iter().enumerate().map(|(i, s)| (Source::DepthView(i), s.pose)));
        }
        // Hypotheses that are the same pose up to the object's symmetry show the same image:
        // when asked, one of each is refined (the start comes first, so it stays).
        let symmetric = ctx.model.symmetries.as_ref().filter(|_| cfg.verify.skip_symmetric).and_then(|s| crate::geometry::symmetric_poses::SymmetricPoses::new(&s.symmetries, ctx.model.diameter()));
        if let Some(s) = &symmetric {
            candidates = s.distinct(candidates, |(_, p)| p);
        }
        if cfg.verify.refined > 0 && candidates.len() > cfg.verify.refined {
            candidates = self.most_agreeing(ctx, candidates, cfg.verify.refined);
        }
        let always = |s: Source| s == start || matches!(s, Source::DepthView(_));
        // The caller's hints are refined in full too, so that they are judged as given.
        let mut verified = self.refine_with_cut(ctx, &candidates, |s| always(s) || matches!(s, Source::Hint(_)), cfg);
        verified.sort_by(|a, b| b.contour.total_cmp(&a.contour));
        let window = mask_window(ctx.mask).expect("validated non-empty");
        // The start (the pipeline's own pose) is always rendered: it must be beaten on the evidence.
        let always: Vec<usize> = verified.iter().enumerate().filter(|(_, v)| always(v.source)).map(|(i, _)| i).collect();
        let rendered = super::verify::to_render(&verified, &always, &cfg.verify);
        self.judge(ctx, &mut verified, &rendered, window, query, cfg)?;
        verified.sort_by(|a, b| b.score.total_cmp(&a.score));
        if cfg.verify.second_look {
            self.second_look(ctx, &mut verified, start, window, query, cfg)?;
        }
        if cfg.verify.nudge_degrees > 0.0 {
            self.nudge(ctx, &mut verified, window, query, cfg)?;
        }
        let t = Instant::now();
        Self::judge_on_depth(ctx, &mut verified, window)?;
        let depth_ms = if ctx.depth.is_some() { ms_since(t) } else { 0.0 };
        // Only the winner's render is reused (by selection); the others are dropped now.
        for v in verified.iter_mut().skip(1) {
            v.render = None;
        }
        Ok((verified, depth_ms))
    }

    /// Each candidate refined, with its contour agreement; those the refiner fails on are
    /// left out. Not yet rendered or scored.
    fn refine_hypotheses(&self, ctx: &RefineContext<'_>, candidates: &[(Source, Pose)], cfg: &EstimateConfig) -> Vec<Verified> {
        let refiner = self.refiner(cfg.refiner);
        candidates.par_iter().filter_map(|&(source, p)| self.verified(ctx, source, refiner.refine(ctx, p).ok()?, cfg)).collect()
    }

    /// A refined hypothesis, held to the caller's box where it is one's proposal, with its
    /// contour agreement; not yet rendered or scored.
    fn verified(&self, ctx: &RefineContext<'_>, source: Source, mut r: super::refine::Refined, cfg: &EstimateConfig) -> Option<Verified> {
        let held = held_to_box(ctx, cfg.box_prior, &mut r.pose);
        r.report.moved_to_box = held;
        let contour = if cfg.refiner == RefinerKind::Contour && !held { r.report.agreement } else { self.contour.agreement(ctx, &r.pose).ok()?.score };
        Some(Verified::unscored(source, r.pose, r.report, contour))
    }

    /// Renders the hypotheses `which` over the mask's `window` and measures what the
    /// renders say (IoU, edges, colour, and the backbone's features when they count), then
    /// scores every hypothesis of `verified` (unrendered ones by their outline alone).
    fn judge(&self, ctx: &RefineContext<'_>, verified: &mut [Verified], which: &[usize], window: (u32, u32, u32, u32), query: &QueryView, cfg: &EstimateConfig) -> Result<(), EstimateError> {
        let poses: Vec<Pose> = which.iter().map(|&i| verified[i].pose).collect();
        // Nothing to render must not wait for a pooled renderer.
        let evidence = if poses.is_empty() {
            vec![]
        } else {
            render_evidence(&self.renderer, &ctx.model.mesh, &poses, ctx.intrinsics, ctx.image, ctx.mask, ctx.unknown.filter(|_| cfg.verify.occlusion_aware_iou), window)?
        };
        for (&i, e) in which.iter().zip(evidence) {
            // A box's proposal: its pose must fill the box as well as overlap the proposal,
            // which may have taken in clutter or missed a face.
            verified[i].iou = match ctx.from_box {
                Some(b) => box_blend(e.iou, box_agreement(&e.render, window, &b, ctx.unknown)),
                None => e.iou,
            };
            verified[i].appearance = super::verify::appearance(e.edges, e.colour, cfg.verify.colour_share);
            verified[i].edges = e.edges;
            verified[i].colour = e.colour;
            verified[i].render = Some(e.render);
        }
        if cfg.verify.feature_share > 0.0 && !which.is_empty() {
            // The renders cropped exactly as the photo was, encoded in one batch.
            let (x0, y0) = (window.0 as f64, window.1 as f64);
            let crops: Vec<crate::features::CropInput> = which
                .par_iter()
                .map(|&i| {
                    let r = verified[i].render.as_ref().expect("rendered above");
                    crate::features::sample_crop(&r.rgb, &r.mask, &query.crop_box, crate::features::ToSource::Shift(x0, y0))
                })
                .collect();
            let maps = self.backbone.extract(&crops)?;
            for (&i, map) in which.iter().zip(&maps) {
                let v = &mut verified[i];
                v.features = super::verify::feature_agreement(&query.features, map, ctx.model.config.min_coverage);
                v.appearance = super::verify::with_features(v.appearance, v.features, cfg.verify.feature_share);
            }
        }
        for v in verified.iter_mut() {
            v.score = verification_score(v, &cfg.verify.weights);
        }
        Ok(())
    }

    /// The `keep` candidates whose outline agrees best with the mask where they start, and
    /// the start (the first: the pipeline's pose) whatever its agreement, in their order.
    fn most_agreeing(&self, ctx: &RefineContext<'_>, candidates: Vec<(Source, Pose)>, keep: usize) -> Vec<(Source, Pose)> {
        let scores: Vec<f64> = candidates.par_iter().map(|(_, p)| self.contour.agreement(ctx, p).map_or(f64::NEG_INFINITY, |a| a.score)).collect();
        let kept = super::verify::always_and_best(&scores, |i| i == 0, keep);
        candidates.into_iter().zip(kept).filter_map(|(c, k)| k.then_some(c)).collect()
    }

    /// Step 5 for one mask: the templates ranked for its query, best first.
    fn retrieve_for_mask(&self, model: &ObjectModel, q: &QueryView, cfg: &EstimateConfig, h: &mut Hypothesis, timings: &mut StageTimings) -> Vec<usize> {
        let t = Instant::now();
        let _span = tracing::info_span!("retrieval").entered();
        let retrieved = retrieve(model, &q.features.global, &q.silhouette, &cfg.retrieval);
        h.retrieved_templates = retrieved.len();
        if let Some(top) = retrieved.first() {
            h.top_template_cosine = top.cosine;
            h.top_template_silhouette_iou = top.silhouette_iou;
        }
        timings.retrieval += ms_since(t);
        retrieved.iter().map(|r| r.template).collect()
    }

    /// Steps 6–8 for one mask: matching against the `ranked` templates, PnP, RRC. Returns
    /// the templates placed by their matches (for verification). `photo` is the image and
    /// the mask `q` was cropped from (turned again where the object shares its patch rows
    /// per view).
    #[allow(clippy::too_many_arguments)]
    fn pose_for_mask(
        &self,
        model: &ObjectModel,
        q: &QueryView,
        photo: (&RgbImage, &GrayImage),
        k: &Intrinsics,
        ranked: &[usize],
        cfg: &EstimateConfig,
        h: &mut Hypothesis,
        timings: &mut StageTimings,
    ) -> Result<Vec<Pose>, EstimateError> {
        let t = Instant::now();
        let m = tracing::info_span!("matching").in_scope(|| super::turned::match_templates(model, self.backbone.as_ref(), photo.0, photo.1, q, ranked, cfg.k_nn))?;
        // Encoding turned queries (rows shared per view) is feature work, not matching.
        timings.features += m.encode_ms;
        timings.matching -= m.encode_ms;
        let (pool, corr) = (m.pool, m.correspondences);
        h.matches = corr.len();
        let matched = if cfg.verify.enabled { super::placement::matched_templates(model, &corr, &pool, q.crop_box.scale(), k, cfg.verify.matched_templates) } else { vec![] };
        timings.matching += ms_since(t);

        let t = Instant::now();
        let first = tracing::info_span!("pnp", matches = corr.len()).in_scope(|| run_pnp(&corr, k, &cfg.pnp));
        timings.pnp += ms_since(t);
        let first = match first {
            Ok(r) => r,
            Err(e) => {
                h.failure = Some(format!("no pose from {} matches: {e}", corr.len()));
                return Ok(matched);
            }
        };
        h.inliers = first.inliers.len();
        h.reprojection_error_px = first.mean_reprojection_error_px;
        h.pose = Some(first.pose);

        h.rrc_skipped = cfg.rrc && rrc_is_sure(first.inliers.len(), q.foreground.len(), cfg.rrc_sure_share);
        if cfg.rrc && !h.rrc_skipped {
            let t = Instant::now();
            let _span = tracing::info_span!("rrc").entered();
            let pool = rrc_pool(model, &first.pose, k, self.backbone.as_ref(), &self.renderer, cfg.rrc_render_scale, cfg.rrc_render_cap)?;
            // RRC's pool comes straight from the backbone: the query's own descriptors.
            let corr = correspond(q, &q.descriptors, &pool, cfg.k_nn);
            h.rrc_matches = corr.len();
            // The RRC pose replaces the first when it explains at least as many matches.
            if let Ok(r) = run_pnp(&corr, k, &cfg.pnp) {
                h.rrc_inliers = r.inliers.len();
                if r.inliers.len() >= first.inliers.len() {
                    h.pose = Some(r.pose);
                    h.reprojection_error_px = r.mean_reprojection_error_px;
                    h.rrc_used = true;
                }
            }
            timings.rrc += ms_since(t);
        }
        Ok(matched)
    }

    /// The IoU of `h`'s kept pose, rendered in its mask's window, with the mask (the
    /// pixels under `others` left out where verification leaves them out), kept as `h.iou`
    /// with the render in `h.render` (verification's own where it made one); None without
    /// a pose.
    fn kept_iou(&self, model: &ObjectModel, k: &Intrinsics, h: &mut Hypothesis, d: &Detection, others: Option<&GrayImage>, cfg: &EstimateConfig) -> Result<Option<f32>, EstimateError> {
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
    fn select(
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
fn box_blend(iou: f64, agreement: f32) -> f64 {
    (iou.max(0.0) * agreement as f64).sqrt()
}

/// A [0, 1] confidence from the raw selection inputs with the selection weights.
fn confidence(h: &Hypothesis, w: &[f32; 3]) -> f32 {
    let c = h.cosine.clamp(0.0, 1.0);
    let total = w.iter().sum::<f32>().max(1e-6);
    ((w[0] * c + w[1] * h.iou + w[2] * h.detector_score.clamp(0.0, 1.0)) / total).clamp(0.0, 1.0)
}

/// Whether `inliers` of a query's `foreground` patches are sure enough to skip RRC at
/// `share` (never at 0 or less).
fn rrc_is_sure(inliers: usize, foreground: usize, share: f64) -> bool {
    share > 0.0 && inliers as f64 >= share * foreground as f64
}

fn run_pnp(c: &Correspondences, k: &Intrinsics, cfg: &PnpConfig) -> Result<PnpResult, super::pnp::PnpError> {
    solve_pnp_ransac(&c.image_points, &c.object_points, k, cfg)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::masks::PixelBox;

    /// The service answers `by_stage`; a stage added to the struct but not to it would be
    /// missing from answers and metrics while the CLI's JSON (serde) shows it.
    #[test]
    fn stages_by_name_are_the_serialised_ones() {
        let as_json = |t: &StageTimings| serde_json::from_value::<std::collections::BTreeMap<String, f64>>(serde_json::to_value(t).unwrap()).unwrap();
        let mut t = StageTimings { crop: 1.0, features: 2.0, retrieval: 3.0, screen: 0.0, matching: 4.0, pnp: 5.0, rrc: 6.0, refine: 7.0, depth: 0.0, selection: 9.0, total: 45.0 };
        assert_eq!(t.by_stage(), as_json(&t));
        assert!(!t.by_stage().contains_key("depth") && !t.by_stage().contains_key("screen"));
        (t.depth, t.screen) = (8.0, 2.5);
        assert_eq!(t.by_stage(), as_json(&t));
        assert_eq!((t.by_stage()["depth"], t.by_stage()["screen"]), (8.0, 2.5));
    }

    #[test]
    fn rrc_always_turns_the_skip_off_and_otherwise_keeps_the_share() {
        let share = |always| EstimateConfig { rrc_sure_share: 0.2, ..Default::default() }.with_rrc_always(always).rrc_sure_share;
        assert_eq!((share(true), share(false)), (0.0, 0.2));
        assert!(!rrc_is_sure(1000, 10, 0.0) && rrc_is_sure(2, 10, 0.2) && !rrc_is_sure(1, 10, 0.2));
    }

    #[test]
    fn configs_without_the_box_prior_take_the_default_and_its_old_flag_still_reads() {
        let mut older = serde_json::to_value(EstimateConfig { box_prior: BoxPrior::Tight, ..Default::default() }).unwrap();
        assert_eq!(serde_json::from_value::<EstimateConfig>(older.clone()).unwrap().box_prior, BoxPrior::Tight);
        older["box_prior"] = serde_json::Value::Bool(false);
        assert_eq!(serde_json::from_value::<EstimateConfig>(older.clone()).unwrap().box_prior, BoxPrior::Off);
        older.as_object_mut().unwrap().remove("box_prior");
        assert_eq!(serde_json::from_value::<EstimateConfig>(older).unwrap().box_prior, BoxPrior::Auto);
    }

    fn det(score: f32, from_box: Option<PixelBox>) -> Detection {
        Detection { mask: GrayImage::new(1, 1), score, from_box, later: None }
    }

    #[test]
    fn a_box_proposals_silhouette_term_needs_the_proposal_and_the_box() {
        assert_eq!(box_blend(1.0, 1.0), 1.0);
        assert!((box_blend(0.81, 1.0) - 0.9).abs() < 1e-12);
        // A pose that fits its proposal but not the box (or the other way) scores nothing.
        assert_eq!(box_blend(0.95, 0.0), 0.0);
        assert_eq!(box_blend(0.0, 0.9), 0.0);
        assert!(box_blend(0.9, 0.6) < box_blend(0.8, 0.8));
    }

    #[test]
    fn a_boxs_proposals_count_as_one_candidate_and_are_all_tried() {
        let (a, b) = (PixelBox { x0: 0, y0: 0, x1: 4, y1: 4 }, PixelBox { x0: 5, y0: 5, x1: 9, y1: 9 });
        let cfg = EstimateConfig { max_masks: 2, ..Default::default() };
        // Three proposals of box a, a mask of its own, then box b: over max_masks.
        let dets = [det(0.9, Some(a)), det(0.9, Some(a)), det(0.8, Some(b)), det(0.85, None), det(0.9, Some(a)), det(0.8, Some(b))];
        assert_eq!(Estimator::candidate_masks(&dets, &cfg), vec![0, 1, 4, 3]);
        // Masks without boxes: the best max_masks above the threshold, as before.
        let plain = [det(0.2, None), det(0.9, None), det(0.5, None), det(0.7, None)];
        assert_eq!(Estimator::candidate_masks(&plain, &cfg), vec![1, 3]);
        // None passes: the best alone.
        let low = [det(0.1, None), det(0.3, None)];
        assert_eq!(Estimator::candidate_masks(&low, &cfg), vec![1]);
    }
}
