//! Matching the query against templates, including objects whose in-plane turns share their view's patch rows
//! (`--patch-rows per-view`, `onboard::per_view_rows`): a template of turn `a` holds the
//! rows of the same view unturned, so the query is turned by −a to meet them, cropped as
//! onboarding crops a turned template, and each turn's templates are matched against the
//! query turned for them. Every match keeps its image pixel: the turned crop's patch
//! centres are mapped back through the turn.

use super::correspond::{Correspondences, PatchPool};
use super::matching::{grouped_mutual_matches, MatchGroup};
use super::query::{encode_with, QueryView, Silhouettes};
use crate::features::{mask_row_ends, sample_crop, Backbone, CropInput, FeatureError, ToSource};
use crate::geometry::{CropBox, Turn};
use crate::onboard::ObjectModel;
use image::{GrayImage, RgbImage};
use rayon::prelude::*;
use std::collections::BTreeMap;

/// The query turned by −`angle` about the centre of its unturned crop `query_box`, cropped
/// around the turned mask (whose `mask_row_ends` are `outline`) as onboarding crops a template
/// of turn `angle` (with `padding`, to `size`²), and the turn that maps the crop's image
/// coordinates back to the photo's.
pub fn turned_crop(image: &RgbImage, mask: &GrayImage, outline: &[(f64, f64)], query_box: &CropBox, angle: f64, padding: f64, size: u32) -> Option<(CropInput, CropBox, Turn)> {
    let middle = (query_box.size as f64 - 1.0) * 0.5;
    let centre = query_box.to_image(middle, middle);
    let turn = Turn::new(-angle, [centre.0, centre.1]);
    let [l, t, r, b] = turn.extents(outline.iter().copied())?;
    let bx = CropBox::around_edges(l - 0.5, t - 0.5, r + 0.5, b + 0.5, padding, size);
    let back = turn.inverse();
    Some((sample_crop(image, mask, &bx, ToSource::Turned(back)), bx, back))
}

/// What matching produced: where each row of one pool of every template's rows (in turn
/// order) came from, the matches into that pool, and the milliseconds spent encoding the
/// turned queries.
pub struct TurnedMatches {
    /// Per pool row, its template and cell (`PatchPool::origins`): all that is asked of the
    /// pool after matching, so its descriptors (megabytes) are not joined.
    pub origins: Vec<(u32, u16)>,
    pub correspondences: Correspondences,
    pub encode_ms: f64,
}

/// Matches the patches of `templates` against the query: the photo's own (`query`) for
/// templates with rows of their own, and where rows are shared per view, the query turned
/// for each other turn among them (encoded here in one batch). With one group this is
/// `correspond` (`matching::grouped_mutual_matches` of one group is `mutual_matches`).
pub fn match_templates(model: &ObjectModel, backbone: &dyn Backbone, image: &RgbImage, mask: &GrayImage, query: &QueryView, templates: &[usize], k_nn: usize) -> Result<TurnedMatches, FeatureError> {
    // The turn each template's rows need the query turned by.
    let mut by_turn: BTreeMap<u32, Vec<usize>> = BTreeMap::new();
    for &t in templates {
        by_turn.entry(if model.rows_per_view() { model.templates[t].in_plane } else { 0 }).or_default().push(t);
    }
    let t0 = std::time::Instant::now();
    // Turned queries at the backbone's reduced size where it has one: a query is encoded
    // once per turn (up to 11 times), and the photo seldom holds more detail than the
    // smaller crop keeps (docs/store.md, "Patch rows per view").
    let size = backbone.reduced_input_size().unwrap_or(model.grid.n * model.grid.patch);
    let outline = if by_turn.keys().any(|&r| r != 0) { mask_row_ends(mask) } else { vec![] };
    // The turns' crops side by side: each is small enough at the reduced size that its own
    // split into bands of rows leaves the cores idle between them.
    let turns: Vec<(u32, f64)> = by_turn.iter().filter(|(&r, _)| r != 0).map(|(&r, group)| (r, model.in_plane_angle(group[0]))).collect();
    let made: Vec<_> = turns
        .par_iter()
        .filter_map(|&(r, angle)| turned_crop(image, mask, &outline, &query.crop_box, angle, model.config.crop_padding, size).map(|(crop, bx, back)| ((crop, bx), (r, back))))
        .collect();
    let (crops, backs): (Vec<_>, Vec<_>) = made.into_iter().unzip();
    let mut turned: BTreeMap<u32, QueryView> = BTreeMap::new();
    if !crops.is_empty() {
        for (mut q, (r, back)) in encode_with(backbone, crops, model.config.min_coverage, Silhouettes::Skipped)?.into_iter().zip(backs) {
            q.turn = Some(back);
            turned.insert(r, q);
        }
    }
    let encode_ms = t0.elapsed().as_secs_f64() * 1e3;

    let mut parts: Vec<Part<'_>> = Vec::with_capacity(by_turn.len());
    let mut unmatched = query.foreground.len();
    for (r, group) in &by_turn {
        let q = if *r == 0 {
            query
        } else if let Some(q) = turned.get(r) {
            q
        } else {
            continue;
        };
        let patches = if *r == 0 { (0..q.foreground.len()).collect() } else { photo_patches(query, q, &mut unmatched) };
        parts.push(Part { query: q, descriptors: model.to_stored_space(&q.descriptors), patches, pool: PatchPool::from_templates(model, group.iter().copied()) });
    }
    let groups: Vec<MatchGroup<'_>> = parts.iter().map(|p| MatchGroup { query: &p.descriptors, patches: &p.patches, pool: &p.pool.descriptors }).collect();
    let matches = grouped_mutual_matches(&groups, model.local_dim, k_nn);
    // The groups' pools, joined in order: a match's pool index is its group's offset plus
    // its index there.
    let offsets: Vec<usize> = parts.iter().scan(0, |next, part| Some(std::mem::replace(next, *next + part.pool.len()))).collect();
    let mut correspondences = Correspondences::default();
    for (g, m) in matches {
        let part = &parts[g];
        correspondences.push(part.query.patch_centre(m.query), part.pool.points[m.pool], m.similarity, offsets[g] + m.pool);
    }
    let origins = parts.iter().flat_map(|part| part.pool.origins.iter().copied()).collect();
    Ok(TurnedMatches { origins, correspondences, encode_ms })
}

/// One turn's share of the matching: its query, the query's rows in the templates' space
/// (PCA-projected where the object is), the photo patch each row stands for, and the pool
/// of that turn's templates.
struct Part<'a> {
    query: &'a QueryView,
    descriptors: std::borrow::Cow<'a, [f32]>,
    patches: Vec<usize>,
    pool: PatchPool,
}

/// For each foreground patch of the turned query `turned`, the foreground patch of the
/// photo's own query that its centre falls in, so that the two compete as one patch; a
/// centre outside the photo query's foreground gets a number of its own (from `unmatched`).
fn photo_patches(query: &QueryView, turned: &QueryView, unmatched: &mut usize) -> Vec<usize> {
    let grid = query.features.grid;
    let mut index = vec![usize::MAX; grid.len()];
    for (i, &cell) in query.foreground.iter().enumerate() {
        index[cell] = i;
    }
    (0..turned.foreground.len())
        .map(|m| {
            let (u, v) = turned.patch_centre(m);
            let (cu, cv) = query.crop_box.to_crop(u, v);
            let found = grid.patch_at(cu, cv).map(|(i, j)| index[(i * grid.n + j) as usize]).filter(|&i| i != usize::MAX);
            found.unwrap_or_else(|| {
                *unmatched += 1;
                *unmatched - 1
            })
        })
        .collect()
}
