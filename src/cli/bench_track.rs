//! `b2tf bench track`: the tracker on generated sequences (track::sequence): ms per
//! frame, share of frames with MSSD < 0.1·d, losses. Each sequence starts from its true
//! first pose; a lost frame restarts the track at the true pose of that frame (standing
//! in for a full estimate from a detection), counted as a re-initialisation.

use crate::eval::pose_error::mssd;
use crate::geometry::Intrinsics;
use crate::mesh::Units;
use crate::track::sequence::{generate, SequenceConfig};
use crate::track::{Tracker, TrackerConfig};
use anyhow::Result;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct BenchTrackArgs {
    /// Meshes to track (default: the generated sample box); each gets its own sequences.
    #[arg(long = "mesh")]
    pub meshes: Vec<PathBuf>,
    #[arg(long)]
    pub units: Option<Units>,
    #[arg(long, default_value_t = 5)]
    pub sequences: usize,
    #[arg(long, default_value_t = 100)]
    pub frames: usize,
    /// Largest motion between frames: degrees and metres.
    #[arg(long, default_value_t = 3.0)]
    pub degrees: f64,
    #[arg(long, default_value_t = 0.01)]
    pub metres: f64,
    /// Image size (the intrinsics scale with it: fx = 1.25 × width).
    #[arg(long, default_value_t = 640)]
    pub width: u32,
    #[arg(long, default_value_t = 480)]
    pub height: u32,
    /// Store that caches the onboarded models.
    #[arg(long, default_value = "dir://out/bench-models")]
    pub store: String,
}

pub fn run(a: BenchTrackArgs) -> Result<()> {
    let backbone = crate::features::EmbeddedBackbone::new(Default::default()).map_err(anyhow::Error::msg)?;
    let pool = Arc::new(super::open_renderer(1)?);
    let meshes = super::bench_estimate::bench_meshes(&a.meshes, a.units)?;
    let store = crate::store::open(&a.store)?;
    let k = Intrinsics::new(1.25 * a.width as f64, 1.25 * a.width as f64, (a.width as f64 - 1.0) / 2.0, (a.height as f64 - 1.0) / 2.0, a.width, a.height)?;
    println!("| object | frames | tracked | MSSD < 0.1·d | lost → re-initialised | ms per tracked frame, median | p95 |");
    println!("|---|---:|---:|---:|---:|---:|---:|");
    for (name, mesh) in &meshes {
        let model = Arc::new(super::cached_model(name, mesh, store.as_ref(), &backbone, &pool, crate::onboard::PcaSetting::Off)?);
        let (mut frames, mut good, mut lost) = (0usize, 0usize, 0usize);
        let mut ms = Vec::new();
        for s in 0..a.sequences {
            let cfg = SequenceConfig { frames: a.frames, max_degrees_per_frame: a.degrees, max_metres_per_frame: a.metres, seed: 1 + s as u64, ..Default::default() };
            let seq = generate(&model.mesh, &k, &cfg, &pool)?;
            let mut tracker = Tracker::new(model.clone(), pool.clone(), &seq[0].rgb, &k, seq[0].truth, TrackerConfig::default()).map_err(anyhow::Error::msg)?;
            for f in &seq[1..] {
                let t = Instant::now();
                let step = tracker.track(&f.rgb, &k).map_err(anyhow::Error::msg)?;
                frames += 1;
                if step.lost {
                    lost += 1;
                    tracker.restart(&f.rgb, &k, f.truth).map_err(anyhow::Error::msg)?;
                    continue;
                }
                ms.push(t.elapsed().as_secs_f64() * 1e3);
                if mssd(&step.pose, &f.truth, model.mesh.positions()) < 0.1 * model.diameter() {
                    good += 1;
                }
            }
        }
        ms.sort_by(f64::total_cmp);
        let pick = |q: f64| ms.get(((ms.len() as f64 - 1.0) * q).round() as usize).copied().unwrap_or(f64::NAN);
        println!("| {name} | {frames} | {} | {:.1} % | {lost} | {:.1} | {:.1} |", ms.len(), 100.0 * good as f64 / frames.max(1) as f64, pick(0.5), pick(0.95));
    }
    Ok(())
}
