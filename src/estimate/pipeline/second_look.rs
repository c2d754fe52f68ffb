//! Verification's second look: when the winner's print agrees with nothing in the photo.
//!
//! Verification renders only the hypotheses whose outline agrees best, because the outline
//! is what the mask can judge. A textured object turned the wrong way round about an axis
//! its outline does not show (a bottle seen from the back, or upside down) can still win
//! on the outline; then its rendered print agrees with nothing in the photo, and the right
//! pose may be among the hypotheses whose outline agreed less, or be an axis flip of one
//! of them: one that shows the right face of the print but turned 180° about the line of
//! sight, its outline off where the object's ends differ. So, only then, every hypothesis
//! is rendered, and the axis flips of the two whose print agrees best are refined and
//! verified too (docs/benchmarks.md, "A real photo").

use super::{EstimateConfig, EstimateError, Estimator, QueryView, RefineContext, Verified};
use crate::estimate::hypotheses::{flips, Source};
use crate::estimate::verify::appearance;

/// Print agreement (edges and colour; `verify::appearance`) below which a render confirms
/// nothing. Right hypotheses on generated HOPE scenes agree at 0.48 or more in 95 % of
/// cases and never below 0.1; wrong ones fall below 0.1 in 9–13 % of cases
/// (`tools/hypothesis_sources.py`; docs/benchmarks.md, "A real photo").
const CONFIRMS: f64 = 0.1;

/// How many of the best-printed hypotheses have their flips tried.
const FLIPPED: usize = 2;

/// The print agreement of a rendered hypothesis; `None` where it was not rendered or the
/// mesh has no colours (untextured objects have little print to judge by).
fn print(v: &Verified, colour_share: f64) -> Option<f64> {
    (!v.iou.is_nan() && !v.colour.is_nan()).then(|| appearance(v.edges, v.colour, colour_share))
}

/// Whether `sorted`'s winner calls for a second look: rendered, on a mesh with colours,
/// and its print below [`CONFIRMS`].
fn needed(sorted: &[Verified], colour_share: f64) -> bool {
    sorted.first().and_then(|w| print(w, colour_share)).is_some_and(|p| p < CONFIRMS)
}

/// The hypotheses of `sorted` (winner first) whose flips the second look tries: up to
/// [`FLIPPED`] whose print confirms something and agrees better than the winner's, best
/// print first. Not the start (`start`: the pipeline's pose): its flips were hypotheses
/// from the start.
fn flip_sources(sorted: &[Verified], start: Source, colour_share: f64) -> Vec<usize> {
    let winner = sorted.first().and_then(|w| print(w, colour_share)).unwrap_or(0.0);
    let mut printed: Vec<(usize, f64)> =
        (0..sorted.len()).filter(|&i| sorted[i].source != start).filter_map(|i| print(&sorted[i], colour_share).map(|p| (i, p))).filter(|&(_, p)| p >= CONFIRMS && p > winner).collect();
    printed.sort_by(|a, b| b.1.total_cmp(&a.1));
    printed.into_iter().take(FLIPPED).map(|(i, _)| i).collect()
}

impl Estimator {
    /// Takes the second look where [`needed`]: renders the hypotheses not rendered yet,
    /// and adds the nine axis flips of the best prints ([`flip_sources`]), refined and
    /// rendered. `verified` is sorted best first before and after.
    pub(super) fn second_look(
        &self,
        ctx: &RefineContext<'_>,
        verified: &mut Vec<Verified>,
        start: Source,
        window: (u32, u32, u32, u32),
        query: &QueryView,
        cfg: &EstimateConfig,
    ) -> Result<(), EstimateError> {
        let share = cfg.verify.colour_share;
        if !needed(verified, share) {
            return Ok(());
        }
        let unrendered: Vec<usize> = (0..verified.len()).filter(|&i| verified[i].iou.is_nan()).collect();
        self.judge(ctx, verified, &unrendered, window, query, cfg)?;
        let mut more = Vec::new();
        for i in flip_sources(verified, start, share) {
            tracing::debug!(source = %verified[i].source, "second look: the flips of a best print");
            let candidates: Vec<(Source, _)> = flips(ctx.model, &verified[i].pose).map(|(k, pose)| (Source::PrintFlip(k), pose)).collect();
            more.extend(self.refine_hypotheses(ctx, &candidates, cfg));
        }
        let all: Vec<usize> = (0..more.len()).collect();
        self.judge(ctx, &mut more, &all, window, query, cfg)?;
        verified.extend(more);
        verified.sort_by(|a, b| b.score.total_cmp(&a.score));
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::refine::RefineReport;
    use crate::geometry::Pose;

    fn rendered(edges: f64, colour: f64) -> Verified {
        let nan = f64::NAN;
        Verified {
            source: Source::Pipeline,
            pose: Pose::identity(),
            refinement: RefineReport::default(),
            contour: 0.9,
            iou: 0.9,
            appearance: nan,
            edges,
            colour,
            features: nan,
            score: nan,
            render: None,
        }
    }

    /// Only a rendered winner on a coloured mesh whose print agrees with nothing asks for
    /// a second look.
    #[test]
    fn a_second_look_only_where_the_winner_confirms_nothing() {
        assert!(needed(&[rendered(0.04, 0.0)], 0.5));
        assert!(!needed(&[rendered(0.5, 0.6)], 0.5), "a print that agrees");
        assert!(!needed(&[rendered(0.04, f64::NAN)], 0.5), "no colours: untextured");
        let mut unrendered = rendered(0.0, 0.0);
        unrendered.iou = f64::NAN;
        assert!(!needed(&[unrendered], 0.5), "not rendered");
        assert!(!needed(&[], 0.5));
    }

    /// The flips tried are those of the best prints that beat the winner's and confirm
    /// something, at most two, never the start's (the pipeline's pose).
    #[test]
    fn flips_of_the_best_prints_but_not_the_pipelines() {
        let with = |source, edges, colour| Verified { source, ..rendered(edges, colour) };
        let sorted = [
            with(Source::Matched(0), 0.04, 0.0),
            with(Source::Pipeline, 0.3, 0.3),
            with(Source::Template(1), 0.1, 0.2),
            with(Source::Matched(2), 0.2, 0.25),
            with(Source::Spin { axis: 0, degrees: 45 }, 0.12, 0.2),
            with(Source::Flip(3), 0.05, 0.05),
        ];
        assert_eq!(flip_sources(&sorted, Source::Pipeline, 0.5), vec![3, 4]);
        assert!(flip_sources(&sorted[..2], Source::Pipeline, 0.5).is_empty(), "only the pipeline's print beats the winner's");
        // Where PnP found no pose, the start is a template, and its flips are left out too.
        assert_eq!(flip_sources(&sorted, Source::Matched(2), 0.5), vec![1, 4]);
    }
}
