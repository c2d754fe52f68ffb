//! A detection confirmed at its estimated pose. The detector's own score is measured at
//! the coarse pose of a template (10–20° and some pixels off), where a true object's
//! outline and print only half line up and a false one's can fit as well. Once the
//! estimator has placed the object, the same evidence (`verify::Window::evidence`) taken
//! at the estimated pose separates them far better (docs/detection.md, "Confirmation"):
//! the right object lines up whole, the wrong one does not, however the estimator turns
//! it. So when a caller asks for poses by object (no detections given), a few more
//! candidates than wanted are estimated, in the detector's order until enough are surely
//! confirmed, and the confirmed ones are kept, best first.

use super::depth_check::depth_agreement;
use super::detector::{bbox_of, best_possible_score, combined_score};
use super::verify::Window;
use super::DetectOptions;
use crate::depth::DepthImage;
use crate::geometry::{Intrinsics, Pose};
use crate::mesh::Mesh;
use crate::render::{RenderError, RenderPool};
use image::{GrayImage, RgbImage};

/// Candidate instances estimated beyond those wanted, so that confirmation can choose.
const EXTRA_CANDIDATES: usize = 3;

/// How many candidate instances are estimated at most for `wanted` instances.
pub fn candidates_tried(wanted: usize) -> usize {
    wanted + EXTRA_CANDIDATES
}

/// The detector's settings for the candidates of a detect-then-estimate request: the
/// caller's, with the threshold below the final one, since confirmation decides (the
/// caller's `min_score` applies to the confirmation, `answer_threshold`).
pub fn candidate_options(caller: &DetectOptions) -> DetectOptions {
    DetectOptions { min_score: CANDIDATE_SHARE * caller.min_score, ..caller.clone() }
}
const CANDIDATE_SHARE: f32 = 0.5;

/// The confirmation score of `mesh` at an estimated `pose`, 0–1 (0 for an empty mask),
/// from the detection `mask` (image-sized) the estimate came from: the detector's evidence
/// in the window around the mask, combined as `combined_score` combines a detection's.
/// With the frame's registered `depth`, that evidence as a share of the most it can be for
/// this mesh (`best_possible_score`), times what the depth says (`depth_check`: the
/// surface there and the segment covered). Both must agree: on real frames without the
/// objects, furniture and crockery of an object's size fit its surface as well as the
/// object does (docs/detection.md, "With depth"), and only the photo's outline tells them
/// apart; the outline alone is what the colour-only path already had.
pub fn confirm(image: &RgbImage, depth: Option<&DepthImage>, k: &Intrinsics, mesh: &Mesh, mask: &GrayImage, pose: &Pose, renderer: &RenderPool) -> Result<f32, RenderError> {
    let photo = match bbox_of(mask).and_then(|bbox| Window::new(image, k, bbox)) {
        Some(window) => combined_score(&window.evidence(renderer, mesh, pose)?),
        None => return Ok(0.0),
    };
    let Some(depth) = depth else { return Ok(photo) };
    let a = depth_agreement(depth, k, mesh, pose, mask, renderer)?;
    let score = a.score() * (photo / best_possible_score(mesh)).min(1.0);
    tracing::debug!(agree = a.agree, seen_through = a.seen_through, occluded = a.occluded, covered = a.covered, depth = a.score(), photo, score, "depth confirmation");
    Ok(score)
}

/// The confirmation score an answer needs for the caller's `min_score`: more than the
/// detector's own threshold, because the estimator fits the pose to the image and the
/// evidence at a fitted pose runs higher for wrong objects too (a pose fitted to clutter
/// lines up better than a template's coarse pose does). Measured with `b2tf bench detect
/// --estimate-store` (docs/detection.md, "The one-call path"): needing 0.55 instead of 0.45
/// at the default `min_score` took the poses answered on images without the objects from
/// 0.92 to 0.33 per image (7 objects asked for in each) and the wrong poses answered in
/// the scenes from 16 to 3, for 7 right answers of 29 instead of 9.
pub fn answer_threshold(min_score: f32) -> f32 {
    (FITTED_POSE_GAIN * min_score).min(1.0)
}
const FITTED_POSE_GAIN: f32 = 0.55 / 0.45;

/// The confirmation score an answer needs for the caller's `min_score`: with the depth
/// detector's candidates (`compared`, confirmed with depth) less than `answer_threshold`,
/// since the depth's agreement already stands between a fitted pose and clutter. Measured
/// on the real frames (`tools/bench/real_rgbd_detect.sh`, docs/detection.md "With depth"):
/// on the ten frames holding none of the objects, the best confirmations of the 70
/// searches were 0.56, then 0.43 and less, so 0.5 answers the same there as 0.55 did (one
/// false pose); on the YCB-V frames it answered two more right poses of the mug (depth
/// agreement 0.94, its plain surface's outline evidence 0.6 of the most it can be) and no
/// wrong one.
pub fn confirmation_needed(min_score: f32, compared: bool) -> f32 {
    if compared {
        (COMPARED_GAIN * min_score).min(1.0)
    } else {
        answer_threshold(min_score)
    }
}
const COMPARED_GAIN: f32 = 0.5 / 0.45;

/// Which estimated instances are answered.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Choice {
    /// The caller's detections: the instances wanted are estimated and all answered.
    Given,
    /// The detector's candidates: a few more than wanted are estimated, in order until
    /// enough are surely confirmed, and those confirmed at `answer_threshold(min_score)`
    /// answered, best first (`min_score`: the caller's).
    Confirmed { min_score: f32 },
    /// The depth detector's candidates (`compared_choice`): up to `limit` are estimated,
    /// in order until the instances wanted are confirmed at `SURE_COMPARED`, and all those
    /// confirmed at `answer_threshold(min_score)` kept, best first, for `one_per_place`.
    Compared { min_score: f32, limit: usize },
}

/// What `estimate_instances` did: the instances answered, with their confirmation scores
/// (`None` unconfirmed: given detections, or no pose), and what was tried.
pub struct Instances<T> {
    pub kept: Vec<(T, Option<f32>)>,
    /// Instances estimated, answered or not.
    pub tried: usize,
    /// The best confirmation score among those tried.
    pub best: Option<f32>,
}

/// Estimates instance groups in order (`estimate` gives its result and, when confirming,
/// the confirmation score at its pose) and chooses which to answer (`Choice`). The one
/// loop every detect-then-estimate path runs: the service, the CLI and `bop run`.
pub fn estimate_instances<G, T, E>(groups: impl IntoIterator<Item = G>, wanted: usize, choice: Choice, mut estimate: impl FnMut(G) -> Result<(T, Option<f32>), E>) -> Result<Instances<T>, E> {
    // How many are estimated at most, how many are kept, and the score that settles.
    let (limit, kept_at_most, sure) = match choice {
        Choice::Given => (wanted, wanted, None),
        Choice::Confirmed { min_score } => (candidates_tried(wanted), wanted, Some(answer_threshold(min_score).max(SURE))),
        Choice::Compared { min_score, limit } => (limit, limit, Some(confirmation_needed(min_score, true).max(SURE_COMPARED))),
    };
    let mut tried: Vec<(T, Option<f32>)> = Vec::new();
    for group in groups.into_iter().take(limit) {
        tried.push(estimate(group)?);
        if sure.is_some_and(|sure| settled(&tried.iter().map(|t| t.1).collect::<Vec<_>>(), wanted, sure)) {
            break;
        }
    }
    let scores: Vec<Option<f32>> = tried.iter().map(|t| t.1).collect();
    let best = scores.iter().flatten().copied().reduce(f32::max);
    let count = tried.len();
    let kept = match choice {
        Choice::Given => tried,
        Choice::Confirmed { min_score } | Choice::Compared { min_score, .. } => {
            let order = chosen(&scores, kept_at_most, confirmation_needed(min_score, matches!(choice, Choice::Compared { .. })));
            let mut slots: Vec<Option<(T, Option<f32>)>> = tried.into_iter().map(Some).collect();
            order.into_iter().filter_map(|i| slots[i].take()).collect()
        }
    };
    Ok(Instances { kept, tried: count, best })
}

/// Which estimated candidates to answer: those confirmed at `min_score` or more, best
/// first, at most `wanted`. `scores[i]` is candidate i's confirmation score (`None`: the
/// estimator found no pose). Returns candidate indices.
fn chosen(scores: &[Option<f32>], wanted: usize, min_score: f32) -> Vec<usize> {
    let mut order: Vec<usize> = (0..scores.len()).filter(|&i| scores[i].is_some_and(|s| s >= min_score)).collect();
    order.sort_by(|&a, &b| scores[b].unwrap_or(0.0).total_cmp(&scores[a].unwrap_or(0.0)).then(a.cmp(&b)));
    order.truncate(wanted);
    order
}

/// A confirmation this high is taken as sure: once the instances wanted have one, the
/// remaining candidates are not estimated. Measured on generated scenes (docs/detection.md,
/// "Confirmation"): the same AR with 42 % fewer estimates, at thresholds 0 and 0.45.
const SURE: f32 = 0.45;

/// With the depth detector's candidates, a confirmation this high is taken as sure. Its
/// candidates are compared rather than taken in order because a wrong object fitted to
/// another's segment confirms up to about 0.67 on the real YCB-V frames, while 24 of the
/// 33 right candidates confirm at 0.7 or more; stopping an object's candidates at its
/// first 0.7 estimated 91 of the 165 candidates there with the same answers (on generated
/// scenes over real frames, 39 % less time for one answer fewer in 32; docs/detection.md,
/// "With depth").
const SURE_COMPARED: f32 = 0.7;

/// Whether the candidates confirmed so far (`scores`, in the order estimated) settle the
/// answer: `wanted` of them at `sure` or more.
fn settled(scores: &[Option<f32>], wanted: usize, sure: f32) -> bool {
    scores.iter().flatten().filter(|&&s| s >= sure).count() >= wanted
}

/// Candidates of one object compared at their estimated poses when the depth detector
/// found them: each of its segments (up to this many, or those wanted) is estimated until
/// one is confirmed at `SURE_COMPARED`, since a segment's size ranks them too weakly to
/// stop at the first confirmed at `SURE` (`one_per_place` then decides).
pub const DEPTH_CANDIDATES_COMPARED: usize = 9;

/// The most candidates of an object with `wanted` instances compared when the depth
/// detector found them (and so the most worth screening).
pub fn compared_at_most(wanted: usize) -> usize {
    DEPTH_CANDIDATES_COMPARED.max(wanted)
}

/// How the candidates of an object with `wanted` instances and `candidates` candidate
/// groups are chosen: with the depth detector's candidates (`compared`) and the caller's
/// `Choice::Confirmed`, all of them up to `DEPTH_CANDIDATES_COMPARED` (and at least those
/// wanted) compared, to be chosen among once every object's are in; else `choice`.
pub fn compared_choice(compared: bool, candidates: usize, wanted: usize, choice: Choice) -> Choice {
    match choice {
        Choice::Confirmed { min_score } if compared => Choice::Compared { min_score, limit: candidates.min(compared_at_most(wanted)) },
        other => other,
    }
}

/// Whether `mask` lies on one of the `taken` places (IoU ≥ 0.5 with its mask). With the
/// depth detector's candidates, a candidate on a place where another object's answer was
/// confirmed at `SURELY_TAKEN` (`sure_places`) is not estimated: a wrong object fitted
/// there confirms lower, so `one_per_place` would give the place to the sure one anyway,
/// and each estimate costs about 0.3 s.
pub fn on_taken_place(mask: &GrayImage, taken: &[GrayImage]) -> bool {
    taken.iter().any(|t| same_place(t, mask))
}

/// Whether two masks are one place: IoU ≥ `SAME_PLACE_IOU`.
pub fn same_place(a: &GrayImage, b: &GrayImage) -> bool {
    crate::masks::mask_iou(a, b) >= SAME_PLACE_IOU
}

/// The masks of an object's answers (each its confirmation and the mask it was estimated
/// from) confirmed at `SURELY_TAKEN` or more, for `on_taken_place`.
pub fn sure_places<'a>(answers: impl IntoIterator<Item = (f32, &'a GrayImage)> + 'a) -> impl Iterator<Item = GrayImage> + 'a {
    answers.into_iter().filter(|a| a.0 >= SURELY_TAKEN).map(|a| a.1.clone())
}

/// A place answered with this confirmation is taken for the other objects. Higher than
/// `SURE_COMPARED`: on the real YCB-V frames wrong objects confirmed at most 0.67, but on
/// generated scenes of bare HOPE meshes a box confirmed 0.83 on the place of another box of
/// like shape, which confirmed higher there (at 0.7 that answer was lost: AR 0.554 → 0.523;
/// at 0.85 none, and the real frames took 70 estimates instead of 78, 29 s instead of 34;
/// docs/detection.md, "With depth").
const SURELY_TAKEN: f32 = 0.85;

/// Two masks this alike (IoU) are one place.
const SAME_PLACE_IOU: f64 = 0.5;

/// Each place answered once across objects: `answers[o]` are object o's confirmed answers
/// (anything, its confirmation score, the detection mask it was estimated from), and at
/// most `wanted[o]` are kept for it. Best score first over all objects, an answer whose
/// mask overlaps (IoU ≥ 0.5) one already kept is dropped: the depth detector offers one
/// segment to every object of its size, and the object that fits it best takes it.
pub fn one_per_place<T>(answers: Vec<Vec<(T, f32, GrayImage)>>, wanted: &[usize]) -> Vec<Vec<(T, f32)>> {
    let mut all: Vec<(usize, T, f32, GrayImage)> = answers.into_iter().enumerate().flat_map(|(o, a)| a.into_iter().map(move |(t, s, m)| (o, t, s, m))).collect();
    all.sort_by(|a, b| b.2.total_cmp(&a.2));
    let mut kept: Vec<Vec<(T, f32)>> = (0..wanted.len()).map(|_| Vec::new()).collect();
    let mut places: Vec<GrayImage> = Vec::new();
    for (o, t, s, m) in all {
        if kept[o].len() < wanted[o] && !on_taken_place(&m, &places) {
            kept[o].push((t, s));
            places.push(m);
        }
    }
    kept
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_best_confirmed_candidates_are_chosen_in_order() {
        let s = [Some(0.3), None, Some(0.8), Some(0.5), Some(0.5), Some(0.1)];
        assert_eq!(chosen(&s, 2, 0.2), vec![2, 3]);
        assert_eq!(chosen(&s, 10, 0.2), vec![2, 3, 4, 0]);
        assert_eq!(chosen(&s, 10, 0.9), Vec::<usize>::new());
        assert_eq!(chosen(&[], 3, 0.0), Vec::<usize>::new());
    }

    #[test]
    fn confirmed_instances_are_estimated_until_settled_and_answered_best_first() {
        let scores = [Some(0.3), None, Some(0.8), Some(0.5), Some(0.9), Some(0.95)];
        let mut calls = 0;
        let out = estimate_instances(0..scores.len(), 1, Choice::Confirmed { min_score: 0.2 }, |i| {
            calls += 1;
            Ok::<_, ()>((i, scores[i]))
        })
        .unwrap();
        // The third candidate settles one instance (0.8 ≥ 0.45): the rest are not estimated.
        assert_eq!(calls, 3);
        assert_eq!(out.tried, 3);
        assert_eq!(out.kept, vec![(2, Some(0.8))]);
        assert_eq!(out.best, Some(0.8));
        // At most `wanted + EXTRA_CANDIDATES` are tried; none confirmed keeps none.
        let out = estimate_instances(0..10, 2, Choice::Confirmed { min_score: 0.6 }, |i| Ok::<_, ()>((i, Some(0.1 * i as f32 / 10.0)))).unwrap();
        assert_eq!((out.tried, out.kept.len()), (2 + EXTRA_CANDIDATES, 0));
    }

    #[test]
    fn answers_need_more_than_the_detectors_threshold_and_never_more_than_one() {
        assert!((answer_threshold(0.45) - 0.55).abs() < 1e-6);
        assert_eq!(answer_threshold(0.0), 0.0);
        assert_eq!(answer_threshold(0.99), 1.0);
        // A candidate confirmed at 0.5 passes the detector's default threshold but is not answered.
        let out = estimate_instances(0..1, 1, Choice::Confirmed { min_score: 0.45 }, |i| Ok::<_, ()>((i, Some(0.5)))).unwrap();
        assert!(out.kept.is_empty() && out.best == Some(0.5));
    }

    #[test]
    fn depth_confirmed_candidates_need_less_and_never_more_than_one() {
        assert!((confirmation_needed(0.45, true) - 0.5).abs() < 1e-6);
        assert_eq!(confirmation_needed(0.45, false), answer_threshold(0.45));
        assert_eq!(confirmation_needed(0.95, true), 1.0);
        // Confirmed at 0.52 with depth: answered, where the colour path's 0.55 is not met.
        let out = estimate_instances(0..1, 1, Choice::Compared { min_score: 0.45, limit: 1 }, |i| Ok::<_, ()>((i, Some(0.52)))).unwrap();
        assert_eq!(out.kept, vec![(0, Some(0.52))]);
    }

    #[test]
    fn given_instances_are_all_answered_in_order_and_errors_stop_the_loop() {
        let out = estimate_instances(0..10, 3, Choice::Given, |i| Ok::<_, ()>((i, None))).unwrap();
        assert_eq!(out.kept, vec![(0, None), (1, None), (2, None)]);
        assert_eq!(out.best, None);
        let err = estimate_instances(0..10, 3, Choice::Given, |i| if i == 1 { Err("broken") } else { Ok((i, None)) });
        assert_eq!(err.err(), Some("broken"));
    }

    #[test]
    fn places_surely_answered_are_taken_for_the_other_objects() {
        let square = |x0: u32| GrayImage::from_fn(20, 10, |x, _| image::Luma([if (x0..x0 + 8).contains(&x) { 255 } else { 0 }]));
        let answers = [("sure", 0.9, square(0)), ("unsure", 0.75, square(10))];
        let taken: Vec<GrayImage> = sure_places(answers.iter().map(|a| (a.1, &a.2))).collect();
        assert_eq!(taken.len(), 1, "only the answer confirmed at 0.85 or more");
        let shifted = GrayImage::from_fn(20, 10, |x, _| image::Luma([if (1..9).contains(&x) { 255 } else { 0 }]));
        assert!(on_taken_place(&shifted, &taken), "IoU 7/9 with the sure place");
        assert!(!on_taken_place(&square(10), &taken), "the unsure answer's place stays open");
    }

    #[test]
    fn each_place_goes_to_the_object_confirmed_best_there() {
        let place = |x: u32| {
            let mut m = GrayImage::new(4, 1);
            m.put_pixel(x, 0, image::Luma([255]));
            m
        };
        // Object 0 fits place 0 at 0.8 and place 1 at 0.6; object 1 fits place 0 at 0.9.
        let answers = vec![vec![("a0", 0.8, place(0)), ("a1", 0.6, place(1))], vec![("b0", 0.9, place(0))]];
        let kept = one_per_place(answers, &[1, 1]);
        assert_eq!(kept, vec![vec![("a1", 0.6)], vec![("b0", 0.9)]]);
        // With depth every candidate (up to the cap, or those wanted) is compared; else the choice stands.
        let confirmed = Choice::Confirmed { min_score: 0.45 };
        let limit = |c: Choice| match c {
            Choice::Compared { limit, .. } => Some(limit),
            _ => None,
        };
        assert_eq!(
            (limit(compared_choice(true, 3, 1, confirmed)), limit(compared_choice(true, 40, 1, confirmed)), limit(compared_choice(true, 40, 12, confirmed))),
            (Some(3), Some(DEPTH_CANDIDATES_COMPARED), Some(12))
        );
        assert_eq!(compared_choice(false, 40, 1, confirmed), confirmed);
        assert_eq!(compared_choice(true, 40, 1, Choice::Given), Choice::Given);
        // An object answers no more instances than wanted, even on free places.
        let kept = one_per_place(vec![vec![("a0", 0.8, place(0)), ("a1", 0.6, place(1))]], &[1]);
        assert_eq!(kept, vec![vec![("a0", 0.8)]]);
    }

    #[test]
    fn candidates_stop_once_enough_are_surely_confirmed() {
        assert!(!settled(&[Some(0.3), None], 1, SURE));
        assert!(settled(&[Some(0.3), Some(0.5)], 1, SURE));
        assert!(!settled(&[Some(0.5)], 2, SURE));
        assert!(!settled(&[Some(0.5)], 1, 0.6));
        assert!(settled(&[Some(0.7), Some(0.65)], 2, 0.6));
    }

    #[test]
    fn compared_candidates_are_all_kept_and_stop_at_a_sure_one() {
        // Up to the limit, each confirmed one kept best first; a 0.8 settles the one wanted.
        let scores = [Some(0.6), Some(0.2), Some(0.8), Some(0.9)];
        let mut calls = 0;
        let out = estimate_instances(0..scores.len(), 1, Choice::Compared { min_score: 0.45, limit: 4 }, |i| {
            calls += 1;
            Ok::<_, ()>((i, scores[i]))
        })
        .unwrap();
        assert_eq!((calls, out.kept), (3, vec![(2, Some(0.8)), (0, Some(0.6))]));
        // Without a sure one every candidate up to the limit is estimated.
        let out = estimate_instances(0..10, 1, Choice::Compared { min_score: 0.45, limit: 5 }, |i| Ok::<_, ()>((i, Some(0.6)))).unwrap();
        assert_eq!((out.tried, out.kept.len()), (5, 5));
    }
}
