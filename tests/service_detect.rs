//! Detection through the service, as clients see it: a real `b2tf serve` on loopback finds
//! the sample object with no mask and no box over HTTP and gRPC, hands its detections to
//! Estimate as they are, estimates by object id alone, starts a tracking session from a
//! detection, answers "nothing found" as a normal result, answers only the object that is
//! there when two of one size are searched with depth, and refuses every kind of bad input
//! by name.

mod common;

use b2tfpose::detect::nms::box_iou;
use b2tfpose::features::{EmbeddedBackbone, EmbeddedConfig};
use b2tfpose::geometry::ViewSampling;
use b2tfpose::onboard::{onboard, ObjectModel, OnboardConfig};
use b2tfpose::render::{RenderPool, RendererConfig};
use b2tfpose::service::client::png_bytes;
use b2tfpose::service::proto::{self as pb, pose_service_client::PoseServiceClient};
use base64::Engine as _;
use common::{sample_mesh, scene, start};
use serde_json::{json, Value};
use std::sync::OnceLock;
use std::time::Duration;

fn png<P: image::PixelWithColorType>(img: &image::ImageBuffer<P, Vec<P::Subpixel>>) -> Vec<u8>
where
    [P::Subpixel]: image::EncodableLayout,
{
    png_bytes(img).unwrap()
}

fn post(c: &reqwest::blocking::Client, url: &str, body: &Value) -> (u16, Value) {
    let r = c.post(url).json(body).send().expect("request sent");
    let status = r.status().as_u16();
    let text = r.text().unwrap_or_default();
    (status, serde_json::from_str(&text).unwrap_or(Value::String(text)))
}

/// `mesh` onboarded cheaply as `id`.
fn onboard_cheaply(id: &str, mesh: &b2tfpose::mesh::Mesh) -> ObjectModel {
    let pool = RenderPool::new(1, RendererConfig::default()).unwrap();
    let backbone = EmbeddedBackbone::new(EmbeddedConfig::default()).unwrap();
    let cfg = OnboardConfig { views: ViewSampling { level: 0, in_plane_steps: 2 }, render_size: 128, ..Default::default() };
    onboard(id, mesh, &cfg, &backbone, &pool, &|_| {}).unwrap()
}

/// The sample box onboarded cheaply, stored as an object from before the detector (no
/// templates), so the server builds them on first use.
fn store_sample(url: &str) {
    let old = ObjectModel { detector: OnceLock::new(), ..onboard_cheaply("box", &sample_mesh()) };
    b2tfpose::store::open(url).unwrap().put(&old, false).unwrap();
}

fn truth_box(mask: &image::GrayImage) -> [f64; 4] {
    b2tfpose::detect::detector::bbox_of(mask).unwrap()
}

fn bbox(v: &Value) -> [f64; 4] {
    let b: Vec<f64> = v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
    [b[0], b[1], b[2], b[3]]
}

#[test]
fn detect_and_estimate_by_object_id_over_http_and_grpc() {
    let dir = tempfile::tempdir().unwrap();
    let url = format!("dir://{}", dir.path().join("store").display());
    let server = start(&url, None, &[]);
    let base = server.http.clone();
    let c = common::http_client().timeout(Duration::from_secs(300)).build().unwrap();
    let sc = scene();
    let k = sc.k;
    let b64 = |b: &[u8]| base64::engine::general_purpose::STANDARD.encode(b);
    let intrinsics = json!({"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy, "width": k.width, "height": k.height});
    let photo = json!({"encoded": b64(&png(&sc.render.rgb))});
    let detect = |objects: Value, options: Value| json!({"image": photo, "intrinsics": intrinsics, "objects": objects, "options": options});
    let every = json!({"min_score": 0.0, "max_detections": 3});

    // An empty store: nothing to search, said so.
    let (s, e) = post(&c, &format!("{base}/v1/detect"), &detect(json!([]), every.clone()));
    assert_eq!(s, 400, "{e}");
    assert!(e["error"]["message"].as_str().unwrap().contains("holds no object; onboard one first"), "{e}");

    store_sample(&url);
    // Every object of the store (none named), every candidate kept.
    let (s, r) = post(&c, &format!("{base}/v1/detect"), &detect(json!([]), every.clone()));
    assert_eq!(s, 200, "{r}");
    let dets = r["detections"].as_array().unwrap();
    assert!(!dets.is_empty() && dets.len() <= 3, "{r}");
    for d in dets {
        assert_eq!(d["object_id"], "box");
        assert_eq!(d["mask_rle"]["size"], json!([k.height, k.width]));
        assert_eq!(d["coarse_pose"]["R"].as_array().map(|r| r.len()), Some(9));
        assert!(d["terms"]["shape"].as_f64().is_some() && d["score"].as_f64().is_some(), "{d}");
        // The score is its terms combined (docs/detection.md): they all came through.
        let term = |name: &str, absent: f64| d["terms"][name].as_f64().unwrap_or(absent);
        let combined = term("outline", f64::NAN) * term("colour", 0.5) * (0.5 + 0.5 * term("texture", 0.5));
        assert!((d["score"].as_f64().unwrap() - combined).abs() < 1e-4, "{d}");
    }
    let truth = truth_box(&sc.render.mask);
    let best = dets.iter().map(|d| box_iou(&bbox(&d["bbox"]), &truth)).fold(0.0, f64::max);
    assert!(best >= 0.5, "no detection on the box {truth:?}: {:?}", dets.iter().map(|d| &d["bbox"]).collect::<Vec<_>>());
    assert_eq!(r["searched"][0]["object_id"], "box");
    assert!(r["timings_ms"]["total"].as_f64().unwrap() > 0.0 && r["reason"].is_null(), "{r}");

    // A detection goes back to Estimate as it is.
    let (s, est) = post(&c, &format!("{base}/v1/estimate"), &json!({"image": photo, "intrinsics": intrinsics, "detections": [dets[0]], "options": {"rrc": false}}));
    assert_eq!(s, 200, "{est}");
    assert_eq!(est["results"][0]["detection_index"], 0);
    assert!(est["results"][0]["confirmation_score"].is_null(), "{est}");

    // Estimate by object id alone: detect, then estimate; the response lists the detections.
    let by_id = json!({"image": photo, "intrinsics": intrinsics, "objects": ["box"], "detect": every, "options": {"rrc": false}});
    let (s, est) = post(&c, &format!("{base}/v1/estimate"), &by_id);
    assert_eq!(s, 200, "{est}");
    let found = est["detections"].as_array().unwrap();
    let result = &est["results"][0];
    assert!(!found.is_empty() && result["pose"]["t"].as_array().is_some(), "{est}");
    assert!((result["detection_index"].as_u64().unwrap() as usize) < found.len(), "{est}");
    // Confirmed at its estimated pose (detect::confirm), one instance as asked by default.
    assert!(result["confirmation_score"].as_f64().is_some_and(|c| (0.0..=1.0).contains(&c)), "{est}");
    assert_eq!(est["results"].as_array().unwrap().len(), 1, "{est}");
    // With the camera's depth the object is found among the surfaces of its size (the
    // depth detector: the segment is the object's silhouette), estimated and confirmed by
    // the photo and the depth at its pose together.
    let tenths: Vec<u16> = sc.render.depth.iter().map(|&z| (z * 10_000.0).round() as u16).collect();
    let depth_png = png(&image::ImageBuffer::<image::Luma<u16>, _>::from_raw(k.width, k.height, tenths).unwrap());
    let mut with_depth = by_id.clone();
    with_depth["depth"] = json!({"png16": b64(&depth_png), "scale_mm": 0.1});
    let (s, est) = post(&c, &format!("{base}/v1/estimate"), &with_depth);
    assert_eq!(s, 200, "{est}");
    let found = est["detections"].as_array().unwrap();
    assert_eq!(found.len(), 1, "one thing stands in the depth: {est}");
    assert_eq!(found[0]["mask_source"], "depth_segment");
    assert!(box_iou(&bbox(&found[0]["bbox"]), &truth) > 0.9, "{:?} against {truth:?}", found[0]["bbox"]);
    // Detect alone takes the depth the same way.
    let mut detect_depth = detect(json!(["box"]), json!({}));
    detect_depth["depth"] = with_depth["depth"].clone();
    let (s, r) = post(&c, &format!("{base}/v1/detect"), &detect_depth);
    assert_eq!(s, 200, "{r}");
    assert_eq!(r["detections"][0]["mask_source"], "depth_segment", "{r}");
    let result = &est["results"][0];
    assert!(result["pose"]["t"].as_array().is_some() && result["confirmation_score"].as_f64().is_some_and(|c| (0.0..=1.0).contains(&c)), "{est}");
    // Two objects of one size searched (a can as wide as the box, not in the image): the
    // box's segment is a candidate of both, and only the box is answered there
    // (`detect::rivals` drops a candidate far below another object's on its place;
    // `one_per_place` keeps the better confirmed).
    b2tfpose::store::open(&url).unwrap().put(&onboard_cheaply("can", &b2tfpose::mesh::procedural::cylinder(0.05, 0.17, 24)), false).unwrap();
    let mut both = with_depth.clone();
    both["objects"] = json!(["box", "can"]);
    let (s, est) = post(&c, &format!("{base}/v1/estimate"), &both);
    assert_eq!(s, 200, "{est}");
    let offered: Vec<&Value> = est["detections"].as_array().unwrap().iter().map(|d| &d["object_id"]).collect();
    assert!(offered.contains(&&json!("box")) && offered.contains(&&json!("can")), "{est}");
    let results = est["results"].as_array().unwrap();
    assert_eq!(results.len(), 1, "{est}");
    assert_eq!(results[0]["object_id"], "box", "{est}");
    let t: Vec<f64> = results[0]["pose"]["t"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
    let off = ((t[0] - sc.truth.translation.x).powi(2) + (t[1] - sc.truth.translation.y).powi(2) + (t[2] - sc.truth.translation.z).powi(2)).sqrt();
    assert!(off < 0.02, "the box {off} m off: {est}");
    // More views than the depth search gives: refused, naming the option.
    let mut many = with_depth.clone();
    many["options"] = json!({"depth_views": 13});
    let (s, r) = post(&c, &format!("{base}/v1/estimate"), &many);
    assert_eq!(s, 400, "{r}");
    assert!(r.to_string().contains("options.depth_views is 13, over the limit of 12"), "{r}");
    // A depth range that holds nothing: no result, and the detector's reason.
    let mut far = with_depth.clone();
    far["detect"] = json!({"min_distance_m": 5.0});
    let (s, r) = post(&c, &format!("{base}/v1/estimate"), &far);
    assert_eq!(s, 200, "{r}");
    assert!(r["results"].as_array().unwrap().is_empty() && r["reason"].as_str().unwrap_or("").contains("distance range"), "{r}");
    // A threshold nothing reaches: no result, and a reason.
    let mut strict = by_id.clone();
    strict["detect"] = json!({"min_score": 0.99, "max_detections": 3});
    let (s, r) = post(&c, &format!("{base}/v1/estimate"), &strict);
    assert_eq!(s, 200, "{r}");
    assert!(r["results"].as_array().unwrap().is_empty() && r["reason"].as_str().is_some_and(|m| !m.is_empty()), "{r}");

    // An image without the object: no detection is an answer with a reason, for both calls.
    let blank = json!({"encoded": b64(&png(&image::RgbImage::from_pixel(k.width, k.height, image::Rgb([90, 90, 90]))))});
    let mut nothing = detect(json!(["box"]), json!({}));
    nothing["image"] = blank.clone();
    let (s, r) = post(&c, &format!("{base}/v1/detect"), &nothing);
    assert_eq!(s, 200, "{r}");
    assert!(r["detections"].as_array().unwrap().is_empty() && r["reason"].as_str().is_some_and(|m| !m.is_empty()), "{r}");
    let mut nothing_est = by_id.clone();
    nothing_est["image"] = blank;
    nothing_est["detect"] = json!({});
    let (s, r) = post(&c, &format!("{base}/v1/estimate"), &nothing_est);
    assert_eq!(s, 200, "{r}");
    assert!(r["results"].as_array().unwrap().is_empty() && r["reason"].as_str().is_some(), "{r}");

    // Bad input, refused by name.
    let many: Vec<String> = (0..=b2tfpose::limits::MAX_DETECT_OBJECTS).map(|i| format!("o{i}")).collect();
    let mut small = detect(json!(["box"]), json!({}));
    small["image"] = json!({"encoded": b64(&png(&image::RgbImage::new(32, 24)))});
    let mut both = by_id.clone();
    both["detections"] = json!([{"object_id": "box", "bbox": [10, 10, 50, 50]}]);
    let mut neither = by_id.clone();
    neither["objects"] = json!([]);
    let cases = [
        ("/v1/detect", detect(json!(["nope"]), json!({})), 404, "\"nope\""),
        ("/v1/detect", detect(json!(many), json!({})), 400, "over the limit"),
        ("/v1/detect", detect(json!(["../x"]), json!({})), 400, "objects[0]"),
        ("/v1/detect", detect(json!(["box"]), json!({"min_distance_m": 2.0, "max_distance_m": 1.0})), 400, "min_distance_m (2) must be below max_distance_m (1)"),
        ("/v1/detect", detect(json!(["box"]), json!({"min_score": 2.0})), 400, "min_score must be within 0–1"),
        ("/v1/detect", detect(json!(["box"]), json!({"max_detections": 0})), 400, "max_detections must be 1–"),
        ("/v1/detect", small, 400, "image is 32×24 but intrinsics say 320×240"),
        ("/v1/estimate", both, 400, "give detections or objects, not both"),
        ("/v1/estimate", neither, 400, "at least one is needed (or name objects to detect)"),
        ("/v1/estimate", json!({"image": photo, "intrinsics": intrinsics, "objects": ["box"], "detect": {"max_distance_m": -1.0}}), 400, "max_distance_m must be within"),
    ];
    for (route, body, status, needle) in cases {
        let (s, e) = post(&c, &format!("{base}{route}"), &body);
        assert_eq!(s, status, "{route} {needle}: {e}");
        assert!(e["error"]["message"].as_str().unwrap_or("").contains(needle), "{route}: {e} lacks {needle:?}");
    }
    let metrics = c.get(format!("{base}/metrics")).send().unwrap().text().unwrap();
    assert!(metrics.contains("b2tf_requests_total{method=\"POST\",route=\"/v1/detect\",status=\"200\"}"), "{metrics}");
    assert!(metrics.contains("b2tf_stage_seconds_count{stage=\"detect_total\"}"), "{metrics}");

    // A tracking session starts from a detection: the first frame names the object, the
    // detector finds it and a full estimate starts the track; on the next frame the object
    // is followed (no search while its track holds).
    let (s, session) = post(&c, &format!("{base}/v1/tracks"), &json!({}));
    assert_eq!(s, 201, "{session}");
    let frames = format!("{base}/v1/tracks/{}/frames", session["id"].as_str().unwrap());
    let frame = json!({"image": photo, "intrinsics": intrinsics, "objects": ["box"], "detect": {"min_score": 0.0, "max_detections": 1}});
    let (s, f0) = post(&c, &frames, &frame);
    assert_eq!(s, 200, "{f0}");
    assert!(f0["objects"].as_array().unwrap().len() == 1 && f0["objects"][0]["mode"] == "estimated" && f0["objects"][0]["pose"].is_object(), "{f0}");
    let (s, f1) = post(&c, &frames, &frame);
    assert_eq!(s, 200, "{f1}");
    assert!(f1["objects"].as_array().unwrap().len() == 1 && f1["objects"][0]["mode"] == "tracked", "{f1}");
    // A candidate that its estimate does not confirm starts no track: it is answered
    // refused, with the reason.
    let (s, session) = post(&c, &format!("{base}/v1/tracks"), &json!({}));
    assert_eq!(s, 201, "{session}");
    let strict_frames = format!("{base}/v1/tracks/{}/frames", session["id"].as_str().unwrap());
    let (s, f) = post(&c, &strict_frames, &json!({"image": photo, "intrinsics": intrinsics, "objects": ["box"], "detect": {"min_score": 0.99, "max_detections": 2}}));
    assert_eq!(s, 200, "{f}");
    let objects = f["objects"].as_array().unwrap();
    assert!(!objects.is_empty() && objects.iter().all(|o| o["mode"] == "refused" && o["reason"].as_str().unwrap().contains("not confirmed at its estimated pose")), "{f}");
    let mut both = frame.clone();
    both["detections"] = json!([{"object_id": "box", "bbox": [10, 10, 50, 50]}]);
    let (s, e) = post(&c, &frames, &both);
    assert!(s == 400 && e["error"]["message"].as_str().unwrap().contains("not both"), "{e}");
    let mut unknown = frame.clone();
    unknown["objects"] = json!(["box", "nope"]);
    let (s, e) = post(&c, &frames, &unknown);
    assert!(s == 404 && e["error"]["message"].as_str().unwrap().contains("\"nope\""), "{e}");

    // gRPC: the same calls.
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
    rt.block_on(async {
        let mut g = PoseServiceClient::connect(server.grpc.clone()).await.unwrap();
        let image = Some(pb::Image { data: Some(pb::image::Data::Encoded(png(&sc.render.rgb))), width: 0, height: 0 });
        let intrinsics = Some(pb::Intrinsics { fx: k.fx, fy: k.fy, cx: k.cx, cy: k.cy, width: k.width, height: k.height });
        let options = Some(pb::DetectOptions { min_score: Some(0.0), max_detections: 3, ..Default::default() });
        let req = pb::DetectRequest { image: image.clone(), intrinsics, objects: vec!["box".into()], options, depth: None };
        let r = g.detect(req.clone()).await.expect("Detect").into_inner();
        let d = &r.detections[0];
        assert_eq!((d.object_id.as_str(), d.mask_rle.as_ref().map(|m| (m.height, m.width))), ("box", Some((k.height, k.width))));
        assert!(d.coarse_pose.as_ref().is_some_and(|p| p.r.len() == 9) && r.timings_ms.contains_key("total") && r.searched.len() == 1, "{r:?}");
        let e = g.detect(pb::DetectRequest { objects: vec!["nope".into()], ..req.clone() }).await.unwrap_err();
        assert_eq!(e.code(), tonic::Code::NotFound, "{e:?}");
        let e = g.detect(pb::DetectRequest { options: Some(pb::DetectOptions { min_distance_m: Some(0.0), ..Default::default() }), ..req.clone() }).await.unwrap_err();
        assert!(e.code() == tonic::Code::InvalidArgument && e.message().contains("min_distance_m must be within"), "{e:?}");
        let est = pb::EstimateRequest {
            image,
            intrinsics,
            objects: vec!["box".into()],
            detect: req.options,
            options: Some(pb::EstimateOptions { rrc: Some(false), ..Default::default() }),
            ..Default::default()
        };
        let r = g.estimate(est).await.expect("Estimate by object id").into_inner();
        assert!(!r.detections.is_empty() && r.results[0].pose.is_some() && r.results[0].detection_index >= 0, "{r:?}");
        assert!(r.results[0].confirmation_score.is_some_and(|c| (0.0..=1.0).contains(&c)), "{r:?}");
    });
}
