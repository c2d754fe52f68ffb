//! `b2tf bop eval`: BOP'19 AR of a results CSV and/or BOP'22 detection AP of a detections
//! JSON, as tables or JSON.

use crate::bop::detection_eval::{evaluate_detections, format_detection_report, DetectionReport};
use crate::bop::detection_gt::{dataset_objects, load_detection_gt, BoxType};
use crate::bop::detections::read_detections;
use crate::bop::eval_models::SymmetriesFrom;
use crate::bop::evaluate::evaluate;
use crate::bop::results_csv::read_results;
use crate::bop::scoring::{format_report, ArReport, Bop19Params};
use crate::render::RenderPool;
use anyhow::{Context, Result};
use clap::{ArgGroup, Args};
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
#[command(group(ArgGroup::new("input").required(true).multiple(true).args(["results", "detections"])))]
pub struct EvalArgs {
    /// Dataset root (models/, test/, test_targets_bop19.json).
    #[arg(long)]
    pub dataset: PathBuf,
    /// BOP results CSV (scene_id,im_id,obj_id,score,R,t,time): pose AR.
    #[arg(long)]
    pub results: Option<PathBuf>,
    /// Detections JSON (CNOS / BOP default-detections format): bbox AP, and segm AP when
    /// the detections carry a segmentation.
    #[arg(long)]
    pub detections: Option<PathBuf>,
    /// Ground-truth box for the bbox AP: amodal (whole silhouette, the toolkit's default)
    /// or modal (visible part).
    #[arg(long, default_value = "amodal")]
    pub bbox_type: BoxType,
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Print the report as JSON instead of a table (with both inputs:
    /// {"pose": …, "detection": …}).
    #[arg(long)]
    pub json: bool,
    /// VSD visibility tolerance in mm (BOP'19: 15; 5 for ITODD).
    #[arg(long, default_value_t = 15.0)]
    pub vsd_delta: f64,
    /// Not BOP: score up to the symmetries found in each mesh's shape and colours beside
    /// those models_info.json declares: on meshes without their textures, how much of
    /// what is lost are turns the shape cannot tell.
    #[arg(long)]
    pub mesh_symmetries: bool,
}

pub fn run(a: EvalArgs) -> Result<()> {
    let pose = a.results.as_deref().map(|csv| pose_ar(&a, csv)).transpose()?;
    let detection = a.detections.as_deref().map(|file| detection_ap(&a, file)).transpose()?;
    if a.json {
        let text = match (&pose, &detection) {
            (Some(p), None) => serde_json::to_string_pretty(p)?,
            (None, Some(d)) => serde_json::to_string_pretty(d)?,
            _ => serde_json::to_string_pretty(&serde_json::json!({ "pose": pose, "detection": detection }))?,
        };
        println!("{text}");
        return Ok(());
    }
    if let Some(p) = &pose {
        print!("{}", format_report(p));
    }
    if let (Some(d), Some(file)) = (&detection, &a.detections) {
        if pose.is_some() {
            println!();
        }
        print!("{}: {}", file.display(), format_detection_report(d));
    }
    Ok(())
}

fn pose_ar(a: &EvalArgs, csv: &Path) -> Result<ArReport> {
    // What the files hold that the toolkit accepts but is worth a look (rotations that are
    // rotations only roughly), printed once the progress bar is gone.
    let mut warnings = Vec::new();
    let results = read_results(csv, &mut warnings)?;
    let pool = super::open_renderer(RenderPool::DEFAULT_SIZE)?;
    let params = Bop19Params { vsd_delta: a.vsd_delta, symmetries: if a.mesh_symmetries { SymmetriesFrom::Mesh } else { SymmetriesFrom::Declared }, ..Default::default() };
    let pb = super::progress::bar(0, "targets");
    let progress = |done: usize, total: usize| {
        pb.set_length(total as u64);
        pb.set_position(done as u64);
    };
    let report = evaluate(&a.dataset, &a.split, &results, &pool, &params, &progress, &mut warnings)?;
    pb.finish_and_clear();
    for w in &warnings {
        eprintln!("warning: {w}");
    }
    if !a.json {
        let seconds: Vec<f64> = {
            let mut per_image: std::collections::BTreeMap<(u32, u32), f64> = Default::default();
            for r in &results {
                per_image.insert((r.scene_id, r.im_id), r.time);
            }
            per_image.into_values().collect()
        };
        let mean = if seconds.is_empty() { 0.0 } else { seconds.iter().sum::<f64>() / seconds.len() as f64 };
        println!("{}: {} estimates over {} images, mean {:.2} s per image", csv.display(), results.len(), seconds.len(), mean);
    }
    Ok(report)
}

fn detection_ap(a: &EvalArgs, file: &Path) -> Result<DetectionReport> {
    let dets = read_detections(file)?;
    let mut warnings = Vec::new();
    let images = load_detection_gt(&a.dataset, &a.split, a.bbox_type, &mut warnings)?;
    let objects = dataset_objects(&a.dataset, &images);
    // The ground truth's warnings name their files; the detections' are about this one.
    let mut dropped = Vec::new();
    let report = evaluate_detections(&images, &objects, &dets, a.bbox_type, &mut dropped).with_context(|| file.display().to_string())?;
    warnings.extend(dropped.iter().map(|w| format!("{}: {w}", file.display())));
    for w in &warnings {
        eprintln!("warning: {w}");
    }
    Ok(report)
}
