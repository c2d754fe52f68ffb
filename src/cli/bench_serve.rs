//! `b2tf bench serve`: the service under load, measured from outside: a real `b2tf serve`
//! child process, N concurrent clients sending estimates of the sample box over HTTP/JSON
//! and over gRPC (one connection per client), req/s and p50 / p99 latency per concurrency;
//! then the server's resident memory once every object in its store (up to 10) is loaded.

use crate::geometry::views::view_pose;
use crate::geometry::Intrinsics;
use crate::render::{RenderOptions, RenderPool};
use crate::service::client::{one_mask_request, png_bytes};
use crate::service::proto as pb;
use anyhow::{anyhow, bail, Result};
use base64::Engine as _;
use serde_json::{json, Value};
use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

#[derive(clap::Args, Debug)]
pub struct BenchServeArgs {
    /// Store the server uses; it must hold the sample box onboarded with the same backbone
    /// (`b2tf bench estimate [--backbone …]` with the same store puts it there).
    #[arg(long, default_value = "dir://out/bench-models")]
    pub store: String,
    /// Concurrent clients, one measurement each.
    #[arg(long, value_delimiter = ',', default_value = "1,4,16")]
    pub clients: Vec<usize>,
    /// Requests per client per measurement.
    #[arg(long, default_value_t = 8)]
    pub requests: usize,
    /// RRC in the estimate requests.
    #[arg(long)]
    pub no_rrc: bool,
    /// Crops per backbone pass of the server's batching queue (0: no queue).
    #[arg(long, default_value_t = 32)]
    pub backbone_batch: usize,
    #[command(flatten)]
    pub backbone: super::backbone_args::BackboneArgs,
    /// Protocols measured: http, grpc or both.
    #[arg(long, value_delimiter = ',', default_value = "http,grpc")]
    pub protocols: Vec<String>,
}

/// One HTTP/1.1 request on a fresh connection; returns (status, body).
pub(super) fn http(addr: &str, method: &str, path: &str, body: Option<&[u8]>) -> Result<(u16, Vec<u8>)> {
    let mut s = TcpStream::connect(addr)?;
    let body = body.unwrap_or(&[]);
    write!(s, "{method} {path} HTTP/1.1\r\nHost: {addr}\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n", body.len())?;
    s.write_all(body)?;
    let mut raw = Vec::new();
    s.read_to_end(&mut raw)?;
    let split = raw.windows(4).position(|w| w == b"\r\n\r\n").ok_or_else(|| anyhow!("no HTTP header in the reply"))?;
    let head = String::from_utf8_lossy(&raw[..split]);
    let status = head.split_whitespace().nth(1).and_then(|c| c.parse().ok()).ok_or_else(|| anyhow!("bad status line {head:?}"))?;
    Ok((status, raw[split + 4..].to_vec()))
}

pub(super) fn json_call(addr: &str, method: &str, path: &str, body: Option<&Value>) -> Result<(u16, Value)> {
    let bytes = body.map(serde_json::to_vec).transpose()?;
    let (status, body) = http(addr, method, path, bytes.as_deref())?;
    Ok((status, serde_json::from_slice(&body).unwrap_or(Value::Null)))
}

/// A process's resident memory, MB (NaN where /proc cannot tell): in all, and its
/// anonymous (heap) and file-backed (mapped files, e.g. `dir://` tensors) parts.
pub(super) struct Memory {
    pub rss: f64,
    pub anon: f64,
    pub file: f64,
}

pub(super) fn memory_mb(pid: u32) -> Memory {
    let s = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    let mb = |key: &str| s.lines().find(|l| l.starts_with(key)).and_then(|l| l.split_whitespace().nth(1)).and_then(|kb| kb.parse::<f64>().ok()).map_or(f64::NAN, |kb| kb / 1024.0);
    Memory { rss: mb("VmRSS:"), anon: mb("RssAnon:"), file: mb("RssFile:") }
}

/// The nearest-rank percentile `p` (0–1) of ascending `sorted`; NaN when it is empty.
pub(super) fn nearest_rank(sorted: &[f64], p: f64) -> f64 {
    match sorted.len() {
        0 => f64::NAN,
        n => sorted[((n as f64 * p).ceil() as usize).clamp(1, n) - 1],
    }
}

pub(super) fn b64(bytes: &[u8]) -> String {
    base64::engine::general_purpose::STANDARD.encode(bytes)
}

/// The sample box's id in the store for the chosen backbone (as `bench estimate` caches it).
fn object_id(a: &BenchServeArgs) -> Result<String> {
    Ok(match &a.backbone.backbone {
        crate::features::BackboneChoice::Embedded => "box".into(),
        crate::features::BackboneChoice::Onnx(p) => super::bench_estimate::cached_object_id("box", Some(&crate::features::onnx::read_sidecar(p)?.onnx_sha256)),
    })
}

pub fn run(a: BenchServeArgs) -> Result<()> {
    let max_clients = a.clients.iter().copied().max().unwrap_or(1);
    let object = object_id(&a)?;
    let extra: Vec<String> =
        ["--max-estimates", &max_clients.to_string(), "--backbone-batch", &a.backbone_batch.to_string(), "--backbone", &a.backbone.backbone.to_string(), "--device", &a.backbone.device.to_string()]
            .map(String::from)
            .to_vec();
    let server = super::child_server::ChildServer::start(&a.store, &extra)?;
    measure(&a, &object, &server.http, &server.grpc, server.pid())?;
    server.stop()
}

fn measure(a: &BenchServeArgs, object: &str, addr: &str, grpc: &str, pid: u32) -> Result<()> {
    let t = Instant::now();
    while json_call(addr, "GET", "/readyz", None).map(|r| r.0).unwrap_or(0) != 200 {
        if t.elapsed() > Duration::from_secs(120) {
            bail!("server not ready after 120 s");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let mesh = crate::mesh::procedural::textured_box([0.10, 0.06, 0.16], 3);
    if json_call(addr, "GET", &format!("/v1/objects/{object}"), None)?.0 != 200 {
        bail!("the store {} has no object {object:?}: run `b2tf bench estimate --store {} --backbone {}` once (it onboards the sample box)", a.store, a.store, a.backbone.backbone);
    }
    let pool = RenderPool::new(1, Default::default())?;
    let k = Intrinsics::new(600.0, 600.0, 319.5, 239.5, 640, 480)?;
    let truth = view_pose(&nalgebra::Vector3::new(0.3, -0.5, 0.8).normalize(), 0.7, &nalgebra::Vector3::zeros(), 0.5);
    let r = pool.render(&mesh, &truth, &k, &RenderOptions::default())?;
    let intrinsics = json!({"fx": 600.0, "fy": 600.0, "cx": 319.5, "cy": 239.5, "width": 640, "height": 480});
    let (rgb_png, mask_png) = (png_bytes(&r.rgb)?, png_bytes(&r.mask)?);
    let request =
        json!({"image": {"encoded": b64(&rgb_png)}, "intrinsics": intrinsics, "detections": [{"object_id": object, "mask_png": b64(&mask_png), "score": 1.0}], "options": {"rrc": !a.no_rrc}});
    let grpc_request = one_mask_request(object, rgb_png, mask_png, &k, !a.no_rrc);
    let body = serde_json::to_vec(&request)?;
    // One request first, so every measurement starts with the object loaded.
    let (s, v) = http(addr, "POST", "/v1/estimate", Some(&body))?;
    if s != 200 {
        bail!("estimate failed: {s} {}", String::from_utf8_lossy(&v));
    }
    // The server renders on the adapter this process gets (same machine, same environment).
    println!("server pid {pid}, store {}; 640×480 PNG of the sample box, RRC {}, backbone batch {}; rendering: {}", a.store, if a.no_rrc { "off" } else { "on" }, a.backbone_batch, pool.describe());
    // Server CPU per request and the cores it kept busy say whether the CPU stages, not
    // the backbone, set the rate (on a GPU machine with many cores).
    println!("| protocol | clients | requests | req/s | p50 (ms) | p99 (ms) | server CPU ms/req | server cores busy | failed |");
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|");
    let mut by_thread = Vec::new();
    for protocol in &a.protocols {
        for &c in &a.clients {
            let (t0, cpu0, threads0) = (Instant::now(), super::thread_cpu::process_cpu_seconds(pid), super::thread_cpu::cpu_by_thread_group(pid));
            let results: Vec<(bool, f64)> = match protocol.as_str() {
                "http" => http_load(addr, &body, c, a.requests),
                "grpc" => grpc_load(grpc, &grpc_request, c, a.requests)?,
                other => bail!("--protocols: {other:?} is neither http nor grpc"),
            };
            let (wall, cpu) = (t0.elapsed().as_secs_f64(), super::thread_cpu::process_cpu_seconds(pid) - cpu0);
            let mut ms: Vec<f64> = results.iter().map(|r| r.1).collect();
            ms.sort_by(f64::total_cmp);
            let bad = results.iter().filter(|r| !r.0).count();
            let n = results.len();
            let threads = super::thread_cpu::describe_growth(&threads0, &super::thread_cpu::cpu_by_thread_group(pid), n, 6);
            by_thread.push(format!("{protocol}, {c} clients: {threads}"));
            println!("| {protocol} | {c} | {n} | {:.2} | {:.0} | {:.0} | {:.0} | {:.1} | {bad} |", n as f64 / wall, nearest_rank(&ms, 0.5), nearest_rank(&ms, 0.99), cpu * 1e3 / n as f64, cpu / wall);
        }
    }
    println!("server CPU per request by thread group (the largest; threads that ended are not counted):");
    for line in &by_thread {
        println!("  {line}");
    }
    // Memory: every object of the store (up to 10) loaded into the server's cache.
    let before = memory_mb(pid).rss;
    let (_, list) = json_call(addr, "GET", "/v1/objects", None)?;
    let ids: Vec<String> = list["objects"].as_array().map(|a| a.iter().filter_map(|o| o["id"].as_str().map(String::from)).take(10).collect()).unwrap_or_default();
    for id in &ids {
        let mut req = request.clone();
        req["detections"][0]["object_id"] = json!(id);
        req["options"]["rrc"] = json!(false);
        json_call(addr, "POST", "/v1/estimate", Some(&req))?;
    }
    let (_, metrics) = http(addr, "GET", "/metrics", None)?;
    let loaded = String::from_utf8_lossy(&metrics).lines().find(|l| l.starts_with("b2tf_objects_loaded")).map(String::from).unwrap_or_default();
    println!("server RSS: {:.0} MB with the sample box loaded; {:.0} MB after loading {} objects ({loaded})", before, memory_mb(pid).rss, ids.len());
    Ok(())
}

/// `clients` threads, each posting `requests` estimates one after another: (ok, ms).
fn http_load(addr: &str, body: &[u8], clients: usize, requests: usize) -> Vec<(bool, f64)> {
    std::thread::scope(|sc| {
        let hs: Vec<_> = (0..clients)
            .map(|_| {
                sc.spawn(|| {
                    (0..requests)
                        .map(|_| {
                            let t = Instant::now();
                            let ok = http(addr, "POST", "/v1/estimate", Some(body)).map(|r| r.0 == 200).unwrap_or(false);
                            (ok, t.elapsed().as_secs_f64() * 1e3)
                        })
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        hs.into_iter().flat_map(|h| h.join().unwrap_or_default()).collect()
    })
}

/// `clients` tasks, each with its own connection, sending `requests` estimates one after
/// another: (ok, ms).
fn grpc_load(addr: &str, request: &pb::EstimateRequest, clients: usize, requests: usize) -> Result<Vec<(bool, f64)>> {
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build()?;
    rt.block_on(async {
        let mut tasks = tokio::task::JoinSet::new();
        for _ in 0..clients {
            let channel = tonic::transport::Channel::from_shared(format!("http://{addr}"))?.connect().await?;
            let request = request.clone();
            tasks.spawn(async move {
                let mut client = pb::pose_service_client::PoseServiceClient::new(channel);
                let mut out = Vec::with_capacity(requests);
                for _ in 0..requests {
                    let t = Instant::now();
                    let ok = client.estimate(request.clone()).await.is_ok();
                    out.push((ok, t.elapsed().as_secs_f64() * 1e3));
                }
                out
            });
        }
        let mut all = Vec::new();
        while let Some(r) = tasks.join_next().await {
            all.extend(r?);
        }
        Ok(all)
    })
}

#[cfg(test)]
mod tests {
    use super::nearest_rank;

    #[test]
    fn nearest_rank_takes_the_ceiling_rank() {
        let v = [1.0, 2.0, 3.0, 4.0];
        assert_eq!((nearest_rank(&v, 0.0), nearest_rank(&v, 0.5), nearest_rank(&v, 0.51), nearest_rank(&v, 0.99), nearest_rank(&v, 1.0)), (1.0, 2.0, 3.0, 4.0, 4.0));
        assert!(nearest_rank(&[], 0.5).is_nan());
    }
}
