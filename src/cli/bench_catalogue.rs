//! `b2tf bench catalogue`: a server with a catalogue of many objects, measured from
//! outside. Fills a scratch store with `--objects` copies of the objects of `--from`
//! (round robin, ids `<source>-<k>`: each copy its own files, so nothing is shared between
//! them on disk, in the page cache or on the heap), starts `b2tf serve` on it, and sends
//! each object one estimate of a view rendered from its own mesh while it is not loaded
//! (cold: the store's load, its first GPU upload) and two once it is (warm, and warm again:
//! their difference is the noise the cold − warm figure stands in). Prints the
//! store's bytes, the server's resident memory before and after (anonymous = heap,
//! file = mapped tensors), and cold/warm latency.

use super::bench_serve::{b64, json_call, memory_mb, nearest_rank};
use crate::geometry::views::{fitted_distance, view_pose};
use crate::geometry::Intrinsics;
use crate::onboard::DescriptorCoding;
use crate::render::{RenderOptions, RenderPool};
use crate::service::client::png_bytes;
use anyhow::{bail, Result};
use serde_json::{json, Value};
use std::time::{Duration, Instant};

#[derive(clap::Args, Debug)]
pub struct BenchCatalogueArgs {
    /// Store whose objects are copied (all of them, in id order).
    #[arg(long, default_value = "dir://out/bench-models")]
    pub from: String,
    /// Scratch store filled with the copies; copies already there are kept, so a second
    /// run starts at once.
    #[arg(long, default_value = "dir://out/catalogue")]
    pub store: String,
    /// Objects in the catalogue.
    #[arg(long, default_value_t = 100)]
    pub objects: usize,
    /// Descriptor coding of the copies (each source is recoded once, as onboarding would).
    #[arg(long, value_enum, default_value_t = DescriptorCoding::F16)]
    pub descriptors: DescriptorCoding,
    /// Which templates keep patch rows in the copies (`b2tf onboard --patch-rows`).
    #[arg(long, value_enum, default_value_t = crate::onboard::PatchRows::Auto)]
    pub patch_rows: crate::onboard::PatchRows,
    /// The server's model cache budget, MB (its default: 4000).
    #[arg(long)]
    pub cache_mb: Option<u64>,
    /// RRC in the estimate requests.
    #[arg(long)]
    pub no_rrc: bool,
    /// The backbone the server runs (and the one `--patch-rows auto` resolves for).
    #[command(flatten)]
    pub backbone: super::backbone_args::BackboneArgs,
}

pub fn run(a: BenchCatalogueArgs) -> Result<()> {
    // What `auto` means for the backbone the server runs, said in the figures' heading.
    let rows = a.patch_rows.resolve(a.backbone.open()?.as_ref());
    let ids = fill(&a, rows)?;
    let mut extra = vec!["--max-estimates".to_string(), "1".to_string()];
    extra.extend(["--backbone".to_string(), a.backbone.backbone.to_string(), "--device".to_string(), a.backbone.device.to_string()]);
    if let Some(mb) = a.cache_mb {
        extra.extend(["--cache-mb".to_string(), mb.to_string()]);
    }
    let server = super::child_server::ChildServer::start(&a.store, &extra)?;
    let addr = server.http.clone();
    let t = Instant::now();
    while json_call(&addr, "GET", "/readyz", None).map(|r| r.0).unwrap_or(0) != 200 {
        if t.elapsed() > Duration::from_secs(120) {
            bail!("server not ready after 120 s");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let (_, list) = json_call(&addr, "GET", "/v1/objects", None)?;
    let bytes: u64 = list["objects"].as_array().map_or(0, |l| l.iter().filter_map(|o| o["bytes"].as_u64()).sum());
    let store = crate::store::open_read_only(&a.store)?;
    let pool = RenderPool::new(1, Default::default())?;
    let k = Intrinsics::new(600.0, 600.0, 319.5, 239.5, 640, 480)?;
    let before = memory_mb(server.pid());
    let mut requests: std::collections::HashMap<String, Value> = Default::default();
    let (mut cold, mut warm, mut again) = (Vec::new(), Vec::new(), Vec::new());
    for (i, id) in ids.iter().enumerate() {
        let source = source_of(id);
        if !requests.contains_key(source) {
            requests.insert(source.to_string(), view_request(&store.get(id)?.mesh, &pool, &k, !a.no_rrc)?);
        }
        let mut request = requests[source].clone();
        request["detections"][0]["object_id"] = json!(id);
        let timed = || -> Result<Timed> {
            let t = Instant::now();
            let (s, v) = json_call(&addr, "POST", "/v1/estimate", Some(&request))?;
            if s != 200 {
                bail!("estimate of {id} failed: {s} {v}");
            }
            let stages = v["results"][0]["timings_ms"].as_object().map(|m| m.iter().filter_map(|(k, v)| Some((k.clone(), v.as_f64()?))).collect()).unwrap_or_default();
            Ok(Timed { ms: t.elapsed().as_secs_f64() * 1e3, stages })
        };
        cold.push(timed()?);
        warm.push(timed()?);
        again.push(timed()?);
        if (i + 1) % 25 == 0 {
            let m = memory_mb(server.pid());
            println!("  {} objects estimated: RSS {:.0} MB", i + 1, m.rss);
        }
    }
    let after = memory_mb(server.pid());
    let (_, metrics) = super::bench_serve::http(&addr, "GET", "/metrics", None)?;
    let metric = |name: &str| String::from_utf8_lossy(&metrics).lines().find(|l| l.starts_with(name)).and_then(|l| l.split_whitespace().nth(1)).and_then(|v| v.parse::<f64>().ok()).unwrap_or(f64::NAN);
    let extra_ms: Vec<f64> = cold.iter().zip(&warm).map(|(c, w)| c.ms - w.ms).collect();
    // The same difference between two warm estimates: what the noise alone gives.
    let noise_ms: Vec<f64> = again.iter().zip(&warm).map(|(a, w)| a.ms - w.ms).collect();
    println!(
        "catalogue: {} objects copied from {} ({} descriptors, patch rows {}) into {}; server --max-estimates 1{}, RRC {}",
        ids.len(),
        a.from,
        a.descriptors,
        rows,
        a.store,
        a.cache_mb.map_or(String::new(), |mb| format!(", --cache-mb {mb}")),
        if a.no_rrc { "off" } else { "on" }
    );
    println!("| store | MB on disk | MB per object | server RSS before (MB) | after: RSS / anon / file (MB) | per object (MB) | objects loaded | cache MB |");
    println!("|---|---:|---:|---:|---:|---:|---:|---:|");
    println!(
        "| {} | {:.0} | {:.1} | {:.0} | {:.0} / {:.0} / {:.0} | {:.1} | {} | {:.0} |",
        a.store,
        bytes as f64 / 1e6,
        bytes as f64 / 1e6 / ids.len().max(1) as f64,
        before.rss,
        after.rss,
        after.anon,
        after.file,
        (after.rss - before.rss) / ids.len().max(1) as f64,
        metric("b2tf_objects_loaded"),
        metric("b2tf_cache_bytes") / 1e6
    );
    println!("| estimate (ms) | median | p90 | max |");
    println!("|---|---:|---:|---:|");
    let ms = |v: &[Timed]| v.iter().map(|t| t.ms).collect::<Vec<_>>();
    for (name, v) in [("cold (object not loaded)", &ms(&cold)), ("warm", &ms(&warm)), ("cold − warm, per object", &extra_ms), ("warm − warm (noise)", &noise_ms)] {
        let s = sorted(v);
        println!("| {name} | {:.0} | {:.0} | {:.0} |", nearest_rank(&s, 0.5), nearest_rank(&s, 0.9), s.last().copied().unwrap_or(f64::NAN));
    }
    print_extra_by_stage(&cold, &warm);
    server.stop()
}

/// One estimate's round trip and the server's stage times (`timings_ms`), milliseconds.
struct Timed {
    ms: f64,
    stages: std::collections::BTreeMap<String, f64>,
}

/// Where the cold estimate's extra time goes: per pipeline stage, and outside the pipeline
/// (the request's round trip less the pipeline's `total`: the store's load, decoding).
fn print_extra_by_stage(cold: &[Timed], warm: &[Timed]) {
    let mut names: Vec<&String> = cold.first().map(|t| t.stages.keys().filter(|k| *k != "total").collect()).unwrap_or_default();
    names.sort();
    let outside = |t: &Timed| t.ms - t.stages.get("total").copied().unwrap_or(f64::NAN);
    let cells: Vec<(String, Vec<f64>)> = names
        .iter()
        .map(|n| (n.to_string(), cold.iter().zip(warm).map(|(c, w)| c.stages.get(*n).copied().unwrap_or(0.0) - w.stages.get(*n).copied().unwrap_or(0.0)).collect()))
        .chain(std::iter::once(("outside the pipeline".to_string(), cold.iter().zip(warm).map(|(c, w)| outside(c) - outside(w)).collect())))
        .collect();
    println!("| cold − warm by stage (ms) | median | p90 |");
    println!("|---|---:|---:|");
    for (name, v) in cells {
        let s = sorted(&v);
        println!("| {name} | {:.0} | {:.0} |", nearest_rank(&s, 0.5), nearest_rank(&s, 0.9));
    }
}

/// Copies the sources into the scratch store until it holds `objects` ids, their patch
/// rows shared per view where `rows` says so; returns the ids.
fn fill(a: &BenchCatalogueArgs, rows: crate::onboard::PatchRows) -> Result<Vec<String>> {
    let from = crate::store::open_read_only(&a.from)?;
    let sources: Vec<String> = from.list()?.into_iter().map(|o| o.id).collect();
    if sources.is_empty() {
        bail!("{} holds no objects to copy (`b2tf bench estimate --store {}` onboards the sample box there)", a.from, a.from);
    }
    let target = crate::store::open(&a.store)?;
    let ids: Vec<String> = (0..a.objects).map(|k| format!("{}-{k:03}", sources[k % sources.len()])).collect();
    let t = Instant::now();
    let mut copied = 0;
    for (i, source) in sources.iter().enumerate() {
        let missing: Vec<&String> = ids.iter().skip(i).step_by(sources.len()).filter(|id| !target.exists(id).unwrap_or(false)).collect();
        if missing.is_empty() {
            continue;
        }
        let mut model = from.get(source)?;
        if rows == crate::onboard::PatchRows::PerView && !model.rows_per_view() {
            crate::onboard::share_rows_per_view(&mut model).map_err(anyhow::Error::msg)?;
        }
        crate::onboard::apply_coding(&mut model, a.descriptors)?;
        // As onboarding stores them since format 7, whatever the source's format.
        model.patch_points.to_grid();
        model.config.descriptors = a.descriptors;
        for id in missing {
            model.object_id = id.clone();
            target.put(&model, true)?;
            copied += 1;
        }
    }
    if copied > 0 {
        println!("copied {copied} object(s) into {} in {:.0} s", a.store, t.elapsed().as_secs_f64());
    }
    Ok(ids)
}

/// `<source>-<k>` → `<source>`.
fn source_of(id: &str) -> &str {
    id.rsplit_once('-').map_or(id, |(s, _)| s)
}

/// An estimate request for a 640×480 view of `mesh` filling a third of the image height,
/// its mask as the detection.
fn view_request(mesh: &crate::mesh::Mesh, pool: &RenderPool, k: &Intrinsics, rrc: bool) -> Result<Value> {
    let centre = nalgebra::Vector3::from(mesh.bbox_center());
    let distance = fitted_distance(mesh.diameter() / 2.0, k.fy, k.height as f64 / 2.0, 0.35);
    let pose = view_pose(&nalgebra::Vector3::new(0.3, -0.5, 0.8).normalize(), 0.7, &centre, distance);
    let r = pool.render(mesh, &pose, k, &RenderOptions::default())?;
    let intrinsics = json!({"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy, "width": k.width, "height": k.height});
    Ok(json!({"image": {"encoded": b64(&png_bytes(&r.rgb)?)}, "intrinsics": intrinsics,
        "detections": [{"object_id": "", "mask_png": b64(&png_bytes(&r.mask)?), "score": 1.0}], "options": {"rrc": rrc}}))
}

fn sorted(v: &[f64]) -> Vec<f64> {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s
}
