//! Estimation: retrieval with geodesic NMS, mutual-NN matching, RANSAC-PnP, RRC, refinement
//! and hypothesis selection across masks (DESIGN.md steps 4–10).

pub mod box_prior;
pub mod candidate_effort;
pub mod candidates;
pub mod contour;
pub mod correspond;
pub mod depth_fit;
pub mod depth_search;
pub mod hypotheses;
pub mod matching;
pub mod near_miss;
pub mod pipeline;
pub mod placement;
pub mod pnp;
pub mod query;
pub mod refine;
pub mod retrieve;
pub mod rrc;
pub mod runner_up;
pub mod select;
pub mod silhouette_refiner;
pub mod turned;
pub mod verify;

pub use box_prior::BoxPrior;
pub use candidates::{Candidates, Detection};
pub use pipeline::{CandidateEffort, CoarseCheck, DepthScreen, EstimateConfig, EstimateResult, Estimator, Hypothesis, Reviewed, Screen, StageTimings};
pub use refine::{PassThrough, RefineContext, RefineReport, Refined, Refiner, RefinerKind};
pub use runner_up::RunnerUp;
pub use verify::VerifyConfig;

#[derive(Debug, thiserror::Error)]
pub enum EstimateError {
    #[error("invalid input: {0}")]
    BadInput(String),
    #[error("object {object:?} was onboarded with backbone {model}, but this estimator runs {ours}: onboard it again with this backbone")]
    BackboneMismatch { object: String, model: String, ours: String },
    #[error("rendering failed: {0}")]
    Render(#[from] crate::render::RenderError),
    #[error("feature extraction failed: {0}")]
    Features(#[from] crate::features::FeatureError),
}
