//! `b2tf bop synth`: a complete BOP test dataset made from a BOP models folder (PLY in mm,
//! optional `models_info.json`), plus a detections file in the CNOS default-detections
//! format, so that `bop run` and `bop eval` can be exercised on any objects.
//!
//! Detections per target instance: its true visible mask with score 1.0; with `degraded`,
//! one imperfect copy (eroded, dilated or shifted) scoring 0.4–0.8; with `distractors`, per
//! image one detection that names an object wrongly (another instance's mask, or a blob
//! where nothing is) scoring 0.1–0.5. The wrong ones are what mask selection must reject.
//! The same detections as boxes only (no segmentation) go to `detections_box.json`: what a
//! user's 2D detector hands over.
//!
//! With `targets`, only those objects are targets (in `test_targets_bop19.json` and the
//! detections); the others still stand in the scenes, in the ground truth and in front of
//! the targets, as distractors nobody searches for. With `untextured`, the models are
//! copied without their textures, so the scenes and whatever onboards them see bare shape.
//! With `backgrounds` (a BOP dataset of real frames, e.g. `../shared/data/empty-rgbd`),
//! each image is drawn over one of its photos, its measured depth behind the objects.

use super::dataset::{load_depth_mm, load_scene_cameras, load_split_gt, load_targets, model_path};
use super::detections::{write_detections, DetectionRecord};
use super::format::{MODELS_INFO, TEST_SPLIT};
use super::scene_dataset::{generate_dataset_over, SCENE_ID};
use super::synth_masks::{area, morph, shift};
use crate::eval::scenes::{Background, SceneConfig};
use crate::masks::rle::Rle;
use crate::mesh::procedural::Rng;
use crate::mesh::{load_mesh, Mesh, Units};
use crate::render::RenderPool;
use anyhow::{bail, Context, Result};
use image::{GrayImage, Luma};
use std::path::{Path, PathBuf};

/// The detections file `synth` writes, relative to the dataset root.
pub const DETECTIONS_FILE: &str = "detections_synth.json";
/// The same detections as boxes alone, relative to the dataset root.
pub const BOX_DETECTIONS_FILE: &str = "detections_box.json";

#[derive(Clone, Debug)]
pub struct SynthOptions {
    pub scene: SceneConfig,
    pub degraded: bool,
    pub distractors: bool,
    /// The objects to estimate (`None`: all); the rest are distractors in the scenes.
    pub targets: Option<Vec<u32>>,
    /// Copy the models without their textures (the PLY's `TextureFile` line dropped).
    pub untextured: bool,
    /// A BOP dataset of real frames to draw the scenes over (its test split's photos and
    /// depth); `None`: procedural clutter and a flat wall.
    pub backgrounds: Option<PathBuf>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct SynthSummary {
    pub objects: Vec<u32>,
    pub images: usize,
    pub instances: usize,
    pub detections: usize,
    pub detections_path: PathBuf,
    pub box_detections_path: PathBuf,
    /// The objects that are targets (all of `objects` unless `targets` was given).
    pub targets: Vec<u32>,
}

/// BOP object ids of the `obj_<id:06>.ply` files in a models folder, ascending.
pub fn model_ids(models: &Path) -> Result<Vec<u32>> {
    let mut ids = Vec::new();
    for e in std::fs::read_dir(models).with_context(|| format!("reading {}", models.display()))? {
        let name = e?.file_name();
        let name = name.to_string_lossy();
        if let Some(id) = name.strip_prefix("obj_").and_then(|s| s.strip_suffix(".ply")).and_then(|s| s.parse::<u32>().ok()) {
            ids.push(id);
        }
    }
    ids.sort_unstable();
    if ids.is_empty() {
        bail!("{}: no BOP models (obj_NNNNNN.ply) in this folder", models.display());
    }
    Ok(ids)
}

/// Copies the models (PLY files, their textures: every `obj_*` file; only the PLY files,
/// bare, when `untextured`) and the models_info entries of those objects into
/// `out/models/`, then generates the scenes and detections.
pub fn synth(models: &Path, out: &Path, opts: &SynthOptions, pool: &RenderPool) -> Result<SynthSummary> {
    let ids = model_ids(models)?;
    let targets = match &opts.targets {
        None => ids.clone(),
        Some(t) => {
            if t.is_empty() {
                bail!("no target objects given");
            }
            if let Some(missing) = t.iter().find(|id| !ids.contains(id)) {
                bail!("target object {missing} is not among the models in {} ({ids:?})", models.display());
            }
            t.clone()
        }
    };
    let out_models = out.join("models");
    std::fs::create_dir_all(&out_models).with_context(|| format!("creating {}", out_models.display()))?;
    for e in std::fs::read_dir(models)? {
        let e = e?;
        let name = e.file_name().to_string_lossy().into_owned();
        if !name.starts_with("obj_") || !e.file_type()?.is_file() {
            continue;
        }
        let to = out_models.join(&name);
        if opts.untextured {
            if name.ends_with(".ply") {
                let bytes = std::fs::read(e.path()).with_context(|| format!("reading {}", e.path().display()))?;
                std::fs::write(&to, without_texture(&bytes)).with_context(|| format!("writing {}", to.display()))?;
            }
        } else {
            std::fs::copy(e.path(), &to).with_context(|| format!("copying {} to {}", e.path().display(), to.display()))?;
        }
    }
    copy_models_info(models, out, &ids)?;
    let objects: Vec<(u32, Mesh)> = ids.iter().map(|&id| Ok((id, load_mesh(&model_path(out, id), Some(Units::Mm))?))).collect::<Result<_>>()?;
    let backgrounds = opts.backgrounds.as_deref().map(load_backgrounds).transpose()?.unwrap_or_default();
    let summary = generate_dataset_over(&objects, &opts.scene, pool, out, &backgrounds)?;
    if opts.targets.is_some() {
        keep_targets(out, &targets)?;
    }
    let detections = make_detections(out, &targets, opts)?;
    let detections_path = out.join(DETECTIONS_FILE);
    write_detections(&detections_path, &detections)?;
    let boxes: Vec<DetectionRecord> = detections.into_iter().map(|d| DetectionRecord { segmentation: None, ..d }).collect();
    let box_detections_path = out.join(BOX_DETECTIONS_FILE);
    write_detections(&box_detections_path, &boxes)?;
    Ok(SynthSummary { objects: ids, images: summary.images, instances: summary.instances, detections: boxes.len(), detections_path, box_detections_path, targets })
}

/// A PLY file's bytes without its header's `comment TextureFile` line (the rest, binary
/// bodies included, unchanged).
fn without_texture(ply: &[u8]) -> Vec<u8> {
    let header_end = ply.windows(10).position(|w| w == b"end_header").unwrap_or(0);
    let mut out = Vec::with_capacity(ply.len());
    let mut start = 0;
    while start < header_end {
        let end = ply[start..].iter().position(|&b| b == b'\n').map_or(ply.len(), |i| start + i + 1);
        let line = String::from_utf8_lossy(&ply[start..end]);
        let mut words = line.split_whitespace();
        if !(words.next() == Some("comment") && words.next().is_some_and(|w| w.eq_ignore_ascii_case("TextureFile"))) {
            out.extend_from_slice(&ply[start..end]);
        }
        start = end;
    }
    out.extend_from_slice(&ply[start.min(ply.len())..]);
    out
}

/// Every frame of a BOP dataset's test split: its photo and, where its depth file exists,
/// its depth in metres.
fn load_backgrounds(root: &Path) -> Result<Vec<Background>> {
    let split = root.join(TEST_SPLIT);
    let mut scenes: Vec<PathBuf> =
        std::fs::read_dir(&split).with_context(|| format!("backgrounds: reading {}", split.display()))?.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.is_dir()).collect();
    scenes.sort();
    let mut out = Vec::new();
    for scene in scenes {
        for camera in load_scene_cameras(&scene)?.into_values() {
            let rgb = image::open(&camera.rgb_path).with_context(|| format!("background {}", camera.rgb_path.display()))?.to_rgb8();
            let depth = if camera.depth_path.exists() {
                let (w, h, mm) = load_depth_mm(&camera.depth_path, camera.depth_scale)?;
                if (w, h) != rgb.dimensions() {
                    bail!("background {}: depth is {w}x{h}, the photo {}x{}", camera.depth_path.display(), rgb.width(), rgb.height());
                }
                Some(mm.into_iter().map(|v| v / 1000.0).collect())
            } else {
                None
            };
            out.push(Background::new(rgb, depth).with_context(|| format!("background {}", camera.rgb_path.display()))?);
        }
    }
    if out.is_empty() {
        bail!("backgrounds: no frames in {}", split.display());
    }
    Ok(out)
}

/// Rewrites the dataset's test targets keeping only `targets`' objects.
fn keep_targets(dataset: &Path, targets: &[u32]) -> Result<()> {
    let kept: Vec<_> = load_targets(dataset)?.into_iter().filter(|t| targets.contains(&t.obj_id)).collect();
    if kept.is_empty() {
        bail!("no image holds any of the target objects {targets:?}: more images or objects per image");
    }
    super::scene_write::write_test_targets(dataset, &kept)
}

/// The source's models_info entries of the copied objects (symmetries included); objects
/// it lacks are measured by the scene writer.
fn copy_models_info(models: &Path, out: &Path, ids: &[u32]) -> Result<()> {
    let src = models.join("models_info.json");
    if !src.exists() {
        return Ok(());
    }
    let text = std::fs::read_to_string(&src).with_context(|| format!("reading {}", src.display()))?;
    let all: serde_json::Map<String, serde_json::Value> = serde_json::from_str(&text).with_context(|| format!("{}: not a JSON object keyed by object id", src.display()))?;
    let kept: serde_json::Map<String, serde_json::Value> = all.into_iter().filter(|(k, _)| k.parse::<u32>().is_ok_and(|id| ids.contains(&id))).collect();
    let dst = out.join(MODELS_INFO);
    std::fs::write(&dst, serde_json::to_string_pretty(&kept)?).with_context(|| format!("writing {}", dst.display()))
}

fn record(im_id: u32, obj_id: u32, mask: &GrayImage, score: f64) -> DetectionRecord {
    let rle = Rle::encode(mask);
    let bbox = rle.bbox().map_or([0.0; 4], |b| b.map(|v| v as f64));
    DetectionRecord { scene_id: SCENE_ID, image_id: im_id, obj_id, bbox, score, time: 0.0, segmentation: Some(rle) }
}

/// Detections of the instances of `ids` (the targets); distractors in the scene get none.
fn make_detections(dataset: &Path, ids: &[u32], opts: &SynthOptions) -> Result<Vec<DetectionRecord>> {
    // Ground truth just written from exact rotations: nothing to warn about.
    let images = load_split_gt(dataset, TEST_SPLIT, &mut Vec::new())?;
    let mut rng = Rng::new(opts.scene.seed ^ 0xDE7E_C710);
    let mut out = Vec::new();
    for img in &images {
        let mut masks = Vec::new();
        for inst in &img.instances {
            let mask = image::open(&inst.mask_visib_path).with_context(|| format!("reading {}", inst.mask_visib_path.display()))?.to_luma8();
            // BOP'19 targets are the instances at least 10 % visible; others get no detection.
            if inst.visib_fract.unwrap_or(1.0) < 0.1 || area(&mask) == 0 {
                continue;
            }
            // A distractor object's mask may still be named as a target below, as a
            // detector confusing the two would.
            if !ids.contains(&inst.obj_id) {
                masks.push((inst.obj_id, mask));
                continue;
            }
            out.push(record(img.im_id, inst.obj_id, &mask, 1.0));
            if opts.degraded {
                let bad = degrade(&mask, &mut rng);
                if area(&bad) > 0 {
                    out.push(record(img.im_id, inst.obj_id, &bad, rng.range(0.4, 0.8)));
                }
            }
            masks.push((inst.obj_id, mask));
        }
        if opts.distractors {
            let wrong_id = ids[(rng.next_u64() % ids.len() as u64) as usize];
            let other = masks.iter().find(|(id, _)| *id != wrong_id);
            let mask = match other {
                Some((_, m)) => m.clone(),
                None => blob(img.cam.width, img.cam.height, &mut rng),
            };
            out.push(record(img.im_id, wrong_id, &mask, rng.range(0.1, 0.5)));
        }
    }
    Ok(out)
}

/// Eroded, dilated or shifted by 4–15 % of the mask's size.
fn degrade(mask: &GrayImage, rng: &mut Rng) -> GrayImage {
    let side = (area(mask) as f64).sqrt();
    let r = (side * rng.range(0.04, 0.15)).round().max(1.0);
    match rng.next_u64() % 3 {
        0 => morph(mask, r as u32, false),
        1 => morph(mask, r as u32, true),
        _ => {
            let a = rng.range(0.0, std::f64::consts::TAU);
            shift(mask, (r * 1.5 * a.cos()).round() as i64, (r * 1.5 * a.sin()).round() as i64)
        }
    }
}

/// An elliptical blob somewhere in the image: a detection of nothing.
fn blob(w: u32, h: u32, rng: &mut Rng) -> GrayImage {
    let (cx, cy) = (rng.range(0.2, 0.8) * w as f64, rng.range(0.2, 0.8) * h as f64);
    let (rx, ry) = (rng.range(0.03, 0.12) * h as f64, rng.range(0.03, 0.12) * h as f64);
    GrayImage::from_fn(w, h, |x, y| {
        let (dx, dy) = ((x as f64 - cx) / rx, (y as f64 - cy) / ry);
        Luma([if dx * dx + dy * dy <= 1.0 { 255 } else { 0 }])
    })
}
