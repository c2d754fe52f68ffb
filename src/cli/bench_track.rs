//! `b2tf bench track`: the tracker on generated sequences (track::sequence): ms per
//! frame, share of frames with MSSD < 0.1·d, ADD and ADD-S AUC, losses. In process, each
//! sequence starts from its true first pose and a lost frame restarts the track at the
//! true pose of that frame (standing in for a full estimate from a detection), counted as
//! a re-initialisation. With `--grpc` the same sequences also go through a `b2tf serve`
//! child's `Track` stream, which re-initialises by itself: frames per second end to end.

use super::bench_track_grpc::{stream_sequence, StreamStats};
use crate::depth::DepthImage;
use crate::eval::pose_error::{add, add_s, auc, mssd, sample_points};
use crate::geometry::{Intrinsics, Pose};
use crate::mesh::Units;
use crate::onboard::ObjectModel;
use crate::track::sequence::{generate, Frame, SequenceConfig};
use crate::track::sequence_bop::{write_sequences, SequenceSpec};
use crate::track::{TrackTimings, Tracker, TrackerConfig};
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
    /// A bar crossing the view once per sequence, hiding the object as it passes.
    #[arg(long)]
    pub occluder: bool,
    /// Gaussian blur of every frame, pixels.
    #[arg(long, default_value_t = 0.0)]
    pub blur: f64,
    /// Gaussian noise of every frame, grey levels.
    #[arg(long, default_value_t = 0.0)]
    pub noise: f64,
    /// Image size (the intrinsics scale with it: fx = 1.25 × width).
    #[arg(long, default_value_t = 640)]
    pub width: u32,
    #[arg(long, default_value_t = 480)]
    pub height: u32,
    /// Store that caches the onboarded models.
    #[arg(long, default_value = "dir://out/bench-models")]
    pub store: String,
    /// Also stream every sequence through a `b2tf serve` child's gRPC Track stream.
    #[arg(long)]
    pub grpc: bool,
    /// Also track every sequence with its depth frames (RGB-D) and report both.
    #[arg(long)]
    pub depth: bool,
    /// The renderer's exact depth instead of the Kinect-class sensor model's
    /// (`depth::sensor`), for --depth and --save-bop.
    #[arg(long)]
    pub exact_depth: bool,
    /// Also write the sequences as a BOP dataset here (one scene per sequence; object ids
    /// from `obj_NNNNNN` mesh names, else 1, 2, … in the order given).
    #[arg(long, value_name = "DIR")]
    pub save_bop: Option<PathBuf>,
    /// Frames between the tracker's relearning renders (`TrackerConfig::relearn_every`;
    /// default the tracker's), in process.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    pub relearn_every: Option<u64>,
    /// Correspondence passes per line scale of the contour step
    /// (`TrackerConfig::contour_passes`; default the tracker's), in process.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    pub contour_passes: Option<u64>,
}

impl BenchTrackArgs {
    /// The tracker's settings with this run's overrides.
    fn tracker_config(&self) -> TrackerConfig {
        let defaults = TrackerConfig::default();
        TrackerConfig {
            relearn_every: self.relearn_every.map_or(defaults.relearn_every, |n| n as usize),
            contour_passes: self.contour_passes.map_or(defaults.contour_passes, |n| n as usize),
            ..defaults
        }
    }
}

/// A mesh's BOP object id: the number of an `obj_000005`-style name, else its place.
fn bop_object_id(name: &str, place: usize) -> u32 {
    name.rsplit('/').next().and_then(|n| n.strip_prefix("obj_")).and_then(|n| n.split('.').next()).and_then(|n| n.parse().ok()).filter(|&id| id > 0).unwrap_or(place as u32 + 1)
}

/// Per-frame accuracy of one object's frames; a missing pose counts as a miss.
#[derive(Default)]
struct Accuracy {
    frames: usize,
    mssd_ok: usize,
    add: Vec<f64>,
    add_s: Vec<f64>,
}

impl Accuracy {
    fn push(&mut self, pose: Option<&Pose>, f: &Frame, model: &ObjectModel, sample: &[[f32; 3]]) {
        self.frames += 1;
        let Some(p) = pose else {
            self.add.push(f64::INFINITY);
            self.add_s.push(f64::INFINITY);
            return;
        };
        if mssd(p, &f.truth, model.mesh.positions()) < 0.1 * model.diameter() {
            self.mssd_ok += 1;
        }
        self.add.push(add(p, &f.truth, sample));
        self.add_s.push(add_s(p, &f.truth, sample));
    }

    /// "MSSD %, ADD AUC, ADD-S AUC" table cells.
    fn cells(&self) -> String {
        format!("{:.1} % | {:.3} | {:.3}", 100.0 * self.mssd_ok as f64 / self.frames.max(1) as f64, auc(&self.add, 0.1), auc(&self.add_s, 0.1))
    }
}

/// One object's frames tracked in one mode (RGB or RGB-D).
#[derive(Default)]
struct TrackRun {
    accuracy: Accuracy,
    /// Frames lost (each restarted at the truth).
    lost: usize,
    /// Tracked frames that rendered (a check and relearning: periodic or doubtful): what
    /// the p95 and the share within 3 ms follow, counted without the timings' noise.
    rendered: usize,
    /// Per tracked frame: the wall-clock time around `Tracker::track` ...
    ms: Vec<f64>,
    /// ... and the tracker's own per-stage times (`TrackTimings::as_row`).
    stages: Vec<[f64; 6]>,
}

/// Tracks one sequence with `tracker` (started at the first frame's true pose), with its
/// depth frames or without; a lost frame restarts at the truth. Adds to `run`'s accuracy,
/// lost count and times per tracked frame.
fn track_in_process(mut tracker: Tracker, model: &ObjectModel, k: &Intrinsics, seq: &[Frame], with_depth: bool, sample: &[[f32; 3]], run: &mut TrackRun) -> Result<()> {
    let TrackRun { accuracy: acc, lost, rendered, ms, stages } = run;
    for f in &seq[1..] {
        let depth = if with_depth { Some(DepthImage::from_metres(k.width, k.height, f.depth.clone())?) } else { None };
        let t = Instant::now();
        let step = tracker.track(&f.rgb, depth.as_ref(), k).map_err(anyhow::Error::msg)?;
        if step.lost {
            *lost += 1;
            acc.push(None, f, model, sample);
            // Out of view at the truth too: the track waits where it was.
            let _ = tracker.restart(&f.rgb, k, f.truth);
            continue;
        }
        ms.push(t.elapsed().as_secs_f64() * 1e3);
        *rendered += usize::from(step.silhouette_iou.is_some());
        stages.push(step.timings.as_row());
        acc.push(Some(&step.pose), f, model, sample);
    }
    Ok(())
}

pub fn run(a: BenchTrackArgs) -> Result<()> {
    let backbone = crate::features::EmbeddedBackbone::new(Default::default()).map_err(anyhow::Error::msg)?;
    let pool = Arc::new(super::open_renderer(1)?);
    let meshes = super::bench_scenes::bench_meshes(&a.meshes, a.units)?;
    let store = crate::store::open(&a.store)?;
    let k = Intrinsics::new(1.25 * a.width as f64, 1.25 * a.width as f64, (a.width as f64 - 1.0) / 2.0, (a.height as f64 - 1.0) / 2.0, a.width, a.height)?;
    let mut models = Vec::new();
    for (name, mesh) in &meshes {
        models.push((name.clone(), Arc::new(super::cached_model(name, mesh, store.as_ref(), &backbone, &pool, super::bench_cache_config())?)));
    }
    drop(store); // the server below opens it
    let config = |s: usize| SequenceConfig {
        frames: a.frames,
        max_degrees_per_frame: a.degrees,
        max_metres_per_frame: a.metres,
        seed: 1 + s as u64,
        occluder: a.occluder,
        blur_sigma: a.blur,
        noise_sigma: a.noise,
        depth_sensor: super::depth_sensor(a.exact_depth),
        ..Default::default()
    };
    if let Some(dir) = &a.save_bop {
        let specs: Vec<SequenceSpec> = meshes
            .iter()
            .enumerate()
            .flat_map(|(place, (name, mesh))| (0..a.sequences).map(move |s| (bop_object_id(name, place), mesh, s)))
            .map(|(obj_id, mesh, s)| SequenceSpec { obj_id, mesh, config: config(s) })
            .collect();
        let frames = write_sequences(dir, &k, &specs, &pool)?;
        println!("Wrote {} sequences ({frames} frames) as a BOP dataset in {}\n", specs.len(), dir.display());
    }
    let server = if a.grpc { Some(super::child_server::ChildServer::start(&a.store, &[])?) } else { None };
    let mut grpc_rows = Vec::new();
    println!("In process (a lost frame restarts at the truth):\n");
    println!("| object | frames | tracked | MSSD < 0.1·d | ADD AUC | ADD-S AUC | lost → re-initialised | ms per tracked frame, median | p95 | within 3 ms | rendered |");
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    let modes: &[bool] = if a.depth { &[false, true] } else { &[false] };
    let tracker_config = a.tracker_config();
    // Each run's stage shares, printed after the table (the next speed step's data).
    let mut profiles = Vec::new();
    for (name, model) in &models {
        let sample = sample_points(model.mesh.positions(), 500);
        let mut runs: Vec<TrackRun> = modes.iter().map(|_| TrackRun::default()).collect();
        let (mut grpc_acc, mut grpc_stats) = (Accuracy::default(), StreamStats::default());
        for s in 0..a.sequences {
            let seq = generate(&model.mesh, &k, &config(s), &pool)?;
            for (run, &with_depth) in runs.iter_mut().zip(modes) {
                let tracker = Tracker::new(model.clone(), pool.clone(), &seq[0].rgb, &k, seq[0].truth, tracker_config.clone()).map_err(anyhow::Error::msg)?;
                track_in_process(tracker, model, &k, &seq, with_depth, &sample, run)?;
            }
            if let Some(server) = &server {
                let first_mask = pool.render(&model.mesh, &seq[0].truth, &k, &Default::default())?.mask;
                let poses = stream_sequence(&server.grpc, &model.object_id, &seq, &first_mask, &k, &mut grpc_stats)?;
                for (pose, f) in poses.iter().zip(&seq).skip(1) {
                    grpc_acc.push(pose.as_ref(), f, model, &sample);
                }
            }
        }
        for (TrackRun { accuracy: acc, lost, rendered, ms, stages }, &with_depth) in runs.iter_mut().zip(modes) {
            ms.sort_by(f64::total_cmp);
            let pick = |q: f64| ms.get(((ms.len() as f64 - 1.0) * q).round() as usize).copied().unwrap_or(f64::NAN);
            let label = if a.depth { format!("{name} ({})", if with_depth { "RGB-D" } else { "RGB" }) } else { name.clone() };
            let within = ms.iter().filter(|&&m| m <= 3.0).count() as f64 / ms.len().max(1) as f64;
            let rendered = *rendered as f64 / ms.len().max(1) as f64;
            println!("| {label} | {} | {} | {} | {lost} | {:.1} | {:.1} | {:.0} % | {:.1} % |", acc.frames, ms.len(), acc.cells(), pick(0.5), pick(0.95), 100.0 * within, 100.0 * rendered);
            profiles.push(format!("profile, {label}: {}", super::bench_profile::stage_shares(&TrackTimings::STAGES, stages, "tracked frames")));
        }
        if server.is_some() {
            grpc_rows.push(format!(
                "| {name} | {} | {} | {} | {} | {} | {:.1} | {:.1} |",
                grpc_acc.frames,
                grpc_stats.tracked,
                grpc_stats.reinitialised,
                grpc_stats.lost,
                grpc_acc.cells(),
                grpc_stats.server_ms_median(),
                grpc_stats.frames_per_second()
            ));
        }
    }
    println!();
    for p in profiles {
        println!("{p}");
    }
    if !grpc_rows.is_empty() {
        println!("\nThrough the gRPC Track stream of a `b2tf serve` child (raw RGB frames, the server re-initialises by itself; frames/s end to end, client to answer):\n");
        println!("| object | frames | tracked | re-initialised | lost | MSSD < 0.1·d | ADD AUC | ADD-S AUC | server ms per frame, median | frames/s |");
        println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
        for r in grpc_rows {
            println!("{r}");
        }
    }
    server.map_or(Ok(()), |s| s.stop())
}
