//! The gRPC service as clients see it: a real `b2tf serve` process on loopback. Onboards
//! the sample through PoseService (watching the operation stream), estimates through gRPC
//! and HTTP with identical results, answers every kind of bad input with its code while
//! staying healthy, honours deadlines, and serves health and reflection; API keys and TLS
//! on both ports in a second server.

mod common;

use b2tfpose::service::client::png_bytes;
use b2tfpose::service::proto as pb;
use b2tfpose::service::proto::pose_service_client::PoseServiceClient;
use base64::Engine as _;
use common::{pose_errors, sample_files, scene, start};
use std::time::{Duration, Instant};
use tonic::transport::Channel;
use tonic::Code;
use tonic_health::pb::health_client::HealthClient;
use tonic_health::pb::{health_check_response::ServingStatus, HealthCheckRequest};

async fn serving(channel: Channel, service: &str) -> ServingStatus {
    let r = HealthClient::new(channel).check(HealthCheckRequest { service: service.into() }).await.expect("health answers");
    r.into_inner().status()
}

async fn wait_serving(channel: &Channel) {
    let t = Instant::now();
    while serving(channel.clone(), "b2tfpose.v1.PoseService").await != ServingStatus::Serving {
        assert!(t.elapsed() < Duration::from_secs(60), "never SERVING");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

fn onboard_request(dir: &std::path::Path, id: &str, level: u32, in_plane: u32) -> pb::OnboardRequest {
    let files = sample_files(dir);
    pb::OnboardRequest {
        object_id: id.into(),
        mesh: Some(pb::Mesh {
            data: files[0].1.clone(),
            format: "obj".into(),
            units: "m".into(),
            resources: files[1..].iter().map(|(n, b)| pb::Resource { name: n.clone(), data: b.clone() }).collect(),
        }),
        options: Some(pb::OnboardOptions { level: Some(level), in_plane, ..Default::default() }),
        replace: false,
    }
}

fn estimate_request(image: pb::image::Data, w: u32, h: u32, mask_png: Vec<u8>, object_id: &str) -> pb::EstimateRequest {
    pb::EstimateRequest {
        image: Some(pb::Image { data: Some(image), width: w, height: h }),
        intrinsics: Some(pb::Intrinsics { fx: 500.0, fy: 500.0, cx: 159.5, cy: 119.5, width: 320, height: 240 }),
        detections: vec![pb::Detection { object_id: object_id.into(), mask: Some(pb::detection::Mask::MaskPng(mask_png)), bbox: None, score: Some(0.9) }],
        options: Some(pb::EstimateOptions { rrc: Some(false), ..Default::default() }),
        ..Default::default()
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn onboard_estimate_bad_inputs_health_and_reflection_over_grpc() {
    let dir = tempfile::tempdir().unwrap();
    let store = format!("sqlite://{}", dir.path().join("objects.db").display());
    let mut server = start(&store, None, &[]);
    let channel = Channel::from_shared(server.grpc.clone()).unwrap().connect().await.expect("gRPC connects");
    wait_serving(&channel).await;
    assert_eq!(serving(channel.clone(), "").await, ServingStatus::Serving);
    let mut c = PoseServiceClient::new(channel.clone());

    // Reflection lists the API and health.
    {
        use tonic_reflection::pb::v1::{
            server_reflection_client::ServerReflectionClient, server_reflection_request::MessageRequest, server_reflection_response::MessageResponse, ServerReflectionRequest,
        };
        let req = ServerReflectionRequest { host: String::new(), message_request: Some(MessageRequest::ListServices(String::new())) };
        let mut stream = ServerReflectionClient::new(channel.clone()).server_reflection_info(tokio_stream::iter([req])).await.unwrap().into_inner();
        let Some(MessageResponse::ListServicesResponse(list)) = stream.message().await.unwrap().unwrap().message_response else { panic!("no service list") };
        let names: Vec<String> = list.service.into_iter().map(|s| s.name).collect();
        assert!(names.contains(&"b2tfpose.v1.PoseService".to_string()) && names.contains(&"grpc.health.v1.Health".to_string()), "{names:?}");
    }

    // Onboard, watching progress to the end.
    let op = c.onboard(onboard_request(dir.path(), "box", 1, 6)).await.expect("onboarding starts").into_inner();
    assert_eq!((op.object_id.as_str(), op.templates_total), ("box", 42 * 6));
    let mut watch = c.watch_operation(pb::GetOperationRequest { id: op.id.clone() }).await.unwrap().into_inner();
    let (mut last, mut updates) = (None, 0);
    while let Some(o) = watch.message().await.expect("stream healthy") {
        if let Some(prev) = &last {
            let prev: &pb::Operation = prev;
            assert!(o.templates_done >= prev.templates_done, "progress went back");
        }
        updates += 1;
        last = Some(o);
    }
    let done = last.expect("at least one update");
    assert_eq!(done.state(), pb::operation::State::Succeeded, "{done:?}");
    assert_eq!(done.object.as_ref().map(|o| o.templates), Some(252));
    assert!(updates >= 2, "{updates} updates");
    let again = c.onboard(onboard_request(dir.path(), "box", 1, 6)).await.unwrap_err();
    assert_eq!(again.code(), Code::AlreadyExists, "{again:?}");
    let listed = c.list_objects(pb::ListObjectsRequest {}).await.unwrap().into_inner();
    assert_eq!(listed.objects.iter().map(|o| o.id.as_str()).collect::<Vec<_>>(), ["box"]);
    let info = c.get_object(pb::GetObjectRequest { object_id: "box".into() }).await.unwrap().into_inner();
    assert!(info.diameter_m > 0.19 && info.diameter_m < 0.2 && info.mesh_units == "m", "{info:?}");
    // Symmetries found from the mesh: the box's textured faces all differ, so it has none.
    let none = Some(pb::Symmetries { source: "mesh".into(), discrete: vec![], continuous: vec![] });
    assert!(info.symmetries == none && listed.objects[0].symmetries == none, "{info:?}");

    // Estimate through gRPC (PNG and raw RGB) and through HTTP: the same pose.
    let sc = scene();
    let (rgb, mask) = (png_bytes(&sc.render.rgb).unwrap(), png_bytes(&sc.render.mask).unwrap());
    let by_png = c.estimate(estimate_request(pb::image::Data::Encoded(rgb.clone()), 0, 0, mask.clone(), "box")).await.expect("estimate").into_inner();
    let res = &by_png.results[0];
    let pose = res.pose.as_ref().expect("a pose");
    let (rot, trans) = pose_errors(&pose.r, &pose.t, &sc.truth);
    assert!(rot < 10.0 && trans < 0.03, "rotation error {rot:.1}°, translation error {:.1} mm", trans * 1e3);
    assert_eq!((pose.quaternion_wxyz.len(), res.detection_index), (4, 0));
    assert!(res.timings_ms.contains_key("pnp") && res.diagnostics_json.starts_with('['), "{res:?}");
    assert!(res.symmetries == none && !res.arbitrary_rotation_about_axis, "{res:?}");
    // Verification judged other poses on the photo: the best that is another answer (a
    // flip or a template of this unsymmetric box) and by how much it lost.
    let up = res.runner_up.as_ref().expect("a runner-up");
    assert!(up.margin >= 0.0 && up.distance_over_diameter > 0.1 && up.pose.as_ref().is_some_and(|p| p.r.len() == 9 && p.t.len() == 3), "{up:?}");
    assert_eq!(up.close_call, (up.margin as f64) < b2tfpose::estimate::runner_up::CLOSE_CALL, "{up:?}");
    let mut raw = estimate_request(pb::image::Data::RawRgb8(sc.render.rgb.as_raw().clone()), 320, 240, mask.clone(), "box");
    raw.options.as_mut().unwrap().overlay = true;
    let by_raw = c.estimate(raw).await.unwrap().into_inner();
    assert_eq!(by_raw.results[0].pose, res.pose);
    // The overlay only when asked for: the photo's size, the pose drawn on it.
    assert!(by_png.overlay_png.is_empty());
    let overlay = image::load_from_memory(&by_raw.overlay_png).expect("overlay PNG").to_rgb8();
    assert!(overlay.dimensions() == (320, 240) && overlay != sc.render.rgb);
    // RGB-D: the render's depth as 16-bit tenths of a millimetre beside the mask: the pose
    // is fitted to the measured surface.
    let tenths: Vec<u8> = sc.render.depth.iter().flat_map(|z| ((z * 10_000.0).round() as u16).to_le_bytes()).collect();
    let mut rgbd = estimate_request(pb::image::Data::Encoded(rgb.clone()), 0, 0, mask.clone(), "box");
    rgbd.depth = Some(pb::Depth { data: Some(pb::depth::Data::RawU16(tenths.clone())), width: 320, height: 240, scale_mm: 0.1 });
    let by_depth = c.estimate(rgbd).await.expect("RGB-D estimate").into_inner();
    let fitted = by_depth.results[0].pose.as_ref().expect("a pose");
    let (rot, trans) = pose_errors(&fitted.r, &fitted.t, &sc.truth);
    assert!(rot < 5.0 && trans < 0.005, "RGB-D: rotation error {rot:.1}°, translation error {:.1} mm", trans * 1e3);
    assert!(by_depth.results[0].diagnostics_json.contains("\"depth_fit\""), "{}", by_depth.results[0].diagnostics_json);
    let b64 = |b: &[u8]| base64::engine::general_purpose::STANDARD.encode(b);
    let http_body = serde_json::json!({
        "image": {"encoded": b64(&rgb)},
        "intrinsics": {"fx": 500.0, "fy": 500.0, "cx": 159.5, "cy": 119.5, "width": 320, "height": 240},
        "detections": [{"object_id": "box", "mask_png": b64(&mask), "score": 0.9}],
        "options": {"rrc": false}
    });
    let http: serde_json::Value = common::async_http_client().build().unwrap().post(format!("{}/v1/estimate", server.http)).json(&http_body).send().await.unwrap().json().await.unwrap();
    let http_pose = &http["results"][0]["pose"];
    let nums = |v: &serde_json::Value| v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect::<Vec<_>>();
    assert_eq!((nums(&http_pose["R"]), nums(&http_pose["t"]), nums(&http_pose["quaternion_wxyz"])), (pose.r.clone(), pose.t.clone(), pose.quaternion_wxyz.clone()), "HTTP and gRPC differ");
    assert_eq!(http["results"][0]["score"].as_f64().unwrap() as f32, res.score);
    let http_up = &http["results"][0]["runner_up"];
    assert_eq!(
        (http_up["margin"].as_f64().unwrap() as f32, nums(&http_up["pose"]["t"]), http_up["close_call"].as_bool()),
        (up.margin, up.pose.as_ref().unwrap().t.clone(), Some(up.close_call)),
        "HTTP and gRPC runner-ups differ"
    );

    // Bad inputs: each gets its code and a message naming the problem; the server stays up.
    let good = || estimate_request(pb::image::Data::Encoded(rgb.clone()), 0, 0, mask.clone(), "box");
    let with = |f: &dyn Fn(&mut pb::EstimateRequest)| {
        let mut r = good();
        f(&mut r);
        r
    };
    let small_mask = png_bytes(&image::GrayImage::new(10, 10)).unwrap();
    let cases: Vec<(pb::EstimateRequest, Code, &str)> = vec![
        (with(&|r| r.image = Some(pb::Image { data: Some(pb::image::Data::Encoded(b"not an image".to_vec())), width: 0, height: 0 })), Code::InvalidArgument, "image.encoded"),
        (with(&|r| r.image = None), Code::InvalidArgument, "image is required"),
        (with(&|r| r.image = Some(pb::Image { data: Some(pb::image::Data::RawRgb8(vec![0; 10])), width: 320, height: 240 })), Code::InvalidArgument, "raw_rgb8"),
        (with(&|r| r.detections[0].object_id = "nope".into()), Code::NotFound, "nope"),
        (with(&|r| r.detections[0].object_id = "../x".into()), Code::InvalidArgument, "object_id"),
        (with(&|r| r.detections[0].mask = Some(pb::detection::Mask::MaskPng(small_mask.clone()))), Code::InvalidArgument, "mask is 10×10"),
        (with(&|r| r.detections[0].mask = Some(pb::detection::Mask::MaskRle(pb::Rle { counts: vec![5, 5], height: 240, width: 320 }))), Code::InvalidArgument, "mask_rle"),
        (with(&|r| r.detections[0].score = Some(f32::NAN)), Code::InvalidArgument, "score"),
        (with(&|r| r.detections.clear()), Code::InvalidArgument, "at least one"),
        (with(&|r| r.intrinsics.as_mut().unwrap().fx = f64::NAN), Code::InvalidArgument, "intrinsics"),
        (with(&|r| r.intrinsics.as_mut().unwrap().fy = -500.0), Code::InvalidArgument, "intrinsics"),
        (with(&|r| r.intrinsics = None), Code::InvalidArgument, "intrinsics is required"),
        (with(&|r| r.intrinsics.as_mut().unwrap().width = 640), Code::InvalidArgument, "intrinsics say 640×240"),
        (with(&|r| r.depth = Some(pb::Depth { data: Some(pb::depth::Data::RawU16(tenths.clone())), width: 320, height: 240, scale_mm: 0.0 })), Code::InvalidArgument, "depth.scale_mm is needed"),
        (
            with(&|r| r.depth = Some(pb::Depth { data: Some(pb::depth::Data::RawU16(tenths.clone())), width: 320, height: 240, scale_mm: -1.0 })),
            Code::InvalidArgument,
            "depth scale must be finite and positive",
        ),
        (
            with(&|r| r.depth = Some(pb::Depth { data: Some(pb::depth::Data::RawU16(tenths[..1000].to_vec())), width: 320, height: 240, scale_mm: 0.1 })),
            Code::InvalidArgument,
            "depth.raw_u16 has 1000 bytes",
        ),
        (with(&|r| r.depth = Some(pb::Depth { data: None, width: 320, height: 240, scale_mm: 0.1 })), Code::InvalidArgument, "depth: give exactly one of"),
        // Over --max-body-mb 3.
        (with(&|r| r.image = Some(pb::Image { data: Some(pb::image::Data::RawRgb8(vec![7; 4_000_000])), width: 0, height: 0 })), Code::InvalidArgument, "too large"),
    ];
    for (req, code, needle) in cases {
        let e = c.estimate(req).await.expect_err(needle);
        assert_eq!(e.code(), code, "{needle}: {e:?}");
        assert!(e.message().contains(needle), "{needle} not in {:?}", e.message());
        assert_eq!(serving(channel.clone(), "").await, ServingStatus::Serving);
    }
    let e = c.get_operation(pb::GetOperationRequest { id: "op-unknown".into() }).await.unwrap_err();
    assert_eq!(e.code(), Code::NotFound);
    assert_eq!(c.cancel_operation(pb::GetOperationRequest { id: "op-unknown".into() }).await.unwrap_err().code(), Code::NotFound);
    assert_eq!(c.watch_operation(pb::GetOperationRequest { id: "op-unknown".into() }).await.unwrap_err().code(), Code::NotFound);
    assert_eq!(c.get_object(pb::GetObjectRequest { object_id: "ghost".into() }).await.unwrap_err().code(), Code::NotFound);
    assert_eq!(c.get_object(pb::GetObjectRequest { object_id: "../etc".into() }).await.unwrap_err().code(), Code::InvalidArgument);
    let mut no_units = onboard_request(dir.path(), "nounits", 0, 1);
    no_units.mesh.as_mut().unwrap().units.clear();
    let e = c.onboard(no_units).await.unwrap_err();
    assert!(e.code() == Code::InvalidArgument && e.message().contains("unit"), "{e:?}");
    let mut bad_format = onboard_request(dir.path(), "badformat", 0, 1);
    bad_format.mesh.as_mut().unwrap().format = "stl".into();
    assert_eq!(c.onboard(bad_format).await.unwrap_err().code(), Code::InvalidArgument);

    // A deadline shorter than the work: DEADLINE_EXCEEDED from the server (CANCELLED if the
    // transport's own timer fires first), well before the work would have finished.
    let mut slow = good();
    slow.options = Some(pb::EstimateOptions { rrc: Some(true), rrc_always: true, ..Default::default() });
    let mut req = tonic::Request::new(slow);
    req.set_timeout(Duration::from_millis(150));
    let t = Instant::now();
    let e = c.estimate(req).await.unwrap_err();
    assert!(matches!(e.code(), Code::DeadlineExceeded | Code::Cancelled), "{e:?}");
    assert!(t.elapsed() < Duration::from_secs(2), "answered after {:?}", t.elapsed());

    // Estimates keep being answered while an onboarding runs; cancelling stores nothing.
    let op2 = c.onboard(onboard_request(dir.path(), "box2", 3, 12)).await.unwrap().into_inner();
    for _ in 0..3 {
        let during = c.estimate(good()).await.expect("estimate during onboarding").into_inner();
        assert_eq!(during.results[0].pose, res.pose);
    }
    let running = c.get_operation(pb::GetOperationRequest { id: op2.id.clone() }).await.unwrap().into_inner();
    assert_eq!(running.state(), pb::operation::State::Running, "the estimates did not overlap the onboarding");
    c.cancel_operation(pb::GetOperationRequest { id: op2.id.clone() }).await.unwrap();
    let mut watch = c.watch_operation(pb::GetOperationRequest { id: op2.id }).await.unwrap().into_inner();
    let mut state = pb::operation::State::Running;
    while let Some(o) = watch.message().await.unwrap() {
        state = o.state();
    }
    assert_eq!(state, pb::operation::State::Cancelled);
    assert_eq!(c.get_object(pb::GetObjectRequest { object_id: "box2".into() }).await.unwrap_err().code(), Code::NotFound);

    // gRPC calls are counted in the metrics by RPC and code.
    let metrics = reqwest::get(format!("{}/metrics", server.http)).await.unwrap().text().await.unwrap();
    for needle in ["route=\"/b2tfpose.v1.PoseService/Estimate\",status=\"OK\"", "route=\"/b2tfpose.v1.PoseService/Estimate\",status=\"NOT_FOUND\""] {
        assert!(metrics.contains(needle), "{needle} not in metrics");
    }

    // Delete, then gone.
    c.delete_object(pb::GetObjectRequest { object_id: "box".into() }).await.unwrap();
    assert_eq!(c.delete_object(pb::GetObjectRequest { object_id: "box".into() }).await.unwrap_err().code(), Code::NotFound);

    // SIGTERM during an onboarding: the server cancels it, exits cleanly, stores nothing.
    c.onboard(onboard_request(dir.path(), "box3", 3, 12)).await.unwrap();
    // SAFETY: kill(2) on our own child's pid.
    unsafe { libc::kill(server.child.id() as i32, libc::SIGTERM) };
    let status = tokio::task::spawn_blocking(move || {
        let s = server.child.wait().unwrap();
        drop(server);
        s
    })
    .await
    .unwrap();
    assert!(status.success(), "{status:?}");
    let reopened = b2tfpose::store::open(&store).unwrap();
    assert!(!reopened.exists("box3").unwrap() && reopened.list().unwrap().is_empty());
}

/// A self-signed certificate for 127.0.0.1 / localhost: (cert PEM, key PEM).
fn self_signed() -> (String, String) {
    let key = rcgen::KeyPair::generate().unwrap();
    let params = rcgen::CertificateParams::new(vec!["localhost".to_string(), "127.0.0.1".to_string()]).unwrap();
    let cert = params.self_signed(&key).unwrap();
    (cert.pem(), key.serialize_pem())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn api_keys_and_tls_on_both_ports() {
    let dir = tempfile::tempdir().unwrap();
    let (cert, key) = self_signed();
    std::fs::write(dir.path().join("cert.pem"), &cert).unwrap();
    std::fs::write(dir.path().join("key.pem"), &key).unwrap();
    let cert_path = dir.path().join("cert.pem").display().to_string();
    let key_path = dir.path().join("key.pem").display().to_string();
    let server = start(&format!("sqlite://{}", dir.path().join("o.db").display()), Some("s3cret"), &["--tls-cert", &cert_path, "--tls-key", &key_path]);
    assert!(server.grpc.starts_with("https://") && server.http.starts_with("https://"), "{} {}", server.grpc, server.http);

    // gRPC over TLS, trusting the self-signed certificate.
    let tls = tonic::transport::ClientTlsConfig::new().ca_certificate(tonic::transport::Certificate::from_pem(&cert)).domain_name("localhost");
    let channel = Channel::from_shared(server.grpc.clone()).unwrap().tls_config(tls).unwrap().connect().await.expect("TLS gRPC connects");
    // Health is open without a key.
    wait_serving(&channel).await;
    let mut c = PoseServiceClient::new(channel.clone());
    let e = c.list_objects(pb::ListObjectsRequest {}).await.unwrap_err();
    assert_eq!(e.code(), Code::Unauthenticated, "{e:?}");
    let with_key = |k: &str| {
        let mut r = tonic::Request::new(pb::ListObjectsRequest {});
        r.metadata_mut().insert("authorization", format!("Bearer {k}").parse().unwrap());
        r
    };
    assert_eq!(c.list_objects(with_key("wrong")).await.unwrap_err().code(), Code::Unauthenticated);
    assert!(c.list_objects(with_key("s3cret")).await.unwrap().into_inner().objects.is_empty());

    // A plaintext gRPC client cannot talk to the TLS port.
    let plain = Channel::from_shared(server.grpc.replacen("https://", "http://", 1)).unwrap().connect().await;
    if let Ok(plain) = plain {
        assert!(HealthClient::new(plain).check(HealthCheckRequest { service: String::new() }).await.is_err());
    }

    // HTTP over TLS, by hand with rustls: health open, the API needs the key.
    assert!(https_get(&server.http, "/healthz", None, &cert).await.starts_with("HTTP/1.1 200"));
    assert!(https_get(&server.http, "/v1/objects", None, &cert).await.starts_with("HTTP/1.1 401"));
    assert!(https_get(&server.http, "/v1/objects", Some("s3cret"), &cert).await.starts_with("HTTP/1.1 200"));
}

/// The response head and body of one HTTPS GET, trusting only `ca_pem`.
async fn https_get(base: &str, path: &str, key: Option<&str>, ca_pem: &str) -> String {
    let auth = key.map(|k| format!("Authorization: Bearer {k}\r\n")).unwrap_or_default();
    common::https_exchange(base, &format!("GET {path} HTTP/1.1\r\nHost: localhost\r\n{auth}Connection: close\r\n\r\n"), ca_pem, None).await.expect("HTTPS exchange")
}
