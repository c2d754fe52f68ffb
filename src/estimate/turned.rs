//! Matching for objects whose in-plane turns share their view's patch rows
//! (`--patch-rows per-view`, `onboard::per_view_rows`): a template of turn `a` holds the
//! rows of the same view unturned, so the query is turned by −a to meet them, cropped as
//! onboarding crops a turned template, and each turn's templates are matched against the
//! query turned for them. Every match keeps its image pixel: the turned crop's patch
//! centres are mapped back through the turn.

use super::correspond::{Correspondences, PatchPool};
use super::matching::{grouped_mutual_matches, MatchGroup};
use super::query::{encode, QueryView};
use crate::features::{mask_bbox, sample_crop, Backbone, CropInput, FeatureError, ToSource};
use crate::geometry::{CropBox, Turn};
use crate::onboard::ObjectModel;
use image::{GrayImage, RgbImage};
use std::collections::BTreeMap;

/// The first and last object pixel of each row of `mask`: the turned extents of the mask
/// are those of these points (a pixel between two others of its row is never extreme).
fn row_ends(mask: &GrayImage) -> Vec<(f64, f64)> {
    let Some((_, v0, _, v1)) = mask_bbox(mask) else { return vec![] };
    let w = mask.width() as usize;
    let raw = mask.as_raw();
    (v0..=v1)
        .filter_map(|v| {
            let row = &raw[v as usize * w..(v as usize + 1) * w];
            let first = row.iter().position(|&m| m > 0)?;
            let last = row.iter().rposition(|&m| m > 0)?;
            Some([(first as f64, v as f64), (last as f64, v as f64)])
        })
        .flatten()
        .collect()
}

/// The query turned by −`angle` about the centre of its unturned crop `query_box`, cropped
/// around the turned mask (whose `row_ends` are `outline`) as onboarding crops a template
/// of turn `angle` (with `padding`, to `size`²), and the turn that maps the crop's image
/// coordinates back to the photo's.
pub fn turned_crop(image: &RgbImage, mask: &GrayImage, outline: &[(f64, f64)], query_box: &CropBox, angle: f64, padding: f64, size: u32) -> Option<(CropInput, CropBox, Turn)> {
    let centre = query_box.to_image((size as f64 - 1.0) * 0.5, (size as f64 - 1.0) * 0.5);
    let turn = Turn::new(-angle, [centre.0, centre.1]);
    let [l, t, r, b] = turn.extents(outline.iter().copied())?;
    let bx = CropBox::around_edges(l - 0.5, t - 0.5, r + 0.5, b + 0.5, padding, size);
    let back = turn.inverse();
    let to_photo = move |u, v| back.apply(u, v);
    Some((sample_crop(image, mask, &bx, ToSource::Map(&to_photo)), bx, back))
}

/// What matching the turned queries produced: one pool of every template's rows (in turn
/// order), the matches into it, and the milliseconds spent encoding the turned queries.
pub struct TurnedMatches {
    pub pool: PatchPool,
    pub correspondences: Correspondences,
    pub encode_ms: f64,
}

/// Matches the patches of `templates` against `query` (turn 0) and the query turned for
/// each other turn among them (encoded here in one batch).
pub fn match_turned(model: &ObjectModel, backbone: &dyn Backbone, image: &RgbImage, mask: &GrayImage, query: &QueryView, templates: &[usize], k_nn: usize) -> Result<TurnedMatches, FeatureError> {
    let mut by_turn: BTreeMap<u32, Vec<usize>> = BTreeMap::new();
    for &t in templates {
        by_turn.entry(model.templates[t].in_plane).or_default().push(t);
    }
    let t0 = std::time::Instant::now();
    let size = model.grid.n * model.grid.patch;
    let turns: Vec<u32> = by_turn.keys().copied().filter(|&r| r != 0).collect();
    let mut crops = Vec::with_capacity(turns.len());
    let mut backs = Vec::with_capacity(turns.len());
    let mut with_crop = Vec::with_capacity(turns.len());
    let outline = row_ends(mask);
    for &r in &turns {
        let angle = model.in_plane_angle(by_turn[&r][0]);
        if let Some((crop, bx, back)) = turned_crop(image, mask, &outline, &query.crop_box, angle, model.config.crop_padding, size) {
            crops.push((crop, bx));
            backs.push(back);
            with_crop.push(r);
        }
    }
    let mut turned: BTreeMap<u32, QueryView> = BTreeMap::new();
    if !crops.is_empty() {
        for ((mut q, back), r) in encode(backbone, crops, model.config.min_coverage)?.into_iter().zip(backs).zip(with_crop) {
            q.turn = Some(back);
            turned.insert(r, q);
        }
    }
    let encode_ms = t0.elapsed().as_secs_f64() * 1e3;

    // Each turn's query and pool; the query rows in the templates' space.
    let mut parts: Vec<(&QueryView, Vec<f32>, Vec<usize>, PatchPool)> = Vec::with_capacity(by_turn.len());
    let mut unmatched = query.foreground.len();
    for (r, group) in &by_turn {
        let q = if *r == 0 { query } else if let Some(q) = turned.get(r) { q } else { continue };
        let patches = if *r == 0 { (0..q.foreground.len()).collect() } else { photo_patches(query, q, &mut unmatched) };
        parts.push((q, model.to_stored_space(&q.descriptors).into_owned(), patches, PatchPool::from_templates(model, group.iter().copied())));
    }
    let groups: Vec<MatchGroup<'_>> = parts.iter().map(|(_, d, p, pool)| MatchGroup { query: d, patches: p, pool: &pool.descriptors }).collect();
    let matches = grouped_mutual_matches(&groups, model.local_dim, k_nn);
    // The groups' pools, joined in order: a match's pool index is its group's offset plus
    // its index there.
    let offsets: Vec<usize> = parts.iter().scan(0, |next, part| Some(std::mem::replace(next, *next + part.3.len()))).collect();
    let mut correspondences = Correspondences::default();
    for (g, m) in matches {
        let (u, v) = parts[g].0.patch_centre(m.query);
        let p = parts[g].3.points[m.pool];
        correspondences.image_points.push([u, v]);
        correspondences.object_points.push([p[0] as f64, p[1] as f64, p[2] as f64]);
        correspondences.similarities.push(m.similarity);
        correspondences.pool_index.push(offsets[g] + m.pool);
    }
    let mut pool = PatchPool { dim: model.local_dim, ..Default::default() };
    for (.., part) in parts {
        pool.append(part);
    }
    Ok(TurnedMatches { pool, correspondences, encode_ms })
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
