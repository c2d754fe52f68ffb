//! The online stage end to end (DESIGN.md steps 4–10) for one object in one image.

use super::candidates::Detection;
use super::contour::ContourRefiner;
use super::correspond::{correspond, Correspondences};
use super::hypotheses::Source;
use super::pnp::{solve_pnp_ransac, PnpConfig, PnpResult};
use super::query::QueryView;
use super::refine::{PassThrough, RefineContext, RefineReport, Refiner, RefinerKind};
use super::retrieve::retrieve;
use super::rrc::rrc_pool;
use super::select::{box_agreement, mask_window};
use super::silhouette_refiner::SilhouetteDepthRefiner;
use super::verify::{render_evidence, score as verification_score, Verified};
use super::EstimateError;
use crate::depth::DepthImage;
use crate::features::Backbone;
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
mod selection;
mod types;
pub use depth_review::Reviewed;

use box_proposals::held_to_box;
use queries::Queries;

pub use super::candidate_effort::CandidateEffort;
pub use screen::{CoarseCheck, DepthScreen, Screen};

use selection::box_blend;
pub use types::{EstimateConfig, EstimateResult, Hypothesis, StageTimings};

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
        box_proposals::winner_to_free_edge(req, detections, &mut result);
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
        let (origins, corr) = (m.origins, m.correspondences);
        h.matches = corr.len();
        let matched = if cfg.verify.enabled { super::placement::matched_templates(model, &corr, &origins, q.crop_box.scale(), k, cfg.verify.matched_templates) } else { vec![] };
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
    use crate::estimate::box_prior::BoxPrior;
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
