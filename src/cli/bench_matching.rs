//! `b2tf bench matching`: what wide descriptors cost at estimation and onboarding. Matching
//! is one query (~300 foreground patches) against the patches of the retrieved templates
//! (125 templates × ~420 patches ≈ 50k), a GEMM whose cost grows with the descriptor size;
//! the PCA that shrinks the descriptors costs a fit and a projection at onboarding. Random
//! unit vectors stand in for descriptors: neither cost depends on their values.

use crate::estimate::matching::mutual_matches;
use crate::onboard::pca::Pca;
use anyhow::Result;
use half::f16;
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct BenchMatchingArgs {
    /// Descriptor sizes to match at (1024: ViT-L; 384: ViT-S; 64: the embedded backbone).
    #[arg(long, value_delimiter = ',', default_value = "1024,384,256,192,128,64")]
    pub dims: Vec<usize>,
    /// Query patches.
    #[arg(long, default_value_t = 300)]
    pub query: usize,
    /// Pool sizes (template patches matched against).
    #[arg(long, value_delimiter = ',', default_value = "10000,50000,100000")]
    pub pool: Vec<usize>,
    /// Descriptor size the PCA rows are fitted at, and the components it keeps.
    #[arg(long, default_value_t = 1024)]
    pub pca_input: usize,
    #[arg(long, value_delimiter = ',', default_value = "256,128")]
    pub pca_keep: Vec<usize>,
    /// Rows projected by the PCA (an object of 1944 templates has ~800k patches).
    #[arg(long, default_value_t = 200_000)]
    pub pca_rows: usize,
    #[arg(long, default_value_t = 3)]
    pub repeats: usize,
}

fn unit_rows(n: usize, dim: usize, rng: &mut crate::mesh::procedural::Rng) -> Vec<f32> {
    let mut v: Vec<f32> = (0..n * dim).map(|_| rng.normal() as f32).collect();
    for r in v.chunks_exact_mut(dim) {
        let norm = r.iter().map(|x| x * x).sum::<f32>().sqrt().max(1e-12);
        r.iter_mut().for_each(|x| *x /= norm);
    }
    v
}

/// Median seconds of `repeats` runs of `f`.
fn median_seconds(repeats: usize, mut f: impl FnMut()) -> f64 {
    let mut t: Vec<f64> = (0..repeats.max(1))
        .map(|_| {
            let s = Instant::now();
            f();
            s.elapsed().as_secs_f64()
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[t.len() / 2]
}

pub fn run(a: BenchMatchingArgs) -> Result<()> {
    let mut rng = crate::mesh::procedural::Rng::new(1);
    println!("mutual nearest neighbours (k = 3) of {} query patches, {} threads:", a.query, rayon::current_num_threads());
    println!("| dim | pool patches | GFLOP | widen f16 pool (ms) | match (ms) | GFLOP/s |");
    println!("|---:|---:|---:|---:|---:|---:|");
    let largest = a.pool.iter().copied().max().unwrap_or(0);
    for &dim in &a.dims {
        let query = unit_rows(a.query, dim, &mut rng);
        // Stored descriptors are f16; estimation widens the retrieved templates' rows first.
        let stored: Vec<f16> = unit_rows(largest, dim, &mut rng).into_iter().map(f16::from_f32).collect();
        for &p in &a.pool {
            let mut pool = Vec::new();
            let widen = median_seconds(a.repeats, || {
                pool.clear();
                crate::onboard::patch_descriptors::widen_half(&stored[..p * dim], &mut pool);
            });
            let secs = median_seconds(a.repeats, || {
                std::hint::black_box(mutual_matches(&query, &pool, dim, 3));
            });
            let gflop = 2.0 * (a.query * p * dim) as f64 / 1e9;
            println!("| {dim} | {p} | {gflop:.1} | {:.1} | {:.1} | {:.1} |", widen * 1e3, secs * 1e3, gflop / secs);
        }
    }
    println!();
    println!("PCA {} → k, fitted on up to 50k rows, projecting {} rows:", a.pca_input, a.pca_rows);
    println!("| k | fit (s) | project (s) | projected rows/s |");
    println!("|---:|---:|---:|---:|");
    let rows: Vec<f16> = unit_rows(a.pca_rows, a.pca_input, &mut rng).into_iter().map(f16::from_f32).collect();
    for &k in &a.pca_keep {
        let t = Instant::now();
        let pca = Pca::fit(&rows, a.pca_input, k).map_err(anyhow::Error::msg)?;
        let fit = t.elapsed().as_secs_f64();
        let t = Instant::now();
        std::hint::black_box(pca.project_f16(&rows));
        let project = t.elapsed().as_secs_f64();
        println!("| {k} | {fit:.2} | {project:.2} | {:.0} |", a.pca_rows as f64 / project);
    }
    Ok(())
}
