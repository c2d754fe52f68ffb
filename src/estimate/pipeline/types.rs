//! What an estimate is asked (`EstimateConfig`) and what it answers: the selected pose with
//! every candidate's hypothesis and the time each stage took.

use crate::estimate::box_prior::BoxPrior;
use crate::estimate::candidate_effort::CandidateEffort;
use crate::estimate::contour::PrintRefineConfig;
use crate::estimate::pnp::PnpConfig;
use crate::estimate::refine::RefinerKind;
use crate::estimate::retrieve::RetrievalConfig;
use crate::estimate::select::SelectionConfig;
use crate::estimate::verify::{Verified, VerifyConfig};
use crate::geometry::Pose;

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
    #[serde(default, deserialize_with = "crate::estimate::box_prior::deserialize")]
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
    pub refinement: Option<crate::estimate::refine::RefineReport>,
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
    pub runner_up: Option<crate::estimate::runner_up::RunnerUp>,
}
