//! Hypothesise and verify: P3P on random triples, every solution scored by inlier count
//! (under a sequential test that drops bad ones early: `sprt.rs`).
//!
//! Samples are triples, not P3P + a fourth point to pick the solution: at the 30 % inlier
//! ratio the pipeline sees, an all-inlier triple is 1/w ≈ 3× likelier than an all-inlier
//! quadruple, and scoring the (on average ~2) solutions with an early exit costs less than
//! the extra samples would.

use super::matches::Matches;
use super::p3p::p3p;
use super::rng::SplitMix64;
use super::sprt::Sprt;
use super::PnpConfig;
use crate::geometry::Pose;

const SAMPLE_SIZE: usize = 3;

pub(crate) struct Consensus {
    /// `None` when no sample gave a single pose with an inlier.
    pub(crate) pose: Option<Pose>,
    pub(crate) inliers: usize,
    pub(crate) iterations: usize,
}

pub(crate) fn search(m: &Matches, cfg: &PnpConfig) -> Consensus {
    let n = m.len();
    let mut rng = SplitMix64::new(cfg.seed);
    let order = rng.permutation(n);
    let mut best = Consensus { pose: None, inliers: 0, iterations: 0 };
    let mut sprt = Sprt::new(0.0);
    let mut needed = cfg.max_iterations;
    while best.iterations < needed {
        best.iterations += 1;
        let idx = rng.distinct::<SAMPLE_SIZE>(n);
        let world = idx.map(|i| m.point(i));
        let bearings = idx.map(|i| m.bearing(i));
        for pose in p3p(&world, &bearings).as_slice() {
            let Some(count) = sprt.score(m, pose, &order, best.inliers) else { continue };
            if count > best.inliers {
                best.inliers = count;
                best.pose = Some(*pose);
                sprt = Sprt::new(count as f64 / n as f64);
                needed = needed.min(samples_needed(count, n, sprt.acceptance(), cfg.confidence));
            }
        }
    }
    best
}

/// Samples after which an all-inlier one has been drawn, and its pose kept by the test, with
/// probability `confidence`, if the inlier ratio is `inliers / n`: log(1 − p) / log(1 − a·wˢ).
fn samples_needed(inliers: usize, n: usize, acceptance: f64, confidence: f64) -> usize {
    let all_inlier = acceptance * (inliers as f64 / n as f64).powi(SAMPLE_SIZE as i32);
    let log_miss = (-all_inlier).ln_1p();
    if log_miss == f64::NEG_INFINITY {
        return 1;
    }
    if log_miss >= 0.0 {
        return usize::MAX;
    }
    let needed = ((1.0 - confidence).ln() / log_miss).ceil();
    if needed >= usize::MAX as f64 {
        usize::MAX
    } else {
        (needed as usize).max(1)
    }
}

#[cfg(test)]
mod tests {
    use super::samples_needed;

    #[test]
    fn adaptive_stop_matches_the_formula() {
        // w = 0.3, s = 3, p = 0.999: ln(0.001)/ln(1 − 0.027) = 252.4.
        assert_eq!(samples_needed(90, 300, 1.0, 0.999), 253);
        assert_eq!(samples_needed(300, 300, 1.0, 0.999), 1);
        assert_eq!(samples_needed(0, 300, 1.0, 0.999), usize::MAX);
    }
}
