//! `b2tf bop run|eval|synth`: BOP datasets in, BOP results CSV and scores out.

use crate::bop::detections::{read_detections, DetectionIndex};
use crate::bop::model_path;
use crate::bop::run::{run as run_targets, DetectionSource, RunOptions};
use crate::bop::synth::{synth, SynthOptions};
use crate::estimate::EstimateConfig;
use crate::eval::scenes::SceneConfig;
use crate::geometry::symmetry::{KnownSymmetries, SymmetrySource, MM_TO_M};
use crate::mesh::{load_mesh, Units};
use crate::onboard::ObjectModel;
use crate::render::RenderPool;
use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use std::collections::HashSet;
use std::path::PathBuf;
use std::sync::Arc;

#[derive(Subcommand, Debug)]
pub enum BopCommand {
    /// Estimate every target of a BOP split from its detections (a file, or found by the
    /// detector); write the BOP results CSV.
    Run(Box<RunArgs>),
    /// Score a results CSV with the BOP'19 metrics (VSD, MSSD, MSPD; AR), and/or a
    /// detections JSON with the BOP'22 2D detection / segmentation AP (COCO).
    Eval(super::bop_eval_cmd::EvalArgs),
    /// Generate a BOP test dataset and a detections file from a BOP models folder.
    Synth(SynthArgs),
}

#[derive(Args, Debug)]
pub struct RunArgs {
    #[command(flatten)]
    pub backbone: super::backbone_args::BackboneArgs,
    /// Dataset root (holding models/, test/ and test_targets_bop19.json).
    #[arg(long)]
    pub dataset: PathBuf,
    /// Detections in the BOP / CNOS default-detections JSON. Without it, the training-free
    /// detector finds each image's targets itself (`b2tf detect`; settings below).
    #[arg(long)]
    pub detections: Option<PathBuf>,
    #[command(flatten)]
    pub search: super::detect_cmd::SearchArgs,
    /// With the detector: also write what it found as a default-detections JSON (for
    /// `b2tf bop eval --detections`).
    #[arg(long)]
    pub detections_out: Option<PathBuf>,
    /// Results CSV; images already in it are skipped (resume).
    #[arg(long)]
    pub out: PathBuf,
    #[arg(long)]
    pub no_rrc: bool,
    /// RRC on every instance, also where the first PnP's inliers are sure enough to skip
    /// it (the paper's method; by default RRC runs where they are under 0.15 of the
    /// query's foreground patches).
    #[arg(long)]
    pub rrc_always: bool,
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Object store for the dataset's onboarded objects (default:
    /// sqlite://<folder of --out>/b2tf-objects.db; object ids are obj_NNNNNN).
    #[arg(long)]
    pub store: Option<String>,
    /// Refiner after PnP/RRC: none (pass-through), silhouette-depth (scales the depth to
    /// the best silhouette IoU) or contour (aligns the outline with the mask).
    #[arg(long, value_enum, default_value_t = crate::estimate::RefinerKind::default())]
    pub refiner: crate::estimate::RefinerKind,
    #[command(flatten)]
    pub verify: super::verify_args::VerifyArgs,
    /// Memory for loaded objects, MB (least recently used ones are dropped beyond it).
    #[arg(long, default_value_t = 4000)]
    pub cache_mb: u64,
    /// Box-only detections: several mask proposals chosen among by their poses
    /// (`propose`), one segmentation inside the box (`segment`), or the filled box.
    #[arg(long, default_value = "propose")]
    pub box_mask: crate::masks::BoxMask,
    /// With `--box-mask propose`: the proposals' sources, comma-separated (cut,
    /// smooth-cut, wide-ring-cut, ellipse, fill).
    #[arg(long, default_value = "cut,smooth-cut,wide-ring-cut")]
    pub box_proposals: crate::masks::ProposalConfig,
    /// Whether a box's poses are moved back until their outline covers the box
    /// (`estimate::box_prior`): `auto`, for meshes without colours; `tight` (also the flag
    /// alone), always, for boxes drawn tight; `off`, never, for boxes drawn loose.
    #[arg(long, value_enum, default_value_t = crate::estimate::BoxPrior::default(), num_args = 0..=1, default_missing_value = "tight")]
    pub box_prior: crate::estimate::BoxPrior,
    /// RGB-D: each image's depth (`depth/`, with its camera's `depth_scale`) fits and
    /// judges the hypotheses (`estimate::depth_fit`).
    #[arg(long)]
    pub depth: bool,
    /// With --depth: each box also gets a mask proposal from the depth (surfaces split at
    /// depth edges, the support plane removed; `masks::depth_proposal`).
    #[arg(long, requires = "depth")]
    pub depth_proposals: bool,
    /// With depth and no detections given: how the depth detector's candidates are
    /// estimated: light (at most 12 verification hypotheses refined; docs/detection.md) or
    /// full (as a given mask).
    #[arg(long, value_enum, default_value_t = crate::estimate::CandidateEffort::default(), requires = "depth")]
    pub candidate_effort: crate::estimate::CandidateEffort,
    /// Threads an image's instances are estimated on side by side, with --detections; the
    /// detector's candidates with --depth are screened on them and estimated on them object
    /// by object (in turn where objects share a place); 1: in turn [default: the cores, at
    /// least 2]
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..=256))]
    pub instance_threads: Option<u16>,
}

#[derive(Args, Debug)]
pub struct SynthArgs {
    /// BOP models folder: obj_NNNNNN.ply in mm (textures beside them), optional models_info.json.
    #[arg(long)]
    pub models: PathBuf,
    /// Output dataset root.
    #[arg(long)]
    pub out: PathBuf,
    #[arg(long, default_value_t = 20)]
    pub images: usize,
    /// Object instances per image: N, or MIN,MAX for a count drawn per image (at most 8).
    #[arg(long, value_parser = parse_count_range, default_value = "3")]
    pub objects_per_image: (usize, usize),
    /// Object diameter as a share of the image height: MIN,MAX.
    #[arg(long, value_parser = super::bench_scenes::parse_range, default_value = "0.10,0.40")]
    pub fill: (f64, f64),
    /// The objects to estimate, as BOP ids (e.g. 1,2,8): only they are targets and get
    /// detections; the folder's other models stand in the scenes as distractors.
    #[arg(long, value_delimiter = ',')]
    pub targets: Option<Vec<u32>>,
    /// Copy the models without their textures: bare shape in the scenes and for whatever
    /// onboards them from the dataset.
    #[arg(long)]
    pub untextured: bool,
    /// A BOP dataset of real frames (e.g. ../shared/data/empty-rgbd) to draw each image
    /// over: one of its photos in place of the procedural clutter, its depth behind the
    /// objects in place of the flat wall.
    #[arg(long)]
    pub backgrounds: Option<PathBuf>,
    /// Place each object beside one already placed (touching or overlapping a little), as
    /// parts stand on a bench or in a bin: a box around one takes in its neighbours.
    #[arg(long)]
    pub clustered: bool,
    #[arg(long, default_value_t = 0.3)]
    pub max_occlusion: f64,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Only the true masks, no degraded copies.
    #[arg(long)]
    pub no_degraded: bool,
    /// No wrongly labelled detections.
    #[arg(long)]
    pub no_distractors: bool,
    /// Write the renderer's exact depth instead of what a Kinect-class depth camera
    /// measures (noise growing with distance, shadows, holes, steps: `depth::sensor`).
    #[arg(long)]
    pub exact_depth: bool,
}

pub fn run(cmd: BopCommand) -> Result<()> {
    match cmd {
        BopCommand::Run(a) => run_cmd(*a),
        BopCommand::Eval(a) => super::bop_eval_cmd::run(a),
        BopCommand::Synth(a) => synth_cmd(a),
    }
}

fn run_cmd(a: RunArgs) -> Result<()> {
    if a.detections.is_some() && a.detections_out.is_some() {
        anyhow::bail!("--detections-out writes what the detector finds; with --detections given there is nothing to write");
    }
    let given = a.detections.as_ref().map(|p| read_detections(p).map(DetectionIndex::new)).transpose()?;
    for path in std::iter::once(&a.out).chain(&a.detections_out) {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        }
    }
    let search = a.search.options();
    crate::detect::check_options(&search)?;
    let backbone = a.backbone.open()?;
    let pool = Arc::new(super::open_renderer_for(RenderPool::DEFAULT_SIZE, targeted_objects(&a.dataset))?);
    let estimator = crate::estimate::Estimator::new(backbone.clone(), pool.clone());
    let url = a.store.clone().unwrap_or_else(|| format!("sqlite://{}", a.out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(std::path::Path::new(".")).join("b2tf-objects.db").display()));
    let store = crate::store::open(&url)?;
    // Each object is checked (onboarded if missing or stale) once, then served from the
    // shared LRU cache, so a dataset with many objects stays within the memory budget.
    let models = crate::store::ModelCache::new(store.clone(), a.cache_mb * 1_000_000);
    let mut checked: HashSet<u32> = HashSet::new();
    // The dataset's own symmetries, where it has a models_info.json.
    let given_symmetries = if a.dataset.join(crate::bop::format::MODELS_INFO).exists() { crate::bop::eval_models::declared_symmetries(&a.dataset)? } else { Default::default() };
    let mut model = |obj_id: u32| -> Result<Arc<ObjectModel>> {
        let id = format!("obj_{obj_id:06}");
        if checked.insert(obj_id) {
            let mesh = load_mesh(&model_path(&a.dataset, obj_id), Some(Units::Mm))?;
            let mut m = super::cached_model(&id, &mesh, store.as_ref(), backbone.as_ref(), &pool, Default::default())?;
            // The dataset's own symmetries, where it declares them, over those found.
            if let Some(given) = given_symmetries.get(&obj_id) {
                let known = KnownSymmetries { source: SymmetrySource::ModelsInfo, symmetries: given.scaled(MM_TO_M) };
                if m.symmetries.as_ref() != Some(&known) {
                    m.symmetries = Some(known);
                    store.put(&m, true)?;
                }
            }
            models.invalidate(&id);
        }
        Ok(models.get(&id)?)
    };
    let estimate = EstimateConfig {
        rrc: !a.no_rrc,
        refiner: a.refiner,
        verify: a.verify.config(),
        print: a.verify.print_config(),
        box_prior: a.box_prior,
        depth_proposals: a.depth_proposals,
        candidate_effort: a.candidate_effort,
        ..Default::default()
    }
    .with_rrc_always(a.rrc_always);
    let opts = RunOptions {
        split: a.split.clone(),
        estimate,
        box_mask: a.box_mask,
        proposals: a.box_proposals.clone(),
        depth: a.depth,
        instance_threads: a.instance_threads.map_or_else(|| crate::parallel::instance_threads(1), usize::from),
        ..Default::default()
    };
    let pb = super::progress::bar(0, "images");
    let progress = |done: usize, total: usize| {
        pb.set_length(total as u64);
        pb.set_position(done as u64);
    };
    let mut found = Vec::new();
    let source = match &given {
        Some(index) => DetectionSource::File(index),
        None => DetectionSource::Detector { pool: &pool, options: search, found: &mut found },
    };
    let s = run_targets(&a.dataset, source, &a.out, &estimator, &mut model, &opts, &progress)?;
    pb.finish_and_clear();
    if given.is_none() {
        println!("the detector found {} objects in {} images", found.len(), s.images);
    }
    if let Some(path) = &a.detections_out {
        crate::bop::detections::write_detections(path, &found).with_context(|| format!("writing {}", path.display()))?;
        println!("detections: {}", path.display());
    }
    println!(
        "{} images estimated ({} already in {}), {} targets ({} instances requested): {} estimates written; {} targets without a detection, {} unusable detections, {} instances without a pose",
        s.images,
        s.images_done_before,
        a.out.display(),
        s.targets,
        s.instances_requested,
        s.estimates_written,
        s.targets_without_detection,
        s.unusable_detections,
        s.instances_without_pose
    );
    for (msg, n) in &s.failures {
        println!("  {n} × {msg}");
    }
    Ok(())
}

/// How many objects the dataset's targets name (0 where they cannot be read: the run
/// reports why when it reads them).
fn targeted_objects(dataset: &std::path::Path) -> usize {
    crate::bop::load_targets(dataset).map(|t| t.iter().map(|t| t.obj_id).collect::<HashSet<u32>>().len()).unwrap_or(0)
}

/// `N` or `MIN,MAX` (1 ≤ MIN ≤ MAX): a count of instances per image.
fn parse_count_range(s: &str) -> Result<(usize, usize), String> {
    let parse = |x: &str| x.trim().parse::<usize>().map_err(|e| format!("{x:?}: {e}"));
    let (lo, hi) = match s.split_once(',') {
        Some((a, b)) => (parse(a)?, parse(b)?),
        None => {
            let n = parse(s)?;
            (n, n)
        }
    };
    if lo == 0 || lo > hi {
        return Err(format!("need N or MIN,MAX with 1 ≤ MIN ≤ MAX, got {s:?}"));
    }
    Ok((lo, hi))
}

fn synth_cmd(a: SynthArgs) -> Result<()> {
    let pool = super::open_renderer(RenderPool::DEFAULT_SIZE)?;
    let (objects_per_image, most) = a.objects_per_image;
    let objects_per_image_max = if most > objects_per_image { most } else { 0 };
    let scene = SceneConfig {
        images: a.images,
        objects_per_image,
        objects_per_image_max,
        fill_range: a.fill,
        max_occlusion: a.max_occlusion,
        clustered: a.clustered,
        seed: a.seed,
        depth_sensor: super::depth_sensor(a.exact_depth),
        ..Default::default()
    };
    let s =
        synth(&a.models, &a.out, &SynthOptions { scene, degraded: !a.no_degraded, distractors: !a.no_distractors, targets: a.targets, untextured: a.untextured, backgrounds: a.backgrounds }, &pool)?;
    println!(
        "wrote a BOP dataset to {}: objects {:?} (targets {:?}), {} images, {} instances; {} detections in {} (as boxes in {})",
        a.out.display(),
        s.objects,
        s.targets,
        s.images,
        s.instances,
        s.detections,
        s.detections_path.display(),
        s.box_detections_path.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    /// The renderers of a run keep as many meshes as its targets name objects.
    #[test]
    fn targeted_objects_are_the_distinct_ids_of_the_targets() {
        let dir = tempfile::tempdir().unwrap();
        assert_eq!(super::targeted_objects(dir.path()), 0, "no targets file");
        let target = |obj: u32, im: u32| format!(r#"{{"scene_id": 0, "im_id": {im}, "obj_id": {obj}, "inst_count": 1}}"#);
        let targets = [target(1, 1), target(2, 1), target(2, 2), target(5, 2)].join(", ");
        std::fs::write(dir.path().join(crate::bop::format::TEST_TARGETS), format!("[{targets}]")).unwrap();
        assert_eq!(super::targeted_objects(dir.path()), 3);
    }
}
