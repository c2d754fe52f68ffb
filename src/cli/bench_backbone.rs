//! `b2tf bench backbone`: crops per second and ms per crop at several batch sizes, for the
//! embedded backbone and any ONNX models given, on the chosen device. The crops are renders
//! of the sample box (speed does not depend on what a crop shows, nor on weight values).

use crate::features::{open_backbone, BackboneChoice, CropInput, Device};
use crate::geometry::views::view_pose;
use crate::geometry::Intrinsics;
use crate::render::RenderOptions;
use anyhow::{bail, Result};
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct BenchBackboneArgs {
    /// ONNX models to measure besides the embedded backbone (e.g. `tools/make_test_vit.py
    /// --dim 384 --depth 12 --heads 6` for ViT-S/16's shape).
    #[arg(long = "onnx")]
    pub onnx: Vec<PathBuf>,
    /// Where the ONNX models run: cpu, cuda[:N], tensorrt[:N].
    #[arg(long, default_value = "cpu")]
    pub device: Device,
    /// Batch sizes measured.
    #[arg(long, value_delimiter = ',', default_value = "1,8,32")]
    pub batches: Vec<usize>,
    /// Passes per batch size (after one warm-up pass).
    #[arg(long, default_value_t = 2)]
    pub passes: usize,
}

/// `n` crops of the sample box from different viewpoints, `size` px square.
fn crops(n: usize, size: u32) -> Result<Vec<CropInput>> {
    let pool = super::open_renderer(1)?;
    let mesh = crate::mesh::procedural::textured_box([0.10, 0.06, 0.16], 3);
    let k = Intrinsics::new(size as f64, size as f64, (size as f64 - 1.0) / 2.0, (size as f64 - 1.0) / 2.0, size, size).map_err(anyhow::Error::msg)?;
    let dirs = crate::geometry::icosphere(2);
    (0..n)
        .map(|i| {
            let pose = view_pose(&dirs[i % dirs.len()], 0.0, &nalgebra::Vector3::zeros(), 0.5);
            let r = pool.render(&mesh, &pose, &k, &RenderOptions::default())?;
            crate::features::crop_query(&r.rgb, &r.mask, 0.1, size).map(|c| c.0).ok_or_else(|| anyhow::anyhow!("view {i} shows nothing"))
        })
        .collect()
}

pub fn run(a: BenchBackboneArgs) -> Result<()> {
    if a.batches.is_empty() || a.batches.contains(&0) || a.passes == 0 {
        bail!("batch sizes and passes must be at least 1");
    }
    // Opened one at a time, so that only one model's session is held at once.
    let backbones = std::iter::once((BackboneChoice::Embedded, Device::Cpu)).chain(a.onnx.iter().map(|p| (BackboneChoice::Onnx(p.clone()), a.device.clone())));
    let largest = *a.batches.iter().max().expect("non-empty");
    println!("| backbone | input | batch | ms per pass | ms per crop | crops/s |");
    println!("|---|---:|---:|---:|---:|---:|");
    for (choice, device) in backbones {
        let name = format!("{choice} ({device})");
        let b = open_backbone(&choice, &device).map_err(anyhow::Error::msg)?;
        let id = b.identity();
        let all = crops(largest, id.input_size)?;
        for &n in &a.batches {
            // Warm-up at each batch size: allocation, and whatever a provider sets up per
            // input shape, stay out of the timed passes.
            b.extract(&all[..n])?;
            let t = Instant::now();
            for _ in 0..a.passes {
                b.extract(&all[..n])?;
            }
            let pass_ms = t.elapsed().as_secs_f64() * 1e3 / a.passes as f64;
            println!("| {name} | {}² | {n} | {pass_ms:.0} | {:.1} | {:.1} |", id.input_size, pass_ms / n as f64, 1e3 * n as f64 / pass_ms);
        }
    }
    Ok(())
}
