//! A depth detector's candidate confirmed short of an answer, looked at again beside the
//! views found in the depth (`Estimator::reviewed_in_depth`) before it is given up.
//!
//! The candidates are estimated lightly and without the depth's views (`candidate_effort`),
//! and a right candidate whose estimate came out half-turned or shifted confirms low: on
//! the real YCB-V frames the foam brick at 0.29 and the mug, handle on the wrong side, at
//! 0.42, against the 0.5 an answer needs. Reviewed, the brick confirmed at 0.71 and the mug
//! at 0.51 (docs/detection.md, "Answers reviewed with the depth's views"). Only candidates
//! within reach are reviewed (`WITHIN_REACH`): a review costs about a light estimate's
//! half, and one far below is another object or none.

use crate::depth::DepthImage;
use crate::estimate::runner_up::RunnerUp;
use crate::estimate::{Detection, EstimateConfig, EstimateError, Estimator};
use crate::geometry::{Intrinsics, Pose};
use crate::onboard::ObjectModel;
use crate::render::RenderPool;
use image::{GrayImage, RgbImage};

/// A confirmation at least this share of what an answer needs is within a review's reach.
/// Measured (docs/detection.md, "Near misses within reach"): of 103 reviews over the real
/// YCB-V frames (the objects in each, and 8 searched) and two generated sets, the 11 that
/// rescued a candidate started from 0.46 of what an answer needs or more, and the 40 from
/// below 0.4 of it reached two thirds of it at most: at 0.2 those were reviewed for nothing.
const WITHIN_REACH: f32 = 0.4;

/// Whether a candidate confirmed at `confirmation` is short of the `needed` one but within
/// reach of a review.
pub fn near_miss(confirmation: f32, needed: f32) -> bool {
    confirmation < needed && confirmation >= WITHIN_REACH * needed
}

/// What a candidate the detector offered was estimated and confirmed as, and where.
pub struct Candidate<'a> {
    pub model: &'a ObjectModel,
    /// Its mask, as the estimate chose it.
    pub detection: &'a Detection,
    /// Where other detections may hide it.
    pub others: Option<&'a GrayImage>,
    pub pose: Pose,
    pub confirmation: f32,
}

/// A candidate's pose and confirmation after `reviewed_near_miss`.
#[derive(Clone, Copy, Debug)]
pub struct Looked {
    pub pose: Pose,
    pub confirmation: f32,
    /// Whether it was reviewed (its pose the reviewed one or beaten by it): another review
    /// would find the same views, so the answer's review after `one_per_place` skips it.
    pub reviewed: bool,
    /// Where the review changed the pose: the best other answer it judged.
    pub runner_up: Option<RunnerUp>,
}

/// The candidate's pose and confirmation: reviewed when a near miss of `needed`, and the
/// reviewed pose kept when it confirms better; as estimated otherwise.
pub fn reviewed_near_miss(
    estimator: &Estimator,
    (image, depth): (&RgbImage, &DepthImage),
    k: &Intrinsics,
    c: Candidate<'_>,
    needed: f32,
    cfg: &EstimateConfig,
    pool: &RenderPool,
) -> Result<Looked, EstimateError> {
    let unchanged = |reviewed| Looked { pose: c.pose, confirmation: c.confirmation, reviewed, runner_up: None };
    if !near_miss(c.confirmation, needed) {
        return Ok(unchanged(false));
    }
    let r = estimator.reviewed_in_depth(c.model, (image, depth), k, c.detection, c.others, c.pose, cfg)?;
    if r.view.is_none() {
        return Ok(unchanged(true));
    }
    let again = crate::detect::confirm::confirm(image, Some(depth), k, &c.model.mesh, &c.detection.mask, &r.pose, pool)?;
    tracing::debug!(before = c.confirmation, after = again, view = r.view, "near miss reviewed");
    Ok(if again > c.confirmation { Looked { pose: r.pose, confirmation: again, reviewed: true, runner_up: r.runner_up } } else { unchanged(true) })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_confirmations_short_of_an_answer_but_within_reach_are_near_misses() {
        assert!(near_miss(0.45, 0.5) && near_miss(0.2, 0.5));
        assert!(!near_miss(0.5, 0.5), "an answer already");
        assert!(!near_miss(0.19, 0.5), "out of reach");
    }
}
