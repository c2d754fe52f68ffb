//! Tracking through the service, as clients see it: a real `b2tf serve` on loopback with
//! the sample object onboarded. An HTTP session follows a generated sequence from one mask,
//! re-initialises from a detection after a jump, refuses bad frames (out of order,
//! malformed, unknown object, bad mask, bad depth) without losing its state, fits frames
//! sent with depth to the measured surface (RGB-D), and expires when idle;
//! the session limit refuses both HTTP sessions and gRPC streams; a gRPC `Track` stream
//! answers every frame in order, reports a bad frame in its answer and goes on, frees its
//! session when it ends, and is ended by the server when idle.

mod common;

use b2tfpose::features::{EmbeddedBackbone, EmbeddedConfig};
use b2tfpose::geometry::{Intrinsics, Pose, ViewSampling};
use b2tfpose::onboard::{onboard, OnboardConfig};
use b2tfpose::render::{RenderPool, RendererConfig};
use b2tfpose::service::client::png_bytes;
use b2tfpose::service::proto as pb;
use b2tfpose::service::proto::pose_service_client::PoseServiceClient;
use b2tfpose::track::sequence::{generate, SequenceConfig};
use base64::Engine as _;
use common::{pose_errors, sample_mesh, start};
use serde_json::{json, Value};
use std::time::{Duration, Instant};
use tonic::Code;

const K: [f64; 4] = [500.0, 500.0, 159.5, 119.5];

fn intrinsics() -> Intrinsics {
    Intrinsics::new(K[0], K[1], K[2], K[3], 320, 240).unwrap()
}

fn b64(bytes: &[u8]) -> String {
    base64::engine::general_purpose::STANDARD.encode(bytes)
}

fn frame_json(rgb: &image::RgbImage, mask: Option<&image::GrayImage>, object: &str, index: Option<u64>) -> Value {
    let detections: Vec<Value> = mask.map(|m| json!({"object_id": object, "mask_png": b64(&png_bytes(m).unwrap())})).into_iter().collect();
    let mut v = json!({
        "image": {"raw_rgb8": b64(rgb.as_raw()), "width": rgb.width(), "height": rgb.height()},
        "intrinsics": {"fx": K[0], "fy": K[1], "cx": K[2], "cy": K[3], "width": 320, "height": 240},
        "detections": detections,
    });
    if let Some(i) = index {
        v["frame_index"] = json!(i);
    }
    v
}

fn pb_frame(rgb: &image::RgbImage, mask: Option<&image::GrayImage>, object: &str) -> pb::TrackFrame {
    pb::TrackFrame {
        image: Some(pb::Image { data: Some(pb::image::Data::RawRgb8(rgb.as_raw().clone())), width: rgb.width(), height: rgb.height() }),
        intrinsics: Some(pb::Intrinsics { fx: K[0], fy: K[1], cx: K[2], cy: K[3], width: 320, height: 240 }),
        detections: mask.map(|m| pb::Detection { object_id: object.into(), mask: Some(pb::detection::Mask::MaskPng(png_bytes(m).unwrap())), bbox: None, score: None }).into_iter().collect(),
        frame_index: None,
        options: None,
        ..Default::default()
    }
}

/// A frame's depth (metres) as JSON raw float32.
fn depth_json(depth: &[f32]) -> Value {
    let bytes: Vec<u8> = depth.iter().flat_map(|v| v.to_le_bytes()).collect();
    json!({"raw_f32": b64(&bytes), "width": 320, "height": 240})
}

/// A frame's depth (metres) as protobuf uint16 tenths of a millimetre.
fn pb_depth(depth: &[f32]) -> pb::Depth {
    let bytes: Vec<u8> = depth.iter().flat_map(|v| ((v * 1e4).round() as u16).to_le_bytes()).collect();
    pb::Depth { data: Some(pb::depth::Data::RawU16(bytes)), width: 320, height: 240, scale_mm: 0.1 }
}

async fn call(c: &reqwest::Client, method: reqwest::Method, url: &str, body: Option<&Value>) -> (u16, Value) {
    let mut r = c.request(method, url);
    if let Some(b) = body {
        r = r.json(b);
    }
    let resp = r.send().await.expect("the server answers");
    let status = resp.status().as_u16();
    let text = resp.text().await.unwrap();
    (status, serde_json::from_str(&text).unwrap_or(Value::String(text)))
}

/// The one object of a frame's answer, with its rotation and translation errors.
fn only_object(v: &Value, truth: &Pose) -> (String, f64, f64) {
    let objects = v["objects"].as_array().unwrap_or_else(|| panic!("no objects in {v}"));
    assert_eq!(objects.len(), 1, "{v}");
    let o = &objects[0];
    let mode = o["mode"].as_str().unwrap().to_string();
    let Some(pose) = o.get("pose").filter(|p| !p.is_null()) else { return (mode, f64::INFINITY, f64::INFINITY) };
    let r: Vec<f64> = serde_json::from_value(pose["R"].clone()).unwrap();
    let t: Vec<f64> = serde_json::from_value(pose["t"].clone()).unwrap();
    let (er, et) = pose_errors(&r, &t, truth);
    (mode, er, et)
}

async fn metric(c: &reqwest::Client, base: &str, line_start: &str) -> f64 {
    let text = c.get(format!("{base}/metrics")).send().await.unwrap().text().await.unwrap();
    text.lines().find(|l| l.starts_with(line_start)).and_then(|l| l.rsplit(' ').next()).and_then(|v| v.parse().ok()).unwrap_or(0.0)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sessions_and_streams_track_refuse_bad_frames_and_expire() {
    // The sample, onboarded straight into the store the server will open.
    let dir = tempfile::tempdir().unwrap();
    let store = format!("sqlite://{}", dir.path().join("objects.db").display());
    let pool = RenderPool::new(1, RendererConfig::default()).unwrap();
    let backbone = EmbeddedBackbone::new(EmbeddedConfig::default()).unwrap();
    let cfg = OnboardConfig { views: ViewSampling { level: 1, in_plane_steps: 6 }, ..Default::default() };
    let model = onboard("box", &sample_mesh(), &cfg, &backbone, &pool, &|_| {}).unwrap();
    b2tfpose::store::open(&store).unwrap().put(&model, false).unwrap();
    let k = intrinsics();
    let seq = generate(&model.mesh, &k, &SequenceConfig { frames: 10, seed: 5, ..Default::default() }, &pool).unwrap();
    let first_mask = pool.render(&model.mesh, &seq[0].truth, &k, &Default::default()).unwrap().mask;

    let server = start(&store, None, &["--max-track-sessions", "2", "--track-idle-timeout-s", "3"]);
    let base = server.http.clone();
    let c = common::async_http_client().timeout(Duration::from_secs(300)).build().unwrap();
    let t = Instant::now();
    while c.get(format!("{base}/readyz")).send().await.map(|r| r.status().as_u16()).ok() != Some(200) {
        assert!(t.elapsed() < Duration::from_secs(60), "never ready");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let tracks = format!("{base}/v1/tracks");
    use reqwest::Method as M;

    // Options are checked when the session opens.
    let (s, v) = call(&c, M::POST, &tracks, Some(&json!({"options": {"max_tracks": 0}}))).await;
    assert!(s == 400 && v.to_string().contains("max_tracks"), "{s} {v}");
    let (s, v) = call(&c, M::POST, &tracks, Some(&json!({"options": {"lost_belowz": 0.5}}))).await;
    assert!(s == 400 && v.to_string().contains("lost_belowz"), "{s} {v}");
    let (s, v) = call(&c, M::POST, &tracks, None).await;
    assert_eq!(s, 201, "{v}");
    let id = v["id"].as_str().unwrap().to_string();
    let frames = format!("{tracks}/{id}/frames");

    // Frame 0: a full estimate from its mask starts track 0.
    let (s, v) = call(&c, M::POST, &frames, Some(&frame_json(&seq[0].rgb, Some(&first_mask), "box", None))).await;
    assert_eq!(s, 200, "{v}");
    let (mode, er, et) = only_object(&v, &seq[0].truth);
    assert!(mode == "estimated" && v["objects"][0]["track_id"] == 0 && v["frame_index"] == 0, "{v}");
    assert_eq!(v["objects"][0]["timings_ms"], json!({}), "a full estimate has no tracking step");
    assert!(er < 10.0 && et < 0.02, "first estimate {er:.1}° {:.1} mm", et * 1e3);

    // Then tracked, without detections; the later frames with their depth (RGB-D), each
    // answer saying how the pose lies on the measured surface.
    let mut errors = vec![];
    for (i, f) in seq.iter().enumerate().skip(1) {
        let mut frame = frame_json(&f.rgb, None, "box", None);
        if i >= 5 {
            frame["depth"] = depth_json(&f.depth);
        }
        let (s, v) = call(&c, M::POST, &frames, Some(&frame)).await;
        assert_eq!(s, 200, "{v}");
        let (mode, er, et) = only_object(&v, &f.truth);
        assert!(mode == "tracked" || mode == "reinitialised", "{v}");
        if i >= 5 && mode == "tracked" {
            assert!(v["objects"][0]["depth_fit"]["inlier_share"].as_f64().is_some_and(|s| s > 0.5), "{v}");
        }
        if mode == "tracked" {
            // The step's stage times, within its total.
            let t = &v["objects"][0]["timings_ms"];
            let total = t["total"].as_f64().unwrap_or(0.0);
            assert!(total > 0.0 && t["contour"].as_f64().is_some_and(|c| c > 0.0 && c <= total), "{v}");
        }
        errors.push((er, et));
    }
    errors.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (median_r, worst_t) = (errors[errors.len() / 2].0, errors.iter().map(|e| e.1).fold(0.0, f64::max));
    assert!(median_r < 5.0 && worst_t < 0.03, "median {median_r:.1}°, worst {:.1} mm", worst_t * 1e3);

    // Bad frames are refused, naming what is wrong, and leave the session as it was.
    let last = seq.len() as u64 - 1;
    let late = frame_json(&seq[9].rgb, None, "box", Some(3));
    let (s, v) = call(&c, M::POST, &frames, Some(&late)).await;
    assert!(s == 400 && v.to_string().contains("frame_index 3") && v.to_string().contains(&format!("({last})")), "{s} {v}");
    let mut wrong_size = frame_json(&seq[9].rgb, None, "box", None);
    wrong_size["intrinsics"]["width"] = json!(640);
    let (s, v) = call(&c, M::POST, &frames, Some(&wrong_size)).await;
    assert!(s == 400 && v.to_string().contains("intrinsics"), "{s} {v}");
    let mut small_depth = frame_json(&seq[9].rgb, None, "box", None);
    small_depth["depth"] = json!({"raw_f32": b64(&[0u8; 4 * 32 * 24]), "width": 32, "height": 24});
    let (s, v) = call(&c, M::POST, &frames, Some(&small_depth)).await;
    assert!(s == 400 && v.to_string().contains("depth.raw_f32") && v.to_string().contains("320×240"), "{s} {v}");
    let (s, v) = call(&c, M::POST, &frames, Some(&frame_json(&seq[9].rgb, Some(&first_mask), "nope", None))).await;
    assert!(s == 404 && v.to_string().contains("nope"), "{s} {v}");
    let mut bad_mask = frame_json(&seq[9].rgb, None, "box", None);
    bad_mask["detections"] = json!([{"object_id": "box", "mask_png": b64(b"not a png")}]);
    let (s, v) = call(&c, M::POST, &frames, Some(&bad_mask)).await;
    assert!(s == 400 && v.to_string().contains("detections[0].mask_png"), "{s} {v}");
    let (s, v) = call(&c, M::POST, &format!("{tracks}/trk-nope/frames"), Some(&frame_json(&seq[9].rgb, None, "box", None))).await;
    assert!(s == 404 && v.to_string().contains("trk-nope"), "{s} {v}");
    let (s, v) = call(&c, M::GET, &format!("{tracks}/{id}"), None).await;
    assert!(s == 200 && v["frames"] == seq.len() && v["last_frame"] == last && v["tracks"].as_array().unwrap().len() == 1, "{v}");

    // The object jumps 5 cm aside and 20 cm back (staying whole in the frame): the track is
    // lost in this frame and takes the detection given with it, wherever it is.
    let towards_middle = if seq[9].truth.translation.x > 0.0 { -0.05 } else { 0.05 };
    let jumped = Pose::new(seq[9].truth.rotation, seq[9].truth.translation + nalgebra::Vector3::new(towards_middle, 0.0, 0.2));
    let jump = pool.render(&model.mesh, &jumped, &k, &Default::default()).unwrap();
    let touches_border =
        (0..320).any(|x| jump.mask.get_pixel(x, 0)[0] > 0 || jump.mask.get_pixel(x, 239)[0] > 0) || (0..240).any(|y| jump.mask.get_pixel(0, y)[0] > 0 || jump.mask.get_pixel(319, y)[0] > 0);
    assert!(!touches_border, "the jumped object should be whole in the frame");
    let (s, v) = call(&c, M::POST, &frames, Some(&frame_json(&jump.rgb, Some(&jump.mask), "box", Some(last + 5)))).await;
    assert_eq!(s, 200, "{v}");
    let (mode, er, et) = only_object(&v, &jumped);
    assert!(mode == "reinitialised" && v["objects"][0]["track_id"] == 0 && v["objects"][0]["detection_index"] == 0 && v["frame_index"] == last + 5, "{v}");
    assert!(er < 10.0 && et < 0.02, "re-initialised {er:.1}° {:.1} mm", et * 1e3);
    assert!(metric(&c, &base, "b2tf_track_objects_total{mode=\"tracked\"}").await >= 9.0);
    assert_eq!(metric(&c, &base, "b2tf_track_sessions_open").await, 1.0);

    // The session limit (2) refuses a third session, HTTP or gRPC; closing one frees it.
    let (s, v) = call(&c, M::POST, &tracks, None).await;
    assert_eq!(s, 201, "{v}");
    let second = v["id"].as_str().unwrap().to_string();
    let (s, v) = call(&c, M::POST, &tracks, None).await;
    assert!(s == 429 && v.to_string().contains("limit"), "{s} {v}");
    let mut grpc = PoseServiceClient::connect(server.grpc.clone()).await.unwrap();
    let (tx, rx) = tokio::sync::mpsc::channel(4);
    tx.send(pb_frame(&seq[0].rgb, Some(&first_mask), "box")).await.unwrap();
    let refused = match grpc.track(tokio_stream::wrappers::ReceiverStream::new(rx)).await {
        Err(status) => status,
        Ok(answers) => answers.into_inner().message().await.expect_err("a stream over the limit is refused"),
    };
    assert_eq!(refused.code(), Code::ResourceExhausted, "{refused:?}");
    assert_eq!(call(&c, M::DELETE, &format!("{tracks}/{second}"), None).await.0, 204);
    assert_eq!(call(&c, M::DELETE, &format!("{tracks}/{second}"), None).await.0, 404);

    // A stream: one answer per frame, in order; a bad frame is answered and the stream goes
    // on; the session exists while the stream does.
    let (tx, rx) = tokio::sync::mpsc::channel(4);
    let mut answers = grpc.track(tokio_stream::wrappers::ReceiverStream::new(rx)).await.unwrap().into_inner();
    tx.send(pb_frame(&seq[0].rgb, Some(&first_mask), "box")).await.unwrap();
    let a = answers.message().await.unwrap().unwrap();
    assert!(a.error.is_none() && a.frame_index == 0 && a.objects.len() == 1, "{a:?}");
    assert_eq!(a.objects[0].mode(), pb::tracked_object::Mode::Estimated);
    let (er, et) = {
        let p = a.objects[0].pose.as_ref().unwrap();
        pose_errors(&p.r, &p.t, &seq[0].truth)
    };
    assert!(er < 10.0 && et < 0.02, "{er:.1}° {:.1} mm", et * 1e3);
    tx.send(pb::TrackFrame { intrinsics: None, ..pb_frame(&seq[1].rgb, None, "box") }).await.unwrap();
    let a = answers.message().await.unwrap().unwrap();
    let e = a.error.as_ref().expect("the bad frame is answered with an error");
    assert!(e.code == "INVALID_ARGUMENT" && e.message.contains("intrinsics"), "{e:?}");
    tx.send(pb::TrackFrame { depth: Some(pb::Depth { scale_mm: 0.0, ..pb_depth(&seq[1].depth) }), ..pb_frame(&seq[1].rgb, None, "box") }).await.unwrap();
    let a = answers.message().await.unwrap().unwrap();
    let e = a.error.as_ref().expect("depth without its scale is answered with an error");
    assert!(e.code == "INVALID_ARGUMENT" && e.message.contains("depth.scale_mm"), "{e:?}");
    for (i, f) in seq[1..4].iter().enumerate() {
        tx.send(pb::TrackFrame { depth: Some(pb_depth(&f.depth)), ..pb_frame(&f.rgb, None, "box") }).await.unwrap();
        let a = answers.message().await.unwrap().unwrap();
        assert!(a.error.is_none() && a.frame_index == i as u64 + 1, "{a:?}");
        assert_eq!(a.objects[0].mode(), pb::tracked_object::Mode::Tracked, "{a:?}");
        assert!(a.objects[0].depth_fit.as_ref().is_some_and(|d| d.inlier_share > 0.5 && d.rms_mm < 5.0), "{a:?}");
        assert!(a.objects[0].timings_ms.get("depth").is_some_and(|&d| d > 0.0 && d <= a.objects[0].timings_ms["total"]), "{a:?}");
    }
    let stream_session = a.session_id.clone();
    let (_, v) = call(&c, M::GET, &tracks, None).await;
    assert!(v.to_string().contains(&stream_session), "{v}");
    drop(tx);
    assert!(answers.message().await.unwrap().is_none(), "the stream ends when the client stops sending");
    let t = Instant::now();
    while call(&c, M::GET, &format!("{tracks}/{stream_session}"), None).await.0 != 404 {
        assert!(t.elapsed() < Duration::from_secs(5), "the stream's session outlived it");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }

    // Idle: the server ends a silent stream, and closes the HTTP session (3 s timeout).
    let (tx, rx) = tokio::sync::mpsc::channel(4);
    let mut answers = grpc.track(tokio_stream::wrappers::ReceiverStream::new(rx)).await.unwrap().into_inner();
    tx.send(pb_frame(&seq[0].rgb, Some(&first_mask), "box")).await.unwrap();
    assert!(answers.message().await.unwrap().unwrap().error.is_none());
    let silent = tokio::time::timeout(Duration::from_secs(20), answers.message()).await.expect("the server ends an idle stream");
    assert_eq!(silent.unwrap_err().code(), Code::DeadlineExceeded);
    drop(tx);
    let t = Instant::now();
    let (s, v) = loop {
        let (s, v) = call(&c, M::GET, &format!("{tracks}/{id}"), None).await;
        if s != 200 || t.elapsed() > Duration::from_secs(20) {
            break (s, v);
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    };
    assert!(s == 404 && v.to_string().contains("expired"), "{s} {v}");
    assert_eq!(metric(&c, &base, "b2tf_track_sessions_open").await, 0.0);
}
