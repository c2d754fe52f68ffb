//! RANSAC-PnP: the camera pose `T_cam_obj` from 2D-3D matches, most of them wrong.
//!
//! Pipeline (`solve.rs`): validate the input, RANSAC over Lambda Twist P3P minimal samples
//! (`ransac.rs`, `p3p.rs`), re-estimate on the consensus set (and from its mirror image, the
//! other minimum of a flat target: `mirror.rs`) and recompute it, then Levenberg–Marquardt on
//! the inliers (`refine.rs`). Reprojection scoring lives in `matches.rs`.
//!
//! Why our own P3P rather than a crate: see the crate evaluation in the stage report
//! (`kornia-3d` is f32-only and heavy, `sqpnp` pins nalgebra 0.34, `lambda-twist` pins
//! nalgebra 0.21 through the unmaintained `cv-core`).

mod matches;
mod mirror;
pub mod p3p;
mod ransac;
mod refine;
mod rng;
mod solve;
mod spread;
mod validate;

#[cfg(test)]
mod tests;

use crate::geometry::Pose;

pub use solve::solve_pnp_ransac;

/// The fewest matches that pin a pose down without a two-fold ambiguity: P3P plus one to check.
pub const MIN_POINTS: usize = 4;

#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PnpConfig {
    /// A match is an inlier when its reprojection error is below this, in pixels.
    pub reprojection_threshold_px: f64,
    /// Hard cap on RANSAC samples, whatever the adaptive stop says.
    pub max_iterations: usize,
    /// Probability of having drawn at least one all-inlier sample when RANSAC stops early.
    pub confidence: f64,
    /// Fewer inliers than this (or than `MIN_POINTS`) is `NoConsensus`.
    pub min_inliers: usize,
    /// Seeds the sampler: equal inputs and seed give equal results.
    pub seed: u64,
    /// Levenberg–Marquardt (Huber loss) on the final inliers. Off, the pose is the consensus
    /// re-estimate only (a few plain least-squares steps), for callers that refine elsewhere.
    pub refine: bool,
}

impl Default for PnpConfig {
    fn default() -> Self {
        Self {
            reprojection_threshold_px: 4.0,
            max_iterations: 10_000,
            confidence: 0.999,
            min_inliers: 6,
            seed: 0,
            refine: true,
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct PnpResult {
    /// `T_cam_obj`, metres.
    pub pose: Pose,
    /// Indices into the input of the matches within the threshold under `pose`, ascending.
    pub inliers: Vec<usize>,
    /// RANSAC samples drawn.
    pub iterations: usize,
    /// Mean reprojection error of the inliers under `pose`, pixels.
    pub mean_reprojection_error_px: f64,
}

#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum PnpError {
    #[error("PnP needs at least {need} matches, got {got}")]
    NotEnoughPoints { got: usize, need: usize },
    #[error("{image} image points but {object} object points")]
    LengthMismatch { image: usize, object: usize },
    #[error("a match or the intrinsics hold NaN or infinity")]
    NonFinite,
    #[error("intrinsics need positive focal lengths")]
    BadIntrinsics,
    #[error("bad PnP config: {0}")]
    BadConfig(&'static str),
    #[error("the points (or the inliers) are coincident or collinear, in 3D or in the image")]
    Degenerate,
    #[error("no pose explains enough matches: best had {best_inliers} inliers")]
    NoConsensus { best_inliers: usize },
}
