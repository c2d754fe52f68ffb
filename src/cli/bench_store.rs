//! `b2tf bench store`: what the object stores cost: bytes per object (f16, PCA, product
//! quantisation), put time,
//! and load time from each backend (dir, sqlite, and S3 with `--s3 URL`), cold (page cache
//! dropped, when allowed) and warm.

use crate::mesh::{load_mesh, Units};
use crate::onboard::{compress, ObjectModel};
use crate::render::RenderPool;
use crate::store::{ModelCache, ObjectStore};
use anyhow::Result;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct BenchStoreArgs {
    /// Mesh to onboard (default: the generated sample box).
    #[arg(long)]
    pub mesh: Option<PathBuf>,
    #[arg(long)]
    pub units: Option<Units>,
    /// PCA sizes to compare with the uncompressed f16 model.
    #[arg(long, value_delimiter = ',', default_value = "32,16")]
    pub pca: Vec<usize>,
    /// Descriptor codings to compare with f16 (`b2tf onboard --descriptors`).
    #[arg(long, value_delimiter = ',', value_enum, default_value = "pq4,pq2")]
    pub descriptors: Vec<crate::onboard::DescriptorCoding>,
    /// Also store f16 and each coding with patch rows per view (`b2tf onboard --patch-rows
    /// per-view`).
    #[arg(long)]
    pub per_view: bool,
    /// Store that caches the onboarded model between runs.
    #[arg(long, default_value = "dir://out/bench-models")]
    pub cache_store: String,
    /// Also time an S3 store: `s3://BUCKET/PREFIX[?OPTIONS]` (as `--store` takes it; each
    /// variant goes under its own folder in PREFIX and is deleted afterwards).
    #[arg(long)]
    pub s3: Option<String>,
    /// Loads timed per backend and variant.
    #[arg(long, default_value_t = 3)]
    pub repeats: usize,
    #[command(flatten)]
    pub backbone: super::backbone_args::BackboneArgs,
}

/// Drops the kernel's page cache so the next read comes from the disk (root only).
fn drop_page_cache() -> bool {
    // SAFETY: sync(2) has no preconditions.
    unsafe { libc_sync() };
    std::fs::write("/proc/sys/vm/drop_caches", "3").is_ok()
}

extern "C" {
    #[link_name = "sync"]
    fn libc_sync();
}

/// `s3://BUCKET/PREFIX?Q` with `folder` added to the prefix.
fn s3_below(url: &str, folder: &str) -> String {
    let (location, query) = url.split_once('?').map_or((url, String::new()), |(l, q)| (l, format!("?{q}")));
    format!("{}/{folder}{query}", location.trim_end_matches('/'))
}

pub fn run(a: BenchStoreArgs) -> Result<()> {
    let backbone = a.backbone.open()?;
    let pool = super::open_renderer(RenderPool::DEFAULT_SIZE)?;
    let (name, mesh) = match &a.mesh {
        Some(p) => (p.file_stem().and_then(|s| s.to_str()).unwrap_or("mesh").replace(' ', "_"), load_mesh(p, a.units)?),
        None => ("box".to_string(), crate::mesh::procedural::textured_box([0.10, 0.06, 0.16], 3)),
    };
    let cache = crate::store::open(&a.cache_store)?;
    let id = super::bench_estimate::cached_id_for(&name, &backbone.identity());
    let full = super::cached_model(&id, &mesh, cache.as_ref(), backbone.as_ref(), &pool, super::bench_cache_config())?;
    let mut variants: Vec<(String, ObjectModel)> = vec![(format!("{} dims (f16)", full.local_dim), full.clone())];
    let mut compress_s = vec![];
    for &d in &a.pca {
        let mut m = full.clone();
        let t = Instant::now();
        compress(&mut m, d)?;
        compress_s.push((d, t.elapsed().as_secs_f64()));
        variants.push((format!("PCA {d} (f16)"), m));
    }
    let per_view = if a.per_view {
        let mut m = full.clone();
        crate::onboard::share_rows_per_view(&mut m).map_err(anyhow::Error::msg)?;
        variants.push((format!("{} dims (f16), rows per view", full.local_dim), m.clone()));
        Some(m)
    } else {
        None
    };
    for &coding in &a.descriptors {
        for (base, rows) in std::iter::once((&full, "")).chain(per_view.as_ref().map(|m| (m, ", rows per view"))) {
            let mut m = base.clone();
            let t = Instant::now();
            crate::onboard::apply_coding(&mut m, coding)?;
            println!("{coding}{rows}: learnt and encoded in {:.2} s", t.elapsed().as_secs_f64());
            variants.push((format!("{} dims ({coding}){rows}", full.local_dim), m));
        }
    }
    let tmp = std::env::temp_dir().join(format!("b2tf-bench-store-{}", std::process::id()));
    let result = (|| -> Result<()> {
        println!("object {name}: {} templates, {} patches", full.template_count(), full.patch_count());
        println!("| backend | descriptors | stored MB | put (s) | cold load (s) | load, page cache warm (s) | cache hit (ms) | heap held once loaded (MB) |");
        println!("|---|---|---:|---:|---:|---:|---:|---:|");
        let mut dropped_all = true;
        let backends = ["dir", "sqlite"].into_iter().chain(a.s3.as_ref().map(|_| "s3"));
        for backend in backends {
            for (label, model) in &variants {
                let folder: String = label.chars().map(|c| if c.is_ascii_alphanumeric() { c } else { '_' }).collect();
                let url = match backend {
                    "dir" => format!("dir://{}", tmp.join(format!("dir-{folder}")).display()),
                    "s3" => s3_below(a.s3.as_deref().unwrap_or_default(), &folder),
                    _ => format!("sqlite://{}", tmp.join(format!("{folder}.db")).display()),
                };
                let store: Arc<dyn ObjectStore> = crate::store::open(&url)?;
                let t = Instant::now();
                let info = store.put(model, true)?;
                let put_s = t.elapsed().as_secs_f64();
                let mut cold = Vec::new();
                let mut warm = Vec::new();
                let mut heap = 0;
                for _ in 0..a.repeats {
                    dropped_all &= drop_page_cache();
                    let t = Instant::now();
                    store.get(&model.object_id)?;
                    cold.push(t.elapsed().as_secs_f64());
                    let t = Instant::now();
                    let loaded = store.get(&model.object_id)?;
                    warm.push(t.elapsed().as_secs_f64());
                    heap = loaded.memory_bytes();
                }
                let models = ModelCache::new(store.clone(), u64::MAX);
                models.get(&model.object_id)?;
                let t = Instant::now();
                models.get(&model.object_id)?;
                let hit_ms = t.elapsed().as_secs_f64() * 1e3;
                let med = |v: &mut Vec<f64>| {
                    v.sort_by(f64::total_cmp);
                    v[v.len() / 2]
                };
                if backend == "s3" {
                    store.delete(&model.object_id)?;
                }
                println!("| {backend} | {label} | {:.1} | {put_s:.2} | {:.3} | {:.3} | {hit_ms:.3} | {:.1} |", info.bytes as f64 / 1e6, med(&mut cold), med(&mut warm), heap as f64 / 1e6);
            }
        }
        for (d, s) in compress_s {
            println!("PCA {} → {d}: fitted and projected in {s:.2} s", full.local_dim);
        }
        if !dropped_all {
            println!("(the page cache could not be dropped (needs root): \"cold\" loads read from memory)");
        }
        Ok(())
    })();
    let _ = std::fs::remove_dir_all(&tmp);
    result
}
