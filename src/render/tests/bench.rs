//! Throughput at 512×512 with a ~10k-triangle mesh. Ignored by default; run with
//! `cargo test --release bench_renders_per_second -- --ignored --nocapture`.

use std::time::Instant;

use super::meshes::uv_sphere;
use super::{pose, renderer_with};
use crate::geometry::{Intrinsics, Pose};
use crate::render::{RenderOptions, RenderPool, RendererConfig};

#[test]
#[ignore]
fn bench_renders_per_second() {
    let Some(mut r) = renderer_with(RendererConfig::default()) else { return };
    let mesh = uv_sphere(0.05, 50, 100); // 2·100·49 = 9800 triangles
    let k = Intrinsics::new(600.0, 600.0, 255.5, 255.5, 512, 512).unwrap();
    let o = RenderOptions::default();
    let views: Vec<(Pose, Intrinsics)> = (0..162).map(|i| (pose([i as f64 * 7.0, i as f64 * 13.0, 0.0], [0.0, 0.0, 0.25]), k)).collect();
    r.render(&mesh, &views[0].0, &k, &o).unwrap(); // upload and target allocation
    let t = Instant::now();
    for (p, k) in &views {
        r.render(&mesh, p, k, &o).unwrap();
    }
    let single = views.len() as f64 / t.elapsed().as_secs_f64();
    eprintln!("{}: {single:.1} renders/s (one renderer, 512x512, {} triangles)", r.describe(), mesh.triangles().len());

    for size in [2, 4] {
        let pool = RenderPool::new(size, RendererConfig::default()).unwrap();
        pool.render_batch(&mesh, &views[..size], &o).unwrap(); // warm every renderer
        let t = Instant::now();
        pool.render_batch(&mesh, &views, &o).unwrap();
        let rate = views.len() as f64 / t.elapsed().as_secs_f64();
        eprintln!("pool of {size}: {rate:.1} renders/s (render_batch of {} views)", views.len());
    }
}
