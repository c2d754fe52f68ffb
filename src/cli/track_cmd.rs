//! `b2tf track`: poses through a video given as a folder of frames. The first frame gets a
//! full estimate from its mask; later frames are tracked (track::Tracker), and a lost frame
//! is re-initialised by a full estimate of the object segmented inside the box around its
//! last pose. One JSON line per frame, written as it is known.

use super::estimate_cmd::{load_mask, write_overlay};
use crate::estimate::{Detection, EstimateConfig, Estimator};
use crate::geometry::{Intrinsics, Pose};
use crate::onboard::ObjectModel;
use crate::track::{Tracker, TrackerConfig};
use anyhow::{bail, Context, Result};
use serde_json::json;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct TrackArgs {
    #[command(flatten)]
    pub target: super::object_args::StoredObjectArgs,
    /// Folder of frames (PNG or JPEG), taken in name order.
    #[arg(long)]
    pub video: PathBuf,
    /// Camera JSON ({"K", "resolution"} or BOP {"cam_K", "width", "height"}).
    #[arg(long)]
    pub camera: PathBuf,
    /// The object's mask in the first frame (PNG, nonzero = object).
    #[arg(long)]
    pub mask: PathBuf,
    /// Output: one JSON line per frame.
    #[arg(long)]
    pub out: PathBuf,
    /// Also write each frame with its pose drawn over it into this folder.
    #[arg(long)]
    pub overlay_dir: Option<PathBuf>,
}

/// The frames of `dir` (PNG / JPEG), sorted by file name.
pub fn frame_paths(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut frames: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("cannot read the frames folder {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().and_then(|e| e.to_str()).is_some_and(|e| matches!(e.to_ascii_lowercase().as_str(), "png" | "jpg" | "jpeg")))
        .collect();
    frames.sort();
    if frames.is_empty() {
        bail!("no PNG or JPEG frames in {}", dir.display());
    }
    Ok(frames)
}

fn load_frame(path: &Path, k: &Intrinsics) -> Result<image::RgbImage> {
    let img = image::open(path).with_context(|| format!("cannot read frame {}", path.display()))?.to_rgb8();
    if img.dimensions() != (k.width, k.height) {
        bail!("frame {} is {}×{} but the camera file says {}×{}", path.display(), img.width(), img.height(), k.width, k.height);
    }
    Ok(img)
}

/// A full estimate of `model` from `mask`.
fn estimate(estimator: &Estimator, model: &ObjectModel, image: &image::RgbImage, k: &Intrinsics, mask: image::GrayImage) -> Result<Option<Pose>> {
    let r = estimator.estimate(model, image, k, &[Detection { mask, score: 1.0 }], &EstimateConfig::default())?;
    Ok(r.pose)
}

/// The object segmented inside the box around the tracker's last pose (None when that box
/// leaves the image or nothing is segmented there).
fn mask_near(tracker: &Tracker, image: &image::RgbImage, k: &Intrinsics) -> Option<image::GrayImage> {
    let w = tracker.window(k, &tracker.pose(), 1.2)?;
    let b = [w.x0 as f64, w.y0 as f64, (w.x1 - w.x0) as f64, (w.y1 - w.y0) as f64];
    crate::masks::box_to_mask(image, b, crate::masks::BoxMask::Segment).ok().map(|s| s.mask)
}

fn pose_line(frame: usize, file: &Path, pose: Option<&Pose>, quality: f64, mode: &str, ms: f64) -> serde_json::Value {
    json!({
        "frame": frame,
        "file": file.file_name().map(|n| n.to_string_lossy().into_owned()),
        "R": pose.map(|p| p.rotation_row_major()),
        "t": pose.map(|p| [p.translation.x, p.translation.y, p.translation.z]),
        "quality": quality,
        "mode": mode,
        "ms": ms,
    })
}

pub fn run(a: TrackArgs) -> Result<()> {
    let model = Arc::new(a.target.load()?);
    let k = super::camera_file::load_camera(&a.camera)?;
    let frames = frame_paths(&a.video)?;
    let first = load_frame(&frames[0], &k)?;
    let mask = crate::masks::decode::check_size(load_mask(&a.mask)?, k.width, k.height).and_then(crate::masks::require_nonempty).with_context(|| format!("--mask {}", a.mask.display()))?;
    if let Some(d) = &a.overlay_dir {
        std::fs::create_dir_all(d).with_context(|| format!("creating {}", d.display()))?;
    }
    let renderer = Arc::new(super::open_renderer(crate::render::RenderPool::DEFAULT_SIZE)?);
    let estimator = Estimator::new(a.target.backbone.open()?, renderer.clone());
    let mut out = std::io::BufWriter::new(std::fs::File::create(&a.out).with_context(|| format!("writing {}", a.out.display()))?);

    let t = Instant::now();
    let pose = estimate(&estimator, &model, &first, &k, mask)?.with_context(|| format!("no pose in the first frame {} from its mask", frames[0].display()))?;
    let mut tracker = Tracker::new(model.clone(), renderer.clone(), &first, &k, pose, TrackerConfig::default()).map_err(anyhow::Error::msg)?;
    let mut counts = [1usize, 0, 0, 0]; // estimated, tracked, re-initialised, lost
    let mut tracked_ms = Vec::new();
    let emit = |out: &mut std::io::BufWriter<std::fs::File>, line: serde_json::Value| -> Result<()> {
        writeln!(out, "{line}")?;
        out.flush().with_context(|| format!("writing {}", a.out.display()))
    };
    emit(&mut out, pose_line(0, &frames[0], Some(&pose), 1.0, "estimated", t.elapsed().as_secs_f64() * 1e3))?;
    if let Some(d) = &a.overlay_dir {
        write_overlay(&first, &renderer, &model, &pose, &k, &d.join(frames[0].file_name().unwrap_or_default()).with_extension("png"))?;
    }
    for (i, path) in frames.iter().enumerate().skip(1) {
        let image = load_frame(path, &k)?;
        let t = Instant::now();
        let step = tracker.track(&image, &k).map_err(anyhow::Error::msg)?;
        let (pose, mode) = if !step.lost {
            tracked_ms.push(t.elapsed().as_secs_f64() * 1e3);
            counts[1] += 1;
            (Some(step.pose), "tracked")
        } else {
            match mask_near(&tracker, &image, &k).map(|m| estimate(&estimator, &model, &image, &k, m)).transpose()?.flatten() {
                Some(p) => {
                    tracker.restart(&image, &k, p).map_err(anyhow::Error::msg)?;
                    counts[2] += 1;
                    (Some(p), "reinitialised")
                }
                None => {
                    counts[3] += 1;
                    (None, "lost")
                }
            }
        };
        emit(&mut out, pose_line(i, path, pose.as_ref(), step.quality, mode, t.elapsed().as_secs_f64() * 1e3))?;
        if let (Some(d), Some(p)) = (&a.overlay_dir, &pose) {
            write_overlay(&image, &renderer, &model, p, &k, &d.join(path.file_name().unwrap_or_default()).with_extension("png"))?;
        }
    }
    tracked_ms.sort_by(f64::total_cmp);
    let median = tracked_ms.get(tracked_ms.len() / 2).copied().unwrap_or(f64::NAN);
    println!("{} frames: {} estimated, {} tracked (median {median:.1} ms), {} re-initialised, {} lost; wrote {}", frames.len(), counts[0], counts[1], counts[2], counts[3], a.out.display());
    Ok(())
}
