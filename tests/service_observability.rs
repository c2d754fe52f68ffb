//! Request ids, logs and traces as operators see them, on a real `b2tf serve` on loopback:
//! every HTTP and gRPC answer (successes, 401/404/413/429, health, a stream's error in its
//! trailers) carries `x-request-id`, a sane client id is echoed and another replaced; the
//! JSON logs parse line by line, every line of a request has its id, and no key or image
//! data reaches them; the spans reach a real OTLP collector (a gRPC trace service on
//! loopback) with the request id and the pipeline's stages; bad settings are refused and an
//! absent collector holds nothing up.

mod common;

use b2tfpose::service::client::png_bytes;
use b2tfpose::service::proto as pb;
use base64::Engine as _;
use common::{sample_files, scene, start_logged, Logs, Server};
use serde_json::{json, Value};
use std::process::Command;
use std::time::{Duration, Instant};

const KEY: &str = "obs-test-key-5ecret";

fn b64(bytes: &[u8]) -> String {
    base64::engine::general_purpose::STANDARD.encode(bytes)
}

fn is_generated(id: &str) -> bool {
    id.len() == 32 && id.bytes().all(|c| c.is_ascii_hexdigit())
}

fn wait_ready(base: &str) {
    let c = common::http_client().build().unwrap();
    let t = Instant::now();
    while c.get(format!("{base}/readyz")).send().map(|r| r.status().as_u16()).unwrap_or(0) != 200 {
        assert!(t.elapsed() < Duration::from_secs(60), "never ready");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// SIGTERM, then waits for the exit (flushing what it exports); returns how long it took.
fn stop(server: &mut Server) -> Duration {
    let t = Instant::now();
    unsafe { libc::kill(server.child.id() as i32, libc::SIGTERM) };
    while server.child.try_wait().unwrap().is_none() {
        assert!(t.elapsed() < Duration::from_secs(30), "the server did not stop");
        std::thread::sleep(Duration::from_millis(50));
    }
    t.elapsed()
}

/// A 320×240 image with a rectangle, and the rectangle's mask.
fn photo() -> (image::RgbImage, image::GrayImage) {
    let rgb = image::RgbImage::from_fn(320, 240, |x, y| image::Rgb([(x % 251) as u8, (y % 241) as u8, ((x * y) % 239) as u8]));
    let mask = image::GrayImage::from_fn(320, 240, |x, y| image::Luma([if (100..200).contains(&x) && (60..180).contains(&y) { 255 } else { 0 }]));
    (rgb, mask)
}

/// What a client sends and what comes back: (status, x-request-id).
fn http(c: &reqwest::blocking::Client, req: reqwest::blocking::RequestBuilder) -> (u16, String) {
    let r = c.execute(req.build().unwrap()).expect("request sent");
    let id = r.headers().get("x-request-id").unwrap_or_else(|| panic!("{} {} has no x-request-id", r.status(), r.url())).to_str().unwrap().to_string();
    (r.status().as_u16(), id)
}

/// A POST that announces `len` bytes and sends none: (status, x-request-id).
fn announced_only(base: &str, path: &str, len: usize) -> (u16, String) {
    use std::io::{Read, Write};
    let addr = base.trim_start_matches("http://");
    let mut s = std::net::TcpStream::connect(addr).unwrap();
    write!(s, "POST {path} HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer {KEY}\r\nContent-Type: application/json\r\nContent-Length: {len}\r\nConnection: close\r\n\r\n").unwrap();
    s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    let mut head = Vec::new();
    let mut byte = [0u8; 1];
    while !head.ends_with(b"\r\n\r\n") && s.read(&mut byte).unwrap() == 1 {
        head.push(byte[0]);
    }
    let head = String::from_utf8_lossy(&head).to_lowercase();
    let id = head.lines().find_map(|l| l.strip_prefix("x-request-id: ")).expect("x-request-id").trim().to_string();
    (head[9..12].parse().unwrap(), id)
}

fn grpc_request<T>(msg: T, key: bool, id: Option<&str>) -> tonic::Request<T> {
    let mut r = tonic::Request::new(msg);
    if key {
        r.metadata_mut().insert("authorization", format!("Bearer {KEY}").parse().unwrap());
    }
    if let Some(id) = id {
        r.metadata_mut().insert("x-request-id", id.parse().unwrap());
    }
    r
}

fn status_id(s: &tonic::Status) -> String {
    s.metadata().get("x-request-id").unwrap_or_else(|| panic!("{s:?} has no x-request-id")).to_str().unwrap().to_string()
}

/// The log's lines, every one of which must be a JSON object (drivers' lines included).
fn json_lines(logs: &Logs) -> Vec<Value> {
    let lines = logs.lock().unwrap().clone();
    lines.iter().map(|l| serde_json::from_str::<Value>(l).ok().filter(Value::is_object).unwrap_or_else(|| panic!("not a JSON object: {l}"))).collect()
}

#[test]
fn request_ids_on_every_answer_and_json_logs_without_secrets() {
    let dir = tempfile::tempdir().unwrap();
    let store = format!("sqlite://{}", dir.path().join("objects.db").display());
    let (server, logs) = start_logged(&store, Some(KEY), &["--log-format", "json", "--max-track-sessions", "1"], &[("B2TF_LOG", "info,b2tfpose=debug"), ("XDG_RUNTIME_DIR", "")]); // as on a bare server: no session
    let (base, c) = (server.http.clone(), common::http_client().build().unwrap());
    wait_ready(&base);
    let auth = |r: reqwest::blocking::RequestBuilder| r.bearer_auth(KEY);
    // (request id, expected status) of every call, for the log checks.
    let mut seen: Vec<(String, String)> = Vec::new();
    let mut expect = |(status, id): (u16, String), want: u16, echoed: Option<&str>| {
        assert_eq!(status, want, "request {id}");
        match echoed {
            Some(e) => assert_eq!(id, e),
            None => assert!(is_generated(&id), "{id}"),
        }
        seen.push((id, status.to_string()));
    };

    expect(http(&c, c.get(format!("{base}/healthz"))), 200, None);
    expect(http(&c, c.get(format!("{base}/v1/objects"))), 401, None);
    expect(http(&c, auth(c.get(format!("{base}/v1/objects/nope"))).header("x-request-id", "client-id.1:a_b-c")), 404, Some("client-id.1:a_b-c"));
    expect(http(&c, auth(c.get(format!("{base}/nowhere")))), 404, None);
    for insane in ["has space", "x".repeat(65).as_str(), "semi;colon"] {
        expect(http(&c, auth(c.get(format!("{base}/v1/objects"))).header("x-request-id", insane)), 200, None);
    }
    // Over the 3 MB limit, refused from the announced length.
    expect(announced_only(&base, "/v1/estimate", 4_000_000), 413, None);
    // A real image and mask, of an object the store does not have.
    let (rgb, mask) = photo();
    let (image_b64, mask_b64) = (b64(&png_bytes(&rgb).unwrap()), b64(&png_bytes(&mask).unwrap()));
    let estimate = json!({"image": {"encoded": image_b64}, "intrinsics": {"fx": 500.0, "fy": 500.0, "cx": 159.5, "cy": 119.5, "width": 320, "height": 240},
                          "detections": [{"object_id": "ghost", "mask_png": mask_b64, "score": 0.9}]});
    expect(http(&c, auth(c.post(format!("{base}/v1/estimate"))).header("x-request-id", "est-1").json(&estimate)), 404, Some("est-1"));
    // One tracking session at most: the second is refused.
    expect(http(&c, auth(c.post(format!("{base}/v1/tracks")))), 201, None);
    expect(http(&c, auth(c.post(format!("{base}/v1/tracks")))), 429, None);

    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async {
        let channel = tonic::transport::Channel::from_shared(server.grpc.clone()).unwrap().connect().await.unwrap();
        let mut pose = pb::pose_service_client::PoseServiceClient::new(channel.clone());
        let ok = pose.list_objects(grpc_request(pb::ListObjectsRequest {}, true, Some("grpc-7"))).await.unwrap();
        assert_eq!(ok.metadata().get("x-request-id").unwrap(), "grpc-7");
        seen.push(("grpc-7".into(), "OK".into()));
        let e = pose.get_object(grpc_request(pb::GetObjectRequest { object_id: "nope".into() }, true, Some("bad id!"))).await.unwrap_err();
        assert_eq!(e.code(), tonic::Code::NotFound);
        assert!(is_generated(&status_id(&e)));
        seen.push((status_id(&e), "NOT_FOUND".into()));
        let e = pose.list_objects(grpc_request(pb::ListObjectsRequest {}, false, None)).await.unwrap_err();
        assert_eq!(e.code(), tonic::Code::Unauthenticated);
        seen.push((status_id(&e), "UNAUTHENTICATED".into()));
        let health = tonic_health::pb::health_client::HealthClient::new(channel).check(tonic_health::pb::HealthCheckRequest { service: String::new() }).await.unwrap();
        assert!(is_generated(health.metadata().get("x-request-id").unwrap().to_str().unwrap()));
        // The Track stream's error comes after its headers, in the trailers: the session
        // limit is taken by the HTTP session above.
        let frame = pb::TrackFrame { frame_index: Some(0), ..Default::default() };
        let resp = pose.track(grpc_request(tokio_stream::iter([frame]), true, Some("stream-1"))).await.unwrap();
        assert_eq!(resp.metadata().get("x-request-id").unwrap(), "stream-1");
        let e = resp.into_inner().message().await.unwrap_err();
        assert_eq!((e.code(), status_id(&e).as_str()), (tonic::Code::ResourceExhausted, "stream-1"));
        seen.push(("stream-1".into(), "RESOURCE_EXHAUSTED".into()));
    });
    std::thread::sleep(Duration::from_millis(300));
    drop(server);

    let lines = json_lines(&logs);
    let text = logs.lock().unwrap().join("\n");
    for secret in [KEY, "Bearer", &image_b64[..48], &mask_b64[..48]] {
        assert!(!text.contains(secret), "{secret:?} is in the logs");
    }
    for l in &lines {
        assert!(l["ts"].is_string() && l["level"].is_string() && l["target"].is_string() && l["message"].is_string(), "{l}");
        // Every line logged inside a request has the request's id.
        if l["span"].as_str().is_some_and(|s| s.starts_with("request")) {
            assert!(l["request_id"].is_string(), "{l}");
        }
    }
    for (id, status) in &seen {
        let of_id: Vec<&Value> = lines.iter().filter(|l| l["request_id"] == id.as_str()).collect();
        let access = of_id.iter().find(|l| l["target"] == "b2tfpose::access").unwrap_or_else(|| panic!("no access line for {id}: {of_id:?}"));
        assert_eq!(access["status"], status.as_str(), "{access}");
        // The route template once routed; a request refused before routing (unknown path,
        // announced length over the limit) has its path only.
        assert!(access["ms"].as_f64().is_some() && (access["route"].is_string() || access["path"].is_string()), "{access}");
    }
    // The estimate's own lines (inside its blocking worker) have its id too.
    let est: Vec<&Value> = lines.iter().filter(|l| l["request_id"] == "est-1").collect();
    assert!(est.iter().any(|l| l["message"] == "estimate request" && l["span"] == "request" && l["route"] == "/v1/estimate"), "{est:?}");
    // The key that admitted it, by its identity (a bare key: `key-` and a digest prefix).
    let est_access = est.iter().find(|l| l["target"] == "b2tfpose::access").expect("an access line");
    assert!(est_access["api_key"].as_str().is_some_and(|k| k.starts_with("key-") && k.len() == 12), "{est_access}");
    assert!(est.iter().any(|l| l["peer"].as_str().is_some_and(|p| p.starts_with("127.0.0.1:"))), "{est:?}");
    assert!(lines.iter().any(|l| l["message"] == "listening"));
}

mod collector {
    use opentelemetry_proto::tonic::collector::trace::v1::trace_service_server::{TraceService, TraceServiceServer};
    use opentelemetry_proto::tonic::collector::trace::v1::{ExportTraceServiceRequest, ExportTraceServiceResponse};
    use opentelemetry_proto::tonic::common::v1::{any_value, KeyValue};
    use opentelemetry_proto::tonic::trace::v1::Span;
    use std::sync::{Arc, Mutex};

    /// An OTLP/gRPC trace receiver on loopback keeping what it is sent.
    #[derive(Clone, Default)]
    pub struct Collector(pub Arc<Mutex<Vec<ExportTraceServiceRequest>>>);

    #[tonic::async_trait]
    impl TraceService for Collector {
        async fn export(&self, r: tonic::Request<ExportTraceServiceRequest>) -> Result<tonic::Response<ExportTraceServiceResponse>, tonic::Status> {
            self.0.lock().unwrap().push(r.into_inner());
            Ok(tonic::Response::new(ExportTraceServiceResponse { partial_success: None }))
        }
    }

    impl Collector {
        /// Serves on a free port of `rt`; returns the endpoint URL.
        pub fn start(&self, rt: &tokio::runtime::Runtime) -> String {
            let listener = rt.block_on(tokio::net::TcpListener::bind("127.0.0.1:0")).unwrap();
            let url = format!("http://{}", listener.local_addr().unwrap());
            let service = TraceServiceServer::new(self.clone());
            rt.spawn(tonic::transport::Server::builder().add_service(service).serve_with_incoming(tokio_stream::wrappers::TcpListenerStream::new(listener)));
            url
        }

        /// Every span received, with its resource's service.name.
        pub fn spans(&self) -> Vec<(String, Span)> {
            let got = self.0.lock().unwrap();
            let mut out = Vec::new();
            for rs in got.iter().flat_map(|r| &r.resource_spans) {
                let service = rs.resource.as_ref().and_then(|r| attr(&r.attributes, "service.name")).unwrap_or_default();
                out.extend(rs.scope_spans.iter().flat_map(|s| s.spans.clone()).map(|s| (service.clone(), s)));
            }
            out
        }
    }

    pub fn attr(attrs: &[KeyValue], key: &str) -> Option<String> {
        attrs.iter().find(|a| a.key == key).and_then(|a| match a.value.as_ref()?.value.as_ref()? {
            any_value::Value::StringValue(s) => Some(s.clone()),
            other => Some(format!("{other:?}")),
        })
    }
}

#[test]
fn spans_reach_an_otlp_collector_with_the_request_id_and_stages() {
    let rt = tokio::runtime::Runtime::new().unwrap();
    let collector = collector::Collector::default();
    let endpoint = collector.start(&rt);
    let dir = tempfile::tempdir().unwrap();
    let store = format!("sqlite://{}", dir.path().join("objects.db").display());
    let (mut server, _logs) = start_logged(&store, None, &["--otlp-endpoint", &endpoint], &[]);
    let (base, c) = (server.http.clone(), common::http_client().build().unwrap());
    wait_ready(&base);
    let files = sample_files(dir.path());
    let onboard = json!({"object_id": "box", "options": {"level": 0, "in_plane": 2},
        "mesh": {"data": b64(&files[0].1), "format": "obj", "units": "m", "resources": [{"name": files[1].0, "data": b64(&files[1].1)}, {"name": files[2].0, "data": b64(&files[2].1)}]}});
    let op: Value = c.post(format!("{base}/v1/objects")).header("x-request-id", "otlp-onboard").json(&onboard).send().unwrap().json().unwrap();
    let t = Instant::now();
    loop {
        let o: Value = c.get(format!("{base}/v1/operations/{}", op["id"].as_str().unwrap())).send().unwrap().json().unwrap();
        if o["state"] != "running" {
            assert_eq!(o["state"], "succeeded", "{o}");
            break;
        }
        assert!(t.elapsed() < Duration::from_secs(120), "onboarding did not finish");
        std::thread::sleep(Duration::from_millis(100));
    }
    let s = scene();
    let estimate = json!({"image": {"encoded": b64(&png_bytes(&s.render.rgb).unwrap())}, "intrinsics": {"fx": 500.0, "fy": 500.0, "cx": 159.5, "cy": 119.5, "width": 320, "height": 240},
                          "detections": [{"object_id": "box", "mask_png": b64(&png_bytes(&s.render.mask).unwrap()), "score": 0.9}], "options": {"rrc": false}});
    let r = c.post(format!("{base}/v1/estimate")).header("x-request-id", "otlp-est-1").json(&estimate).send().unwrap();
    assert_eq!((r.status().as_u16(), r.headers()["x-request-id"].to_str().unwrap()), (200, "otlp-est-1"));
    // The batch is sent at the latest when the server stops (flushed at exit).
    stop(&mut server);

    let spans = collector.spans();
    assert!(spans.iter().all(|(service, _)| service == "b2tfpose"));
    let attr = |s: &opentelemetry_proto::tonic::trace::v1::Span, k: &str| collector::attr(&s.attributes, k);
    let request = spans
        .iter()
        .map(|(_, s)| s)
        .find(|s| s.name == "request" && attr(s, "request_id").as_deref() == Some("otlp-est-1"))
        .unwrap_or_else(|| panic!("no request span: {:?}", spans.iter().map(|(_, s)| &s.name).collect::<Vec<_>>()));
    assert_eq!((attr(request, "route").as_deref(), attr(request, "status").as_deref()), (Some("/v1/estimate"), Some("200")));
    let names: Vec<&str> = spans.iter().map(|(_, s)| s).filter(|s| s.trace_id == request.trace_id).map(|s| s.name.as_str()).collect();
    for stage in ["decode", "masks", "store.get", "instance", "crop", "features", "mask", "retrieval", "matching", "pnp", "refine", "selection"] {
        assert!(names.contains(&stage), "no {stage} span in the estimate's trace: {names:?}");
    }
    // The onboarding is its own trace, with the id of the request that started it.
    let onboarding = spans.iter().map(|(_, s)| s).find(|s| s.name == "onboarding").expect("an onboarding span");
    assert_eq!(attr(onboarding, "request_id").as_deref(), Some("otlp-onboard"));
    let steps: Vec<&str> = spans.iter().map(|(_, s)| s).filter(|s| s.trace_id == onboarding.trace_id).map(|s| s.name.as_str()).collect();
    assert!(["templates", "contours", "pca", "store.put"].iter().all(|n| steps.contains(n)), "{steps:?}");
}

#[test]
fn bad_telemetry_settings_are_refused_and_an_absent_collector_holds_nothing_up() {
    let dir = tempfile::tempdir().unwrap();
    let b2tf = |args: &[&str], env: &[(&str, &str)]| {
        let out =
            Command::new(env!("CARGO_BIN_EXE_b2tf")).args(args).env_remove("B2TF_LOG").env_remove("RUST_LOG").env_remove("OTEL_EXPORTER_OTLP_ENDPOINT").envs(env.iter().copied()).output().unwrap();
        (out.status.code(), String::from_utf8_lossy(&out.stdout).into_owned(), String::from_utf8_lossy(&out.stderr).into_owned())
    };
    let out = dir.path().to_str().unwrap();
    let (code, _, err) = b2tf(&["sample", "--out", out, "--log-format", "xml"], &[]);
    assert!(code == Some(2) && err.contains("xml") && err.contains("json"), "{err}");
    let (code, _, err) = b2tf(&["sample", "--out", out], &[("B2TF_LOG", "b2tfpose=loud")]);
    assert!(code == Some(2) && err.contains("B2TF_LOG") && err.contains("loud"), "{err}");
    for bad in ["ftp://collector:4317", "collector:4317", "https://collector:4317"] {
        let (code, _, err) = b2tf(&["serve", "--otlp-endpoint", bad, "--http", "127.0.0.1:0", "--grpc", "none"], &[]);
        assert!(code == Some(2) && err.contains("--otlp-endpoint") && err.contains(bad), "{bad}: {err}");
    }
    // A fatal error follows the log format.
    let (code, _, err) = b2tf(&["objects", "list", "--store", "bogus://x", "--log-format", "json"], &[]);
    let line: Value = serde_json::from_str(err.trim()).unwrap_or_else(|e| panic!("{e}: {err}"));
    assert!(code == Some(1) && line["level"] == "ERROR" && line["message"].as_str().unwrap().contains("bogus://x"), "{err}");
    // Logs never reach stdout, whatever their format and level.
    let (code, stdout, _) = b2tf(&["sample", "--out", out, "--log-format", "json"], &[("B2TF_LOG", "trace")]);
    assert!(code == Some(0) && stdout.starts_with("wrote ") && stdout.lines().count() == 1, "{stdout}");

    // A collector that is not there: requests are answered at once, the exit is bounded.
    let store = format!("sqlite://{}", dir.path().join("objects.db").display());
    let (mut server, logs) = start_logged(&store, None, &["--otlp-endpoint", "http://127.0.0.1:9"], &[]);
    let c = common::http_client().build().unwrap();
    let t = Instant::now();
    for _ in 0..20 {
        assert_eq!(c.get(format!("{}/v1/objects", server.http)).send().unwrap().status(), 200);
    }
    assert!(t.elapsed() < Duration::from_secs(5), "{:?} for 20 requests", t.elapsed());
    let stopping = stop(&mut server);
    assert!(stopping < Duration::from_secs(12), "{stopping:?} to stop: {:?}", logs.lock().unwrap());
}
