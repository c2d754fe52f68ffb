//! Shared by the service tests: a real `b2tf serve` child process on loopback, and the
//! generated sample object with a rendered photo of it at a known pose.
#![allow(dead_code)]

pub mod s3;

use b2tfpose::geometry::views::view_pose;
use b2tfpose::geometry::{Intrinsics, Pose};
use b2tfpose::mesh::procedural::textured_box;
use b2tfpose::mesh::Mesh;
use b2tfpose::render::{RenderOptions, RenderOutput, RenderPool, RendererConfig};
use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};

/// A blocking HTTP client builder. reqwest's TLS (rustls, which the S3 store enables) needs
/// a process-wide crypto provider before any client is built, even for plain http; ring is
/// the one the product uses.
pub fn http_client() -> reqwest::blocking::ClientBuilder {
    let _ = rustls::crypto::ring::default_provider().install_default();
    reqwest::blocking::Client::builder()
}

/// `http_client`, async.
pub fn async_http_client() -> reqwest::ClientBuilder {
    let _ = rustls::crypto::ring::default_provider().install_default();
    reqwest::Client::builder()
}

pub struct Server {
    pub child: Child,
    /// `http://HOST:PORT` (or https).
    pub http: String,
    /// `http://HOST:PORT` of the gRPC listener, as tonic's endpoint wants it (or https).
    pub grpc: String,
    /// The first stdout line: where it listens.
    pub banner: String,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Starts `b2tf serve` on free ports with `extra` flags; no API keys unless given.
pub fn start(store: &str, keys: Option<&str>, extra: &[&str]) -> Server {
    spawn(serve_command(store, keys, extra))
}

/// The lines the server writes on stderr (its logs), as they come.
pub type Logs = std::sync::Arc<std::sync::Mutex<Vec<String>>>;

/// `start` with `env` set (an empty value removes the variable) and stderr collected line
/// by line.
pub fn start_logged(store: &str, keys: Option<&str>, extra: &[&str], env: &[(&str, &str)]) -> (Server, Logs) {
    let mut cmd = serve_command(store, keys, extra);
    for &(k, v) in env {
        match v {
            "" => cmd.env_remove(k),
            v => cmd.env(k, v),
        };
    }
    cmd.stderr(Stdio::piped());
    let mut server = spawn(cmd);
    let logs = Logs::default();
    let (stderr, sink) = (server.child.stderr.take().unwrap(), logs.clone());
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            sink.lock().unwrap().push(line);
        }
    });
    (server, logs)
}

fn serve_command(store: &str, keys: Option<&str>, extra: &[&str]) -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_b2tf"));
    cmd.args(["serve", "--http", "127.0.0.1:0", "--grpc", "127.0.0.1:0", "--store", store, "--max-body-mb", "3", "--max-estimates", "2", "--render-pool", "1"])
        .args(extra)
        .env("XDG_RUNTIME_DIR", "/tmp")
        .env_remove("B2TF_API_KEYS")
        .env_remove("B2TF_CONFIG")
        .env_remove("B2TF_LOG_FORMAT")
        .env_remove("OTEL_EXPORTER_OTLP_ENDPOINT")
        // Warnings only, unless a test asks for more: one line per request would swamp the
        // test output (the child's stderr is not captured).
        .env("B2TF_LOG", "warn");
    if let Some(k) = keys {
        cmd.env("B2TF_API_KEYS", k);
    }
    cmd
}

/// Runs the server and reads its addresses from the first stdout line.
fn spawn(mut cmd: Command) -> Server {
    let mut child = cmd.stdout(Stdio::piped()).spawn().expect("server starts");
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap()).read_line(&mut line).unwrap();
    // `listening on http://… grpc://… (…)`, or with --log-format json one JSON object.
    let json: Option<serde_json::Value> = serde_json::from_str(&line).ok();
    let word = |scheme: &str| match &json {
        Some(j) => ["http", "grpc"].iter().filter_map(|k| j[*k].as_str()).find(|w| w.starts_with(scheme)).map(str::to_string),
        None => line.split_whitespace().find(|w| w.starts_with(scheme)).map(str::to_string),
    };
    let http = word("http://").or_else(|| word("https://")).unwrap_or_else(|| panic!("no HTTP address in {line:?}"));
    let grpc = word("grpc://")
        .map(|g| g.replacen("grpc://", "http://", 1))
        .or_else(|| word("grpcs://").map(|g| g.replacen("grpcs://", "https://", 1)))
        .unwrap_or_else(|| panic!("no gRPC address in {line:?}"));
    Server { child, http, grpc, banner: line }
}

pub fn sample_mesh() -> Mesh {
    textured_box([0.10, 0.06, 0.16], 3)
}

/// The sample written as OBJ + MTL + PNG into `dir`: (file name, bytes) with the OBJ first.
pub fn sample_files(dir: &std::path::Path) -> Vec<(String, Vec<u8>)> {
    b2tfpose::mesh::write_obj::write_obj(&sample_mesh(), dir, "box").unwrap();
    ["box.obj", "box.mtl", "box_m0.png"].iter().map(|n| (n.to_string(), std::fs::read(dir.join(n)).unwrap())).collect()
}

pub struct Scene {
    pub k: Intrinsics,
    pub truth: Pose,
    pub render: RenderOutput,
}

/// A 320×240 render of the sample at a known pose.
pub fn scene() -> Scene {
    let pool = RenderPool::new(1, RendererConfig::default()).unwrap();
    let k = Intrinsics::new(500.0, 500.0, 159.5, 119.5, 320, 240).unwrap();
    let truth = view_pose(&nalgebra::Vector3::new(0.3, -0.5, 0.8).normalize(), 0.7, &nalgebra::Vector3::zeros(), 0.5);
    let render = pool.render(&sample_mesh(), &truth, &k, &RenderOptions::default()).unwrap();
    Scene { k, truth, render }
}

/// Rotation (degrees) and translation (metres) errors of a row-major R and t.
pub fn pose_errors(r: &[f64], t: &[f64], truth: &Pose) -> (f64, f64) {
    let est = Pose::from_row_major(&r.try_into().unwrap(), [t[0], t[1], t[2]]);
    (b2tfpose::geometry::geodesic_distance(&est.rotation, &truth.rotation).to_degrees(), (est.translation - truth.translation).norm())
}

/// One HTTPS exchange by hand with rustls: sends `request` (request line and headers, with
/// `Connection: close`), trusting only `ca_pem`, presenting `client` (certificate PEM, key
/// PEM) when given. The raw response, or why the connection failed (a refused client
/// certificate shows here: in TLS 1.3 the server's alert arrives after the client's side of
/// the handshake is done).
pub async fn https_exchange(base: &str, request: &str, ca_pem: &str, client: Option<(&str, &str)>) -> Result<String, String> {
    use rustls_pki_types::pem::PemObject;
    use rustls_pki_types::{CertificateDer, PrivateKeyDer};
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    use tokio_rustls::rustls;
    let addr = base.trim_start_matches("https://");
    let mut roots = rustls::RootCertStore::empty();
    roots.add(CertificateDer::from_pem_slice(ca_pem.as_bytes()).unwrap()).unwrap();
    let provider = std::sync::Arc::new(rustls::crypto::ring::default_provider());
    let builder = rustls::ClientConfig::builder_with_provider(provider).with_safe_default_protocol_versions().unwrap().with_root_certificates(roots);
    let config = match client {
        Some((cert, key)) => {
            let chain = CertificateDer::pem_slice_iter(cert.as_bytes()).collect::<Result<Vec<_>, _>>().unwrap();
            builder.with_client_auth_cert(chain, PrivateKeyDer::from_pem_slice(key.as_bytes()).unwrap()).unwrap()
        }
        None => builder.with_no_client_auth(),
    };
    let tcp = tokio::net::TcpStream::connect(addr).await.map_err(|e| e.to_string())?;
    let name = rustls_pki_types::ServerName::try_from("localhost").unwrap();
    let mut tls = tokio_rustls::TlsConnector::from(std::sync::Arc::new(config)).connect(name, tcp).await.map_err(|e| format!("handshake: {e}"))?;
    tls.write_all(request.as_bytes()).await.map_err(|e| format!("write: {e}"))?;
    let mut out = Vec::new();
    match tls.read_to_end(&mut out).await {
        // A server may close without close_notify after answering: the answer counts.
        Err(e) if out.is_empty() => Err(format!("read: {e}")),
        _ => Ok(String::from_utf8_lossy(&out).into_owned()),
    }
}
