//! Templates placed by their matches: hypotheses that survive occlusion.
//!
//! A template placed at the mask (`hypotheses::place_template`) takes its position and
//! depth from the mask's box, which is the whole object's box only when the object is
//! whole. When something hides half of it, the box is half the object's, and the placed
//! template is too far away and off-centre. The matches do not have that problem: each
//! ties a query patch to a patch of one template, wherever the visible part is. So the
//! templates that collect the most matches are fitted to them (a scale and a shift from
//! the template's crop to the image, robust to the wrong ones) and placed where that fit
//! puts them.

use super::correspond::Correspondences;
use super::hypotheses::place_in;
use crate::geometry::{Intrinsics, Pose, ScaleShift};
use crate::onboard::ObjectModel;

/// The least-squares fit of `to ≈ s·from + t` over the pairs `idx`; `None` when the
/// `from` points coincide. No rotation: the templates hold the in-plane rotations already.
fn least_squares(from: &[[f64; 2]], to: &[[f64; 2]], idx: &[usize]) -> Option<ScaleShift> {
    let n = idx.len() as f64;
    let mean = |pts: &[[f64; 2]]| idx.iter().fold([0.0; 2], |m, &i| [m[0] + pts[i][0] / n, m[1] + pts[i][1] / n]);
    let (mf, mt) = (mean(from), mean(to));
    let (mut num, mut den) = (0.0, 0.0);
    for &i in idx {
        let (dx, dy) = ([from[i][0] - mf[0], from[i][1] - mf[1]], [to[i][0] - mt[0], to[i][1] - mt[1]]);
        num += dx[0] * dy[0] + dx[1] * dy[1];
        den += dx[0] * dx[0] + dx[1] * dx[1];
    }
    (den > 1e-12).then(|| {
        let scale = num / den;
        ScaleShift { scale, shift: [mt[0] - scale * mf[0], mt[1] - scale * mf[1]] }
    })
}

/// Robust fit of `to ≈ s·from + t`: every pair of pairs (at most `MAX_TRIALS`, spread
/// evenly) proposes a fit with its scale within `scales`, the one with the most pairs
/// within `tolerance` wins and is refitted on those. Deterministic. Returns the fit and
/// its inliers; `None` below 3 inliers.
pub fn fit_scale_shift(from: &[[f64; 2]], to: &[[f64; 2]], tolerance: f64, scales: (f64, f64)) -> Option<(ScaleShift, Vec<usize>)> {
    const MAX_TRIALS: usize = 400;
    let n = from.len().min(to.len());
    if n < 3 {
        return None;
    }
    let pairs = n * (n - 1) / 2;
    let stride = pairs.div_ceil(MAX_TRIALS).max(1);
    let inliers_of = |f: &ScaleShift| -> Vec<usize> {
        (0..n)
            .filter(|&i| {
                let p = f.apply(from[i]);
                (p[0] - to[i][0]).hypot(p[1] - to[i][1]) <= tolerance
            })
            .collect()
    };
    let mut best: Option<(ScaleShift, Vec<usize>)> = None;
    let mut k = 0usize;
    for a in 0..n {
        for b in a + 1..n {
            k += 1;
            if !(k - 1).is_multiple_of(stride) {
                continue;
            }
            let Some(f) = least_squares(from, to, &[a, b]) else { continue };
            if !(scales.0..=scales.1).contains(&f.scale) {
                continue;
            }
            let inl = inliers_of(&f);
            if best.as_ref().is_none_or(|(_, b)| inl.len() > b.len()) {
                best = Some((f, inl));
            }
        }
    }
    let (_, inl) = best?;
    let refit = least_squares(from, to, &inl)?;
    let inl = inliers_of(&refit);
    (inl.len() >= 3 && (scales.0..=scales.1).contains(&refit.scale)).then_some((refit, inl))
}

/// One template's matches: the crop pixel of each matched patch in the template's crop,
/// and the image pixel of the query patch it matched.
#[derive(Default)]
struct TemplateMatches {
    crop: Vec<[f64; 2]>,
    image: Vec<[f64; 2]>,
}

/// Up to `count` poses: the templates with the most matches in `corr` (at least
/// `MIN_MATCHES`), each placed where the robust fit of its matches puts it. Best first.
/// `origins` are the template and cell of each row of the pool `corr` matched
/// (`PatchPool::origins`); none where the pool was not made of templates.
pub fn matched_templates(model: &ObjectModel, corr: &Correspondences, origins: &[(u32, u16)], query_scale: f64, k: &Intrinsics, count: usize) -> Vec<Pose> {
    const MIN_MATCHES: usize = 4;
    if count == 0 || corr.pool_index.iter().any(|&j| j >= origins.len()) {
        return vec![];
    }
    let mut by_template: std::collections::BTreeMap<u32, TemplateMatches> = Default::default();
    for (m, &j) in corr.pool_index.iter().enumerate() {
        let (t, cell) = origins[j];
        let (cu, cv) = model.patch_centre_in_template(t as usize, cell);
        let e = by_template.entry(t).or_default();
        e.crop.push([cu, cv]);
        e.image.push(corr.image_points[m]);
    }
    let mut ranked: Vec<(u32, TemplateMatches)> = by_template.into_iter().filter(|(_, m)| m.crop.len() >= MIN_MATCHES).collect();
    // Most matches first; ties by template index, so the order does not depend on hashing.
    ranked.sort_by(|a, b| b.1.crop.len().cmp(&a.1.crop.len()).then(a.0.cmp(&b.0)));
    // A match may be off by a patch and a half; the query's scale (image pixels per crop
    // pixel) measures a patch. The object may be up to 5× the visible part's box, or a
    // fifth of it where the mask is loose.
    let tolerance = 1.5 * model.grid.patch as f64 * query_scale;
    let scales = (query_scale / 5.0, query_scale * 5.0);
    ranked
        .iter()
        .filter_map(|(t, m)| {
            let (fit, _) = fit_scale_shift(&m.crop, &m.image, tolerance, scales)?;
            place_in(model, *t as usize, &fit, k)
        })
        .take(count)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::correspond::PatchPool;

    /// The fit finds the scale and shift behind most pairs and ignores the rest.
    #[test]
    fn robust_fit_ignores_wrong_pairs() {
        let truth = ScaleShift { scale: 1.7, shift: [120.0, -35.0] };
        let mut from: Vec<[f64; 2]> = (0..12).map(|i| [(i % 4) as f64 * 16.0 + 7.5, (i / 4) as f64 * 16.0 + 7.5]).collect();
        let mut to: Vec<[f64; 2]> = from.iter().map(|&p| truth.apply(p)).collect();
        // Four wrong matches, far from where the fit puts them.
        for (i, p) in [[300.0, 10.0], [5.0, 400.0], [77.0, 77.0], [250.0, 250.0]].into_iter().enumerate() {
            from.push([i as f64 * 30.0, 100.0]);
            to.push(p);
        }
        let (fit, inliers) = fit_scale_shift(&from, &to, 4.0, (0.2, 5.0)).unwrap();
        assert_eq!(inliers, (0..12).collect::<Vec<_>>());
        assert!((fit.scale - truth.scale).abs() < 1e-9 && (fit.shift[0] - truth.shift[0]).abs() < 1e-9 && (fit.shift[1] - truth.shift[1]).abs() < 1e-9, "{fit:?}");
    }

    /// Too few pairs, coincident points or a scale outside the allowed range give no fit.
    #[test]
    fn no_fit_without_support() {
        assert!(fit_scale_shift(&[[0.0, 0.0], [1.0, 1.0]], &[[0.0, 0.0], [2.0, 2.0]], 1.0, (0.1, 10.0)).is_none());
        let same = [[3.0, 3.0]; 5];
        assert!(fit_scale_shift(&same, &same, 1.0, (0.1, 10.0)).is_none());
        let from = [[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0]];
        let to: Vec<[f64; 2]> = from.iter().map(|p| [p[0] * 8.0, p[1] * 8.0]).collect();
        assert!(fit_scale_shift(&from, &to, 1.0, (0.2, 5.0)).is_none(), "scale 8 is out of range");
        assert_eq!(fit_scale_shift(&from, &to, 1.0, (0.2, 10.0)).unwrap().1.len(), 4);
    }

    /// A template seen in its own render, but with only a corner of it matched (the rest
    /// hidden): placing it by its matches gives back the template's own pose, where the
    /// box of the visible corner would put it far too far away.
    #[test]
    fn a_partly_hidden_template_is_placed_by_its_matches() {
        let Some(model) = crate::onboard::test_model::small_model() else { return };
        let (t, other) = (5, 17);
        let pool = PatchPool::from_templates(model, [other, t]);
        let tp = &model.templates[t];
        let mut corr = Correspondences::default();
        for (j, &(owner, cell)) in pool.origins.iter().enumerate() {
            let (cu, cv) = model.grid.centre_of(cell as usize);
            // Template `t`'s patches in the crop's left third and top rows only; fewer of
            // another template's, so that `t` has the most matches.
            let keep = if owner as usize == t { cu < model.grid.patch as f64 * model.grid.n as f64 / 3.0 + 8.0 || cv < 40.0 } else { j % 7 == 0 };
            if keep {
                let (u, v) = tp.crop.to_image(cu, cv);
                corr.image_points.push([u, v]);
                corr.pool_index.push(j);
            }
        }
        let k = model.render_intrinsics;
        let placed = matched_templates(model, &corr, &pool.origins, tp.crop.scale(), &k, 1);
        assert_eq!(placed.len(), 1);
        let p = placed[0];
        let turn = crate::geometry::geodesic_distance(&p.rotation, &tp.pose.rotation).to_degrees();
        let shift = (p.translation - tp.pose.translation).norm() / model.diameter();
        assert!(turn < 0.5 && shift < 0.01, "off by {turn:.2}° and {shift:.3}·d");
        assert_eq!(matched_templates(model, &corr, &pool.origins, tp.crop.scale(), &k, 0).len(), 0);
    }
}
