//! `b2tf track`: poses through a video given as a folder of frames or a video file
//! (src/video/). The first frame gets a full estimate from its mask (or, when no
//! mask is given, from the first of the detector's candidates confirmed at its estimated
//! pose); later frames
//! are tracked (track::TrackSession, as the service's streams), and a lost frame is
//! re-initialised by a full estimate of the object found by the colours its track learnt
//! (near its last pose, else anywhere in the frame). One JSON line per frame, written as
//! it is known.

use super::estimate_cmd::{load_mask, write_overlay};
use crate::detect::confirm::{candidate_options, candidates_tried};
use crate::estimate::Estimator;
use crate::geometry::Intrinsics;
use crate::onboard::ObjectModel;
use crate::track::{FrameDetection, SessionConfig, TrackMode, TrackOutcome, TrackSession};
use crate::video::{Frame, FrameSource};
use anyhow::{bail, Context, Result};
use serde_json::json;
use std::io::Write;
use std::path::PathBuf;
use std::sync::Arc;

#[derive(clap::Args, Debug)]
pub struct TrackArgs {
    #[command(flatten)]
    pub target: super::object_args::StoredObjectArgs,
    /// Folder of frames (PNG or JPEG), taken in name order, or an H.264 video file (.mp4,
    /// .m4v, .mov, or a raw Annex-B .h264 / .264 stream; feature `video`).
    #[arg(long)]
    pub video: PathBuf,
    /// Camera JSON ({"K", "resolution"} or BOP {"cam_K"[, "width", "height"]}; a BOP
    /// scene_camera.json gives its first image's camera).
    #[arg(long)]
    pub camera: PathBuf,
    /// The object's mask in the first frame (PNG, nonzero = object). Without it the
    /// detector finds the object in the first frame (settings as `b2tf detect`'s).
    #[arg(long)]
    pub mask: Option<PathBuf>,
    #[command(flatten)]
    pub search: super::detect_cmd::SearchArgs,
    /// Output: one JSON line per frame.
    #[arg(long)]
    pub out: PathBuf,
    /// Also write each frame with its pose drawn over it into this folder.
    #[arg(long)]
    pub overlay_dir: Option<PathBuf>,
    /// Below this outline agreement (0–1) a frame is lost and the object searched for
    /// again (the API's `lost_below`).
    #[arg(long, value_parser = super::verify_args::share)]
    pub lost_below: Option<f64>,
    /// RGB-D: a folder of 16-bit depth PNGs registered to the colour frames, the k-th in
    /// name order with the k-th frame (a BOP scene's depth/ beside its rgb/). Tracks are
    /// fitted to the measured surface and lost where it refutes them.
    #[arg(long, value_name = "DIR")]
    pub depth: Option<PathBuf>,
    /// Millimetres per --depth unit (BOP's depth_scale: 1 for millimetre PNGs, 0.1 for
    /// tenths).
    #[arg(long, default_value_t = 1.0, requires = "depth")]
    pub depth_scale: f64,
}

fn check_size(frame: &Frame, k: &Intrinsics) -> Result<()> {
    if frame.image.dimensions() != (k.width, k.height) {
        bail!("frame {} is {}×{} but the camera file says {}×{}", frame.name, frame.image.width(), frame.image.height(), k.width, k.height);
    }
    Ok(())
}

fn pose_line(frame: &Frame, o: &TrackOutcome) -> serde_json::Value {
    let pose = o.pose.as_ref();
    json!({
        "frame": frame.index,
        "file": frame.name,
        "R": pose.map(|p| p.rotation_row_major()),
        "t": pose.map(|p| [p.translation.x, p.translation.y, p.translation.z]),
        "quality": o.quality,
        "mode": o.mode.as_str(),
        "ms": o.ms,
        "reason": o.reason,
        "depth_fit": o.depth_fit,
    })
}

/// The depth frames of `dir`: its PNGs in name order.
fn depth_paths(dir: &std::path::Path) -> Result<Vec<PathBuf>> {
    let files: Vec<PathBuf> = crate::video::frame_paths(dir).with_context(|| "--depth")?.into_iter().filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("png"))).collect();
    if files.is_empty() {
        bail!("--depth: no PNG depth frames in {}", dir.display());
    }
    Ok(files)
}

pub fn run(a: TrackArgs) -> Result<()> {
    let model = Arc::new(a.target.load()?);
    let mut frames = FrameSource::open(&a.video)?;
    let first = frames.next().with_context(|| format!("no frame decoded from {}", a.video.display()))??;
    let k = super::camera_file::load_camera_for(&a.camera, Some(first.image.dimensions()))?;
    check_size(&first, &k)?;
    let renderer = Arc::new(super::open_renderer(crate::render::RenderPool::DEFAULT_SIZE)?);
    let depth_files = a.depth.as_deref().map(depth_paths).transpose()?;
    let first_detections = match &a.mask {
        Some(path) => {
            let mask = crate::masks::decode::check_size(load_mask(path)?, k.width, k.height).and_then(crate::masks::require_nonempty).with_context(|| format!("--mask {}", path.display()))?;
            vec![FrameDetection::given(model.object_id.clone(), mask, 1.0)]
        }
        None => {
            let depth = depth_files.as_ref().and_then(|f| f.first()).map(|p| super::depth_file::load_depth(p, a.depth_scale, first.image.dimensions())).transpose()?;
            detect_first(&model, (&first, depth.as_ref()), &k, &a.search, &renderer)?
        }
    };
    if let Some(d) = &a.overlay_dir {
        std::fs::create_dir_all(d).with_context(|| format!("creating {}", d.display()))?;
    }
    let estimator = Estimator::new(a.target.backbone.open()?, renderer.clone());
    let mut out = std::io::BufWriter::new(std::fs::File::create(&a.out).with_context(|| format!("writing {}", a.out.display()))?);
    // One object, searched for around its last pose for as long as the video lasts.
    let mut config = SessionConfig { drop_after_lost: usize::MAX, ..Default::default() };
    if let Some(q) = a.lost_below {
        config.tracker.lost_below = q;
    }
    let mut session = TrackSession::new(renderer.clone(), config);
    let resolve = |_: &str| Ok(model.clone());
    let mut counts = std::collections::BTreeMap::<&str, usize>::new();
    let mut tracked_ms = Vec::new();
    let mut first_detections = Some(first_detections);
    let mut n = 0;
    for frame in std::iter::once(Ok(first)).chain(frames) {
        let frame = frame?;
        check_size(&frame, &k)?;
        let (i, image) = (frame.index, &frame.image);
        n += 1;
        let depth = match &depth_files {
            Some(files) => {
                let path = files
                    .get(n - 1)
                    .with_context(|| format!("frame {}: no depth frame for it ({} in {})", frame.name, files.len(), a.depth.as_deref().unwrap_or_else(|| std::path::Path::new("")).display()))?;
                Some(super::depth_file::load_depth(path, a.depth_scale, image.dimensions()).with_context(|| format!("frame {}", frame.name))?)
            }
            None => None,
        };
        let detections = first_detections.take().unwrap_or_default();
        let (_, outcomes) = session.frame(Some(i as u64), image, depth.as_ref(), &k, detections, &resolve, &estimator).map_err(anyhow::Error::msg)?;
        // The first frame answers each candidate; the track is the one that started.
        let reasons: Vec<String> = outcomes.iter().filter_map(|o| o.reason.clone()).collect();
        let Some(o) = outcomes.into_iter().find(|o| o.track_id.is_some()) else {
            if i == 0 {
                bail!("no pose in the first frame {} from its {}: {}", frame.name, if a.mask.is_some() { "mask" } else { "detector's candidates" }, reasons.join("; "));
            }
            bail!("frame {}: the track ended", frame.name)
        };
        if o.mode == TrackMode::Tracked {
            tracked_ms.push(o.ms);
        }
        *counts.entry(o.mode.as_str()).or_default() += 1;
        writeln!(out, "{}", pose_line(&frame, &o))?;
        out.flush().with_context(|| format!("writing {}", a.out.display()))?;
        if let (Some(d), Some(p)) = (&a.overlay_dir, &o.pose) {
            write_overlay(image, depth.as_ref(), &renderer, &model, p, &k, &d.join(&frame.overlay_name))?;
        }
    }
    tracked_ms.sort_by(f64::total_cmp);
    let median = tracked_ms.get(tracked_ms.len() / 2).copied().unwrap_or(f64::NAN);
    let count = |m: TrackMode| counts.get(m.as_str()).copied().unwrap_or(0);
    println!(
        "{} frames: {} estimated, {} tracked (median {median:.1} ms), {} re-initialised, {} lost; wrote {}",
        n,
        count(TrackMode::Estimated),
        count(TrackMode::Tracked),
        count(TrackMode::Reinitialised),
        count(TrackMode::Lost),
        a.out.display()
    );
    Ok(())
}

/// The object's candidates in the first frame from the detector, below `--min-score`:
/// the track starts from the first one confirmed at its estimated pose (`detect::confirm`).
fn detect_first(
    model: &ObjectModel,
    (first, depth): (&Frame, Option<&crate::depth::DepthImage>),
    k: &Intrinsics,
    search: &super::detect_cmd::SearchArgs,
    renderer: &crate::render::RenderPool,
) -> Result<Vec<FrameDetection>> {
    let found = super::detect_cmd::detect_object(model, (&first.image, depth), k, &candidate_options(&search.options()), renderer).with_context(|| format!("first frame {}", first.name))?;
    Ok(found.into_iter().take(candidates_tried(1)).map(|d| FrameDetection::candidate(d.object_id, d.mask, d.score, search.min_score, depth.is_some())).collect())
}
