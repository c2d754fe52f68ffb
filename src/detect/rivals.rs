//! One place's candidates of several objects, compared before any is estimated. The depth
//! detector offers each surface of an object's size to every object of that size, so with
//! several objects searched most estimates are of an object on another's place (on the real
//! YCB-V frames with 8 objects searched, a third of all estimate time). Screened in full
//! (`Estimator::screen_scores`: the best of three retrieved templates placed at the segment
//! and fitted to the depth, confirmed there), the object that is there scores highest on its
//! place or near it, so a candidate scoring well below another object's on the same place
//! is not estimated (docs/detection.md, "Rivals on one place").

use super::confirm::same_place;
use crate::features::mask_bbox;
use image::GrayImage;

/// A candidate scoring less than this share of another object's candidate on the same place
/// is outranked. Measured (docs/detection.md, "Rivals on one place"): of the candidates
/// later answered right, the lowest share was 0.73 on the real YCB-V frames (8 objects
/// searched) and 0.64 on generated scenes of bare HOPE meshes over real frames; at 0.5 the
/// real frames' wrong candidates estimated fell from 115 to 54.
pub const RIVAL_SHARE: f32 = 0.5;

/// One candidate: its object (any key that tells objects apart), its place (the mask it is
/// estimated from, image-sized) and its screen score.
pub struct Rival<'a> {
    pub object: usize,
    pub place: &'a GrayImage,
    pub score: f32,
}

/// One instance's candidate masks (indices into its object's detections) and, where they
/// were screened, their scores (`Estimator::screen_scores`).
pub struct Screened {
    pub group: Vec<usize>,
    pub scores: Option<Vec<f32>>,
}

impl Screened {
    /// Its best mask's score (`None` unscreened).
    pub fn best(&self) -> Option<f32> {
        self.scores.as_deref().map(best_score)
    }
}

/// A candidate's screen score: the best of its masks' scores (0 for none).
pub fn best_score(scores: &[f32]) -> f32 {
    scores.iter().copied().fold(0.0, f32::max)
}

/// Drops the screened candidates that another object's outrank on their place (`outranked`);
/// `objects[o]` are object o's, `place(o, group)` a group's mask. Unscreened ones stay and
/// outrank none.
pub fn drop_outranked<'a>(objects: &mut [Vec<Screened>], place: impl Fn(usize, &[usize]) -> &'a GrayImage) {
    let mut rivals = Vec::new();
    for (o, candidates) in objects.iter().enumerate() {
        rivals.extend(candidates.iter().filter_map(|c| Some(Rival { object: o, place: place(o, &c.group), score: c.best()? })));
    }
    let mut out = outranked(&rivals).into_iter();
    for candidates in objects.iter_mut() {
        candidates.retain(|c| c.scores.is_none() || !out.next().unwrap_or(false));
    }
}

/// For each candidate, whether another object's candidate on the same place
/// (`confirm::same_place`) scores more than `1 / RIVAL_SHARE` times as much.
pub fn outranked(candidates: &[Rival<'_>]) -> Vec<bool> {
    let boxes: Vec<Option<(u32, u32, u32, u32)>> = candidates.iter().map(|c| mask_bbox(c.place)).collect();
    // Masks whose boxes do not meet share no pixel: most pairs of a frame.
    let meet = |a: usize, b: usize| boxes_meet(boxes[a], boxes[b]);
    (0..candidates.len())
        .map(|i| {
            let c = &candidates[i];
            (0..candidates.len()).any(|j| {
                let r = &candidates[j];
                r.object != c.object && c.score < RIVAL_SHARE * r.score && meet(i, j) && same_place(c.place, r.place)
            })
        })
        .collect()
}

/// Whether two masks' boxes (`mask_bbox`) meet: masks whose boxes do not meet share no pixel.
pub fn boxes_meet(a: Option<(u32, u32, u32, u32)>, b: Option<(u32, u32, u32, u32)>) -> bool {
    match (a, b) {
        (Some(p), Some(q)) => p.0 <= q.2 && q.0 <= p.2 && p.1 <= q.3 && q.1 <= p.3,
        _ => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(x0: u32, side: u32) -> GrayImage {
        GrayImage::from_fn(64, 32, |x, y| image::Luma([u8::from(x >= x0 && x < x0 + side && y < side)]))
    }

    #[test]
    fn a_candidate_far_below_another_object_s_on_its_place_is_outranked() {
        let (left, right, nudged) = (square(0, 20), square(40, 20), square(2, 20));
        let c = |object, place, score| Rival { object, place, score };
        let out = outranked(&[c(0, &left, 0.8), c(1, &nudged, 0.3), c(2, &left, 0.45), c(1, &right, 0.1), c(0, &left, 0.3)]);
        // Object 1 at 0.3 < 0.5 × 0.8 on (nearly) the same place: out. Object 2 at 0.45 is
        // above half of 0.8: kept. Object 1 alone on the right square: kept however low.
        // Object 0's second candidate there, below half its first, is not its own rival
        // (and above half of the others'): kept.
        assert_eq!(out, [false, true, false, false, false]);
        // An empty mask has no place.
        let empty = GrayImage::new(64, 32);
        assert_eq!(outranked(&[c(0, &empty, 0.9), c(1, &empty, 0.1)]), [false, false]);
    }

    #[test]
    fn outranked_candidates_are_dropped_and_unscreened_ones_kept() {
        let places = [square(0, 20), square(1, 20), square(40, 20)];
        let c = |place: usize, scores: Option<Vec<f32>>| Screened { group: vec![place], scores };
        // Object 0: place 0 at 0.8 (its best mask), place 2 at 0.1. Object 1: place 1 (on
        // place 0) at 0.3, and an unscreened candidate there.
        let mut objects = vec![vec![c(0, Some(vec![0.2, 0.8])), c(2, Some(vec![0.1]))], vec![c(1, Some(vec![0.3])), c(1, None)]];
        drop_outranked(&mut objects, |_, g| &places[g[0]]);
        let left: Vec<Vec<usize>> = objects.iter().map(|o| o.iter().map(|c| c.group[0]).collect()).collect();
        assert_eq!(left, [vec![0, 2], vec![1]]);
        assert!(objects[1][0].scores.is_none());
    }
}
