//! Verification's cut after the first line scale: every hypothesis is refined on the
//! coarsest correspondence lines, and only those whose outline then agrees best with the
//! mask (and the ones always judged) go through the finer scales, where most of the
//! refiner's time goes.

use super::{EstimateConfig, Estimator, RefineContext, Verified};
use crate::estimate::contour::{Begun, CoarseRun};
use crate::estimate::hypotheses::Source;
use crate::estimate::refine::Refined;
use crate::estimate::refine::RefinerKind;
use crate::geometry::Pose;
use rayon::prelude::*;
use std::sync::Arc;

impl Estimator {
    /// `candidates` refined as `refine_hypotheses` does, but where the contour refiner runs
    /// and there are more than `VerifyConfig::finished` of them, only that many are
    /// finished after the first scale: those `always` names, then the best by agreement
    /// there. The others are left out; those the refiner already kept at their start
    /// (too few lines saw the mask) stay, as they cost nothing more.
    pub(super) fn refine_with_cut(&self, ctx: &RefineContext<'_>, candidates: &[(Source, Pose)], always: impl Fn(Source) -> bool, cfg: &EstimateConfig) -> Vec<Verified> {
        let keep = cfg.verify.finished;
        if keep == 0 || candidates.len() <= keep || !self.contour_runs(cfg.refiner) {
            return self.refine_hypotheses(ctx, candidates, cfg);
        }
        let begun: Vec<(Source, Begun)> = candidates.par_iter().filter_map(|&(source, p)| Some((source, self.contour.begin(ctx, p).ok()?))).collect();
        let mut done: Vec<(Source, Refined)> = Vec::new();
        let mut running: Vec<(Source, CoarseRun)> = Vec::new();
        for (source, b) in begun {
            match b {
                Begun::Done(r) => done.push((source, r)),
                Begun::Coarse(run) => running.push((source, run)),
            }
        }
        let ranks: Vec<(bool, f64)> = running.iter().map(|(s, run)| (always(*s), run.coarse_agreement)).collect();
        let chosen = to_finish(&ranks, keep);
        let running: Vec<(Source, CoarseRun)> = running.into_iter().zip(chosen).filter_map(|(r, c)| c.then_some(r)).collect();
        let refined: Vec<(Source, Refined)> = running.into_par_iter().filter_map(|(s, run)| Some((s, self.contour.finish(ctx, run).ok()?))).collect();
        done.into_iter().chain(refined).filter_map(|(s, r)| self.verified(ctx, s, r, cfg)).collect()
    }

    /// Whether the refiner run for `kind` is the contour refiner this estimator verifies
    /// with (the only one refined in stages).
    fn contour_runs(&self, kind: RefinerKind) -> bool {
        let run = Arc::as_ptr(&self.refiners[Self::slot(kind)]) as *const ();
        kind == RefinerKind::Contour && std::ptr::eq(run, Arc::as_ptr(&self.contour) as *const ())
    }
}

/// Which runs to finish, from each one's (always finished, agreement after the first
/// scale): those always finished, then the best by agreement, `keep` in all (more where
/// more are always finished). Equal agreements go to the earlier, so the choice does not
/// depend on the threads.
fn to_finish(ranks: &[(bool, f64)], keep: usize) -> Vec<bool> {
    let mut order: Vec<usize> = (0..ranks.len()).collect();
    // No agreement (NaN) ranks last.
    let agreement = |i: usize| if ranks[i].1.is_nan() { f64::NEG_INFINITY } else { ranks[i].1 };
    order.sort_by(|&a, &b| ranks[b].0.cmp(&ranks[a].0).then(agreement(b).total_cmp(&agreement(a))).then(a.cmp(&b)));
    let always = ranks.iter().filter(|r| r.0).count();
    let mut chosen = vec![false; ranks.len()];
    for &i in order.iter().take(keep.max(always)) {
        chosen[i] = true;
    }
    chosen
}

#[cfg(test)]
mod tests {
    use super::to_finish;

    #[test]
    fn those_always_finished_come_first_then_the_best_agreements() {
        let ranks = [(false, 0.5), (true, 0.1), (false, 0.9), (false, 0.5), (false, f64::NAN), (false, 0.7)];
        assert_eq!(to_finish(&ranks, 3), [false, true, true, false, false, true]);
        // A tie goes to the earlier.
        assert_eq!(to_finish(&ranks, 4), [true, true, true, false, false, true]);
        // Those always finished are never cut, even beyond `keep`.
        let all_always = [(true, 0.1), (true, 0.2), (false, 0.9)];
        assert_eq!(to_finish(&all_always, 1), [true, true, false]);
        assert_eq!(to_finish(&ranks, 10), [true; 6]);
    }
}
