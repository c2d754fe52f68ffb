//! The `b2tf` binary as a user runs it: sample → render → onboard, and clear errors.

use std::path::Path;
use std::process::Command;

fn b2tf(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_b2tf")).args(args).env("XDG_RUNTIME_DIR", "/tmp").output().expect("runs");
    (out.status.success(), String::from_utf8_lossy(&out.stdout).into(), String::from_utf8_lossy(&out.stderr).into())
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn sample_render_and_onboard() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (ok, out, err) = b2tf(&["sample", "--out", s(&d.join("sample"))]);
    assert!(ok, "{out}{err}");
    let mesh = d.join("sample/sample_box.obj");
    let dir_store = format!("dir://{}", d.join("models").display());
    let cam = d.join("cam.json");
    std::fs::write(&cam, r#"{"cam_K": [500, 0, 159.5, 0, 500, 119.5, 0, 0, 1], "width": 320, "height": 240}"#).unwrap();
    let (ok, out, err) = b2tf(&["render", "--mesh", s(&mesh), "--units", "m", "--camera", s(&cam), "--out", s(&d.join("r")), "--pose", "1,0,0,0,1,0,0,0,1,0,0,0.5"]);
    assert!(ok, "{out}{err}");
    let mask = image::open(d.join("r/mask.png")).unwrap().to_luma8();
    assert_eq!(mask.dimensions(), (320, 240));
    // The box's 10 × 6 cm face nearest the camera is at 0.5 − 0.08 = 0.42 m; with f = 500
    // it covers 119.0 × 71.4 px.
    let on = mask.pixels().filter(|p| p[0] > 0).count();
    assert!((8300..8700).contains(&on), "{on} mask pixels");
    let depth = image::open(d.join("r/depth.png")).unwrap().to_luma16();
    // The box's front face is at z = 0.5 − 0.08 m = 0.42 m = 4200 × 0.1 mm.
    assert_eq!(depth.get_pixel(160, 120)[0], 4200);
    assert!(image::open(d.join("r/rgb.png")).is_ok());

    let (ok, out, err) = b2tf(&["onboard", "--mesh", s(&mesh), "--units", "m", "--id", "box", "--store", &dir_store, "--level", "0", "--in-plane", "2"]);
    assert!(ok, "{out}{err}");
    assert!(out.contains("24 templates"), "{out}");
    // The default (`auto`) with the embedded backbone: rows per view.
    assert!(out.contains("patch rows: per view, shared by its 2 in-plane turns"), "{out}");
    assert!(d.join("models/box/manifest.json").is_file());
    let (ok, out, err) = b2tf(&["objects", "list", "--store", &dir_store]);
    assert!(ok && out.contains("| box | m |") && out.contains("1 objects"), "{out}{err}");
    let (ok, out, err) = b2tf(&["objects", "show", "box", "--load", "--store", &dir_store]);
    assert!(ok && out.contains("\"templates\": 24") && out.contains("\"loaded\""), "{out}{err}");
    // Same id again without --replace is refused, with it accepted.
    let (ok, _, err) = b2tf(&["onboard", "--mesh", s(&mesh), "--units", "m", "--id", "box", "--store", &dir_store, "--level", "0", "--in-plane", "1"]);
    assert!(!ok && err.contains("--replace"), "{err}");
    // Compact descriptors on request: int8 rows, in less room than f16's.
    let f16_bytes = std::fs::metadata(d.join("models/box/tensors.safetensors")).unwrap().len();
    let (ok, out, err) = b2tf(&["onboard", "--mesh", s(&mesh), "--units", "m", "--id", "box", "--store", &dir_store, "--level", "0", "--in-plane", "2", "--replace", "--descriptors", "i8"]);
    assert!(ok && out.contains("int8 with a scale each"), "{out}{err}");
    assert!(std::fs::metadata(d.join("models/box/tensors.safetensors")).unwrap().len() < f16_bytes);
    let i8_bytes = std::fs::metadata(d.join("models/box/tensors.safetensors")).unwrap().len();
    let (ok, out, err) = b2tf(&["objects", "show", "box", "--load", "--store", &dir_store]);
    assert!(ok && out.contains("\"patch_rows\": \"per-view\"") && out.contains("\"descriptors\": \"i8\""), "{out}{err}");
    // Rows per template on request: every turn its own rows, more bytes.
    let (ok, out, err) = b2tf(&[
        "onboard",
        "--mesh",
        s(&mesh),
        "--units",
        "m",
        "--id",
        "box",
        "--store",
        &dir_store,
        "--level",
        "0",
        "--in-plane",
        "2",
        "--replace",
        "--descriptors",
        "i8",
        "--patch-rows",
        "per-template",
    ]);
    assert!(ok && !out.contains("patch rows: per view"), "{out}{err}");
    let (ok, out, err) = b2tf(&["objects", "show", "box", "--load", "--store", &dir_store]);
    assert!(ok && out.contains("\"patch_rows\": \"per-template\""), "{out}{err}");
    assert!(std::fs::metadata(d.join("models/box/tensors.safetensors")).unwrap().len() > i8_bytes);
    let (ok, _, err) = b2tf(&["onboard", "--mesh", s(&mesh), "--units", "m", "--id", "box2", "--store", &dir_store, "--patch-rows", "per-face"]);
    assert!(!ok && err.contains("'per-face'") && err.contains("per-view"), "{err}");
    let (ok, _, err) = b2tf(&["onboard", "--mesh", s(&mesh), "--units", "m", "--id", "box2", "--store", &dir_store, "--descriptors", "zip"]);
    assert!(!ok && err.contains("'zip'") && err.contains("f16"), "{err}");
    // Copied into another store as it is (moving to a bucket works the same way).
    let copy_store = format!("sqlite://{}", d.join("copy.db").display());
    let (ok, out, err) = b2tf(&["objects", "copy", "--store", &dir_store, "--to", &copy_store]);
    assert!(ok && out.contains("copied 1 object(s)"), "{out}{err}");
    let (ok, out, err) = b2tf(&["objects", "show", "box", "--load", "--store", &copy_store]);
    assert!(ok && out.contains("\"templates\": 24"), "{out}{err}");
    let (ok, out, err) = b2tf(&["objects", "copy", "--store", &dir_store, "--to", &copy_store]);
    assert!(ok && out.contains("left alone"), "a second copy without --replace: {out}{err}");
    let (ok, _, err) = b2tf(&["objects", "copy", "--store", &dir_store, "--to", &dir_store]);
    assert!(!ok && err.contains("--to names the store"), "{err}");
    let (ok, _, err) = b2tf(&["objects", "copy", "nope", "--store", &dir_store, "--to", &copy_store]);
    assert!(!ok && err.contains("not found"), "{err}");
    let (ok, _, err) = b2tf(&["objects", "copy", "--store", &dir_store, "--to", "ftp://x"]);
    assert!(!ok && err.contains("ftp://x"), "{err}");
    let (ok, out, err) = b2tf(&["objects", "delete", "box", "--store", &dir_store]);
    assert!(ok && out.contains("deleted"), "{out}{err}");
    let (ok, _, err) = b2tf(&["objects", "show", "box", "--store", &dir_store]);
    assert!(!ok && err.contains("not found"), "{err}");
    let (ok, _, err) = b2tf(&["objects", "list", "--store", "ftp://x"]);
    assert!(!ok && err.contains("dir://PATH, sqlite://PATH or s3://"), "{err}");
}

#[test]
fn bad_inputs_give_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    b2tf(&["sample", "--out", s(d)]);
    let mesh = d.join("sample_box.obj");
    let store = format!("sqlite://{}", d.join("objects.db").display());
    let cases: Vec<(Vec<String>, &str)> = vec![
        (vec!["onboard".into(), "--mesh".into(), s(&mesh).into(), "--id".into(), "x".into(), "--store".into(), store.clone()], "units must be given"),
        (vec!["onboard".into(), "--mesh".into(), s(&d.join("nope.ply")).into(), "--units".into(), "mm".into(), "--id".into(), "x".into(), "--store".into(), store.clone()], "nope.ply"),
        (vec!["onboard".into(), "--mesh".into(), s(&mesh).into(), "--units".into(), "m".into(), "--id".into(), "../evil".into(), "--store".into(), store.clone()], "invalid"),
        (vec!["onboard".into(), "--mesh".into(), s(&mesh).into(), "--units".into(), "m".into(), "--id".into(), "x".into(), "--store".into(), store.clone(), "--level".into(), "7".into()], "level"),
        (
            vec!["onboard".into(), "--mesh".into(), s(&mesh).into(), "--units".into(), "m".into(), "--id".into(), "x".into(), "--store".into(), store.clone(), "--backbone".into(), "dinov3".into()],
            "unknown backbone \"dinov3\"",
        ),
        (
            vec![
                "onboard".into(),
                "--mesh".into(),
                s(&mesh).into(),
                "--units".into(),
                "m".into(),
                "--id".into(),
                "x".into(),
                "--store".into(),
                store.clone(),
                "--backbone".into(),
                format!("onnx:{}", d.join("absent.onnx").display()),
            ],
            "absent.onnx",
        ),
        (
            vec!["onboard".into(), "--mesh".into(), s(&mesh).into(), "--units".into(), "m".into(), "--id".into(), "x".into(), "--store".into(), store.clone(), "--device".into(), "cuda:0".into()],
            "needs an ONNX backbone",
        ),
        (
            vec!["onboard".into(), "--mesh".into(), s(&mesh).into(), "--units".into(), "m".into(), "--id".into(), "x".into(), "--store".into(), store.clone(), "--device".into(), "gpu".into()],
            "unknown device \"gpu\"",
        ),
        (vec!["render".into(), "--mesh".into(), s(&mesh).into(), "--units".into(), "m".into(), "--camera".into(), s(&d.join("missing.json")).into(), "--out".into(), s(d).into()], "missing.json"),
        // Scene flags are checked before anything is onboarded.
        (
            vec!["bench".into(), "estimate".into(), "--images".into(), "1".into(), "--supersample".into(), "2".into(), "--store".into(), format!("dir://{}", d.join("bench").display())],
            "supersampling must be 1 or an odd number",
        ),
        (
            vec!["bench".into(), "refine".into(), "--images".into(), "1".into(), "--supersample".into(), "9".into(), "--store".into(), format!("dir://{}", d.join("bench").display())],
            "supersampling must be 1 or an odd number",
        ),
        (vec!["bench".into(), "estimate".into(), "--images".into(), "1".into(), "--photo-edges".into(), "textured".into()], "'textured'"),
        (
            vec![
                "estimate".into(),
                "--store".into(),
                store.clone(),
                "--object".into(),
                "x".into(),
                "--image".into(),
                "i.png".into(),
                "--camera".into(),
                "c.json".into(),
                "--depth-views".into(),
                "13".into(),
            ],
            "--depth-views",
        ),
        (vec!["render".into(), "--mesh".into(), s(&mesh).into(), "--units".into(), "furlongs".into(), "--camera".into(), "c.json".into(), "--out".into(), s(d).into()], "unknown length unit"),
    ];
    for (args, needle) in cases {
        let a: Vec<&str> = args.iter().map(|x| x.as_str()).collect();
        let (ok, out, err) = b2tf(&a);
        assert!(!ok, "{args:?} succeeded: {out}");
        assert!(err.contains(needle) && !err.contains("panicked"), "{args:?}: expected {needle:?} in {err}");
        assert!(!err.contains("sk-"), "a key in the error: {err}");
    }
}

#[test]
fn estimate_writes_the_result_json_and_overlay() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    assert!(b2tf(&["sample", "--out", s(&d.join("sample"))]).0);
    let mesh = d.join("sample/sample_box.obj");
    let store = format!("sqlite://{}", d.join("objects.db").display());
    let (ok, out, err) = b2tf(&["onboard", "--mesh", s(&mesh), "--units", "m", "--id", "box", "--store", &store, "--level", "1", "--in-plane", "6"]);
    assert!(ok, "{out}{err}");
    // The "photo": the box rendered at a pose (its mask serves as the detection).
    let cam = d.join("cam.json");
    std::fs::write(&cam, r#"{"K": [[500, 0, 159.5], [0, 500, 119.5], [0, 0, 1]], "resolution": [240, 320]}"#).unwrap();
    let pose = "0.8660254,0,0.5, 0.25,0.8660254,-0.4330127, -0.4330127,0.5,0.75, 0.01,-0.01,0.6";
    assert!(b2tf(&["render", "--mesh", s(&mesh), "--units", "m", "--camera", s(&cam), "--out", s(&d.join("r")), "--pose", pose]).0);
    let (img, mask) = (d.join("r/rgb.png"), d.join("r/mask.png"));
    let result = d.join("result.json");
    let overlay = d.join("overlay.png");
    let (ok, out, err) = b2tf(&[
        "estimate",
        "--store",
        &store,
        "--object",
        "box",
        "--image",
        s(&img),
        "--camera",
        s(&cam),
        "--mask",
        s(&mask),
        "--score",
        "0.9",
        "--no-rrc",
        "--out",
        s(&result),
        "--overlay",
        s(&overlay),
    ]);
    assert!(ok, "{out}{err}");
    let doc: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&result).unwrap()).unwrap();
    let p = &doc["poses"][0];
    assert_eq!(p["object"], "box");
    assert_eq!(p["R"].as_array().unwrap().len(), 9);
    assert_eq!(p["mask_index"], 0);
    let t: Vec<f64> = p["t"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    assert!((t[2] - 0.6).abs() < 0.06, "depth {t:?}");
    // The runner-up, printed and written as the service answers it.
    let up = &p["runner_up"];
    assert!(up["margin"].as_f64().unwrap() >= 0.0 && up["distance_over_diameter"].as_f64().unwrap() > 0.1 && up["pose"]["t"].as_array().unwrap().len() == 3, "{p}");
    assert!(out.contains("runner-up: ") && out.contains("lost by"), "{out}");
    // A close call is said where the answer says it is one, and only there.
    assert_eq!(out.contains("a close call"), up["close_call"].as_bool().expect("close_call written"), "{out}{p}");
    for stage in ["crop", "features", "retrieval", "matching", "pnp", "rrc", "selection", "total"] {
        assert!(doc["timings_ms"][stage].is_number(), "missing timing {stage}");
    }
    assert!(image::open(&overlay).is_ok());

    // A box instead of the mask: mask proposals inside it, the answer naming the box.
    let (x0, y0, x1, y1) = b2tfpose::features::mask_bbox(&image::open(&mask).unwrap().to_luma8()).unwrap();
    let bbox = format!("{x0},{y0},{},{}", x1 - x0 + 1, y1 - y0 + 1);
    let (ok, out, err) = b2tf(&["estimate", "--store", &store, "--object", "box", "--image", s(&img), "--camera", s(&cam), "--box", &bbox, "--no-rrc", "--out", s(&result)]);
    assert!(ok && out.contains("mask proposal"), "{out}{err}");
    let doc: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&result).unwrap()).unwrap();
    assert_eq!(doc["poses"][0]["mask_index"], 0, "{doc}");
    let t: Vec<f64> = doc["poses"][0]["t"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    assert!((t[2] - 0.6).abs() < 0.06, "depth from a box {t:?}");

    // With the depth the render wrote (0.1 mm units): the pose is fitted to it, and the
    // answer says how well the depth agrees.
    let depth = d.join("r/depth.png");
    let (ok, out, err) = b2tf(&[
        "estimate",
        "--store",
        &store,
        "--object",
        "box",
        "--image",
        s(&img),
        "--camera",
        s(&cam),
        "--box",
        &bbox,
        "--depth",
        s(&depth),
        "--depth-scale",
        "0.1",
        "--no-rrc",
        "--out",
        s(&result),
    ]);
    assert!(ok, "{out}{err}");
    let doc: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&result).unwrap()).unwrap();
    let t: Vec<f64> = doc["poses"][0]["t"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    assert!((t[0] - 0.01).abs() < 0.005 && (t[1] + 0.01).abs() < 0.005 && (t[2] - 0.6).abs() < 0.005, "with depth {t:?}");
    let fit = doc["poses"][0]["diagnostics"]["hypotheses"].as_array().unwrap().iter().find_map(|h| h["refinement"].get("depth_fit")).unwrap_or_else(|| panic!("no depth_fit in {doc}"));
    assert!(fit["inlier_share"].as_f64().unwrap() > 0.9, "{fit}");
    // Bad depth: not 16-bit, of another size, a scale that is not positive, or one that
    // makes the depth implausible (metres read as millimetres).
    let small = d.join("small-depth.png");
    image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_pixel(32, 24, image::Luma([6000])).save(&small).unwrap();
    for (file, scale, needle) in
        [(&mask, "0.1", "16-bit"), (&small, "0.1", "32×24 but the image is 320×240"), (&depth, "0", "depth scale must be finite and positive"), (&depth, "100", "--depth-scale 100")]
    {
        let (ok, _, err) =
            b2tf(&["estimate", "--store", &store, "--object", "box", "--image", s(&img), "--camera", s(&cam), "--box", &bbox, "--depth", s(file), "--depth-scale", scale, "--out", s(&result)]);
        assert!(!ok && err.contains(needle), "{file:?} × {scale}: {err}");
    }

    // Bad inputs: boxes outside the image or of zero area, neither mask nor box, more
    // scores than masks, a missing mask file, a camera of another size.
    for (bad, needle) in [("400,10,20,20", "lies outside the 320×240 image"), ("10,10,0,5", "zero area"), ("1,2,3", "X,Y,W,H")] {
        let (ok, _, err) = b2tf(&["estimate", "--store", &store, "--object", "box", "--image", s(&img), "--camera", s(&cam), "--box", bad, "--out", s(&result)]);
        assert!(!ok && err.contains(needle), "{bad}: {err}");
    }
    // Several boxes are cut side by side; the first bad one given is the one named.
    let (ok, _, err) =
        b2tf(&["estimate", "--store", &store, "--object", "box", "--image", s(&img), "--camera", s(&cam), "--box", &bbox, "--box", "10,10,0,5", "--box", "400,10,20,20", "--out", s(&result)]);
    assert!(!ok && err.contains("--box 10,10,0,5") && !err.contains("400,10"), "{err}");
    // Neither mask nor box: the detector's candidates are estimated and the one confirmed
    // at its estimated pose is answered; on an image without the object, a refusal that
    // names what to give instead.
    let (ok, out, err) = b2tf(&["estimate", "--store", &store, "--object", "box", "--image", s(&img), "--camera", s(&cam), "--no-rrc", "--out", s(&result)]);
    assert!(ok && out.contains("confirmed at its pose"), "{out}{err}");
    let doc: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&result).unwrap()).unwrap();
    let confirmed = doc["poses"][0]["confirmation_score"].as_f64().unwrap();
    let t: Vec<f64> = doc["poses"][0]["t"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    assert!(confirmed >= b2tfpose::detect::DetectOptions::default().min_score as f64 && (t[2] - 0.6).abs() < 0.06, "{doc}");
    // With the depth: found among the surfaces of its size, and the answer reviewed beside
    // the views found in the depth (which may stand or give way to one).
    let (ok, out, err) =
        b2tf(&["estimate", "--store", &store, "--object", "box", "--image", s(&img), "--camera", s(&cam), "--depth", s(&depth), "--depth-scale", "0.1", "--no-rrc", "--out", s(&result)]);
    assert!(ok && out.contains("confirmed at its pose"), "{out}{err}");
    let doc: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&result).unwrap()).unwrap();
    let t: Vec<f64> = doc["poses"][0]["t"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    assert!((t[2] - 0.6).abs() < 0.03, "{doc}");
    let blank = d.join("blank.png");
    image::RgbImage::from_pixel(320, 240, image::Rgb([90, 90, 90])).save(&blank).unwrap();
    let (ok, _, err) = b2tf(&["estimate", "--store", &store, "--object", "box", "--image", s(&blank), "--camera", s(&cam), "--out", s(&result)]);
    assert!(!ok && err.contains("--mask"), "{err}");
    let (ok, _, err) = b2tf(&["estimate", "--store", &store, "--object", "box", "--image", s(&img), "--camera", s(&cam), "--mask", s(&mask), "--score", "1", "--score", "2", "--out", s(&result)]);
    assert!(!ok && err.contains("--score values"), "{err}");
    let (ok, _, err) = b2tf(&["estimate", "--store", &store, "--object", "box", "--image", s(&img), "--camera", s(&cam), "--mask", s(&d.join("none.png")), "--out", s(&result)]);
    assert!(!ok && err.contains("none.png"), "{err}");
    let cam2 = d.join("cam2.json");
    std::fs::write(&cam2, r#"{"cam_K": [500, 0, 159.5, 0, 500, 119.5, 0, 0, 1], "width": 640, "height": 480}"#).unwrap();
    let (ok, _, err) = b2tf(&["estimate", "--store", &store, "--object", "box", "--image", s(&img), "--camera", s(&cam2), "--mask", s(&mask), "--out", s(&result)]);
    assert!(!ok && err.contains("camera resolution"), "{err}");
    let (ok, _, err) = b2tf(&["estimate", "--store", &store, "--object", "nope", "--image", s(&img), "--camera", s(&cam), "--mask", s(&mask), "--out", s(&result)]);
    assert!(!ok && err.contains("nope"), "{err}");
}

#[test]
fn bop_commands_name_the_bad_file_and_entry() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let csv = d.join("results.csv");
    std::fs::write(&csv, "scene_id,im_id,obj_id,score,R,t,time\n1,0,1,0.9,1 0 0 0 1 0 0 0,0 0 500,0.1\n").unwrap();
    let (ok, _, err) = b2tf(&["bop", "eval", "--dataset", s(d), "--results", s(&csv)]);
    assert!(!ok && err.contains("results.csv") && err.contains("line 2") && err.contains("R"), "{err}");

    let dets = d.join("dets.json");
    std::fs::write(&dets, r#"[{"scene_id": 1, "image_id": 0, "category_id": 1, "bbox": [0, 0, 4, 4], "score": 0.9, "segmentation": {"counts": [3, 2], "size": [4, 4]}}]"#).unwrap();
    let (ok, _, err) = b2tf(&["bop", "run", "--dataset", s(d), "--detections", s(&dets), "--out", s(&d.join("out.csv"))]);
    assert!(!ok && err.contains("dets.json") && err.contains("entry 0") && err.contains("segmentation"), "{err}");

    // A well-formed detections file, but the dataset has no targets file.
    std::fs::write(&dets, "[]").unwrap();
    let (ok, _, err) = b2tf(&["bop", "run", "--dataset", s(d), "--detections", s(&dets), "--out", s(&d.join("out.csv"))]);
    assert!(!ok && err.contains("test_targets_bop19.json"), "{err}");
    // Box masks: an unknown way or proposal source is named before any work.
    let (ok, _, err) = b2tf(&["bop", "run", "--dataset", s(d), "--detections", s(&dets), "--out", s(&d.join("out.csv")), "--box-proposals", "cut,grabcut"]);
    assert!(!ok && err.contains("box proposal source \"grabcut\": expected cut, smooth-cut, wide-ring-cut, ellipse or fill"), "{err}");
    let (ok, _, err) = b2tf(&["bop", "run", "--dataset", s(d), "--detections", s(&dets), "--out", s(&d.join("out.csv")), "--box-mask", "grabcut"]);
    assert!(!ok && err.contains("expected propose, segment or fill"), "{err}");

    let (ok, _, err) = b2tf(&["bop", "synth", "--models", s(d), "--out", s(&d.join("ds"))]);
    assert!(!ok && err.contains("no BOP models"), "{err}");
}

#[test]
fn serve_and_demo_client_refuse_bad_settings_at_start() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let store = format!("sqlite://{}", d.join("o.db").display());
    let config = d.join("b2tf.toml");
    std::fs::write(&config, "max_estimatez = 2\n").unwrap();
    std::fs::write(d.join("junk.pem"), "not a certificate").unwrap();
    std::fs::write(d.join("keys"), "sk-1 scopes=read\nsk-2 scopes=reed\n").unwrap();
    let leaf = rcgen::generate_simple_self_signed(vec!["localhost".to_string()]).unwrap();
    std::fs::write(d.join("cert.pem"), leaf.cert.pem()).unwrap();
    std::fs::write(d.join("key.pem"), leaf.signing_key.serialize_pem()).unwrap();
    let tls = |ca: &str| {
        vec![
            "serve".to_string(),
            "--tls-cert".into(),
            s(&d.join("cert.pem")).into(),
            "--tls-key".into(),
            s(&d.join("key.pem")).into(),
            "--tls-client-ca".into(),
            s(&d.join(ca)).into(),
            "--store".into(),
            store.clone(),
        ]
    };
    let cases: Vec<(Vec<String>, &str)> = vec![
        (vec!["serve".into(), "--config".into(), s(&config).into(), "--store".into(), store.clone()], "max_estimatez"),
        (vec!["serve".into(), "--config".into(), s(&d.join("absent.toml")).into()], "absent.toml"),
        (vec!["serve".into(), "--http".into(), "none".into(), "--grpc".into(), "none".into(), "--store".into(), store.clone()], "both listeners are off"),
        (vec!["serve".into(), "--backbone".into(), "dinov3".into(), "--store".into(), store.clone()], "dinov3"),
        (vec!["serve".into(), "--device".into(), "cuda:0".into(), "--store".into(), store.clone()], "needs an ONNX backbone"),
        (vec!["serve".into(), "--tls-cert".into(), s(&d.join("junk.pem")).into(), "--tls-key".into(), s(&d.join("junk.pem")).into(), "--store".into(), store.clone()], "junk.pem"),
        (vec!["serve".into(), "--http".into(), "not-an-address".into(), "--grpc".into(), "none".into(), "--store".into(), store.clone()], "not-an-address"),
        (vec!["serve".into(), "--api-keys-file".into(), s(&d.join("keys")).into(), "--store".into(), store.clone()], "line 2: unknown scope \"reed\""),
        (vec!["serve".into(), "--tls-client-ca".into(), s(&d.join("cert.pem")).into(), "--store".into(), store.clone()], "tls_client_ca (mTLS) needs TLS"),
        (tls("cert.pem"), "certificate 1 is not a CA certificate"),
        (tls("junk.pem"), "no certificate in it"),
        (tls("absent.pem"), "absent.pem"),
        (vec!["serve".into(), "--rate-limit".into(), "10/day".into(), "--store".into(), store.clone()], "rate limit \"10/day\""),
        (vec!["demo".into(), "--out".into(), s(d).into(), "--server".into(), "ftp://x".into()], "grpc://HOST:PORT"),
        (vec!["demo".into(), "--out".into(), s(d).into(), "--server".into(), "grpcs://127.0.0.1:1".into()], "--ca-cert"),
        (vec!["demo".into(), "--out".into(), s(d).into(), "--server".into(), "grpc://127.0.0.1:1".into()], "cannot reach"),
    ];
    for (args, needle) in cases {
        let a: Vec<&str> = args.iter().map(|x| x.as_str()).collect();
        let (ok, out, err) = b2tf(&a);
        assert!(!ok, "{args:?} succeeded: {out}");
        assert!(err.contains(needle) && !err.contains("panicked"), "{args:?}: expected {needle:?} in {err}");
        assert!(!err.contains("sk-"), "a key in the error: {err}");
    }
}
