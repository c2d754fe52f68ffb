//! The hypothesis-verification options shared by `estimate`, `bop run` and `bench estimate`,
//! and the refinement of the kept pose on its print that follows verification.

use crate::estimate::contour::PrintRefineConfig;
use crate::estimate::VerifyConfig;

#[derive(clap::Args, Debug, Clone)]
pub struct VerifyArgs {
    /// No hypothesis verification: refine the pipeline's pose alone, not also its axis
    /// flips, spins and the best retrieved templates placed at the mask (faster, less accurate).
    #[arg(long)]
    pub no_verify: bool,
    /// Retrieved templates placed at the mask as hypotheses (default 5).
    #[arg(long)]
    pub verify_templates: Option<usize>,
    /// Templates with the most matches, each placed where its matches put it rather than
    /// at the mask's box, as hypotheses: they survive occlusion (default 5; 0: none).
    #[arg(long)]
    pub verify_matched: Option<usize>,
    /// Spins of the pose about each object axis as hypotheses, in this many steps of a
    /// whole turn; the quarter turns are the axis flips (default 8: 45°; 0: none).
    #[arg(long)]
    pub spin_steps: Option<usize>,
    /// Refine one hypothesis of each set equal up to the object's symmetries, not each:
    /// faster on symmetric objects, a little less accurate (docs/estimation.md, "Symmetries").
    #[arg(long)]
    pub skip_symmetric_hypotheses: bool,
    /// Share of the feature-metric agreement (the render and the photo encoded by the
    /// backbone on the same crop, compared patch by patch) in verification's appearance
    /// term, 0–1 (default 0.5; 0 skips the backbone pass over the renders).
    #[arg(long, value_parser = share)]
    pub feature_share: Option<f64>,
    /// Hypotheses rendered in verification, best by contour agreement first (default 3).
    #[arg(long)]
    pub verify_rendered: Option<usize>,
    /// Most hypotheses rendered in verification, those the outline cannot tell apart
    /// included (default 10).
    #[arg(long)]
    pub verify_max_rendered: Option<usize>,
    /// No second look: where the winner's rendered print agrees with nothing in the photo,
    /// verification renders every hypothesis and tries the axis flips of the one whose
    /// print agrees best; this turns that off.
    #[arg(long)]
    pub no_second_look: bool,
    /// Take the flips and spins about the pipeline's pose as it is, even where its outline
    /// and the mask disagree in size or place (by default they are taken about that pose
    /// re-placed at the mask).
    #[arg(long)]
    pub no_replace_at_mask: bool,
    /// Hypotheses refined in full: the best this many by outline agreement where they
    /// start, and the pipeline's pose always (0: all).
    #[arg(long)]
    pub verify_refined: Option<usize>,
    /// Hypotheses taken past the contour refiner's first line scale: the best this many by
    /// outline agreement there, the pipeline's pose, the depth's views and hints always (default
    /// 16; 0: all, about a seventh slower and as accurate within noise).
    #[arg(long)]
    pub verify_finished: Option<usize>,
    /// Count the render's pixels under other detections against a pose's silhouette IoU,
    /// as if nothing could hide the object there (by default they count neither way).
    #[arg(long)]
    pub iou_counts_occluded: bool,
    /// Also try the winner tilted by this many degrees each way across the line of sight,
    /// refined and judged (default 8: 1.2–7.5 points more of generated HOPE scenes right,
    /// for 20–55 ms more per instance; 0: off; at most 45).
    #[arg(long, value_parser = nudge_degrees)]
    pub nudge: Option<f64>,
    /// With depth: the best this many template views placed on the measured surface
    /// under the mask and fitted there, as hypotheses always rendered and judged
    /// (default 4; 0: off; at most 12). With the depth detector's candidates also the
    /// views every answer is reviewed against.
    #[arg(long, value_parser = clap::value_parser!(u64).range(0..=crate::estimate::depth_search::MOST_VIEWS as u64))]
    pub depth_views: Option<u64>,
    /// Rounds of refining the kept pose on its print as well as its outline, on objects
    /// with colours (render, find the print in the photo, update; default 3, 0: none).
    #[arg(long)]
    pub print_rounds: Option<usize>,
}

/// A number from 0 to 1 (a share, a score), or what is wrong with it.
pub(crate) fn share(s: &str) -> Result<f64, String> {
    let v = number(s)?;
    if (0.0..=1.0).contains(&v) {
        Ok(v)
    } else {
        Err(format!("{v} is outside 0–1"))
    }
}

fn nudge_degrees(s: &str) -> Result<f64, String> {
    crate::estimate::verify::nudge_in_range(number(s)?)
}

fn number(s: &str) -> Result<f64, String> {
    s.parse().map_err(|e| format!("{s:?} is not a number: {e}"))
}

impl VerifyArgs {
    pub fn config(&self) -> VerifyConfig {
        let d = VerifyConfig::default();
        VerifyConfig {
            enabled: !self.no_verify,
            templates: self.verify_templates.unwrap_or(d.templates),
            matched_templates: self.verify_matched.unwrap_or(d.matched_templates),
            spin_steps: self.spin_steps.unwrap_or(d.spin_steps),
            skip_symmetric: self.skip_symmetric_hypotheses,
            feature_share: self.feature_share.unwrap_or(d.feature_share),
            refined: self.verify_refined.unwrap_or(d.refined),
            finished: self.verify_finished.unwrap_or(d.finished),
            second_look: !self.no_second_look,
            rendered: self.verify_rendered.unwrap_or(d.rendered),
            max_rendered: self.verify_max_rendered.unwrap_or(d.max_rendered),
            occlusion_aware_iou: !self.iou_counts_occluded,
            replace_off_mask: !self.no_replace_at_mask,
            nudge_degrees: self.nudge.unwrap_or(d.nudge_degrees),
            depth_views: self.depth_views.map_or(d.depth_views, |n| n as usize),
            ..d
        }
    }

    /// The refinement on the print these options ask for.
    pub fn print_config(&self) -> PrintRefineConfig {
        let d = PrintRefineConfig::default();
        PrintRefineConfig { rounds: self.print_rounds.unwrap_or(d.rounds), ..d }
    }
}

#[cfg(test)]
mod tests {
    /// A share outside 0–1, or no number, is refused with what is wrong.
    #[test]
    fn feature_share_must_be_a_share() {
        assert_eq!(super::share("0.5"), Ok(0.5));
        assert!(super::share("1.5").unwrap_err().contains("outside 0–1"));
        assert!(super::share("half").unwrap_err().contains("not a number"));
    }

    #[test]
    fn a_nudge_is_at_most_45_degrees() {
        assert_eq!(super::nudge_degrees("8"), Ok(8.0));
        assert!(super::nudge_degrees("-1").unwrap_err().contains("outside 0–45 degrees"));
        assert!(super::nudge_degrees("90").unwrap_err().contains("outside 0–45 degrees"));
        assert!(super::nudge_degrees("x").unwrap_err().contains("not a number"));
    }
}
