//! COCO detection Average Precision as pycocotools' `COCOeval` computes it (cocoapi
//! `PythonAPI/pycocotools/cocoeval.py`: `evaluateImg`, `accumulate`, `summarize`), in the
//! form the BOP toolkit installs (`MartinSmeyer/cocoapi`, which keeps a ground truth's
//! `ignore` flag where upstream overwrites it with `iscrowd`). Restated from that source:
//!
//! * per image and category, detections best first (stable on equal scores), at most 100;
//!   ground truth to ignore sorted last;
//! * at each IoU threshold 0.50:0.05:0.95, each detection takes the unmatched ground truth
//!   with the highest IoU ≥ the threshold (the last of equals), preferring any regular one
//!   to an ignored one; matched to an ignored one, the detection is ignored too, and an
//!   unmatched detection whose area is outside the area range is ignored;
//! * per category, the detections of all images pooled by score: precision made
//!   non-increasing from the right, read at the first detection reaching each of the 101
//!   recall levels 0:0.01:1 (0 beyond the last recall); recall is the final one;
//! * a category with no ground truth to count has no value (−1) and is left out of the
//!   means; AP averages over thresholds, recall levels and categories.
//!
//! Nothing here knows about BOP: the caller gives areas, ignore flags and IoUs.

use serde::Serialize;
use std::collections::BTreeMap;

pub const N_IOU: usize = 10;
pub const N_RECALL: usize = 101;
/// COCO's `maxDets`: AR1, AR10, and everything else at 100.
pub const MAX_DETS: [usize; 3] = [1, 10, 100];
/// pycocotools' way of saying "no value".
pub const ABSENT: f64 = -1.0;

/// `numpy.linspace(.5, .95, 10)`: start + i · step with step = (stop − start) / 9, the last
/// set to stop. That makes the 0.90 threshold 0.8999999999999999; reproduced as computed
/// because an IoU exactly at a threshold matches (`>=`).
pub fn iou_thresholds() -> [f64; N_IOU] {
    let step = (0.95 - 0.5) / (N_IOU - 1) as f64;
    let mut t = std::array::from_fn(|i| 0.5 + i as f64 * step);
    t[N_IOU - 1] = 0.95;
    t
}

/// `numpy.linspace(0, 1, 101)`: i · 0.01 (0.35 is 0.35000000000000003), the last 1.
pub fn recall_thresholds() -> [f64; N_RECALL] {
    let mut r = std::array::from_fn(|i| i as f64 * 0.01);
    r[N_RECALL - 1] = 1.0;
    r
}

/// COCO's area ranges in pixels (bounds included); `All` is `[0, 1e5²]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AreaRange {
    All,
    Small,
    Medium,
    Large,
}

impl AreaRange {
    pub const EVERY: [AreaRange; 4] = [AreaRange::All, AreaRange::Small, AreaRange::Medium, AreaRange::Large];

    fn bounds(self) -> (f64, f64) {
        match self {
            AreaRange::All => (0.0, 1e10),
            AreaRange::Small => (0.0, 32.0 * 32.0),
            AreaRange::Medium => (32.0 * 32.0, 96.0 * 96.0),
            AreaRange::Large => (96.0 * 96.0, 1e10),
        }
    }

    fn excludes(self, area: f64) -> bool {
        let (lo, hi) = self.bounds();
        area < lo || area > hi
    }
}

/// A ground-truth instance: its area (for the area ranges) and whether to ignore it
/// (neither a miss when undetected, nor a false positive's cause when detected).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gt {
    pub area: f64,
    pub ignore: bool,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dt {
    pub score: f64,
    pub area: f64,
}

/// One image's ground truth and detections of one category, with their IoUs.
#[derive(Clone, Debug)]
pub struct ImageCategory {
    gts: Vec<Gt>,
    dts: Vec<Dt>,
    /// `ious[d * gts.len() + g]`, `d` in the kept (sorted) order.
    ious: Vec<f64>,
}

impl ImageCategory {
    /// `iou(d, g)` takes indices into the lists as given. As COCOeval does before computing
    /// IoUs, detections are put best first (equal scores keep their order) and only the
    /// best `MAX_DETS[2]` are kept; `iou` is asked only about those.
    pub fn new(gts: Vec<Gt>, dts: Vec<Dt>, mut iou: impl FnMut(usize, usize) -> f64) -> Self {
        let mut order: Vec<usize> = (0..dts.len()).collect();
        order.sort_by(|&a, &b| dts[b].score.total_cmp(&dts[a].score));
        order.truncate(MAX_DETS[2]);
        let ious = order.iter().flat_map(|&d| (0..gts.len()).map(move |g| (d, g))).map(|(d, g)| iou(d, g)).collect();
        ImageCategory { dts: order.iter().map(|&d| dts[d]).collect(), gts, ious }
    }
}

/// What matching one image and category at one area range gives (`evaluateImg`).
struct ImageEval {
    /// Best first.
    scores: Vec<f64>,
    /// `[threshold][detection]`.
    matched: Vec<Vec<bool>>,
    ignored: Vec<Vec<bool>>,
    /// Ground truth that counts (not ignored, area in range).
    counted_gts: usize,
}

fn evaluate_image(ic: &ImageCategory, range: AreaRange) -> ImageEval {
    let ignore: Vec<bool> = ic.gts.iter().map(|g| g.ignore || range.excludes(g.area)).collect();
    // Regular ground truth first, so that the scan can stop at the first ignored one
    // once a regular match is in hand.
    let mut gt_order: Vec<usize> = (0..ic.gts.len()).collect();
    gt_order.sort_by_key(|&g| ignore[g]);
    let n_gt = ic.gts.len();
    let mut matched = vec![vec![false; ic.dts.len()]; N_IOU];
    let mut ignored = vec![vec![false; ic.dts.len()]; N_IOU];
    for (t, thr) in iou_thresholds().into_iter().enumerate() {
        let mut gt_taken = vec![false; n_gt];
        for d in 0..ic.dts.len() {
            let mut best = thr.min(1.0 - 1e-10);
            let mut m: Option<usize> = None;
            for &g in &gt_order {
                if gt_taken[g] {
                    continue;
                }
                if m.is_some_and(|m| !ignore[m]) && ignore[g] {
                    break;
                }
                let iou = ic.ious[d * n_gt + g];
                if iou < best {
                    continue;
                }
                best = iou;
                m = Some(g);
            }
            if let Some(g) = m {
                gt_taken[g] = true;
                matched[t][d] = true;
                ignored[t][d] = ignore[g];
            }
        }
        for (d, dt) in ic.dts.iter().enumerate() {
            if !matched[t][d] && range.excludes(dt.area) {
                ignored[t][d] = true;
            }
        }
    }
    ImageEval { scores: ic.dts.iter().map(|d| d.score).collect(), matched, ignored, counted_gts: ignore.iter().filter(|&&i| !i).count() }
}

/// One category's precision at each (threshold, recall level) and final recall per
/// threshold; `None` when there is no ground truth to count.
struct Curves {
    precision: Vec<[f64; N_RECALL]>,
    recall: [f64; N_IOU],
}

fn accumulate(evals: &[ImageEval], max_det: usize) -> Option<Curves> {
    let n_pos: usize = evals.iter().map(|e| e.counted_gts).sum();
    if n_pos == 0 {
        return None;
    }
    // (image, detection) pooled over images in image order, then best first; the sort is
    // stable, as numpy's mergesort, so equal scores keep that order.
    let mut pooled: Vec<(usize, usize)> = evals.iter().enumerate().flat_map(|(i, e)| (0..e.scores.len().min(max_det)).map(move |d| (i, d))).collect();
    pooled.sort_by(|&(ia, da), &(ib, db)| evals[ib].scores[db].total_cmp(&evals[ia].scores[da]));
    let rec_thr = recall_thresholds();
    let mut precision = Vec::with_capacity(N_IOU);
    let mut recall = [0.0; N_IOU];
    for (t, final_recall) in recall.iter_mut().enumerate() {
        let (mut tp, mut fp) = (0.0f64, 0.0f64);
        let mut rc = Vec::with_capacity(pooled.len());
        let mut pr = Vec::with_capacity(pooled.len());
        for &(i, d) in &pooled {
            // An ignored detection adds a point that repeats the previous one.
            if !evals[i].ignored[t][d] {
                if evals[i].matched[t][d] {
                    tp += 1.0;
                } else {
                    fp += 1.0;
                }
            }
            rc.push(tp / n_pos as f64);
            pr.push(tp / (fp + tp + f64::EPSILON));
        }
        *final_recall = rc.last().copied().unwrap_or(0.0);
        for k in (1..pr.len()).rev() {
            if pr[k] > pr[k - 1] {
                pr[k - 1] = pr[k];
            }
        }
        let mut q = [0.0; N_RECALL];
        for (slot, r) in q.iter_mut().zip(rec_thr) {
            // numpy.searchsorted(rc, r, 'left'): the first recall ≥ r.
            match pr.get(rc.partition_point(|&x| x < r)) {
                Some(&p) => *slot = p,
                None => break,
            }
        }
        precision.push(q);
    }
    Some(Curves { precision, recall })
}

/// The twelve numbers of `COCOeval.summarize` (names as the BOP toolkit's
/// `scores_bop22_coco_*.json`), and AP per category (all areas, 100 detections).
/// −1 where nothing could be counted.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CocoSummary {
    #[serde(rename = "AP")]
    pub ap: f64,
    #[serde(rename = "AP50")]
    pub ap50: f64,
    #[serde(rename = "AP75")]
    pub ap75: f64,
    #[serde(rename = "AP_small")]
    pub ap_small: f64,
    #[serde(rename = "AP_medium")]
    pub ap_medium: f64,
    #[serde(rename = "AP_large")]
    pub ap_large: f64,
    #[serde(rename = "AR1")]
    pub ar1: f64,
    #[serde(rename = "AR10")]
    pub ar10: f64,
    #[serde(rename = "AR100")]
    pub ar100: f64,
    #[serde(rename = "AR_small")]
    pub ar_small: f64,
    #[serde(rename = "AR_medium")]
    pub ar_medium: f64,
    #[serde(rename = "AR_large")]
    pub ar_large: f64,
    pub per_category: BTreeMap<u32, f64>,
}

/// Which part of the curves a number averages.
#[derive(Clone, Copy)]
enum Stat {
    /// Precision at one threshold index, or all.
    Precision(Option<usize>),
    Recall,
}

fn mean(values: impl Iterator<Item = f64>) -> f64 {
    let (sum, n) = values.fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    if n == 0 {
        ABSENT
    } else {
        sum / n as f64
    }
}

fn category_value(c: &Curves, stat: Stat) -> f64 {
    match stat {
        Stat::Precision(None) => mean(c.precision.iter().flatten().copied()),
        Stat::Precision(Some(t)) => mean(c.precision[t].iter().copied()),
        Stat::Recall => mean(c.recall.iter().copied()),
    }
}

/// Scores per category: for each category, its images in a fixed order (the order breaks
/// ties between equal scores of different images). Categories with no ground truth to
/// count anywhere are −1 and left out of the means.
pub fn summarize(categories: &BTreeMap<u32, Vec<ImageCategory>>) -> CocoSummary {
    // curves[area range][max dets][category]
    let mut curves: Vec<Vec<Vec<Option<Curves>>>> = AreaRange::EVERY.iter().map(|_| MAX_DETS.iter().map(|_| Vec::new()).collect()).collect();
    for images in categories.values() {
        for (a, &range) in AreaRange::EVERY.iter().enumerate() {
            // COCOeval skips an image with neither ground truth nor detections.
            let evals: Vec<ImageEval> = images.iter().filter(|ic| !(ic.gts.is_empty() && ic.dts.is_empty())).map(|ic| evaluate_image(ic, range)).collect();
            for (m, &max_det) in MAX_DETS.iter().enumerate() {
                curves[a][m].push(accumulate(&evals, max_det));
            }
        }
    }
    let stat = |range: AreaRange, max_det: usize, s: Stat| {
        let a = AreaRange::EVERY.iter().position(|&r| r == range).unwrap_or(0);
        let m = MAX_DETS.iter().position(|&d| d == max_det).unwrap_or(2);
        mean(curves[a][m].iter().flatten().map(|c| category_value(c, s)))
    };
    let all = Stat::Precision(None);
    let per_category = categories.keys().zip(&curves[0][2]).map(|(&k, c)| (k, c.as_ref().map_or(ABSENT, |c| category_value(c, all)))).collect();
    CocoSummary {
        ap: stat(AreaRange::All, 100, all),
        ap50: stat(AreaRange::All, 100, Stat::Precision(Some(0))),
        ap75: stat(AreaRange::All, 100, Stat::Precision(Some(5))),
        ap_small: stat(AreaRange::Small, 100, all),
        ap_medium: stat(AreaRange::Medium, 100, all),
        ap_large: stat(AreaRange::Large, 100, all),
        ar1: stat(AreaRange::All, 1, Stat::Recall),
        ar10: stat(AreaRange::All, 10, Stat::Recall),
        ar100: stat(AreaRange::All, 100, Stat::Recall),
        ar_small: stat(AreaRange::Small, 100, Stat::Recall),
        ar_medium: stat(AreaRange::Medium, 100, Stat::Recall),
        ar_large: stat(AreaRange::Large, 100, Stat::Recall),
        per_category,
    }
}

#[cfg(test)]
#[path = "coco_ap_tests.rs"]
mod tests;
