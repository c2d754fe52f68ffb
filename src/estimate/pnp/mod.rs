//! RANSAC-PnP: the camera pose `T_cam_obj` from 2D-3D matches, most of them wrong.
//!
//! Pipeline (`solve.rs`): validate the input (`validate.rs`), RANSAC over Lambda Twist P3P
//! triples (`ransac.rs`, `p3p.rs`) with sequential early rejection of bad poses (`sprt.rs`),
//! re-estimate on the consensus set (and from its mirror image, the other minimum of a flat
//! target: `mirror.rs`) and recompute it, then Levenberg–Marquardt on the inliers
//! (`refine.rs`). Reprojection scoring lives in `matches.rs`.
//!
//! Why our own P3P rather than a crate (DESIGN.md asks to measure; release build, exact
//! 15 cm-object triples, error = rotation rad + translation m of the closest solution):
//! - ours, Lambda Twist in f64: ~0.39 µs per solve, median error 6e-14;
//! - `kornia-3d` 0.2 AP3P: ~0.40 µs, median 4e-7 (f32 glam interface), and 133 crates of
//!   dependencies (faer pinned `=0.24.4`, kiddo, kornia-image/imgproc, rand 0.10); its
//!   RANSAC (AP3P + EPnP/LM refit) took 3.5 ms per 300-match call against our 0.33 ms;
//!   its EPnP was 23 µs and inaccurate on 4–6 points of a small object;
//! - `lambda-twist` 0.7: 2.8 µs, median 8e-13, but via `cv-core` 0.15 on nalgebra 0.21;
//! - `sqpnp` 0.4: not minimal (1.5 µs on 6 points, 30 µs on 4), f32 glam interface,
//!   nalgebra 0.34.

mod algebra;
mod matches;
mod mirror;
pub mod p3p;
mod ransac;
mod refine;
mod rng;
mod solve;
mod spread;
mod sprt;
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
        Self { reprojection_threshold_px: 4.0, max_iterations: 10_000, confidence: 0.999, min_inliers: 6, seed: 0, refine: true }
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
    /// `need` is `max(MIN_POINTS, cfg.min_inliers)`: fewer matches could never be a consensus.
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
