//! Access control as clients see it, over a real `b2tf serve` on loopback: per-key scopes
//! on both protocols (403 / PERMISSION_DENIED naming the scope, never the key), rate limits
//! per key and per client address (429 with Retry-After / RESOURCE_EXHAUSTED), and mTLS on
//! both ports with generated CAs (a good client certificate in, none or another CA's out,
//! API keys still required on top).

mod common;

use b2tfpose::service::proto as pb;
use b2tfpose::service::proto::pose_service_client::PoseServiceClient;
use common::start;
use serde_json::Value;
use tonic::transport::Channel;
use tonic::Code;

const KEYS: &str = "# test keys\nsk-full-0001\nsk-reader-0002 scopes=read name=cell-7\nsk-writer-0003 scopes=write name=onboarder\nsk-ops-0004 scopes=admin name=prometheus\n";

async fn http(c: &reqwest::Client, method: &str, url: &str, key: Option<&str>) -> (u16, Option<String>, String) {
    let mut r = c.request(method.parse().unwrap(), url);
    if let Some(k) = key {
        r = r.bearer_auth(k);
    }
    if method == "POST" {
        r = r.header("content-type", "application/json").body("{}");
    }
    let resp = r.send().await.unwrap();
    let retry = resp.headers().get("retry-after").map(|v| v.to_str().unwrap().to_string());
    (resp.status().as_u16(), retry, resp.text().await.unwrap())
}

fn with_key<T>(msg: T, key: &str) -> tonic::Request<T> {
    let mut r = tonic::Request::new(msg);
    r.metadata_mut().insert("authorization", format!("Bearer {key}").parse().unwrap());
    r
}

async fn grpc(url: &str) -> PoseServiceClient<Channel> {
    PoseServiceClient::new(Channel::from_shared(url.to_string()).unwrap().connect().await.unwrap())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scopes_on_both_protocols() {
    let dir = tempfile::tempdir().unwrap();
    let keys = dir.path().join("keys");
    std::fs::write(&keys, KEYS).unwrap();
    let server = start(&format!("sqlite://{}", dir.path().join("o.db").display()), None, &["--api-keys-file", keys.to_str().unwrap()]);
    let (c, base) = (common::async_http_client().build().unwrap(), server.http.clone());
    let url = |p: &str| format!("{base}{p}");

    // (method, path, key, status): each scope lets its routes through (to 200 / 404 /
    // 400 from the handler) and no others.
    let cases = [
        ("GET", "/healthz", None, 200),
        ("GET", "/v1/objects", None, 401),
        ("GET", "/v1/objects", Some("sk-unknown"), 401),
        ("GET", "/v1/objects", Some("sk-reader-0002"), 200),
        ("GET", "/openapi.json", Some("sk-reader-0002"), 200),
        ("GET", "/v1/tracks", Some("sk-reader-0002"), 200),
        ("POST", "/v1/estimate", Some("sk-reader-0002"), 400),
        ("POST", "/v1/objects", Some("sk-reader-0002"), 403),
        ("DELETE", "/v1/objects/nope", Some("sk-reader-0002"), 403),
        ("GET", "/v1/operations/nope", Some("sk-reader-0002"), 403),
        ("GET", "/metrics", Some("sk-reader-0002"), 403),
        ("DELETE", "/v1/objects/nope", Some("sk-writer-0003"), 404),
        ("GET", "/v1/operations/nope", Some("sk-writer-0003"), 404),
        ("GET", "/v1/objects", Some("sk-writer-0003"), 403),
        ("POST", "/v1/estimate", Some("sk-writer-0003"), 403),
        ("GET", "/metrics", Some("sk-ops-0004"), 200),
        ("GET", "/v1/objects", Some("sk-ops-0004"), 403),
        ("GET", "/v1/objects", Some("sk-full-0001"), 200),
        ("DELETE", "/v1/objects/nope", Some("sk-full-0001"), 404),
        ("GET", "/metrics", Some("sk-full-0001"), 200),
    ];
    for (method, path, key, want) in cases {
        let (status, _, body) = http(&c, method, &url(path), key).await;
        assert_eq!(status, want, "{method} {path} with {key:?}: {body}");
        if status == 403 {
            let v: Value = serde_json::from_str(&body).unwrap();
            let msg = v["error"]["message"].as_str().unwrap();
            assert_eq!(v["error"]["kind"], "permission_denied");
            let scope = if path == "/metrics" {
                "`admin`"
            } else if method == "POST" && path == "/v1/estimate" || path == "/v1/objects" && method == "GET" {
                "`read`"
            } else {
                "`write`"
            };
            assert!(msg.contains(scope) && msg.contains(path.split("/nope").next().unwrap()) && !msg.contains("sk-"), "{method} {path}: {msg}");
        }
    }

    // gRPC: the same table by method, the Track stream included.
    let mut g = grpc(&server.grpc).await;
    assert_eq!(g.list_objects(pb::ListObjectsRequest {}).await.unwrap_err().code(), Code::Unauthenticated);
    assert!(g.list_objects(with_key(pb::ListObjectsRequest {}, "sk-reader-0002")).await.is_ok());
    let e = g.delete_object(with_key(pb::GetObjectRequest { object_id: "nope".into() }, "sk-reader-0002")).await.unwrap_err();
    assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
    assert!(e.message().contains("`write`") && e.message().contains("/b2tfpose.v1.PoseService/DeleteObject"), "{e:?}");
    assert_eq!(g.delete_object(with_key(pb::GetObjectRequest { object_id: "nope".into() }, "sk-writer-0003")).await.unwrap_err().code(), Code::NotFound);
    assert_eq!(g.get_operation(with_key(pb::GetOperationRequest { id: "nope".into() }, "sk-reader-0002")).await.unwrap_err().code(), Code::PermissionDenied);
    assert_eq!(g.list_objects(with_key(pb::ListObjectsRequest {}, "sk-ops-0004")).await.unwrap_err().code(), Code::PermissionDenied);
    let no_frames = || tokio_stream::iter(Vec::<pb::TrackFrame>::new());
    let e = g.track(with_key(no_frames(), "sk-writer-0003")).await.unwrap_err();
    assert!(e.code() == Code::PermissionDenied && e.message().contains("`read`"), "{e:?}");
    assert!(g.track(with_key(no_frames(), "sk-reader-0002")).await.is_ok());

    // Metrics name keys by identity, never by the key.
    let (_, _, metrics) = http(&c, "GET", &url("/metrics"), Some("sk-ops-0004")).await;
    assert!(metrics.contains("b2tf_key_requests_total{key=\"cell-7\"}") && metrics.contains("b2tf_key_requests_total{key=\"onboarder\"}"), "{metrics}");
    assert!(metrics.contains("route=\"/b2tfpose.v1.PoseService/DeleteObject\",status=\"PERMISSION_DENIED\""), "{metrics}");
    assert!(!metrics.contains("sk-"), "{metrics}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rate_limits_per_key_and_per_address() {
    let dir = tempfile::tempdir().unwrap();
    let store = format!("sqlite://{}", dir.path().join("o.db").display());
    let c = common::async_http_client().build().unwrap();
    // 6 a minute: nothing refills during the test.
    let server = start(&store, Some("key-a,key-b"), &["--rate-limit", "6/m", "--rate-burst", "3"]);
    let url = |p: &str| format!("{}{p}", server.http);
    for _ in 0..3 {
        assert_eq!(http(&c, "GET", &url("/v1/objects"), Some("key-a")).await.0, 200);
    }
    let (status, retry, body) = http(&c, "GET", &url("/v1/objects"), Some("key-a")).await;
    assert_eq!(status, 429, "{body}");
    let retry: u64 = retry.expect("Retry-After").parse().unwrap();
    assert!((1..=10).contains(&retry), "{retry}");
    let v: Value = serde_json::from_str(&body).unwrap();
    assert_eq!(v["error"]["kind"], "resource_exhausted");
    assert!(v["error"]["message"].as_str().unwrap().contains("rate limit"), "{v}");
    // One bucket per key, shared by both protocols; health checks are not limited.
    let mut g = grpc(&server.grpc).await;
    let e = g.list_objects(with_key(pb::ListObjectsRequest {}, "key-a")).await.unwrap_err();
    assert_eq!(e.code(), Code::ResourceExhausted, "{e:?}");
    assert!(e.message().contains("rate limit") && e.metadata().get("retry-after").is_some(), "{e:?}");
    assert!(g.list_objects(with_key(pb::ListObjectsRequest {}, "key-b")).await.is_ok());
    for _ in 0..5 {
        assert_eq!(http(&c, "GET", &url("/healthz"), None).await.0, 200);
    }
    let (status, _, metrics) = http(&c, "GET", &url("/metrics"), Some("key-b")).await;
    assert_eq!(status, 200);
    let refused = metrics.lines().find(|l| l.starts_with("b2tf_rate_limited_total{client=\"key-")).unwrap_or_else(|| panic!("{metrics}"));
    assert!(refused.ends_with(" 2"), "{refused}");
    drop(server);

    // Without keys, by client address.
    let server = start(&store, None, &["--rate-limit", "6/m", "--rate-burst", "2"]);
    let url = format!("{}/v1/objects", server.http);
    assert_eq!(http(&c, "GET", &url, None).await.0, 200);
    assert_eq!(http(&c, "GET", &url, None).await.0, 200);
    let (status, _, body) = http(&c, "GET", &url, None).await;
    assert!(status == 429 && body.contains("client address"), "{status} {body}");
    assert_eq!(grpc(&server.grpc).await.list_objects(pb::ListObjectsRequest {}).await.unwrap_err().code(), Code::ResourceExhausted);
}

struct Ca {
    issuer: rcgen::Issuer<'static, rcgen::KeyPair>,
    pem: String,
}

fn ca(name: &str) -> Ca {
    let mut params = rcgen::CertificateParams::new(Vec::<String>::new()).unwrap();
    params.is_ca = rcgen::IsCa::Ca(rcgen::BasicConstraints::Unconstrained);
    params.distinguished_name.push(rcgen::DnType::CommonName, name);
    let key = rcgen::KeyPair::generate().unwrap();
    let pem = params.self_signed(&key).unwrap().pem();
    Ca { issuer: rcgen::Issuer::new(params, key), pem }
}

/// A certificate for `names` issued by `ca`: (cert PEM, key PEM).
fn issue(ca: &Ca, names: &[&str]) -> (String, String) {
    let key = rcgen::KeyPair::generate().unwrap();
    let params = rcgen::CertificateParams::new(names.iter().map(|n| n.to_string()).collect::<Vec<_>>()).unwrap();
    (params.signed_by(&key, &ca.issuer).unwrap().pem(), key.serialize_pem())
}

async fn grpc_tls(url: &str, ca_pem: &str, client: Option<&(String, String)>) -> Result<PoseServiceClient<Channel>, tonic::transport::Error> {
    let mut tls = tonic::transport::ClientTlsConfig::new().ca_certificate(tonic::transport::Certificate::from_pem(ca_pem)).domain_name("localhost");
    if let Some((cert, key)) = client {
        tls = tls.identity(tonic::transport::Identity::from_pem(cert, key));
    }
    Ok(PoseServiceClient::new(Channel::from_shared(url.to_string()).unwrap().tls_config(tls)?.connect().await?))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mtls_on_both_ports_with_keys_on_top() {
    let dir = tempfile::tempdir().unwrap();
    let (servers, clients, strangers) = (ca("server CA"), ca("client CA"), ca("another CA"));
    let (cert, key) = issue(&servers, &["localhost", "127.0.0.1"]);
    let good = issue(&clients, &["cell-7"]);
    let stranger = issue(&strangers, &["intruder"]);
    let path = |n: &str, text: &str| {
        std::fs::write(dir.path().join(n), text).unwrap();
        dir.path().join(n).display().to_string()
    };
    let flags = [path("cert.pem", &cert), path("key.pem", &key), path("clients.pem", &clients.pem)];
    let server = start(&format!("sqlite://{}", dir.path().join("o.db").display()), Some("k1"), &["--tls-cert", &flags[0], "--tls-key", &flags[1], "--tls-client-ca", &flags[2]]);

    // HTTP: a good certificate and the key get in; the certificate alone meets the key
    // check; no certificate, or another CA's, does not get past the handshake.
    let get = |key: &str| format!("GET /v1/objects HTTP/1.1\r\nHost: localhost\r\n{key}Connection: close\r\n\r\n");
    let as_pair = |p: &(String, String)| (p.0.clone(), p.1.clone());
    let (gc, gk) = as_pair(&good);
    let ok = common::https_exchange(&server.http, &get("Authorization: Bearer k1\r\n"), &servers.pem, Some((&gc, &gk))).await.unwrap();
    assert!(ok.starts_with("HTTP/1.1 200"), "{ok}");
    let no_key = common::https_exchange(&server.http, &get(""), &servers.pem, Some((&gc, &gk))).await.unwrap();
    assert!(no_key.starts_with("HTTP/1.1 401"), "{no_key}");
    let (sc, sk) = as_pair(&stranger);
    for (client, alert) in [(None, "CertificateRequired"), (Some((sc.as_str(), sk.as_str())), "UnknownCA")] {
        let r = common::https_exchange(&server.http, &get("Authorization: Bearer k1\r\n"), &servers.pem, client).await;
        assert!(r.as_ref().is_err_and(|e| e.contains(alert)), "{client:?}: {r:?}");
    }

    // gRPC: the same.
    let mut g = grpc_tls(&server.grpc, &servers.pem, Some(&good)).await.unwrap();
    assert!(g.list_objects(with_key(pb::ListObjectsRequest {}, "k1")).await.is_ok());
    assert_eq!(g.list_objects(pb::ListObjectsRequest {}).await.unwrap_err().code(), Code::Unauthenticated);
    for client in [None, Some(&stranger)] {
        // In TLS 1.3 the server's alert comes after the client's side of the handshake: at
        // connect or at the first call, as the alert or as the connection closing.
        if let Ok(mut g) = grpc_tls(&server.grpc, &servers.pem, client).await {
            let e = g.list_objects(with_key(pb::ListObjectsRequest {}, "k1")).await.unwrap_err();
            assert!(matches!(e.code(), Code::Unknown | Code::Cancelled | Code::Unavailable) && std::error::Error::source(&e).is_some(), "not a transport failure: {e:?}");
        }
    }
}
