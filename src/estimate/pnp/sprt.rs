//! Hypothesis verification by Wald's sequential probability ratio test (Matas & Chum,
//! "Randomized RANSAC with Sequential Probability Ratio Test", ICCV 2005).
//!
//! Scoring, not solving, dominates RANSAC here: a bad pose used to be checked against most
//! matches before it fell behind the best. Checking the matches in random order and dropping
//! the pose once the evidence says "bad" (a run of ~20 outliers) rather than "as good as the
//! best so far" cuts a 300-match call to about half. Random order matters: matches arrive
//! sorted by image patch, so inliers come in clumps.

use super::matches::Matches;
use crate::geometry::Pose;

/// Accepted false-rejection rate of a good pose is about 1/A (Wald's bound).
const LOG_A: f64 = 6.907_755_278_982_137; // ln 1000
/// Assumed fraction of matches a bad pose explains by chance. The test is insensitive to it
/// (rejection takes ~20 outliers anywhere in 0.005–0.05); too small would only slow rejection.
const DELTA: f64 = 0.05;

pub(crate) struct Sprt {
    /// Log-likelihood-ratio increments for an inlier (negative) and an outlier (positive).
    step_inlier: f64,
    step_outlier: f64,
    active: bool,
}

impl Sprt {
    /// The test against the best inlier ratio so far; inactive (plain counting) until that
    /// ratio clearly exceeds what a bad pose gets by chance.
    pub(crate) fn new(best_ratio: f64) -> Self {
        let active = best_ratio > 2.0 * DELTA;
        Self { step_inlier: (DELTA / best_ratio).ln(), step_outlier: ((1.0 - DELTA) / (1.0 - best_ratio)).ln(), active }
    }

    /// Probability that the test keeps a good pose: the adaptive stop has to allow for it.
    pub(crate) fn acceptance(&self) -> f64 {
        if self.active {
            1.0 - (-LOG_A).exp()
        } else {
            1.0
        }
    }

    /// Inlier count of `pose` over the matches in `order`, or `None` once the pose is judged
    /// bad or can no longer beat `to_beat` inliers.
    pub(crate) fn score(&self, m: &Matches, pose: &Pose, order: &[u32], to_beat: usize) -> Option<usize> {
        let r = pose.rotation.matrix();
        let max_outliers = order.len().saturating_sub(to_beat + 1);
        let (mut outliers, mut log_ratio) = (0, 0.0);
        for &i in order {
            if m.is_inlier(i as usize, r, &pose.translation) {
                log_ratio += self.step_inlier;
            } else {
                outliers += 1;
                log_ratio += self.step_outlier;
                if outliers > max_outliers || (self.active && log_ratio > LOG_A) {
                    return None;
                }
            }
        }
        Some(order.len() - outliers)
    }
}
