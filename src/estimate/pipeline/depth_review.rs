//! The depth detector's answers looked at again beside the views found in the depth.
//!
//! The detector's candidates are estimated lightly and without the depth's own views
//! (`candidate_effort`): with them a candidate of the wrong object fits the surface as
//! well as the right one's, and which object a place holds is decided worse. Once the
//! objects' answers are chosen, though, the views are what turns a half-turned or
//! misplaced answer right (docs/detection.md, "Answers reviewed with the depth's views").
//! So each chosen answer is judged again with them: the answer's pose and the views found
//! under its mask, the views refined as verification refines its hypotheses, all rendered,
//! judged and fitted to the depth as verification does, and the best kept. Only the pose
//! can change: which object it is stays the comparison's.

use super::{EstimateError, Estimator, RefineContext, RefineReport, Verified};
use crate::depth::DepthImage;
use crate::estimate::candidates::Detection;
use crate::estimate::hypotheses::Source;
use crate::estimate::query::{crop_all, encode};
use crate::estimate::runner_up::{runner_up, RunnerUp};
use crate::estimate::select::mask_window;
use crate::estimate::EstimateConfig;
use crate::geometry::{Intrinsics, Pose};
use crate::onboard::ObjectModel;
use image::{GrayImage, RgbImage};

/// What a review found: the pose kept, and whether it is one of the depth's views.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reviewed {
    pub pose: Pose,
    /// The depth view that beat the answer (its rank in the search), None when the answer
    /// stood.
    pub view: Option<usize>,
    /// With a view that won: the best other answer the review judged (the answer it
    /// replaced, as a rule), for the answer's close-call verdict; None otherwise.
    pub runner_up: Option<RunnerUp>,
}

impl Estimator {
    /// `pose`, `model`'s answer on `detection`'s mask, judged against the
    /// `cfg.verify.depth_views` best poses found in `depth` under that mask
    /// (`depth_search`); the winner by verification's score with the depth's. The answer is
    /// returned unchanged when it wins (not its copy fitted to the depth again), when the
    /// depth shows nothing under the mask, or with no views asked for.
    #[allow(clippy::too_many_arguments)]
    pub fn reviewed_in_depth(
        &self,
        model: &ObjectModel,
        (image, depth): (&RgbImage, &DepthImage),
        k: &Intrinsics,
        detection: &Detection,
        others: Option<&GrayImage>,
        pose: Pose,
        cfg: &EstimateConfig,
    ) -> Result<Reviewed, EstimateError> {
        let unchanged = Reviewed { pose, view: None, runner_up: None };
        self.validate(model, image, k, std::slice::from_ref(detection))?;
        let found = crate::estimate::depth_search::searched(model, depth, k, &detection.mask, cfg.verify.depth_views);
        if found.is_empty() {
            return Ok(unchanged);
        }
        let size = model.grid.n * model.grid.patch;
        let crops: Vec<_> = crop_all(image, &[&detection.mask], model.config.crop_padding, size).into_iter().flatten().collect();
        let query = encode(self.backbone.as_ref(), crops, model.config.min_coverage)?.pop().ok_or_else(|| EstimateError::BadInput("the mask gives no crop".into()))?;
        let ctx = RefineContext { model, image, intrinsics: k, mask: &detection.mask, unknown: others, mask_is_probability: false, from_box: detection.from_box, depth: Some(depth) };
        // The views refined as verification refines its hypotheses; the answer, refined
        // already, judged as it is (refined again it drifted, and lost to views it had beaten:
        // on the real frames AR 0.625 against 0.655 as it is, docs/detection.md).
        let views: Vec<(Source, Pose)> = found.into_iter().enumerate().map(|(i, s)| (Source::DepthView(i), s.pose)).collect();
        let contour = self.contour.agreement(&ctx, &pose).map_or(0.0, |a| a.score);
        let mut verified = vec![Verified::unscored(Source::Pipeline, pose, RefineReport::default(), contour)];
        verified.extend(self.refine_hypotheses(&ctx, &views, cfg));
        let window = mask_window(&detection.mask).expect("validated non-empty");
        let all: Vec<usize> = (0..verified.len()).collect();
        self.judge(&ctx, &mut verified, &all, window, &query, cfg)?;
        Self::judge_on_depth(&ctx, &mut verified, window)?;
        Ok(match verified.first() {
            Some(Verified { source: Source::DepthView(i), pose, .. }) => Reviewed { pose: *pose, view: Some(*i), runner_up: runner_up(pose, &verified, model) },
            _ => unchanged,
        })
    }
}
