//! Hand-worked cases of `coco_ap`. IoUs are given directly, so each case is a few lines
//! of arithmetic; each would come out differently if the rule it pins were broken.

use super::*;

const BIG: f64 = 10_000.0; // "large" area, so only the All and Large ranges see it

fn gt(area: f64) -> Gt {
    Gt { area, ignore: false }
}

fn ignored(area: f64) -> Gt {
    Gt { area, ignore: true }
}

fn dt(score: f64) -> Dt {
    Dt { score, area: BIG }
}

/// One image; `ious[d][g]` in the order given.
fn image(gts: Vec<Gt>, dts: Vec<Dt>, ious: &[&[f64]]) -> ImageCategory {
    ImageCategory::new(gts, dts, |d, g| ious[d][g])
}

fn one_category(images: Vec<ImageCategory>) -> CocoSummary {
    summarize(&BTreeMap::from([(1, images)]))
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-12
}

#[test]
fn thresholds_are_numpy_linspace() {
    let t = iou_thresholds();
    assert_eq!((t[0], t[2], t[5], t[9]), (0.5, 0.6, 0.75, 0.95));
    assert_eq!(t[8], 0.8999999999999999);
    let r = recall_thresholds();
    assert_eq!((r[0], r[35], r[50], r[100]), (0.0, 0.35000000000000003, 0.5, 1.0));
}

#[test]
fn perfect_detection_scores_one() {
    let s = one_category(vec![image(vec![gt(BIG)], vec![dt(0.9)], &[&[1.0]])]);
    // Precision is tp / (tp + fp + ε) (numpy's spacing(1)): a lone true positive gives
    // 1 / (1 + ε), just under 1, as in pycocotools; two or more round to 1.
    for v in [s.ap, s.ap50, s.ap75, s.ap_large, s.per_category[&1]] {
        assert!(v < 1.0 && v > 1.0 - 1e-15, "{s:?}");
    }
    assert_eq!((s.ar1, s.ar100), (1.0, 1.0));
    // No ground truth is small or medium: nothing to count there.
    assert_eq!((s.ap_small, s.ap_medium, s.ar_small), (ABSENT, ABSENT, ABSENT));
    let s = one_category(vec![image(vec![gt(BIG), gt(BIG)], vec![dt(0.9), dt(0.8)], &[&[1.0, 0.0], &[0.0, 1.0]])]);
    assert_eq!(s.ap, 1.0);
}

#[test]
fn iou_point_six_passes_three_thresholds_of_ten() {
    // 0.50, 0.55 and 0.60 (an IoU equal to a threshold matches): AP = AR = 3/10.
    let s = one_category(vec![image(vec![gt(BIG)], vec![dt(0.9)], &[&[0.6]])]);
    assert!(close(s.ap, 0.3) && close(s.ar100, 0.3), "{s:?}");
    assert!(close(s.ap50, 1.0) && s.ap75 == 0.0, "{s:?}");
    // Just below 0.6: two of ten.
    let s = one_category(vec![image(vec![gt(BIG)], vec![dt(0.9)], &[&[0.5999]])]);
    assert!(close(s.ap, 0.2), "{s:?}");
}

#[test]
fn a_false_positive_ranked_first_halves_precision() {
    // FP then TP: precision 0 then 1/2; made non-increasing, 1/2 at every recall level.
    let s = one_category(vec![image(vec![gt(BIG)], vec![dt(0.9), dt(0.8)], &[&[0.0], &[1.0]])]);
    assert!(close(s.ap, 0.5) && s.ar100 == 1.0, "{s:?}");
    // The same two detections the other way round: the FP comes after full recall.
    let s = one_category(vec![image(vec![gt(BIG)], vec![dt(0.8), dt(0.9)], &[&[0.0], &[1.0]])]);
    assert!(close(s.ap, 1.0), "{s:?}");
}

#[test]
fn precision_is_read_at_the_first_detection_reaching_each_recall_level() {
    // Two GT; TP (0.9), FP (0.8), TP (0.7): recall .5 .5 1, precision 1 .5 2/3 → 1 2/3 2/3.
    // Recall levels 0.00..=0.50 (51) read 1, levels 0.51..=1.00 (50) read 2/3.
    let s = one_category(vec![image(vec![gt(BIG), gt(BIG)], vec![dt(0.9), dt(0.8), dt(0.7)], &[&[1.0, 0.0], &[0.0, 0.0], &[0.0, 1.0]])]);
    let want = (51.0 + 50.0 * (2.0 / (3.0 + f64::EPSILON))) / 101.0;
    assert!(close(s.ap, want), "{} vs {want}", s.ap);
}

#[test]
fn detections_are_pooled_over_images_by_score() {
    // Image A: TP at 0.9. Image B: FP at 0.95, TP at 0.5. Pooled: FP, TP, TP over 2 GT:
    // precision 0, 1/2, 2/3 → 2/3 everywhere.
    let a = image(vec![gt(BIG)], vec![dt(0.9)], &[&[1.0]]);
    let b = image(vec![gt(BIG)], vec![dt(0.95), dt(0.5)], &[&[0.0], &[1.0]]);
    let s = one_category(vec![a, b]);
    assert!(close(s.ap, 2.0 / (3.0 + f64::EPSILON)), "{s:?}");
}

#[test]
fn ignored_ground_truth_is_neither_a_miss_nor_a_false_positive() {
    // Undetected ignored GT beside a detected regular one: no miss.
    let s = one_category(vec![image(vec![gt(BIG), ignored(BIG)], vec![dt(0.9)], &[&[1.0, 0.0]])]);
    assert!(close(s.ap, 1.0) && s.ar100 == 1.0, "{s:?}");
    // A detection of the ignored GT, ranked first: ignored, not a false positive.
    let s = one_category(vec![image(vec![gt(BIG), ignored(BIG)], vec![dt(0.9), dt(0.8)], &[&[0.0, 1.0], &[1.0, 0.0]])]);
    assert!(close(s.ap, 1.0), "{s:?}");
    // Were it not ignored, that GT would be missed... (control: same data, flag off)
    let s = one_category(vec![image(vec![gt(BIG), gt(BIG)], vec![dt(0.9)], &[&[1.0, 0.0]])]);
    assert_eq!(s.ar100, 0.5);
    // ...and a detection that overlaps nothing would be a false positive.
    let s = one_category(vec![image(vec![gt(BIG), ignored(BIG)], vec![dt(0.9), dt(0.8)], &[&[0.0, 0.0], &[1.0, 0.0]])]);
    assert!(close(s.ap, 0.5), "{s:?}");
    // Only ignored GT: the category has no value at all.
    let s = one_category(vec![image(vec![ignored(BIG)], vec![dt(0.9)], &[&[1.0]])]);
    assert_eq!((s.ap, s.per_category[&1]), (ABSENT, ABSENT));
}

#[test]
fn a_regular_match_is_preferred_to_a_better_ignored_one() {
    // IoU 0.6 with the regular GT, 0.9 with the ignored one. Up to 0.60 it takes the
    // regular one (TP); from 0.65 only the ignored one qualifies: ignored, recall 0.
    let s = one_category(vec![image(vec![ignored(BIG), gt(BIG)], vec![dt(0.9)], &[&[0.9, 0.6]])]);
    assert!(close(s.ap, 0.3) && close(s.ar100, 0.3), "{s:?}");
}

#[test]
fn each_ground_truth_is_matched_once_best_detection_first() {
    // Two detections of one GT: the better-scored takes it, the other is an FP after it.
    let s = one_category(vec![image(vec![gt(BIG)], vec![dt(0.5), dt(0.9)], &[&[1.0], &[0.7]])]);
    // At thresholds ≤ 0.70 (5 of 10): the 0.9 detection is TP, the 0.5 one FP after it:
    // AP 1. Above: the 0.9 one is FP, then the 0.5 one TP: AP 1/2.
    assert!(close(s.ap, (5.0 * 1.0 + 5.0 * 0.5) / 10.0), "{s:?}");
}

#[test]
fn a_detection_takes_the_best_overlapping_ground_truth() {
    // One detection overlapping two GT (0.55 and 0.8), a second one exactly the first GT.
    // Best first: the 0.9 detection takes the 0.8 GT; the 0.8 detection the other one.
    let s = one_category(vec![image(vec![gt(BIG), gt(BIG)], vec![dt(0.9), dt(0.8)], &[&[0.55, 0.8], &[1.0, 0.0]])]);
    // Thresholds ≤ 0.80 (7): both TP, AP 1. Above (3): FP then TP: precision 1/2 at
    // recall 1/2, so 51 levels (0..=0.5) read 1/2 and the rest 0.
    let want = (7.0 + 3.0 * (51.0 * 0.5 / 101.0)) / 10.0;
    assert!(close(s.ap, want), "{} vs {want}", s.ap);
}

#[test]
fn categories_are_averaged_and_one_without_ground_truth_is_left_out() {
    let cats = BTreeMap::from([(1, vec![image(vec![gt(BIG)], vec![dt(0.9)], &[&[1.0]])]), (2, vec![image(vec![gt(BIG)], vec![dt(0.9)], &[&[0.6]])]), (3, vec![image(vec![], vec![dt(0.9)], &[&[]])])]);
    let s = summarize(&cats);
    assert!(close(s.ap, 0.65), "{s:?}");
    assert!(close(s.per_category[&1], 1.0));
    assert!(close(s.per_category[&2], 0.3));
    assert_eq!(s.per_category[&3], ABSENT);
    // Detections in an image without that category's GT are false positives.
    let cats = BTreeMap::from([(1, vec![image(vec![gt(BIG)], vec![dt(0.5)], &[&[1.0]]), image(vec![], vec![dt(0.9)], &[&[]])])]);
    assert!(close(summarize(&cats).ap, 0.5));
}

#[test]
fn area_ranges_count_only_their_ground_truth() {
    // A small GT (400 px) found and a medium one (2000 px) missed; a small FP detection.
    let small = Gt { area: 400.0, ignore: false };
    let medium = Gt { area: 2000.0, ignore: false };
    let found = Dt { score: 0.9, area: 420.0 };
    let stray = Dt { score: 0.95, area: 300.0 };
    let s = one_category(vec![image(vec![small, medium], vec![found, stray], &[&[1.0, 0.0], &[0.0, 0.0]])]);
    // Medium: the missed GT counts; the small detections do not (matched to GT out of
    // range, or unmatched and out of range): recall 0.
    assert_eq!((s.ap_medium, s.ar_medium), (0.0, 0.0));
    // Small: FP (0.95) then TP: 1/2. All: FP then TP over 2 GT: 1/2 up to recall 1/2.
    assert!(close(s.ap_small, 0.5) && s.ar_small == 1.0, "{s:?}");
    assert!(close(s.ap, 51.0 * 0.5 / 101.0) && s.ar100 == 0.5, "{s:?}");
    assert_eq!(s.ap_large, ABSENT);
}

#[test]
fn max_dets_limit_recall_per_image() {
    // Two GT, two perfect detections: AR1 sees one per image.
    let s = one_category(vec![image(vec![gt(BIG), gt(BIG)], vec![dt(0.9), dt(0.8)], &[&[1.0, 0.0], &[0.0, 1.0]])]);
    assert_eq!((s.ar1, s.ar10, s.ar100), (0.5, 1.0, 1.0));
    // 101 detections of 101 GT in one image: the lowest-scored one is dropped.
    let n = 101;
    let gts = vec![gt(BIG); n];
    let dts: Vec<Dt> = (0..n).map(|i| dt(1.0 - i as f64 * 1e-3)).collect();
    let ic = ImageCategory::new(gts, dts, |d, g| if d == g { 1.0 } else { 0.0 });
    let s = one_category(vec![ic]);
    assert!(close(s.ar100, 100.0 / 101.0), "{s:?}");
}

/// Random cases (`tools/coco_cases.py`): several images and 3 categories, ignored ground
/// truth, areas in every range, tied scores, an image with over 100 detections; the twelve
/// numbers and per-category AP as pycocotools (as the BOP toolkit installs it) gave them.
#[test]
fn agrees_with_pycocotools() {
    use super::super::coco_iou::box_iou;
    let fixture: serde_json::Value = serde_json::from_str(include_str!("testdata/coco_cases.json")).unwrap();
    let bbox = |v: &serde_json::Value| -> [f64; 4] { std::array::from_fn(|i| v[i].as_f64().unwrap()) };
    let cases = fixture["cases"].as_array().unwrap();
    assert!(cases.len() >= 8);
    for case in cases {
        let images = case["images"].as_array().unwrap();
        let mut cats = BTreeMap::new();
        for cat in 1..=3u64 {
            let mut list = Vec::new();
            for im in images {
                let of_cat = |key: &str| -> Vec<serde_json::Value> { im[key].as_array().unwrap().iter().filter(|x| x["cat"].as_u64() == Some(cat)).cloned().collect() };
                let (gs, ds) = (of_cat("gts"), of_cat("dts"));
                if gs.is_empty() && ds.is_empty() {
                    continue;
                }
                let gts = gs.iter().map(|g| Gt { area: g["area"].as_f64().unwrap(), ignore: g["ignore"].as_bool().unwrap() }).collect();
                let dts = ds.iter().map(|d| Dt { score: d["score"].as_f64().unwrap(), area: bbox(&d["bbox"])[2] * bbox(&d["bbox"])[3] }).collect();
                list.push(ImageCategory::new(gts, dts, |d, g| box_iou(bbox(&ds[d]["bbox"]), bbox(&gs[g]["bbox"]))));
            }
            cats.insert(cat as u32, list);
        }
        let s = summarize(&cats);
        let got = [s.ap, s.ap50, s.ap75, s.ap_small, s.ap_medium, s.ap_large, s.ar1, s.ar10, s.ar100, s.ar_small, s.ar_medium, s.ar_large];
        let want: Vec<f64> = case["stats"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
        for (i, (g, w)) in got.iter().zip(&want).enumerate() {
            assert!((g - w).abs() < 1e-12, "seed {}: stat {i}: {g} vs pycocotools {w}", case["seed"]);
        }
        for (k, w) in case["per_category"].as_object().unwrap() {
            let g = s.per_category[&k.parse::<u32>().unwrap()];
            assert!((g - w.as_f64().unwrap()).abs() < 1e-12, "seed {}: category {k}: {g} vs {w}", case["seed"]);
        }
    }
}
