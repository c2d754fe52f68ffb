//! Verification's cut after the first line scale: every hypothesis is refined on the
//! coarsest correspondence lines, and only those whose outline then agrees best with the
//! mask (and the ones always judged) go through the finer scales, where most of the
//! refiner's time goes.

use super::{EstimateConfig, Estimator, RefineContext, Verified};
use crate::estimate::contour::{Begun, CoarseRun};
use crate::estimate::hypotheses::Source;
use crate::estimate::refine::{Refined, RefinerKind};
use crate::estimate::verify::always_and_best;
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
        let begun: Vec<(Source, Begun<'_>)> = candidates.par_iter().filter_map(|&(source, p)| Some((source, self.contour.begin(ctx, p).ok()?))).collect();
        let mut done: Vec<(Source, Refined)> = Vec::new();
        let mut running: Vec<(Source, CoarseRun<'_>)> = Vec::new();
        for (source, b) in begun {
            match b {
                Begun::Done(r) => done.push((source, r)),
                Begun::Coarse(run) => running.push((source, run)),
            }
        }
        let agreements: Vec<f64> = running.iter().map(|(_, run)| run.coarse_agreement).collect();
        let chosen = always_and_best(&agreements, |i| always(running[i].0), keep);
        let running: Vec<(Source, CoarseRun<'_>)> = running.into_iter().zip(chosen).filter_map(|(r, c)| c.then_some(r)).collect();
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
