//! `b2tf bench proposals`: what a box's mask proposals cost and how near each comes to the
//! object, on a BOP dataset's box-only detections beside its mask detections (the true
//! visible masks, in `ycbv-rgbd`): per source, ms of one core and IoU with the true mask;
//! per box, the wall time of `masks::propose` and the best proposal's IoU. Fast (seconds):
//! the loop for the cuts' speed and quality, before a `bop run` measures what reaches the
//! pose (tools/bench/real_boxes.sh).

use super::bench_estimate::median;
use crate::bop::dataset::{load_rgb, load_scene_cameras};
use crate::bop::detections::{read_detections, DetectionRecord};
use crate::bop::format::scene_dir;
use crate::masks::{mask_from_rle, mask_iou, propose, PixelBox, ProposalConfig};
use anyhow::{Context, Result};
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct BenchProposalsArgs {
    /// A BOP dataset folder (with `SPLIT/SCENE/rgb`, `scene_camera.json`).
    #[arg(long)]
    pub dataset: PathBuf,
    /// Box-only detections (default: DATASET/detections_box.json).
    #[arg(long)]
    pub boxes: Option<PathBuf>,
    /// Detections with masks, the reference each box's proposals are compared with (the
    /// one of the same object in the same image whose box overlaps most; default:
    /// DATASET/detections.json).
    #[arg(long)]
    pub masks: Option<PathBuf>,
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Proposal sources, as `bop run --box-proposals` takes them.
    #[arg(long, default_value = "cut,smooth-cut,wide-ring-cut")]
    pub proposals: ProposalConfig,
    /// Print a line per box too.
    #[arg(long)]
    pub per_box: bool,
}

/// What one source gave over all boxes.
#[derive(Default)]
struct SourceTally {
    ms: Vec<f64>,
    iou: Vec<f64>,
    declined: usize,
}

pub fn run(a: BenchProposalsArgs) -> Result<()> {
    let boxes = read_detections(&a.boxes.clone().unwrap_or_else(|| a.dataset.join("detections_box.json")))?;
    let masks = read_detections(&a.masks.clone().unwrap_or_else(|| a.dataset.join("detections.json")))?;
    let sources = a.proposals.sources();
    let mut tally: BTreeMap<String, SourceTally> = BTreeMap::new();
    let (mut wall, mut best, mut kept) = (Vec::new(), Vec::new(), 0usize);
    let mut cameras = BTreeMap::new();
    let mut images: BTreeMap<(u32, u32), image::RgbImage> = BTreeMap::new();
    for d in boxes.iter().filter(|d| d.segmentation.is_none()) {
        let scene = scene_dir(&a.dataset, &a.split, d.scene_id);
        if let std::collections::btree_map::Entry::Vacant(e) = cameras.entry(d.scene_id) {
            e.insert(load_scene_cameras(&scene)?);
        }
        if let std::collections::btree_map::Entry::Vacant(e) = images.entry((d.scene_id, d.image_id)) {
            let camera = cameras[&d.scene_id].get(&d.image_id).with_context(|| format!("scene {} has no camera for image {}", d.scene_id, d.image_id))?;
            e.insert(load_rgb(&camera.rgb_path)?);
        }
        let image = &images[&(d.scene_id, d.image_id)];
        let b = PixelBox::from_xywh(d.bbox, image.width(), image.height())?;
        let truth = reference(d, &masks).map(|rle| mask_from_rle(rle, image.width(), image.height())).transpose()?;
        // Each source alone, on one core, then all of them as a box gets them (side by side).
        for src in &sources {
            let t = Instant::now();
            let mask = src.propose(image, &b);
            let entry = tally.entry(src.kind().to_string()).or_default();
            entry.ms.push(t.elapsed().as_secs_f64() * 1e3);
            match (mask, &truth) {
                (Some(m), Some(truth)) => entry.iou.push(mask_iou(&m, truth)),
                (None, _) => entry.declined += 1,
                _ => {}
            }
        }
        let t = Instant::now();
        let proposals = propose(image, &b, &a.proposals);
        wall.push(t.elapsed().as_secs_f64() * 1e3);
        kept += proposals.len();
        if let Some(truth) = &truth {
            let ious: Vec<(String, f64)> = proposals.iter().map(|p| (p.kind.to_string(), mask_iou(&p.mask, truth))).collect();
            best.push(ious.iter().map(|p| p.1).fold(0.0, f64::max));
            if a.per_box {
                let row: Vec<String> = ious.iter().map(|(k, iou)| format!("{k} {iou:.2}")).collect();
                println!("scene {} image {} obj {}: {}", d.scene_id, d.image_id, d.obj_id, row.join(", "));
            }
        }
    }
    let n = wall.len();
    println!("{n} boxes, {:.2} proposals kept per box; propose() wall {:.0} ms mean, {:.0} ms median", kept as f64 / n.max(1) as f64, mean(&wall), median(&mut wall));
    println!("best proposal's IoU with the true mask: mean {:.3} over {} boxes with one", mean(&best), best.len());
    println!("| source | ms mean (one core) | ms median | IoU mean | declined |");
    println!("|---|---:|---:|---:|---:|");
    for (kind, mut t) in tally {
        println!("| {kind} | {:.0} | {:.0} | {:.3} | {} |", mean(&t.ms), median(&mut t.ms), mean(&t.iou), t.declined);
    }
    Ok(())
}

/// The mask detection of `d`'s object in its image whose box overlaps `d`'s most.
fn reference<'a>(d: &DetectionRecord, masks: &'a [DetectionRecord]) -> Option<&'a crate::masks::Rle> {
    masks
        .iter()
        .filter(|m| (m.scene_id, m.image_id, m.obj_id) == (d.scene_id, d.image_id, d.obj_id))
        .filter_map(|m| Some((crate::bop::coco_iou::box_iou(m.bbox, d.bbox), m.segmentation.as_ref()?)))
        .max_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, rle)| rle)
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}
