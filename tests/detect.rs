//! The training-free detector on generated scenes (lavapipe): it finds an object on
//! clutter with no mask and no box, every instance of it, nothing on an image without it,
//! refuses bad search settings by name, and its templates survive the store.

use b2tfpose::detect::detector::bbox_of;
use b2tfpose::detect::nms::box_iou;
use b2tfpose::detect::{detect, DetectOptions, ShapeModel, Target};
use b2tfpose::eval::scenes::{generate_image, SceneConfig, SceneImage};
use b2tfpose::features::{EmbeddedBackbone, EmbeddedConfig};
use b2tfpose::geometry::{geodesic_distance, ViewSampling};
use b2tfpose::mesh::procedural::textured_box;
use b2tfpose::mesh::Mesh;
use b2tfpose::onboard::{onboard, OnboardConfig, PatchRows};
use b2tfpose::render::{RenderPool, RendererConfig};
use std::sync::OnceLock;

// Two tests that find objects on clutter are ignored for now: there the true object scores
// under the default threshold at its coarse pose, and one of several instances is missed
// (docs/detection.md). They state what it must do; `cargo test --test detect -- --ignored`
// runs them.

struct Fixture {
    mesh: Mesh,
    shape: ShapeModel,
    pool: RenderPool,
}

fn fixture() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        let pool = RenderPool::new(1, RendererConfig::default()).unwrap();
        let mesh = textured_box([0.10, 0.06, 0.16], 3);
        let shape = ShapeModel::build(&mesh, &pool, &Default::default()).unwrap();
        Fixture { mesh, shape, pool }
    })
}

fn target(f: &Fixture) -> Vec<Target<'_>> {
    vec![Target { id: "box", shape: &f.shape, mesh: &f.mesh }]
}

fn scene(objects: &[(u32, Mesh)], per_image: usize, seed: u64) -> SceneImage {
    let cfg = SceneConfig { images: 1, objects_per_image: per_image, fill_range: (0.25, 0.4), max_occlusion: 0.2, seed, ..Default::default() };
    generate_image(objects, &cfg, &fixture().pool, 0).unwrap()
}

#[test]
#[ignore = "the detector does not reach this yet (docs/detection.md, issue 26): run with --ignored while improving it"]
fn finds_the_object_on_clutter_with_its_coarse_pose() {
    let f = fixture();
    let s = scene(&[(1, f.mesh.clone())], 1, 11);
    let r = detect(&s.rgb, None, &s.cam, &target(f), &DetectOptions::default(), &f.pool).unwrap();
    let truth = &s.instances[0];
    let d = r.detections.first().unwrap_or_else(|| panic!("nothing found: {:?}", r.reason));
    let iou = box_iou(&d.bbox, &bbox_of(&truth.mask_visib).unwrap());
    assert!(iou >= 0.7, "box IoU {iou}");
    let rot = geodesic_distance(&d.pose.rotation, &truth.pose.rotation).to_degrees();
    let depth = (d.pose.translation.z / truth.pose.translation.z - 1.0).abs();
    // A template is at most ~20° from any view; the box's half-turn symmetries count as right.
    assert!(!(35.0..=145.0).contains(&rot), "coarse rotation {rot}° off");
    assert!(depth < 0.15, "coarse depth {:.0} % off", depth * 100.0);
    // Only one instance: whatever else scored is far below it or suppressed.
    assert_eq!(r.detections.len(), 1, "{:?}", r.detections.iter().map(|d| (d.bbox, d.score)).collect::<Vec<_>>());
}

#[test]
#[ignore = "the detector does not reach this yet (docs/detection.md, issue 26): run with --ignored while improving it"]
fn finds_every_instance_of_one_object() {
    let f = fixture();
    let s = scene(&[(1, f.mesh.clone())], 3, 5);
    let r = detect(&s.rgb, None, &s.cam, &target(f), &DetectOptions::default(), &f.pool).unwrap();
    for (i, inst) in s.instances.iter().enumerate() {
        let b = bbox_of(&inst.mask_visib).unwrap();
        assert!(r.detections.iter().any(|d| box_iou(&d.bbox, &b) >= 0.5), "instance {i} at {b:?} not found among {:?}", r.detections.iter().map(|d| d.bbox).collect::<Vec<_>>());
    }
}

#[test]
fn an_image_without_the_object_gives_no_detection_and_a_reason() {
    let f = fixture();
    // A different shape (a flat disc-like box of other colours) on the same clutter.
    let other = textured_box([0.20, 0.20, 0.02], 9);
    let s = scene(&[(2, other)], 2, 21);
    let r = detect(&s.rgb, None, &s.cam, &target(f), &DetectOptions::default(), &f.pool).unwrap();
    assert!(r.detections.is_empty(), "{:?}", r.detections.iter().map(|d| (d.bbox, d.score)).collect::<Vec<_>>());
    assert!(r.reason.as_deref().unwrap_or("").contains("no candidate scored"), "{:?}", r.reason);
}

#[test]
fn bad_search_settings_are_refused_by_name() {
    let f = fixture();
    let s = scene(&[(1, f.mesh.clone())], 1, 11);
    let run = |o: DetectOptions| detect(&s.rgb, None, &s.cam, &target(f), &o, &f.pool).err().map(|e| e.to_string()).unwrap_or_default();
    assert!(run(DetectOptions { min_distance_m: Some(2.0), max_distance_m: Some(1.0), ..Default::default() }).contains("min_distance_m (2) must be below max_distance_m (1)"));
    assert!(run(DetectOptions { max_distance_m: Some(f64::NAN), ..Default::default() }).contains("max_distance_m must be within"));
    assert!(run(DetectOptions { max_detections: 0, ..Default::default() }).contains("max_detections must be 1–"));
    assert!(run(DetectOptions { min_score: 1.5, ..Default::default() }).contains("min_score must be within 0–1"));
    let mut wrong = s.cam;
    wrong.width += 2;
    let e = detect(&s.rgb, None, &wrong, &target(f), &DetectOptions::default(), &f.pool).unwrap_err().to_string();
    assert!(e.contains("differs from the image's"), "{e}");
    // A range where the object cannot show at a searchable size is an answer, not an error.
    let far = detect(&s.rgb, None, &s.cam, &target(f), &DetectOptions { min_distance_m: Some(500.0), max_distance_m: Some(900.0), ..Default::default() }, &f.pool).unwrap();
    assert!(far.detections.is_empty() && far.reason.as_deref().unwrap_or("").contains("no scale to search"), "{:?}", far.reason);
}

#[test]
fn templates_are_stored_with_the_object_and_rebuilt_for_older_ones() {
    let f = fixture();
    let backbone = EmbeddedBackbone::new(EmbeddedConfig::default()).unwrap();
    let cfg = OnboardConfig { views: ViewSampling { level: 0, in_plane_steps: 2 }, render_size: 128, ..Default::default() };
    let model = onboard("box", &f.mesh, &cfg, &backbone, &f.pool, &|_| {}).unwrap();
    let built = model.detector.get().expect("onboarding builds the detector's templates");
    assert_eq!(**built, f.shape, "onboarding's templates are the detector's own");
    let dir = tempfile::tempdir().unwrap();
    let store = b2tfpose::store::open(&format!("dir://{}", dir.path().display())).unwrap();
    store.put(&model, false).unwrap();
    let loaded = store.get("box").unwrap();
    assert_eq!(loaded.detector.get().map(|d| d.as_ref()), Some(built.as_ref()));
    // An object stored before the detector existed gets its templates on first use.
    let old = b2tfpose::onboard::ObjectModel { detector: OnceLock::new(), ..loaded.clone() };
    assert_eq!(*old.shape_model_or_build(&f.pool).unwrap(), f.shape);
}

#[test]
fn finds_the_object_on_a_plain_background() {
    let f = fixture();
    let k = b2tfpose::geometry::Intrinsics::new(600.0, 600.0, 319.5, 239.5, 640, 480).unwrap();
    let truth = b2tfpose::geometry::views::view_pose(&nalgebra::Vector3::new(0.3, -0.5, 0.8).normalize(), 0.7, &nalgebra::Vector3::zeros(), 0.6);
    let truth = b2tfpose::geometry::Pose::new(truth.rotation, truth.translation + nalgebra::Vector3::new(0.05, -0.03, 0.0));
    let r = f.pool.render(&f.mesh, &truth, &k, &Default::default()).unwrap();
    let img = image::RgbImage::from_fn(640, 480, |x, y| if r.mask.get_pixel(x, y)[0] > 0 { *r.rgb.get_pixel(x, y) } else { image::Rgb([90, 100, 110]) });
    // The whole box ranks first, not a part of its print (at the coarse pose it scores
    // about 0.4, under the default threshold: docs/detection.md).
    let rep = detect(&img, None, &k, &target(f), &DetectOptions { min_score: 0.0, ..Default::default() }, &f.pool).unwrap();
    let truth_box = bbox_of(&r.mask).unwrap();
    let found: Vec<_> = rep.detections.iter().take(5).map(|d| (d.bbox, d.score, box_iou(&d.bbox, &truth_box))).collect();
    assert!(found.first().is_some_and(|d| d.2 > 0.7), "truth {truth_box:?}, best five {found:?}");
}

fn b2tf(args: &[&str]) -> (bool, String, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_b2tf")).args(args).env("XDG_RUNTIME_DIR", "/tmp").output().expect("runs");
    (out.status.success(), String::from_utf8_lossy(&out.stdout).into(), String::from_utf8_lossy(&out.stderr).into())
}

/// `b2tf objects upgrade` gives an object stored without detector templates (and with the
/// f32 patch points of format 6, and a contour model without plain runs) its templates,
/// grid-coded points and plain runs;
/// `b2tf detect` writes BOP default detections and refuses bad input by name.
#[test]
fn upgrade_and_detect_from_the_command_line() {
    let f = fixture();
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let store_url = format!("dir://{}", d.join("store").display());
    let (ok, out, err) = b2tf(&["detect", "--store", &store_url, "--image", "x.png", "--camera", "c.json", "--out", "o.json"]);
    assert!(!ok && err.contains("holds no object: onboard one first"), "{out}{err}");

    let backbone = EmbeddedBackbone::new(EmbeddedConfig::default()).unwrap();
    let cfg = OnboardConfig { views: ViewSampling { level: 0, in_plane_steps: 2 }, render_size: 128, ..Default::default() };
    let model = onboard("box_7", &f.mesh, &cfg, &backbone, &f.pool, &|_| {}).unwrap();
    let mut points = Vec::new();
    model.patch_points.extend_range(0..model.patch_count(), &mut points);
    // The printed box's contour model as stored before plain runs were kept.
    let contour = b2tfpose::onboard::ContourModel { plain_share: vec![], ..(**model.contours.get().unwrap()).clone() };
    let old = b2tfpose::onboard::ObjectModel {
        detector: OnceLock::new(),
        patch_points: b2tfpose::onboard::PatchPoints::Exact(points.into()),
        contours: OnceLock::from(std::sync::Arc::new(contour)),
        ..model
    };
    let store = b2tfpose::store::open(&store_url).unwrap();
    store.put(&old, false).unwrap();
    assert!(store.get("box_7").unwrap().detector.get().is_none() && !store.get("box_7").unwrap().patch_points.is_grid());
    let (ok, out, err) = b2tf(&["objects", "upgrade", "--store", &store_url]);
    assert!(ok && out.contains("box_7: added plain print runs and detector templates and compact patch points"), "{out}{err}");
    let upgraded = store.get("box_7").unwrap();
    assert_eq!(upgraded.contours.get().unwrap().plain_share.len(), upgraded.contours.get().unwrap().points.len());
    assert_eq!(upgraded.detector.get().map(|d| d.template_count()), Some(f.shape.template_count()));
    assert!(upgraded.patch_points.is_grid());
    let (ok, out, _) = b2tf(&["objects", "upgrade", "--store", &store_url, "box_7"]);
    assert!(ok && out.contains("box_7: up to date"), "{out}");

    // An object holding its patch rows per template (as before per view was the default)
    // is left so, with a hint, unless asked to keep them per view.
    let rows_url = format!("dir://{}", d.join("rows").display());
    let per_template = onboard("box_9", &f.mesh, &OnboardConfig { patch_rows: PatchRows::PerTemplate, ..cfg.clone() }, &backbone, &f.pool, &|_| {}).unwrap();
    let rows_store = b2tfpose::store::open(&rows_url).unwrap();
    rows_store.put(&per_template, false).unwrap();
    let (ok, out, err) = b2tf(&["objects", "upgrade", "--store", &rows_url]);
    assert!(ok && out.contains("box_9: up to date (patch rows per template: --rows-per-view"), "{out}{err}");
    assert!(!rows_store.get("box_9").unwrap().rows_per_view());
    let (ok, out, err) = b2tf(&["objects", "upgrade", "--store", &rows_url, "--rows-per-view", "box_9"]);
    assert!(ok && out.contains("box_9: added patch rows per view"), "{out}{err}");
    let shared = rows_store.get("box_9").unwrap();
    assert!(shared.rows_per_view() && shared.patch_count() < per_template.patch_count() && shared.templates.len() == per_template.templates.len());
    let (ok, out, _) = b2tf(&["objects", "upgrade", "--store", &rows_url, "--rows-per-view"]);
    assert!(ok && out.contains("box_9: up to date") && !out.contains("--rows-per-view"), "{out}");

    let s = scene(&[(1, f.mesh.clone())], 1, 11);
    s.rgb.save(d.join("scene.png")).unwrap();
    let k = s.cam;
    std::fs::write(d.join("cam.json"), format!(r#"{{"cam_K": [{}, 0, {}, 0, {}, {}, 0, 0, 1], "width": {}, "height": {}}}"#, k.fx, k.cx, k.fy, k.cy, k.width, k.height)).unwrap();
    let (img, cam, out_json) = (d.join("scene.png"), d.join("cam.json"), d.join("dets.json"));
    let common = ["detect", "--store", &store_url, "--image", img.to_str().unwrap(), "--camera", cam.to_str().unwrap(), "--out", out_json.to_str().unwrap()];
    // Every candidate kept: the file's entries are BOP default detections.
    let (ok, out, err) = b2tf(&[&common[..], &["--min-score", "0", "--max-detections", "3", "--scene-id", "4", "--image-id", "9", "--overlay", d.join("o.png").to_str().unwrap()]].concat());
    assert!(ok, "{out}{err}");
    let list: Vec<serde_json::Value> = serde_json::from_slice(&std::fs::read(&out_json).unwrap()).unwrap();
    assert!(!list.is_empty() && list.len() <= 3, "{list:?}");
    for e in &list {
        assert_eq!((e["scene_id"].as_u64(), e["image_id"].as_u64(), e["category_id"].as_u64(), e["object"].as_str()), (Some(4), Some(9), Some(7), Some("box_7")));
        assert_eq!(e["bbox"].as_array().map(|b| b.len()), Some(4));
        assert!(e["score"].as_f64().is_some() && e["time"].as_f64().is_some());
        assert_eq!(e["segmentation"]["size"], serde_json::json!([k.height, k.width]));
    }
    // The file reads back with the BOP detections reader.
    assert_eq!(b2tfpose::bop::detections::read_detections(&out_json).unwrap().len(), list.len());
    assert_eq!(image::open(d.join("o.png")).unwrap().to_rgb8().dimensions(), (k.width, k.height));
    let (ok, _, err) = b2tf(&[&common[..], &["--min-distance", "2", "--max-distance", "1"]].concat());
    assert!(!ok && err.contains("min_distance_m (2) must be below max_distance_m (1)"), "{err}");
    let (ok, _, err) = b2tf(&[&common[..], &["--object", "nothing_here"]].concat());
    assert!(!ok && err.contains("\"nothing_here\"") && err.contains("not found"), "{err}");

    // `b2tf bench detect --estimate-store` needs every searched mesh onboarded under its
    // file's name, and the textured objects: both refused by name before any work.
    let ply = b2tfpose::mesh::write_ply::write_bop_ply(&f.mesh, d, "obj_000001").unwrap();
    let bench = ["bench", "detect", "--mesh", ply.to_str().unwrap(), "--units", "mm", "--images", "1", "--empty-images", "0", "--estimate-store", &store_url];
    let (ok, _, err) = b2tf(&bench);
    assert!(!ok && err.contains("has no object \"obj_000001\"") && err.contains("--id obj_000001"), "{err}");
    let (ok, _, err) = b2tf(&[&bench[..], &["--untextured"]].concat());
    assert!(!ok && err.contains("leave out --untextured"), "{err}");

    // `b2tf estimate` with no mask and no box: the object id alone, the detector finds it.
    let est = d.join("est.json");
    let estimate = ["estimate", "--store", &store_url, "--object", "box_7", "--image", img.to_str().unwrap(), "--camera", cam.to_str().unwrap(), "--out", est.to_str().unwrap(), "--no-rrc"];
    let (ok, out, err) = b2tf(&[&estimate[..], &["--min-score", "0"]].concat());
    assert!(ok && out.contains("box_7 detected at [") && est.exists(), "{out}{err}");
    image::RgbImage::from_pixel(k.width, k.height, image::Rgb([90, 90, 90])).save(&img).unwrap();
    let (ok, out, err) = b2tf(&estimate);
    assert!(!ok && err.contains("the detector did not find box_7") && err.contains("give a --mask"), "{out}{err}");
}

/// The scene's depth (objects only, nothing behind them) as a depth camera's image.
fn depth_of(s: &SceneImage) -> b2tfpose::depth::DepthImage {
    b2tfpose::depth::DepthImage::from_metres(s.cam.width, s.cam.height, s.depth.clone()).unwrap()
}

#[test]
fn with_depth_every_thing_of_the_objects_size_is_a_candidate_and_others_are_not() {
    let f = fixture();
    // The box (16 cm tall) and a 40 cm plate: only the box is of the box's size.
    let plate = textured_box([0.40, 0.40, 0.02], 9);
    let s = scene(&[(1, f.mesh.clone()), (2, plate)], 2, 7);
    let depth = depth_of(&s);
    let r = detect(&s.rgb, Some(&depth), &s.cam, &target(f), &DetectOptions::default(), &f.pool).unwrap();
    let boxes: Vec<[f64; 4]> = s.instances.iter().filter(|i| i.obj_id == 1).filter_map(|i| bbox_of(&i.mask_visib)).collect();
    let plates: Vec<[f64; 4]> = s.instances.iter().filter(|i| i.obj_id == 2).filter_map(|i| bbox_of(&i.mask_visib)).collect();
    let found: Vec<[f64; 4]> = r.detections.iter().map(|d| d.bbox).collect();
    for b in &boxes {
        assert!(found.iter().any(|d| box_iou(d, b) >= 0.5), "box at {b:?} not among {found:?}");
    }
    for p in &plates {
        assert!(found.iter().all(|d| box_iou(d, p) < 0.5), "the plate at {p:?} taken for the box: {found:?}");
    }
    assert!(r.detections.iter().all(|d| d.mask_source == b2tfpose::detect::MaskSource::DepthSegment));
    // A distance range that holds none of it answers why, and a depth of another size is refused.
    let far = detect(&s.rgb, Some(&depth), &s.cam, &target(f), &DetectOptions { min_distance_m: Some(50.0), ..Default::default() }, &f.pool).unwrap();
    assert!(far.detections.is_empty() && far.reason.as_deref().unwrap_or("").contains("distance range"), "{:?}", far.reason);
    let small = b2tfpose::depth::DepthImage::from_metres(4, 4, vec![1.0; 16]).unwrap();
    let e = detect(&s.rgb, Some(&small), &s.cam, &target(f), &DetectOptions::default(), &f.pool).unwrap_err().to_string();
    assert!(e.contains("depth is 4×4 but the image is"), "{e}");
}

#[test]
fn the_depth_confirms_the_object_where_it_is_and_refutes_it_elsewhere() {
    let f = fixture();
    let s = scene(&[(1, f.mesh.clone())], 1, 11);
    let depth = depth_of(&s);
    let truth = &s.instances[0];
    let at = |pose: &b2tfpose::geometry::Pose| b2tfpose::detect::confirm::confirm(&s.rgb, Some(&depth), &s.cam, &f.mesh, &truth.mask_visib, pose, &f.pool).unwrap();
    let right = at(&truth.pose);
    // 5 cm nearer: the camera sees the object's surface behind the pose everywhere.
    let nearer = b2tfpose::geometry::Pose::new(truth.pose.rotation, truth.pose.translation * (1.0 - 0.05 / truth.pose.translation.norm()));
    let wrong = at(&nearer);
    assert!(right > 0.6 && wrong < 0.2, "right {right}, 5 cm nearer {wrong}");
    // The screen of the depth detector's candidates confirms as an answer would, and
    // needs less than an answer: a coarse pose is 10–20° off.
    use b2tfpose::detect::confirm::confirmation_needed;
    use b2tfpose::estimate::{CoarseCheck, DepthScreen};
    assert!(DepthScreen::of(&s.rgb, None, &s.cam, &f.mesh, &f.pool, 0.45).is_none(), "no screen without depth");
    let screen = DepthScreen::of(&s.rgb, Some(&depth), &s.cam, &f.mesh, &f.pool, 0.45).unwrap();
    assert_eq!(screen.score(&truth.mask_visib, &truth.pose).unwrap(), right);
    assert!(screen.needed() > 0.0 && screen.needed() < 0.5 * confirmation_needed(0.45, true), "{}", screen.needed());
}
