//! BOP end to end on lavapipe: a synthetic dataset of the generated box, scored from its
//! own ground truth (AR 1, and a known MSSD), then run through the estimator (resumable);
//! and the 2D detection AP of its detections through the CLI (AP 1, and a known shift).

use b2tfpose::bop::detections::{read_detections, write_detections, DetectionIndex, DetectionRecord};
use b2tfpose::bop::evaluate::evaluate;
use b2tfpose::bop::results_csv::{read_results, write_results, ResultRow};
use b2tfpose::bop::run::{run, DetectionSource, RunOptions};
use b2tfpose::bop::scoring::{ArReport, Bop19Params};
use b2tfpose::bop::synth::{synth, SynthOptions, SynthSummary};
use b2tfpose::bop::synth_masks::shift;
use b2tfpose::bop::{load_models_info, load_split_gt, load_targets, TEST_SPLIT};
use b2tfpose::estimate::Estimator;
use b2tfpose::eval::scenes::SceneConfig;
use b2tfpose::features::{EmbeddedBackbone, EmbeddedConfig};
use b2tfpose::geometry::{Pose, ViewSampling};
use b2tfpose::masks::rle::Rle;
use b2tfpose::mesh::procedural::textured_box;
use b2tfpose::mesh::write_ply::write_bop_ply;
use b2tfpose::onboard::{onboard, OnboardConfig};
use b2tfpose::render::{RenderPool, RendererConfig};
use nalgebra::Vector3;
use std::path::Path;
use std::sync::Arc;

fn pool() -> RenderPool {
    RenderPool::new(1, RendererConfig::default()).unwrap()
}

/// A BOP models folder holding the generated box as object 1, and a dataset made from it.
fn dataset(root: &Path, images: usize, pool: &RenderPool) -> SynthSummary {
    let scene = SceneConfig { images, objects_per_image: 1, image_size: (320, 240), fill_range: (0.45, 0.6), max_occlusion: 0.1, seed: 5, ..Default::default() };
    dataset_of(root, scene, pool)
}

fn dataset_of(root: &Path, scene: SceneConfig, pool: &RenderPool) -> SynthSummary {
    let models = root.join("source_models");
    write_bop_ply(&textured_box([0.10, 0.06, 0.16], 3), &models, "obj_000001").unwrap();
    synth(&models, &root.join("ds"), &SynthOptions { scene, degraded: true, distractors: true, targets: None, untextured: false, backgrounds: None }, pool).unwrap()
}

fn no_progress(_: usize, _: usize) {}

/// The dataset's box onboarded at `views` and `render_size`, and an estimator beside it.
fn onboarded_box(ds: &Path, views: ViewSampling, render_size: u32, pool: &Arc<RenderPool>) -> (Arc<b2tfpose::onboard::ObjectModel>, Estimator) {
    let backbone = Arc::new(EmbeddedBackbone::new(EmbeddedConfig::default()).unwrap());
    let cfg = OnboardConfig { views, render_size, ..Default::default() };
    let mesh = b2tfpose::mesh::load_mesh(&ds.join("models/obj_000001.ply"), Some(b2tfpose::mesh::Units::Mm)).unwrap();
    let model = Arc::new(onboard("obj_000001", &mesh, &cfg, backbone.as_ref(), pool, &|_| {}).unwrap());
    (model, Estimator::new(backbone, pool.clone()))
}

/// BOP'19 scores of `rows`, with the warnings the files gave.
fn score_warned(ds: &Path, rows: &[ResultRow], pool: &RenderPool) -> (ArReport, Vec<String>) {
    let mut warnings = Vec::new();
    let r = evaluate(ds, TEST_SPLIT, rows, pool, &Bop19Params::default(), &no_progress, &mut warnings).unwrap();
    (r, warnings)
}

/// BOP'19 scores of `rows`; the generated ground truth is exact, so nothing is worth a warning.
fn score(ds: &Path, rows: &[ResultRow], pool: &RenderPool) -> ArReport {
    let (r, warnings) = score_warned(ds, rows, pool);
    assert!(warnings.is_empty(), "{warnings:?}");
    r
}

fn read(csv: &Path) -> Vec<ResultRow> {
    read_results(csv, &mut Vec::new()).unwrap()
}

#[test]
fn ground_truth_scores_one_and_a_known_shift_scores_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let pool = pool();
    let s = dataset(dir.path(), 3, &pool);
    let ds = dir.path().join("ds");
    assert_eq!((s.images, s.instances), (3, 3));
    // True mask, a degraded copy and a distractor per image; each reads back.
    let dets = read_detections(&s.detections_path).unwrap();
    assert!(dets.len() >= 3 && dets.iter().filter(|d| d.score == 1.0).count() == 3, "{}", dets.len());
    assert_eq!(load_targets(&ds).unwrap().len(), 3);

    let gt = load_split_gt(&ds, TEST_SPLIT, &mut Vec::new()).unwrap();
    let rows = |shift: f64| -> Vec<ResultRow> {
        gt.iter()
            .flat_map(|im| im.instances.iter().map(move |g| (im, g)))
            .map(|(im, g)| ResultRow {
                scene_id: im.scene_id,
                im_id: im.im_id,
                obj_id: g.obj_id,
                score: 1.0,
                pose: Pose::new(g.pose.rotation, g.pose.translation + Vector3::new(shift, 0.0, 0.0)),
                time: 0.5,
            })
            .collect()
    };
    let csv = dir.path().join("truth.csv");
    write_results(&csv, &rows(0.0)).unwrap();
    let r = score(&ds, &read(&csv), &pool);
    assert_eq!(r.targets, 3);
    assert!((r.ar - 1.0).abs() < 1e-12 && r.ar_vsd == 1.0 && r.ar_mssd == 1.0 && r.ar_mspd == 1.0, "{r:?}");
    assert_eq!(r.half_turns, 0);

    // The truth turned half a turn about the object's own x axis, in place: every estimate
    // is a half-turn (the box declares no symmetry), and the table says so.
    let turned: Vec<ResultRow> = rows(0.0)
        .into_iter()
        .map(|r| ResultRow { pose: Pose::new(r.pose.rotation * nalgebra::Rotation3::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI), r.pose.translation), ..r })
        .collect();
    let r = score(&ds, &turned, &pool);
    assert_eq!((r.half_turns, r.per_object[&1].half_turns), (3, 3), "{r:?}");
    assert!(r.to_string().contains("| all | 3 |") && r.to_string().contains("| 3 |\n"), "{r}");

    // Every vertex moves by the shift: MSSD = 0.12 d, correct at thresholds 0.15…0.50,
    // i.e. 8 of 10.
    let d_mm = load_models_info(&ds).unwrap()[&1].diameter;
    write_results(&csv, &rows(0.12 * d_mm / 1000.0)).unwrap();
    let r = score(&ds, &read(&csv), &pool);
    assert!((r.ar_mssd - 0.8).abs() < 1e-9, "{r:?}");
    assert!(r.ar_vsd < 1.0 && r.ar_mspd < 1.0, "{r:?}");

    // No results at all: every recall is 0.
    let r = score(&ds, &[], &pool);
    assert_eq!((r.ar, r.targets, r.estimates), (0.0, 3, 0));
}

/// Several instances of an image estimated side by side write what estimating them in turn
/// writes (the rows' times apart).
#[test]
fn instances_side_by_side_write_the_same_rows() {
    let dir = tempfile::tempdir().unwrap();
    let pool = Arc::new(pool());
    let scene = SceneConfig { images: 2, objects_per_image: 3, image_size: (320, 240), fill_range: (0.25, 0.35), max_occlusion: 0.1, seed: 9, ..Default::default() };
    let s = dataset_of(dir.path(), scene, &pool);
    let ds = dir.path().join("ds");
    assert!(load_targets(&ds).unwrap().iter().all(|t| t.inst_count == 3), "three instances of the box in each image");
    let (model, estimator) = onboarded_box(&ds, ViewSampling { level: 0, in_plane_steps: 4 }, 128, &pool);
    let index = DetectionIndex::new(read_detections(&s.detections_path).unwrap());
    let rows = |threads: usize| {
        let csv = dir.path().join(format!("threads-{threads}.csv"));
        let opts = RunOptions { instance_threads: threads, estimate: b2tfpose::estimate::EstimateConfig { rrc: false, ..Default::default() }, ..Default::default() };
        let summary = run(&ds, DetectionSource::File(&index), &csv, &estimator, &mut |_| Ok(model.clone()), &opts, &no_progress).unwrap();
        let rows: Vec<_> = read(&csv).into_iter().map(|r| ResultRow { time: 0.0, ..r }).collect();
        (summary, rows)
    };
    let (in_turn, side_by_side) = (rows(1), rows(3));
    assert_eq!(in_turn.0.instances_requested, 6, "{:?}", in_turn.0);
    assert!(in_turn.1.len() >= 4, "most instances answered: {:?}", in_turn.0);
    assert_eq!(in_turn, side_by_side);
}

#[test]
fn run_estimates_every_target_resumes_and_is_scored() {
    let dir = tempfile::tempdir().unwrap();
    let pool = Arc::new(pool());
    let s = dataset(dir.path(), 2, &pool);
    let ds = dir.path().join("ds");
    let (model, estimator) = onboarded_box(&ds, ViewSampling { level: 1, in_plane_steps: 12 }, 256, &pool);
    // A box outside its image besides each true detection: counted unusable, not estimated.
    let mut records = read_detections(&s.detections_path).unwrap();
    let outside = records.iter().map(|d| DetectionRecord { bbox: [1e4, 1e4, 10.0, 10.0], segmentation: None, score: 0.1, ..d.clone() }).collect::<Vec<_>>();
    let unusable = outside.len();
    records.extend(outside);
    let index = DetectionIndex::new(records);
    let csv = dir.path().join("out/results.csv");
    std::fs::create_dir_all(csv.parent().unwrap()).unwrap();
    let mut calls = 0;
    let mut get = |id: u32| {
        assert_eq!(id, 1);
        calls += 1;
        Ok(model.clone())
    };
    let summary = run(&ds, DetectionSource::File(&index), &csv, &estimator, &mut get, &RunOptions::default(), &no_progress).unwrap();
    assert_eq!((summary.images, summary.targets, summary.images_done_before), (2, 2, 0), "{summary:?}");
    assert_eq!(summary.estimates_written + summary.instances_without_pose, 2, "{summary:?}");
    assert_eq!(summary.unusable_detections, unusable, "{summary:?}");
    let rows = read(&csv);
    assert_eq!(rows.len(), summary.estimates_written);
    assert!(rows.iter().all(|r| r.time > 0.0 && (0.0..=1.0).contains(&r.score)));

    // Resuming skips the images already in the CSV and leaves it as it was.
    let before = std::fs::read_to_string(&csv).unwrap();
    let again = run(&ds, DetectionSource::File(&index), &csv, &estimator, &mut get, &RunOptions::default(), &no_progress).unwrap();
    assert_eq!((again.images, again.images_done_before), (0, 2));
    assert_eq!(std::fs::read_to_string(&csv).unwrap(), before);

    let r = score(&ds, &rows, &pool);
    eprintln!("AR {:.3} (VSD {:.3}, MSSD {:.3}, MSPD {:.3})", r.ar, r.ar_vsd, r.ar_mssd, r.ar_mspd);
    assert!(r.ar_mspd > 0.5, "{r:?}");

    // No detections file: the detector finds each image's targets (every candidate kept
    // here, so every target has one), and what it found reads as a default-detections file.
    let mut found = Vec::new();
    let options = b2tfpose::detect::DetectOptions { min_score: 0.0, ..Default::default() };
    let csv = dir.path().join("out/detected.csv");
    let detected = run(&ds, DetectionSource::Detector { pool: &pool, options, found: &mut found }, &csv, &estimator, &mut get, &RunOptions::default(), &no_progress).unwrap();
    assert_eq!((detected.images, detected.targets, detected.targets_without_detection), (2, 2, 0), "{detected:?}");
    assert_eq!(detected.estimates_written + detected.instances_without_pose, 2, "{detected:?}");
    assert!(!found.is_empty() && found.iter().all(|d| d.obj_id == 1 && d.time > 0.0 && d.segmentation.is_some()), "{found:?}");
    let images: std::collections::BTreeSet<(u32, u32)> = found.iter().map(|d| (d.scene_id, d.image_id)).collect();
    assert_eq!(images.len(), 2);
    let file = dir.path().join("out/found.json");
    write_detections(&file, &found).unwrap();
    assert_eq!(read_detections(&file).unwrap().len(), found.len());
    assert_eq!(read(&csv).len(), detected.estimates_written);
}

/// With depth and no detections, two objects of one size searched in images holding one of
/// them (the box; a can as wide is not there): the box's segment is a candidate of both,
/// only the box is answered, near its true pose, and the rows are the same whether the
/// objects are screened and estimated in turn or side by side (`detect::compared`).
#[test]
fn depth_candidates_of_two_objects_answer_the_one_there_on_any_threads() {
    let dir = tempfile::tempdir().unwrap();
    let pool = Arc::new(pool());
    // The box whole and well inside both images (seed 21 put one at the image's corner,
    // where the cheaply onboarded box confirmed lower than the can).
    let scene = SceneConfig { images: 2, objects_per_image: 1, image_size: (320, 240), fill_range: (0.35, 0.45), max_occlusion: 0.0, seed: 23, ..Default::default() };
    let models = dir.path().join("source_models");
    write_bop_ply(&textured_box([0.10, 0.06, 0.16], 3), &models, "obj_000001").unwrap();
    let ds = dir.path().join("ds");
    synth(&models, &ds, &SynthOptions { scene, degraded: false, distractors: false, targets: None, untextured: false, backgrounds: None }, &pool).unwrap();
    // The can is searched in every image as well.
    let mut targets: Vec<serde_json::Value> = serde_json::from_str(&std::fs::read_to_string(ds.join("test_targets_bop19.json")).unwrap()).unwrap();
    let can_targets: Vec<serde_json::Value> = targets.iter().map(|t| serde_json::json!({"scene_id": t["scene_id"], "im_id": t["im_id"], "obj_id": 2, "inst_count": 1})).collect();
    targets.extend(can_targets);
    std::fs::write(ds.join("test_targets_bop19.json"), serde_json::to_string(&targets).unwrap()).unwrap();
    let (the_box, estimator) = onboarded_box(&ds, ViewSampling { level: 0, in_plane_steps: 4 }, 128, &pool);
    let backbone = EmbeddedBackbone::new(EmbeddedConfig::default()).unwrap();
    let cfg = OnboardConfig { views: ViewSampling { level: 0, in_plane_steps: 4 }, render_size: 128, ..Default::default() };
    let can = Arc::new(onboard("obj_000002", &b2tfpose::mesh::procedural::cylinder(0.05, 0.17, 24), &cfg, &backbone, &pool, &|_| {}).unwrap());
    let gt = load_split_gt(&ds, TEST_SPLIT, &mut Vec::new()).unwrap();
    let rows = |threads: usize| {
        let csv = dir.path().join(format!("depth-{threads}.csv"));
        let opts = RunOptions { depth: true, instance_threads: threads, ..Default::default() };
        let mut found = Vec::new();
        // Every candidate confirmed is kept (the cheap onboarding's confirmations are low):
        // each place goes to the object confirmed best there.
        let options = b2tfpose::detect::DetectOptions { min_score: 0.0, ..Default::default() };
        let source = DetectionSource::Detector { pool: &pool, options, found: &mut found };
        let summary = run(&ds, source, &csv, &estimator, &mut |id| Ok(if id == 1 { the_box.clone() } else { can.clone() }), &opts, &no_progress).unwrap();
        assert!(found.iter().any(|d| d.obj_id == 2), "the box's segment is offered to the can too: {found:?}");
        let rows: Vec<_> = read(&csv).into_iter().map(|r| ResultRow { time: 0.0, ..r }).collect();
        (summary.instances_requested, rows)
    };
    let (in_turn, side_by_side) = (rows(1), rows(2));
    assert_eq!(in_turn.0, 4, "the box and the can in each of two images");
    // One answer an image (one place), the box's.
    assert!(in_turn.1.len() == 2 && in_turn.1.iter().all(|r| r.obj_id == 1), "{:?}", in_turn.1);
    for r in &in_turn.1 {
        let truth = gt.iter().find(|im| (im.scene_id, im.im_id) == (r.scene_id, r.im_id)).unwrap();
        let off = (r.pose.translation - truth.instances[0].pose.translation).norm();
        assert!(off < 0.02, "image {}: {:.1} mm from the box", r.im_id, off * 1e3);
    }
    assert_eq!(in_turn, side_by_side);
}

/// `bop synth` as the RGB-D benchmark uses it: two objects, only the first a target (the
/// second stands in the scenes as a distractor), bare meshes, 1–2 instances an image, and
/// the detections as boxes too; a target that is not among the models is refused.
#[test]
fn synth_with_distractor_objects_bare_meshes_a_count_range_and_boxes() {
    let dir = tempfile::tempdir().unwrap();
    let pool = pool();
    let models = dir.path().join("source_models");
    write_bop_ply(&textured_box([0.10, 0.06, 0.16], 3), &models, "obj_000001").unwrap();
    write_bop_ply(&textured_box([0.08, 0.08, 0.08], 4), &models, "obj_000002").unwrap();
    assert!(models.join("obj_000001.png").exists());
    let scene = SceneConfig { images: 6, objects_per_image: 1, objects_per_image_max: 2, image_size: (320, 240), fill_range: (0.3, 0.4), max_occlusion: 0.3, seed: 2, ..Default::default() };
    let opts = SynthOptions { scene, degraded: false, distractors: true, targets: Some(vec![1]), untextured: true, backgrounds: None };
    let ds = dir.path().join("ds");
    let s = synth(&models, &ds, &opts, &pool).unwrap();
    assert_eq!((s.objects.clone(), s.targets.clone()), (vec![1, 2], vec![1]));

    // Bare meshes: no texture copied, none named, none loaded.
    assert!(!ds.join("models/obj_000001.png").exists());
    let ply = std::fs::read_to_string(ds.join("models/obj_000001.ply")).unwrap();
    assert!(!ply.contains("TextureFile"), "{}", &ply[..200]);
    let mesh = b2tfpose::mesh::load_mesh(&ds.join("models/obj_000001.ply"), Some(b2tfpose::mesh::Units::Mm)).unwrap();
    assert!(mesh.materials().iter().all(|m| m.texture.is_none()));

    // Between one and two instances an image, both counts drawn; both objects in the scenes.
    let gt = load_split_gt(&ds, TEST_SPLIT, &mut Vec::new()).unwrap();
    let counts: Vec<usize> = gt.iter().map(|im| im.instances.len()).collect();
    assert!(counts.iter().all(|n| (1..=2).contains(n)) && counts.contains(&1) && counts.contains(&2), "{counts:?}");
    assert_eq!(counts.iter().sum::<usize>(), s.instances);
    assert!(gt.iter().any(|im| im.instances.iter().any(|g| g.obj_id == 2)));

    // Only object 1 is a target and named by detections; the boxes are the masks' boxes.
    let targets = load_targets(&ds).unwrap();
    assert!(!targets.is_empty() && targets.iter().all(|t| t.obj_id == 1), "{targets:?}");
    let masks = read_detections(&s.detections_path).unwrap();
    let boxes = read_detections(&s.box_detections_path).unwrap();
    assert!(masks.iter().all(|d| d.obj_id == 1 && d.segmentation.is_some()));
    assert_eq!(masks.len(), boxes.len());
    for (m, b) in masks.iter().zip(&boxes) {
        assert!(b.segmentation.is_none());
        assert_eq!((m.image_id, m.obj_id, m.bbox, m.score), (b.image_id, b.obj_id, b.bbox, b.score));
    }

    // The bare box turned half a turn about its x axis: BOP (no symmetry declared) counts
    // each a half-turn; scored up to the symmetries found in the bare mesh, each is right.
    let turned: Vec<ResultRow> = gt
        .iter()
        .flat_map(|im| im.instances.iter().filter(|g| g.obj_id == 1).map(move |g| (im, g)))
        .map(|(im, g)| ResultRow {
            scene_id: im.scene_id,
            im_id: im.im_id,
            obj_id: 1,
            score: 1.0,
            pose: Pose::new(g.pose.rotation * nalgebra::Rotation3::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI), g.pose.translation),
            time: 0.5,
        })
        .collect();
    let declared = score(&ds, &turned, &pool);
    assert_eq!(declared.half_turns, turned.len(), "{declared}");
    assert!(declared.ar_mssd < 0.5, "{declared}");
    let params = Bop19Params { symmetries: b2tfpose::bop::eval_models::SymmetriesFrom::Mesh, ..Default::default() };
    let shape = evaluate(&ds, TEST_SPLIT, &turned, &pool, &params, &no_progress, &mut Vec::new()).unwrap();
    assert_eq!(shape.half_turns, 0, "{shape}");
    assert!(shape.ar_mssd > 0.99 && shape.ar_mspd > 0.99, "{shape}");

    let refused = synth(&models, &dir.path().join("ds2"), &SynthOptions { targets: Some(vec![7]), ..opts }, &pool).unwrap_err();
    assert!(format!("{refused:#}").contains("target object 7"), "{refused:#}");
}

/// `bop synth --backgrounds`: each image drawn over a real frame's photo, its depth behind
/// the objects (scaled back where it would stand in front of them); a frame whose depth
/// has another size than its photo is refused naming it.
#[test]
fn synth_over_real_frames_takes_their_photo_and_depth() {
    let dir = tempfile::tempdir().unwrap();
    let pool = pool();
    let models = dir.path().join("source_models");
    write_bop_ply(&textured_box([0.10, 0.06, 0.16], 3), &models, "obj_000001").unwrap();
    // A "real" frame: a red photo, a flat surface 0.3 m away (in front of where the objects
    // will stand), no depth in its top rows; depth in mm at scale 1, as empty-rgbd has it.
    let frames = dir.path().join("frames");
    let scene = frames.join("test/000001");
    std::fs::create_dir_all(scene.join("rgb")).unwrap();
    std::fs::create_dir_all(scene.join("depth")).unwrap();
    image::RgbImage::from_pixel(320, 240, image::Rgb([200, 30, 30])).save(scene.join("rgb/000016.png")).unwrap();
    image::ImageBuffer::<image::Luma<u16>, _>::from_fn(320, 240, |_, y| image::Luma([if y < 10 { 0 } else { 300 }])).save(scene.join("depth/000016.png")).unwrap();
    std::fs::write(scene.join("scene_camera.json"), r#"{"16": {"cam_K": [290, 0, 160, 0, 290, 120, 0, 0, 1], "depth_scale": 1.0}}"#).unwrap();

    let cfg = SceneConfig {
        images: 2,
        objects_per_image: 1,
        image_size: (320, 240),
        fill_range: (0.3, 0.4),
        min_occlusion: 0.1,
        seed: 4,
        depth_sensor: b2tfpose::depth::sensor::SensorModel::exact(),
        ..Default::default()
    };
    let opts = SynthOptions { scene: cfg, degraded: false, distractors: false, targets: None, untextured: false, backgrounds: Some(frames.clone()) };
    let ds = dir.path().join("ds");
    synth(&models, &ds, &opts, &pool).unwrap();
    for im in load_split_gt(&ds, TEST_SPLIT, &mut Vec::new()).unwrap() {
        let rgb = image::open(scene_folder(&ds).join(format!("rgb/{:06}.png", im.im_id))).unwrap().to_rgb8();
        let (w, _, depth) = b2tfpose::bop::load_depth_mm(&im.depth_path, im.depth_scale).unwrap();
        let object_mm = im.instances[0].pose.translation.z * 1000.0;
        // Away from the object: the red photo (through the sensor noise and colour shift),
        // and the flat surface moved behind the object; the frame's holes stay holes.
        let (x, y) = (5u32, 230u32);
        let p = rgb.get_pixel(x, y);
        assert!(p[0] > 150 && p[1] < 80 && p[2] < 80, "{p:?}");
        let behind = depth[(y * w + x) as usize] as f64;
        assert!(behind > object_mm, "{behind} mm behind an object at {object_mm} mm");
        assert_eq!(depth[(3 * w + x) as usize], 0.0);
        // The occluders are cut from the (red) real photo too, not flat random colours.
        let name = format!("{:06}_000000.png", im.im_id);
        let [all, visible] = [format!("mask/{name}"), format!("mask_visib/{name}")].map(|m| image::open(scene_folder(&ds).join(m)).unwrap().to_luma8());
        let hidden: Vec<_> = all.enumerate_pixels().filter(|(x, y, p)| p[0] > 0 && visible.get_pixel(*x, *y)[0] == 0).map(|(x, y, _)| *rgb.get_pixel(x, y)).collect();
        assert!(hidden.len() > 20, "min_occlusion 0.1 hides part of the object: {} pixels", hidden.len());
        let red = hidden.iter().filter(|p| p[0] > 150 && p[1] < 80 && p[2] < 80).count();
        assert!(red * 10 >= hidden.len() * 8, "{red} of {} hidden pixels show the photo", hidden.len());
    }

    // A frame whose depth does not match its photo is refused.
    image::ImageBuffer::<image::Luma<u16>, _>::from_pixel(160, 120, image::Luma([300])).save(scene.join("depth/000016.png")).unwrap();
    let err = synth(&models, &dir.path().join("ds2"), &opts, &pool).unwrap_err();
    assert!(format!("{err:#}").contains("depth is 160x120"), "{err:#}");
    // A folder that is not a BOP dataset is named.
    let nowhere = dir.path().join("no-frames");
    let err = synth(&models, &dir.path().join("ds3"), &SynthOptions { backgrounds: Some(nowhere), ..opts }, &pool).unwrap_err();
    assert!(format!("{err:#}").contains("backgrounds: reading") && format!("{err:#}").contains("no-frames"), "{err:#}");
}

/// The only scene folder of a generated dataset.
fn scene_folder(ds: &Path) -> std::path::PathBuf {
    std::fs::read_dir(ds.join(TEST_SPLIT)).unwrap().next().unwrap().unwrap().path()
}

/// Rewrites every instance of a scene JSON file (`{"im_id": [instance, …]}`).
fn edit_instances(path: &Path, edit: impl Fn(&mut serde_json::Map<String, serde_json::Value>)) {
    let mut json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    for list in json.as_object_mut().unwrap().values_mut() {
        list.as_array_mut().unwrap().iter_mut().for_each(|i| edit(i.as_object_mut().unwrap()));
    }
    std::fs::write(path, json.to_string()).unwrap();
}

#[test]
fn ground_truth_as_real_datasets_ship_it_is_scored_and_broken_files_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let pool = pool();
    dataset(dir.path(), 1, &pool);
    let ds = dir.path().join("ds");
    let scene = scene_folder(&ds);
    // LM-O-like annotation noise: R's first row 0.3 % too long (R·Rᵀ 6·10⁻³ off the
    // identity); and a scene_gt_info.json with nothing but visib_fract.
    edit_instances(&scene.join("scene_gt.json"), |i| {
        let r = i["cam_R_m2c"].as_array_mut().unwrap();
        r.iter_mut().take(3).for_each(|v| *v = serde_json::json!(v.as_f64().unwrap() * 1.003));
    });
    edit_instances(&scene.join("scene_gt_info.json"), |i| i.retain(|k, _| k == "visib_fract"));

    // Results made from that ground truth, as the toolkit's own test files are: perfect.
    let gt = load_split_gt(&ds, TEST_SPLIT, &mut Vec::new()).unwrap();
    let rows: Vec<ResultRow> =
        gt.iter().flat_map(|im| im.instances.iter().map(move |g| ResultRow { scene_id: im.scene_id, im_id: im.im_id, obj_id: g.obj_id, score: 1.0, pose: g.pose, time: 0.5 })).collect();
    let csv = dir.path().join("rough.csv");
    write_results(&csv, &rows).unwrap();
    let mut read_warnings = Vec::new();
    let read_back = read_results(&csv, &mut read_warnings).unwrap();
    assert_eq!(read_back.len(), 1);
    assert_eq!(read_back[0].pose.rotation_row_major(), gt[0].instances[0].pose.rotation_row_major());
    assert!(read_warnings.len() == 1 && read_warnings[0].contains("rough.csv") && read_warnings[0].contains("scored as given"), "{read_warnings:?}");
    let (r, warnings) = score_warned(&ds, &read_back, &pool);
    assert!((r.ar - 1.0).abs() < 1e-12, "{r:?}");
    assert!(warnings.len() == 1 && warnings[0].contains("scene_gt.json: 1 of 1 cam_R_m2c matrices are rotations only to within 6.0e-3"), "{warnings:?}");

    // A mirrored rotation is no annotation noise.
    edit_instances(&scene.join("scene_gt.json"), |i| {
        let r = i["cam_R_m2c"].as_array_mut().unwrap();
        r.iter_mut().take(3).for_each(|v| *v = serde_json::json!(-v.as_f64().unwrap()));
    });
    let err = evaluate(&ds, TEST_SPLIT, &read_back, &pool, &Bop19Params::default(), &no_progress, &mut Vec::new()).unwrap_err().to_string();
    assert!(err.contains("scene_gt.json: image 0, instance 0: cam_R_m2c: not a rotation: determinant is -1.00"), "{err}");
}

/// The `b2tf` binary, as a user runs it: (success, stdout, stderr).
fn b2tf(args: &[&str]) -> (bool, String, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_b2tf")).args(args).env("XDG_RUNTIME_DIR", "/tmp").output().expect("runs");
    (out.status.success(), String::from_utf8_lossy(&out.stdout).into(), String::from_utf8_lossy(&out.stderr).into())
}

fn json_of(stdout: &str) -> serde_json::Value {
    serde_json::from_str(stdout).unwrap_or_else(|e| panic!("{e}: {stdout}"))
}

#[test]
fn detection_ap_of_true_and_shifted_detections_through_the_cli() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let models = d.join("models_src");
    write_bop_ply(&textured_box([0.10, 0.06, 0.16], 3), &models, "obj_000001").unwrap();
    write_bop_ply(&textured_box([0.05, 0.12, 0.08], 4), &models, "obj_000002").unwrap();
    let ds = d.join("ds");
    let (ok, out, err) = b2tf(&["bop", "synth", "--models", &s(&models), "--out", &s(&ds), "--images", "4", "--objects-per-image", "2", "--seed", "3"]);
    assert!(ok, "{out}{err}");
    for bad in ["0", "3,2", "two"] {
        let (ok, _, err) = b2tf(&["bop", "synth", "--models", &s(&models), "--out", &s(&d.join("bad")), "--objects-per-image", bad]);
        assert!(!ok && err.contains("--objects-per-image"), "{bad}: {err}");
    }
    let dets_path = ds.join("detections_synth.json");
    let eval = |dets: &Path, extra: &[&str]| {
        let mut args = vec!["bop".to_string(), "eval".into(), "--dataset".into(), s(&ds), "--detections".into(), s(dets), "--json".into()];
        args.extend(extra.iter().map(|a| a.to_string()));
        let (ok, out, err) = b2tf(&args.iter().map(String::as_str).collect::<Vec<_>>());
        assert!(ok, "{out}{err}");
        (json_of(&out), err)
    };

    // Each instance's true visible mask (score 1) ranks above every degraded copy and
    // distractor, so those cost nothing: segm AP and the modal bbox AP are 1 (to within
    // the ε pycocotools adds to precision's denominator: one true positive alone in a
    // category gives 1 / (1 + ε)).
    let one = |v: &serde_json::Value| (v.as_f64().unwrap() - 1.0).abs() < 1e-15;
    let (r, _) = eval(&dets_path, &[]);
    assert!(one(&r["segm"]["AP"]) && r["segm"]["AR100"] == 1.0 && one(&r["segm"]["per_category"]["1"]), "{r:#}");
    let (modal, _) = eval(&dets_path, &["--bbox-type", "modal"]);
    assert!(modal["bbox_type"] == "modal" && one(&modal["bbox"]["AP"]), "{modal:#}");
    // Amodal boxes (the default, whole silhouettes) are larger than the visible ones
    // wherever an occluder hides part of an object, so visible-mask boxes may score lower.
    let amodal = r["bbox"]["AP"].as_f64().unwrap();
    assert!(r["bbox_type"] == "amodal" && amodal > 0.5 && amodal <= 1.0, "{r:#}");

    // Only the true detections, each box moved right by a tenth of its width: box IoU
    // (0.9 w·h) / (1.1 w·h) = 0.818, a match at 0.50…0.80, 7 thresholds of 10: AP 0.7.
    // The masks move by as many whole pixels: lower, and no longer exact.
    let shifted: Vec<DetectionRecord> = read_detections(&dets_path)
        .unwrap()
        .into_iter()
        .filter(|r| r.score == 1.0)
        .map(|mut r| {
            let dx = r.bbox[2] / 10.0;
            r.bbox[0] += dx;
            let mask = r.segmentation.as_ref().unwrap().decode().unwrap();
            r.segmentation = Some(Rle::encode(&shift(&mask, dx.round() as i64, 0)));
            r
        })
        .collect();
    let shifted_path = d.join("shifted.json");
    write_detections(&shifted_path, &shifted).unwrap();
    let (r, _) = eval(&shifted_path, &["--bbox-type", "modal"]);
    assert!((r["bbox"]["AP"].as_f64().unwrap() - 0.7).abs() < 1e-12 && one(&r["bbox"]["AP50"]) && one(&r["bbox"]["AP75"]), "{r:#}");
    let segm = r["segm"]["AP"].as_f64().unwrap();
    assert!(segm > 0.3 && segm < 0.95, "{r:#}");

    // Entries for other images and objects are skipped with a warning, as the toolkit
    // skips them; the table names both scores.
    let mut extra = shifted.clone();
    extra.push(DetectionRecord { image_id: 999, ..shifted[0].clone() });
    extra.push(DetectionRecord { obj_id: 42, ..shifted[0].clone() });
    write_detections(&shifted_path, &extra).unwrap();
    let (ok, out, err) = b2tf(&["bop", "eval", "--dataset", &s(&ds), "--detections", &s(&shifted_path)]);
    assert!(ok, "{out}{err}");
    assert!(err.contains("shifted.json: 1 detections are for images that are not test targets") && err.contains("category_id 42"), "{err}");
    assert!(out.contains("bbox AP (amodal boxes") && out.contains("segm AP") && out.contains("| obj 2 |"), "{out}");

    // Both inputs: both reports. Neither: a clear error.
    let gt = load_split_gt(&ds, TEST_SPLIT, &mut Vec::new()).unwrap();
    let rows: Vec<ResultRow> =
        gt.iter().flat_map(|im| im.instances.iter().map(move |g| ResultRow { scene_id: im.scene_id, im_id: im.im_id, obj_id: g.obj_id, score: 1.0, pose: g.pose, time: 0.5 })).collect();
    let csv = d.join("truth.csv");
    write_results(&csv, &rows).unwrap();
    let (ok, out, err) = b2tf(&["bop", "eval", "--dataset", &s(&ds), "--results", &s(&csv), "--detections", &s(&dets_path), "--json"]);
    assert!(ok, "{out}{err}");
    let both = json_of(&out);
    assert!((both["pose"]["ar"].as_f64().unwrap() - 1.0).abs() < 1e-12 && one(&both["detection"]["segm"]["AP"]), "{both:#}");
    let (ok, _, err) = b2tf(&["bop", "eval", "--dataset", &s(&ds)]);
    assert!(!ok && err.contains("--results") && err.contains("--detections"), "{err}");
}
