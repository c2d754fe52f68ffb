//! The HTTP service as clients see it: a real `b2tf serve` process on loopback, onboarding
//! the generated sample object through the API, estimating its pose in a rendered photo,
//! and every kind of bad input answered with the right status while the server keeps
//! serving.

mod common;

use b2tfpose::service::client::png_bytes;
use base64::Engine as _;
use common::{pose_errors, sample_files, scene, start};
use serde_json::{json, Value};
use std::time::{Duration, Instant};

fn b64(bytes: &[u8]) -> String {
    base64::engine::general_purpose::STANDARD.encode(bytes)
}

/// PNG file bytes of an RGB or grey image, base64.
fn png<P: image::PixelWithColorType>(img: &image::ImageBuffer<P, Vec<P::Subpixel>>) -> String
where
    [P::Subpixel]: image::EncodableLayout,
{
    b64(&png_bytes(img).unwrap())
}

/// A metric's value in the server's Prometheus text (0 when absent).
fn metric(c: &reqwest::blocking::Client, base: &str, name: &str) -> f64 {
    let text = c.get(format!("{base}/metrics")).send().unwrap().text().unwrap();
    text.lines().find_map(|l| l.strip_prefix(name).and_then(|rest| rest.strip_prefix(' ')).and_then(|v| v.trim().parse().ok())).unwrap_or(0.0)
}

fn client() -> reqwest::blocking::Client {
    common::http_client().timeout(Duration::from_secs(300)).build().unwrap()
}

fn call(c: &reqwest::blocking::Client, method: &str, url: &str, body: Option<&Value>) -> (u16, Value) {
    let req = match method {
        "GET" => c.get(url),
        "DELETE" => c.delete(url),
        _ => c.post(url),
    };
    let req = match body {
        Some(b) => req.json(b),
        None => req,
    };
    let r = req.send().expect("request sent");
    let status = r.status().as_u16();
    let text = r.text().unwrap_or_default();
    (status, serde_json::from_str(&text).unwrap_or(Value::String(text)))
}

#[test]
fn onboard_estimate_and_bad_inputs_over_http() {
    let dir = tempfile::tempdir().unwrap();
    let store = format!("sqlite://{}", dir.path().join("objects.db").display());
    // One estimate may wait for a slot (2 run): the concurrency check below fills the line.
    let mut server = start(&store, None, &["--queue-depth", "1"]);
    let (c, base) = (client(), server.http.clone());
    let healthy = |c: &reqwest::blocking::Client| assert_eq!(call(c, "GET", &format!("{base}/healthz"), None).0, 200);
    healthy(&c);
    let t = Instant::now();
    while call(&c, "GET", &format!("{base}/readyz"), None).0 != 200 {
        assert!(t.elapsed() < Duration::from_secs(60), "never ready");
        std::thread::sleep(Duration::from_millis(100));
    }

    // Onboard the sample box (OBJ + MTL + PNG texture) through the API.
    let files = sample_files(dir.path());
    let onboard = json!({
        "object_id": "box",
        "mesh": {"data": b64(&files[0].1), "format": "obj", "units": "m",
                 "resources": [{"name": files[1].0, "data": b64(&files[1].1)}, {"name": files[2].0, "data": b64(&files[2].1)}]},
        "options": {"level": 1, "in_plane": 6}
    });
    let (status, op) = call(&c, "POST", &format!("{base}/v1/objects"), Some(&onboard));
    assert_eq!(status, 202, "{op}");
    let op_url = format!("{base}/v1/operations/{}", op["id"].as_str().unwrap());
    let t = Instant::now();
    let done = loop {
        let (s, o) = call(&c, "GET", &op_url, None);
        assert_eq!(s, 200, "{o}");
        if o["state"] != "running" {
            break o;
        }
        assert!(t.elapsed() < Duration::from_secs(600), "onboarding did not finish: {o}");
        std::thread::sleep(Duration::from_millis(200));
    };
    assert_eq!(done["state"], "succeeded", "{done}");
    assert_eq!(done["object"]["templates"], 42 * 6);
    // Onboarding went through the backbone queue with many templates per pass.
    let (passes, crops) = (metric(&c, &base, "b2tf_backbone_batch_crops_count"), metric(&c, &base, "b2tf_backbone_batch_crops_sum"));
    assert!(crops >= 252.0 && passes * 4.0 <= crops, "{passes} queue passes for {crops} crops");
    let (s, list) = call(&c, "GET", &format!("{base}/v1/objects"), None);
    assert!(s == 200 && list["objects"][0]["id"] == "box", "{list}");
    // Symmetries found from the mesh: the box's textured faces all differ, so it has none.
    let no_symmetries = json!({"source": "mesh", "discrete": [], "continuous": []});
    let (s, info) = call(&c, "GET", &format!("{base}/v1/objects/box"), None);
    assert!(s == 200 && info["symmetries"] == no_symmetries && list["objects"][0]["symmetries"] == no_symmetries, "{info} {list}");
    // Its thumbnail: a PNG of the asked size with the object drawn on the plain background;
    // a size out of range or an unknown object is refused, naming what is wrong.
    let r = c.get(format!("{base}/v1/objects/box/thumbnail?size=96")).send().unwrap();
    assert_eq!((r.status().as_u16(), r.headers()["content-type"].to_str().unwrap()), (200, "image/png"));
    let thumb = image::load_from_memory(&r.bytes().unwrap()).unwrap().to_rgb8();
    let drawn = thumb.pixels().filter(|p| p.0 != [238, 241, 245]).count();
    assert!(thumb.dimensions() == (96, 96) && drawn > 96 * 96 / 5 && drawn < 96 * 96 * 9 / 10, "{:?}, {drawn} object pixels", thumb.dimensions());
    for (path, status, needle) in [("box/thumbnail?size=4000", 400, "size 4000 is outside 32–512"), ("box/thumbnail?size=big", 400, "query"), ("nothing/thumbnail", 404, "not found")] {
        let (s, v) = call(&c, "GET", &format!("{base}/v1/objects/{path}"), None);
        assert!(s == status && v.to_string().contains(needle), "{path}: {s} {v}");
    }
    // The same id again without replace: 409.
    assert_eq!(call(&c, "POST", &format!("{base}/v1/objects"), Some(&onboard)).0, 409);
    // PCA settings the backbone cannot give, or that are no setting at all: 400 at once.
    for (pca, needle) in [(json!(65), "cannot keep 65 components of the backbone's 64-dimensional"), (json!(0), "at least 1"), (json!("lots"), "lots")] {
        let mut bad = onboard.clone();
        bad["object_id"] = json!("box_pca");
        bad["options"]["pca"] = pca;
        let (s, v) = call(&c, "POST", &format!("{base}/v1/objects"), Some(&bad));
        assert!(s == 400 && v.to_string().contains(needle), "{needle}: {s} {v}");
    }
    let mut bad = onboard.clone();
    bad["options"]["descriptors"] = json!("int4");
    let (s, v) = call(&c, "POST", &format!("{base}/v1/objects"), Some(&bad));
    assert!(s == 400 && v.to_string().contains("int4"), "{s} {v}");
    let mut bad = onboard.clone();
    bad["options"]["patch_rows"] = json!("per-face");
    let (s, v) = call(&c, "POST", &format!("{base}/v1/objects"), Some(&bad));
    assert!(s == 400 && v.to_string().contains("per-face"), "{s} {v}");

    // The same files as multipart/form-data, as they are (12 templates: quick).
    let part = |(name, bytes): &(String, Vec<u8>)| reqwest::blocking::multipart::Part::bytes(bytes.clone()).file_name(name.clone());
    let form = reqwest::blocking::multipart::Form::new()
        .text("object_id", "box_mp")
        .text("units", "m")
        .text("level", "0")
        .text("in_plane", "1")
        .text("descriptors", "pq4")
        .part("mesh", part(&files[0]))
        .part("resource", part(&files[1]))
        .part("resource", part(&files[2]));
    let r = c.post(format!("{base}/v1/objects")).multipart(form).send().unwrap();
    assert_eq!(r.status().as_u16(), 202);
    let op: Value = r.json().unwrap();
    let mp_url = format!("{base}/v1/operations/{}", op["id"].as_str().unwrap());
    let t = Instant::now();
    let mp_done = loop {
        let (_, o) = call(&c, "GET", &mp_url, None);
        if o["state"] != "running" {
            break o;
        }
        assert!(t.elapsed() < Duration::from_secs(300), "multipart onboarding did not finish: {o}");
        std::thread::sleep(Duration::from_millis(200));
    };
    assert_eq!((mp_done["state"].as_str(), mp_done["object"]["templates"].as_u64()), (Some("succeeded"), Some(12)), "{mp_done}");
    // Stored in the coding asked for: product-quantised codes, not f16 rows.
    let stored = b2tfpose::store::open_read_only(&store).unwrap().get("box_mp").unwrap();
    assert!(matches!(stored.patch_descriptors, b2tfpose::onboard::PatchDescriptors::Quantized { .. }), "{:?}", stored.config.descriptors);
    // Bad multipart bodies name what is wrong.
    for (form, needle) in [
        (reqwest::blocking::multipart::Form::new().text("object_id", "x").text("colour", "red"), "colour"),
        (reqwest::blocking::multipart::Form::new().text("object_id", "x"), "mesh file part is missing"),
        (reqwest::blocking::multipart::Form::new().part("mesh", part(&files[0])), "object_id"),
        (reqwest::blocking::multipart::Form::new().text("object_id", "x").text("level", "two").part("mesh", part(&files[0])), "level"),
        (reqwest::blocking::multipart::Form::new().text("object_id", "x").text("pca", "half").part("mesh", part(&files[0])), "pca: PCA setting"),
        (reqwest::blocking::multipart::Form::new().text("object_id", "x").text("descriptors", "pq3").part("mesh", part(&files[0])), "descriptors: unknown descriptor coding"),
        (reqwest::blocking::multipart::Form::new().text("object_id", "x").text("patch_rows", "per-face").part("mesh", part(&files[0])), "patch_rows: unknown patch rows"),
    ] {
        let r = c.post(format!("{base}/v1/objects")).multipart(form).send().unwrap();
        let (s, v) = (r.status().as_u16(), r.text().unwrap());
        assert!(s == 400 && v.contains(needle), "{needle}: {s} {v}");
    }
    assert_eq!(call(&c, "DELETE", &format!("{base}/v1/objects/box_mp"), None).0, 204);

    // A photo of the box at a known pose, its mask as the detection.
    let sc = scene();
    let (truth, r) = (&sc.truth, &sc.render);
    let intrinsics = json!({"fx": 500.0, "fy": 500.0, "cx": 159.5, "cy": 119.5, "width": 320, "height": 240});
    let request = |image: Value, intrinsics: Value, detections: Value| json!({"image": image, "intrinsics": intrinsics, "detections": detections, "options": {"rrc": false}});
    let good_image = json!({"encoded": png(&r.rgb)});
    let good_dets = json!([{"object_id": "box", "mask_png": png(&r.mask), "score": 0.9}]);
    let jobs = || metric(&c, &base, "b2tf_backbone_queue_wait_seconds_count");
    let jobs_before = jobs();
    let (s, est) = call(&c, "POST", &format!("{base}/v1/estimate"), Some(&request(good_image.clone(), intrinsics.clone(), good_dets.clone())));
    assert_eq!(s, 200, "{est}");
    // Estimates' backbone passes go through the same queue: the query crop, and with RRC
    // its renders as well.
    let plain_jobs = jobs() - jobs_before;
    // With RRC, its renders' pass as well: always with `rrc_always`, and by default unless
    // the answer says the first matches were sure enough to skip it.
    for always in [true, false] {
        let mut with_rrc = request(good_image.clone(), intrinsics.clone(), good_dets.clone());
        with_rrc["options"]["rrc"] = json!(true);
        with_rrc["options"]["rrc_always"] = json!(always);
        let jobs_before = jobs();
        let (s, answer) = call(&c, "POST", &format!("{base}/v1/estimate"), Some(&with_rrc));
        assert_eq!(s, 200, "{answer}");
        let rrc_jobs = jobs() - jobs_before;
        let skipped = answer["results"][0]["diagnostics"][0]["rrc_skipped"] == json!(true);
        assert!(!(always && skipped), "rrc_always, yet skipped: {answer}");
        assert!(plain_jobs >= 1.0 && (rrc_jobs > plain_jobs) != skipped, "queue jobs: {plain_jobs} without RRC, {rrc_jobs} with (always {always}, skipped {skipped})");
    }
    let res = &est["results"][0];
    assert_eq!(res["object_id"], "box");
    let tv: Vec<f64> = res["pose"]["t"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    let rv: Vec<f64> = res["pose"]["R"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    let (rot, trans) = pose_errors(&rv, &tv, truth);
    assert!(rot < 10.0 && trans < 0.03, "rotation error {rot:.1}°, translation error {:.1} mm", trans * 1e3);
    assert_eq!(res["pose"]["quaternion_wxyz"].as_array().unwrap().len(), 4);
    assert_eq!((&res["symmetries"], &res["arbitrary_rotation_about_axis"]), (&no_symmetries, &json!(false)), "{res}");
    // The best other answer verification judged on the photo, and by how much it lost; none
    // when verification is off (nothing else was judged).
    let up = &res["runner_up"];
    assert!(up["margin"].as_f64().unwrap() >= 0.0 && up["distance_over_diameter"].as_f64().unwrap() > 0.1 && up["pose"]["R"].as_array().unwrap().len() == 9, "{res}");
    // The server's verdict on the margin, so that no client keeps a threshold of its own.
    assert_eq!(up["close_call"].as_bool(), Some(up["margin"].as_f64().unwrap() < b2tfpose::estimate::runner_up::CLOSE_CALL), "{res}");
    let mut unverified = request(good_image.clone(), intrinsics.clone(), good_dets.clone());
    unverified["options"]["verify"] = json!(false);
    let (s, est_unverified) = call(&c, "POST", &format!("{base}/v1/estimate"), Some(&unverified));
    assert_eq!((s, &est_unverified["results"][0]["runner_up"]), (200, &Value::Null), "{est_unverified}");

    // Raw RGB8 gives the same answer as the PNG.
    let raw = json!({"raw_rgb8": b64(r.rgb.as_raw()), "width": 320, "height": 240});
    let (s, est_raw) = call(&c, "POST", &format!("{base}/v1/estimate"), Some(&request(raw, intrinsics.clone(), good_dets.clone())));
    assert_eq!(s, 200, "{est_raw}");
    assert_eq!(est_raw["results"][0]["pose"], res["pose"]);
    // The answer drawn on the photo when asked for (and only then): the same pose.
    assert!(est.get("overlay_png").is_none(), "an overlay nobody asked for");
    let mut drawn = request(good_image.clone(), intrinsics.clone(), good_dets.clone());
    drawn["options"]["overlay"] = json!(true);
    let (s, est_drawn) = call(&c, "POST", &format!("{base}/v1/estimate"), Some(&drawn));
    assert_eq!((s, &est_drawn["results"][0]["pose"]), (200, &res["pose"]), "{est_drawn}");
    let overlay = base64::engine::general_purpose::STANDARD.decode(est_drawn["overlay_png"].as_str().unwrap()).unwrap();
    let overlay = image::load_from_memory(&overlay).unwrap().to_rgb8();
    let changed = overlay.pixels().zip(r.rgb.pixels()).filter(|(a, b)| a != b).count();
    let object = r.mask.pixels().filter(|p| p.0[0] > 0).count();
    assert!(overlay.dimensions() == (320, 240) && changed * 2 > object, "{:?}: {changed} pixels drawn over an object of {object}", overlay.dimensions());

    // A box alone: mask proposals inside it, and the pose is as good.
    let (x0, y0, x1, y1) = b2tfpose::features::mask_bbox(&r.mask).unwrap();
    let box_dets = json!([{"object_id": "box", "bbox": [x0, y0, x1 - x0 + 1, y1 - y0 + 1], "score": 0.9}]);
    let (s, est_box) = call(&c, "POST", &format!("{base}/v1/estimate"), Some(&request(good_image.clone(), intrinsics.clone(), box_dets.clone())));
    assert_eq!(s, 200, "{est_box}");
    let pose = &est_box["results"][0]["pose"];
    let floats = |v: &Value| v.as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect::<Vec<f64>>();
    let (rot, trans) = pose_errors(&floats(&pose["R"]), &floats(&pose["t"]), truth);
    assert!(rot < 10.0 && trans < 0.03, "from a box: rotation error {rot:.1}°, translation error {:.1} mm", trans * 1e3);
    // The box became proposals (here, on a clean scene, the cuts agree and count once);
    // the answer names the caller's detection, and each proposal's pose says how well it
    // filled the box.
    assert_eq!(est_box["results"][0]["detection_index"], 0, "{est_box}");
    let hyps = est_box["results"][0]["diagnostics"].as_array().unwrap();
    assert!(!hyps.is_empty() && hyps.iter().all(|h| h["box_agreement"].as_f64().is_some_and(|b| (0.0..=1.0).contains(&b))), "{hyps:?}");
    // RGB-D: the render's depth (float metres, 0 off the object) beside the box: the pose
    // is fitted to it, and each judged hypothesis says how the depth agreed with it.
    let f32_bytes = |v: &[f32]| b64(&v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>());
    let mut rgbd = request(good_image.clone(), intrinsics.clone(), box_dets.clone());
    rgbd["depth"] = json!({"raw_f32": f32_bytes(&r.depth), "width": 320, "height": 240});
    let (s, est_d) = call(&c, "POST", &format!("{base}/v1/estimate"), Some(&rgbd));
    assert_eq!(s, 200, "{est_d}");
    let pose = &est_d["results"][0]["pose"];
    let (rot, trans) = pose_errors(&floats(&pose["R"]), &floats(&pose["t"]), truth);
    assert!(rot < 5.0 && trans < 0.005, "RGB-D from a box: rotation error {rot:.1}°, translation error {:.1} mm", trans * 1e3);
    let fits: Vec<&Value> = est_d["results"][0]["diagnostics"].as_array().unwrap().iter().filter_map(|h| h["refinement"].get("depth_fit")).collect();
    assert!(!fits.is_empty() && fits.iter().all(|f| f["inlier_share"].as_f64().unwrap() > 0.8), "{est_d}");
    // Without verification the kept pose is fitted all the same.
    let mut unverified = rgbd.clone();
    unverified["options"]["verify"] = json!(false);
    let (s, est_u) = call(&c, "POST", &format!("{base}/v1/estimate"), Some(&unverified));
    assert_eq!(s, 200, "{est_u}");
    let pose = &est_u["results"][0]["pose"];
    let (rot, trans) = pose_errors(&floats(&pose["R"]), &floats(&pose["t"]), truth);
    assert!(rot < 5.0 && trans < 0.005, "RGB-D unverified: rotation error {rot:.1}°, translation error {:.1} mm", trans * 1e3);
    assert!(est_u["results"][0]["diagnostics"].as_array().unwrap().iter().any(|h| h["refinement"].get("depth_fit").is_some()), "{est_u}");
    // Bad depth: 400 naming the field and what is wrong.
    let mut nan_depth = r.depth.clone();
    nan_depth[5] = f32::NAN;
    for (depth, needle) in [
        (json!({"raw_f32": f32_bytes(&r.depth[..320 * 120]), "width": 320, "height": 120}), "depth is 320×120 but the image is 320×240"),
        (json!({"raw_f32": f32_bytes(&nan_depth), "width": 320, "height": 240}), "depth.raw_f32: depth value at pixel (5, 0) is NaN"),
        (json!({"raw_u16": b64(&vec![0u8; 320 * 240 * 2]), "width": 320, "height": 240}), "depth.scale_mm is needed"),
        (json!({"raw_u16": b64(&vec![0u8; 320 * 240 * 2]), "width": 320, "height": 240, "scale_mm": 1.0}), "depth holds no measurement"),
        (json!({"raw_f32": f32_bytes(&r.depth.iter().map(|z| z * 1000.0).collect::<Vec<f32>>()), "width": 320, "height": 240}), "raw_f32 is metres"),
        (json!({"png16": png(&r.mask), "scale_mm": 1.0}), "depth.png16: depth is not a 16-bit"),
    ] {
        let mut bad = request(good_image.clone(), intrinsics.clone(), box_dets.clone());
        bad["depth"] = depth;
        let (s, v) = call(&c, "POST", &format!("{base}/v1/estimate"), Some(&bad));
        assert!(s == 400 && v.to_string().contains(needle), "{needle}: {s} {v}");
    }
    // A box and a mask of the same instance: one instance, whose answer points at one of the
    // two detections, never at a proposal's place in the list.
    let (bx, mk) = (box_dets[0].clone(), json!({"object_id": "box", "mask_png": png(&r.mask), "score": 0.5}));
    let (s, both) = call(&c, "POST", &format!("{base}/v1/estimate"), Some(&request(good_image.clone(), intrinsics.clone(), json!([bx, mk]))));
    assert_eq!(s, 200, "{both}");
    assert!(both["results"].as_array().unwrap().len() == 1 && both["results"][0]["detection_index"].as_u64().is_some_and(|i| i <= 1), "{both}");

    // Bad inputs: each gets its status and names the problem; the server keeps serving.
    let with_option = |mut body: Value, name: &str, value: Value| {
        body["options"][name] = value;
        body
    };
    let small_mask = png(&image::GrayImage::new(10, 10));
    let empty_mask = png(&image::GrayImage::new(320, 240));
    let good_det = json!({"object_id": "box", "mask_png": png(&r.mask)});
    let cases: Vec<(Value, u16, &str)> = vec![
        (request(json!({"encoded": b64(b"not an image")}), intrinsics.clone(), good_dets.clone()), 400, "image.encoded"),
        (request(good_image.clone(), intrinsics.clone(), json!([{"object_id": "nope", "mask_png": png(&r.mask)}])), 404, "nope"),
        (request(good_image.clone(), intrinsics.clone(), json!([{"object_id": "box", "mask_png": small_mask}])), 400, "mask is 10×10"),
        (request(good_image.clone(), json!({"fx": -500.0, "fy": 500.0, "cx": 159.5, "cy": 119.5, "width": 320, "height": 240}), good_dets.clone()), 400, "intrinsics"),
        (request(good_image.clone(), json!({"fx": 500.0, "fy": 500.0, "cx": 159.5, "cy": 119.5, "width": 640, "height": 480}), good_dets.clone()), 400, "intrinsics say 640×480"),
        (request(good_image.clone(), intrinsics.clone(), json!([])), 400, "at least one"),
        (request(good_image.clone(), intrinsics.clone(), json!([{"object_id": "../x", "mask_png": png(&r.mask)}])), 400, "object_id"),
        (json!({"image": "wrong"}), 400, "request body"),
        (
            request(good_image.clone(), intrinsics.clone(), json!([{"object_id": "box", "bbox": [400.0, 10.0, 20.0, 20.0]}])),
            400,
            "detections[0].bbox: box [400.0, 10.0, 20.0, 20.0] ([x, y, w, h]) lies outside the 320×240 image",
        ),
        (
            request(good_image.clone(), intrinsics.clone(), json!([good_det, {"object_id": "box", "bbox": [10.0, 10.0, 0.0, 20.0]}])),
            400,
            "detections[1].bbox: box [10.0, 10.0, 0.0, 20.0] ([x, y, w, h]) has zero area",
        ),
        (request(good_image.clone(), intrinsics.clone(), json!([{"object_id": "box", "mask_png": empty_mask}])), 400, "detections[0].mask_png: the mask is empty"),
        // Detections are decoded side by side; the first bad one in the request is named.
        (
            request(
                good_image.clone(),
                intrinsics.clone(),
                json!([box_dets[0].clone(), {"object_id": "box", "bbox": [10.0, 10.0, 0.0, 20.0]}, {"object_id": "box", "bbox": [400.0, 10.0, 20.0, 20.0]}]),
            ),
            400,
            "detections[1].bbox: box [10.0, 10.0, 0.0, 20.0] ([x, y, w, h]) has zero area",
        ),
        (with_option(request(good_image.clone(), intrinsics.clone(), good_dets.clone()), "box_prior", json!("loose")), 400, "box_prior: expected true, false"),
    ];
    for (body, want, needle) in cases {
        let (s, v) = call(&c, "POST", &format!("{base}/v1/estimate"), Some(&body));
        assert_eq!(s, want, "{needle}: {v}");
        assert!(v.to_string().contains(needle), "{needle} not in {v}");
        healthy(&c);
    }
    // NaN cannot be written in JSON; a string where a number belongs is refused as such.
    let (s, _) =
        call(&c, "POST", &format!("{base}/v1/estimate"), Some(&request(good_image.clone(), json!({"fx": "NaN", "fy": 500.0, "cx": 1, "cy": 1, "width": 320, "height": 240}), good_dets.clone())));
    assert_eq!(s, 400);
    // Larger than --max-body-mb 3: refused from its Content-Length, before the body is
    // read. Sent by hand: a client still writing the body may see the connection close
    // before it reads the answer.
    assert_eq!(oversized_post(&base, "/v1/estimate", 4_000_000), 413);
    assert_eq!(call(&c, "GET", &format!("{base}/v1/operations/op-unknown"), None).0, 404);
    assert_eq!(call(&c, "GET", &format!("{base}/v1/objects/..%2Fetc"), None).0, 400);
    healthy(&c);

    // Two estimates run and one waits; beyond that requests are refused at once, each
    // with when to come back (Retry-After in seconds, retry-after-ms, and in the body).
    let with_rrc = json!({"image": good_image, "intrinsics": intrinsics, "detections": good_dets});
    let answers: Vec<(u16, Option<u64>, Option<u64>, Value)> = std::thread::scope(|sc| {
        let hs: Vec<_> = (0..6)
            .map(|_| {
                sc.spawn(|| {
                    let r = client().post(format!("{base}/v1/estimate")).json(&with_rrc).send().unwrap();
                    let header = |name: &str| r.headers().get(name).and_then(|v| v.to_str().ok()).and_then(|v| v.parse().ok());
                    let (retry_s, retry_ms) = (header("retry-after"), header("retry-after-ms"));
                    (r.status().as_u16(), retry_s, retry_ms, r.json::<Value>().unwrap())
                })
            })
            .collect();
        hs.into_iter().map(|h| h.join().unwrap()).collect()
    });
    let ok = answers.iter().filter(|a| a.0 == 200).count();
    let refused: Vec<_> = answers.iter().filter(|a| a.0 == 429).collect();
    assert!(ok >= 3 && !refused.is_empty() && ok + refused.len() == answers.len(), "{answers:?}");
    for (_, secs, ms, body) in &refused {
        let (secs, ms) = (secs.expect("Retry-After"), ms.expect("retry-after-ms"));
        assert!(ms >= 1 && secs == ms.div_ceil(1000).max(1), "{secs} s, {ms} ms");
        assert_eq!(body["error"]["retry_after_ms"].as_u64(), Some(ms), "{body}");
        assert!(body["error"]["message"].as_str().unwrap().contains("--queue-depth"), "{body}");
    }

    // Estimates keep working while another object onboards; the onboarding can be cancelled
    // and leaves nothing behind.
    let mut slow = onboard.clone();
    slow["object_id"] = json!("box2");
    slow["options"] = json!({"level": 3, "in_plane": 12});
    let (s, op2) = call(&c, "POST", &format!("{base}/v1/objects"), Some(&slow));
    assert_eq!(s, 202, "{op2}");
    let op2_url = format!("{base}/v1/operations/{}", op2["id"].as_str().unwrap());
    let (s, again) = call(&c, "POST", &format!("{base}/v1/objects"), Some(&slow));
    assert_eq!(s, 409, "a second onboarding of the same id: {again}");
    let (s, est2) = call(&c, "POST", &format!("{base}/v1/estimate"), Some(&request(json!({"encoded": png(&r.rgb)}), intrinsics_again(), good_dets_again(&r.mask))));
    assert_eq!(s, 200, "{est2}");
    assert_eq!(call(&c, "GET", &op2_url, None).1["state"], "running");
    assert_eq!(call(&c, "POST", &format!("{op2_url}/cancel"), None).0, 200);
    let t = Instant::now();
    while call(&c, "GET", &op2_url, None).1["state"] == "running" {
        assert!(t.elapsed() < Duration::from_secs(120), "cancel not honoured");
        std::thread::sleep(Duration::from_millis(100));
    }
    assert_eq!(call(&c, "GET", &op2_url, None).1["state"], "cancelled");
    assert_eq!(call(&c, "GET", &format!("{base}/v1/objects/box2"), None).0, 404);

    // Metrics count what happened; the OpenAPI document lists every route.
    let metrics = c.get(format!("{base}/metrics")).send().unwrap().text().unwrap();
    for needle in [
        "b2tf_requests_total{method=\"POST\",route=\"/v1/estimate\",status=\"200\"}",
        "b2tf_estimate_queue_wait_seconds_count",
        "b2tf_estimate_queue_length 0",
        "b2tf_estimate_queue_refused_total{reason=\"full\"}",
        "b2tf_estimate_service_seconds",
        "status=\"429\"",
        "b2tf_request_seconds_bucket",
        "b2tf_stage_seconds_bucket{stage=\"pnp\"",
        "b2tf_objects_loaded 1",
        "b2tf_ready 1",
        "b2tf_thumbnails_drawn_total 1\n",
    ] {
        assert!(metrics.contains(needle), "{needle} not in metrics:\n{metrics}");
    }
    let (s, doc) = call(&c, "GET", &format!("{base}/openapi.json"), None);
    assert_eq!((s, doc["openapi"].as_str()), (200, Some("3.0.3")));
    for path in ["/healthz", "/readyz", "/metrics", "/v1/objects", "/v1/objects/{id}", "/v1/operations/{id}", "/v1/operations/{id}/cancel", "/v1/estimate"] {
        assert!(doc["paths"][path].is_object(), "{path} missing from openapi.json");
    }

    // Delete: 204, then the object is gone.
    assert_eq!(call(&c, "DELETE", &format!("{base}/v1/objects/box"), None).0, 204);
    assert_eq!(call(&c, "GET", &format!("{base}/v1/objects/box"), None).0, 404);
    assert_eq!(call(&c, "DELETE", &format!("{base}/v1/objects/box"), None).0, 404);

    // SIGTERM: the server stops accepting, finishes, and exits cleanly.
    // SAFETY: kill(2) on our own child's pid.
    unsafe { libc::kill(server.child.id() as i32, libc::SIGTERM) };
    let status = server.child.wait().unwrap();
    assert!(status.success(), "{status:?}");
}

/// Status of a POST announcing `len` body bytes, of which none are sent.
fn oversized_post(base: &str, path: &str, len: usize) -> u16 {
    use std::io::{Read, Write};
    let addr = base.trim_start_matches("http://");
    let mut s = std::net::TcpStream::connect(addr).unwrap();
    write!(s, "POST {path} HTTP/1.1\r\nHost: {addr}\r\nContent-Type: application/json\r\nContent-Length: {len}\r\nConnection: close\r\n\r\n").unwrap();
    s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    let mut head = [0u8; 12];
    s.read_exact(&mut head).unwrap();
    String::from_utf8_lossy(&head[9..12]).parse().unwrap()
}

fn intrinsics_again() -> Value {
    json!({"fx": 500.0, "fy": 500.0, "cx": 159.5, "cy": 119.5, "width": 320, "height": 240})
}

fn good_dets_again(mask: &image::GrayImage) -> Value {
    json!([{"object_id": "box", "mask_png": png(mask), "score": 0.9}])
}

#[test]
fn api_keys_guard_everything_but_health() {
    let dir = tempfile::tempdir().unwrap();
    let server = start(&format!("sqlite://{}", dir.path().join("o.db").display()), Some("s3cret,other"), &[]);
    let (c, base) = (client(), server.http.clone());
    assert_eq!(call(&c, "GET", &format!("{base}/healthz"), None).0, 200);
    for path in ["/v1/objects", "/metrics", "/openapi.json", "/v1/operations/x"] {
        let (s, v) = call(&c, "GET", &format!("{base}{path}"), None);
        assert_eq!(s, 401, "{path}: {v}");
        assert_eq!(c.get(format!("{base}{path}")).header("Authorization", "Bearer wrong").send().unwrap().status().as_u16(), 401, "{path}");
    }
    let ok = c.get(format!("{base}/v1/objects")).header("Authorization", "Bearer s3cret").send().unwrap();
    assert_eq!(ok.status().as_u16(), 200);
    // The console's page needs no key (it asks for one); / leads to it; its answers
    // forbid inline script and framing. Who a key is needs a key.
    assert!(server.banner.contains(&format!("web console {base}/console/")), "{}", server.banner);
    let page = c.get(format!("{base}/")).send().unwrap();
    assert_eq!((page.status().as_u16(), page.url().path()), (200, "/console/"));
    let csp = page.headers()["content-security-policy"].to_str().unwrap().to_string();
    assert!(csp.contains("script-src 'self'") && !csp.contains("unsafe-inline") && csp.contains("frame-ancestors 'none'"), "{csp}");
    assert!(page.text().unwrap().contains("<script type=\"module\" src=\"./main.js\">"));
    let script = c.get(format!("{base}/console/main.js")).send().unwrap();
    assert_eq!((script.status().as_u16(), script.headers()["content-type"].to_str().unwrap()), (200, "text/javascript; charset=utf-8"));
    let (s, v) = call(&c, "GET", &format!("{base}/console/secrets.js"), None);
    assert!(s == 404 && v.to_string().contains("no file"), "{s} {v}");
    assert_eq!(call(&c, "GET", &format!("{base}/v1/caller"), None).0, 401);
    let who: Value = c.get(format!("{base}/v1/caller")).header("Authorization", "Bearer other").send().unwrap().json().unwrap();
    assert_eq!((&who["keys_required"], &who["scopes"], &who["read_only"]), (&json!(true), &json!(["read", "write", "admin"]), &json!(false)), "{who}");
    let ok = c.get(format!("{base}/metrics")).header("Authorization", "Bearer other").send().unwrap();
    assert_eq!(ok.status().as_u16(), 200);
}

/// A replica started with --read-only serves a store that `b2tf onboard` (an onboarding
/// job) fills, objects added after it started included, and refuses writes with 403.
#[test]
fn read_only_replica_serves_a_store_it_never_writes() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("objects");
    std::fs::create_dir(&root).unwrap();
    let url = format!("dir://{}", root.display());
    let server = start(&url, None, &["--read-only", "--console", "false"]);
    let (c, base) = (client(), server.http.clone());
    let t = Instant::now();
    while call(&c, "GET", &format!("{base}/readyz"), None).0 != 200 {
        assert!(t.elapsed() < Duration::from_secs(60), "never ready");
        std::thread::sleep(Duration::from_millis(100));
    }
    assert_eq!(call(&c, "GET", &format!("{base}/v1/objects"), None).1["objects"], json!([]));
    // Without keys everyone may do everything the server does; this one writes nothing,
    // and serves no console (--console false).
    let who = call(&c, "GET", &format!("{base}/v1/caller"), None).1;
    assert_eq!((&who["keys_required"], &who["identity"], &who["read_only"]), (&json!(false), &Value::Null, &json!(true)), "{who}");
    assert_eq!(call(&c, "GET", &format!("{base}/console/"), None).0, 404);
    assert!(!server.banner.contains("console"), "{}", server.banner);

    // The onboarding job writes after the replica started.
    let files = sample_files(dir.path());
    let job = std::process::Command::new(env!("CARGO_BIN_EXE_b2tf"))
        .args(["onboard", "--id", "box", "--units", "m", "--level", "0", "--in-plane", "2", "--render-pool", "1", "--store", &url])
        .arg("--mesh")
        .arg(dir.path().join(&files[0].0))
        .output()
        .unwrap();
    assert!(job.status.success(), "{}", String::from_utf8_lossy(&job.stderr));
    let (s, list) = call(&c, "GET", &format!("{base}/v1/objects"), None);
    assert!(s == 200 && list["objects"][0]["id"] == "box", "{list}");
    let sc = scene();
    let estimate = json!({"image": {"encoded": png(&sc.render.rgb)}, "intrinsics": intrinsics_again(), "detections": good_dets_again(&sc.render.mask), "options": {"rrc": false}});
    let (s, est) = call(&c, "POST", &format!("{base}/v1/estimate"), Some(&estimate));
    assert!(s == 200 && est["results"][0]["object_id"] == "box", "{est}");

    // Writes are refused, naming why, and the store keeps its object.
    let onboard = json!({"object_id": "box2", "mesh": {"data": b64(&files[0].1), "format": "obj", "units": "m"}, "options": {"level": 0, "in_plane": 1}});
    for (method, path, body) in [("POST", "/v1/objects".to_string(), Some(&onboard)), ("DELETE", "/v1/objects/box".to_string(), None)] {
        let (s, v) = call(&c, method, &format!("{base}{path}"), body);
        assert!(s == 403 && v.to_string().contains("read-only"), "{method} {path}: {s} {v}");
    }
    assert!(root.join("box").is_dir() && !root.join("box2").exists());
}

/// `b2tf` run as another process on the same store: onboarding (with `--replace`) or
/// deleting the sample box.
fn writer(args: &[&str], url: &str, dir: &std::path::Path) {
    let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_b2tf"));
    cmd.args(args);
    if args[0] == "onboard" {
        let files = sample_files(dir);
        cmd.args(["--id", "box", "--units", "m", "--level", "0", "--in-plane", "2", "--render-pool", "1"]).arg("--mesh").arg(dir.join(&files[0].0));
    }
    let out = cmd.args(["--store", url]).env("XDG_RUNTIME_DIR", "/tmp").output().unwrap();
    assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
}

/// Waits until the server's /metrics has `needle`.
fn await_metric(c: &reqwest::blocking::Client, base: &str, needle: &str) {
    let t = Instant::now();
    loop {
        let text = c.get(format!("{base}/metrics")).send().unwrap().text().unwrap();
        if text.contains(needle) {
            return;
        }
        assert!(t.elapsed() < Duration::from_secs(30), "{needle} never appeared in:\n{text}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// A read-only replica notices, without a restart, that another process replaced or
/// deleted an object it holds in memory (a generation check every --revalidate-s), on a
/// store of each kind (S3: a real server on loopback, tests/common/s3.rs).
#[test]
fn replica_picks_up_replaced_and_deleted_objects() {
    let dir = tempfile::tempdir().unwrap();
    let s3 = common::s3::S3Server::start(dir.path());
    let urls = [format!("dir://{}", dir.path().join("objects").display()), format!("sqlite://{}", dir.path().join("objects.db").display())];
    for url in urls.into_iter().chain(s3.as_ref().map(|s| s.url("objects"))) {
        writer(&["onboard"], &url, dir.path());
        let server = start(&url, None, &["--read-only", "--revalidate-s", "0.2"]);
        let (c, base) = (client(), server.http.clone());
        let sc = scene();
        let estimate = json!({"image": {"encoded": png(&sc.render.rgb)}, "intrinsics": intrinsics_again(), "detections": good_dets_again(&sc.render.mask), "options": {"rrc": false}});
        let (s, est) = call(&c, "POST", &format!("{base}/v1/estimate"), Some(&estimate));
        assert!(s == 200 && est["results"][0]["object_id"] == "box", "{url}: {est}");
        await_metric(&c, &base, "b2tf_objects_loaded 1\n");
        // Unchanged, it stays loaded.
        std::thread::sleep(Duration::from_millis(600));
        await_metric(&c, &base, "b2tf_cache_stale_total 0\n");

        writer(&["onboard", "--replace"], &url, dir.path());
        await_metric(&c, &base, "b2tf_cache_stale_total 1\n");
        await_metric(&c, &base, "b2tf_objects_loaded 0\n");
        let (s, est) = call(&c, "POST", &format!("{base}/v1/estimate"), Some(&estimate));
        assert!(s == 200 && est["results"][0]["pose"].is_object(), "{url}: the replaced object: {est}");
        await_metric(&c, &base, "b2tf_objects_loaded 1\n");

        writer(&["objects", "delete", "box"], &url, dir.path());
        await_metric(&c, &base, "b2tf_cache_stale_total 2\n");
        let (s, est) = call(&c, "POST", &format!("{base}/v1/estimate"), Some(&estimate));
        assert_eq!(s, 404, "{url}: the deleted object is not served from memory: {est}");
    }
}

/// A server whose S3 store goes away answers 503 / UNAVAILABLE naming the store, not 500,
/// and serves again once the store is back, without a restart.
#[test]
fn s3_store_that_goes_away_answers_503() {
    let dir = tempfile::tempdir().unwrap();
    let Some(mut s3) = common::s3::S3Server::start(dir.path()) else { return };
    let url = s3.url("objects");
    writer(&["onboard"], &url, dir.path());
    let server = start(&url, None, &["--read-only", "--revalidate-s", "0"]);
    let (c, base) = (client(), server.http.clone());
    let (s, list) = call(&c, "GET", &format!("{base}/v1/objects"), None);
    assert!(s == 200 && list.to_string().contains("\"box\""), "{list}");
    s3.kill();
    for path in ["/v1/objects", "/v1/objects/box"] {
        let (s, body) = call(&c, "GET", &format!("{base}{path}"), None);
        assert_eq!(s, 503, "{path} with the store down: {body}");
        let message = body.to_string();
        assert!(message.contains("objects") && message.contains(&format!("127.0.0.1:{}", s3.port)), "{path}: {message}");
        assert!(!message.contains("b2tf-test-secret"), "{path} shows the secret: {message}");
    }
    s3.restart();
    let (s, _) = call(&c, "GET", &format!("{base}/v1/objects/box"), None);
    assert_eq!(s, 200, "served again once the store is back");
}
