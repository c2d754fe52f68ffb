use crate::depth::DepthImage;
use crate::detect::confirm::{candidate_options, compared_choice, confirm, confirmation_needed, estimate_instances, Choice};
use crate::estimate::near_miss::{reviewed_near_miss, Candidate, Looked};
use crate::estimate::DepthScreen;
use crate::estimate::{Candidates, Detection, EstimateConfig, EstimateResult};
use crate::geometry::{Intrinsics, Pose};
use crate::onboard::ObjectModel;
use anyhow::{bail, Context, Result};
use rayon::prelude::*;
use serde_json::json;
use std::path::{Path, PathBuf};
use std::sync::Arc;

#[derive(clap::Args, Debug)]
pub struct EstimateArgs {
    #[command(flatten)]
    pub target: super::object_args::StoredObjectArgs,
    /// RGB image (PNG or JPEG).
    #[arg(long)]
    pub image: PathBuf,
    /// Camera JSON ({"K", "resolution"} or BOP {"cam_K"[, "width", "height"]}; a BOP
    /// scene_camera.json gives its first image's camera).
    #[arg(long)]
    pub camera: PathBuf,
    /// Depth image registered to --image (same size and camera): a 16-bit PNG whose
    /// values × --depth-scale are millimetres, 0 = no measurement. Each hypothesis is
    /// then fitted to the measured surface and judged on it (`estimate::depth_fit`).
    #[arg(long)]
    pub depth: Option<PathBuf>,
    /// Millimetres per --depth unit (BOP's depth_scale: 1 for millimetre PNGs, 0.1 for
    /// tenth-millimetre ones).
    #[arg(long, default_value_t = 1.0, requires = "depth")]
    pub depth_scale: f64,
    /// Object mask PNG, image-sized, nonzero = object. Repeat for candidate masks. With
    /// no --mask and no --box the detector finds the object (settings below).
    #[arg(long = "mask")]
    pub masks: Vec<PathBuf>,
    /// Box X,Y,W,H in pixels around the object, when there is no mask: the object is
    /// segmented inside it. Repeatable, and can be mixed with --mask.
    #[arg(long = "box", value_parser = parse_box)]
    pub boxes: Vec<[f64; 4]>,
    /// Whether a box's poses are moved back until their outline covers the box
    /// (`estimate::box_prior`): `auto`, for meshes without colours; `tight` (also the flag
    /// alone), always, for boxes drawn tight; `off`, never, for boxes drawn loose.
    #[arg(long, value_enum, default_value_t = crate::estimate::BoxPrior::default(), num_args = 0..=1, default_missing_value = "tight", requires = "boxes")]
    pub box_prior: crate::estimate::BoxPrior,
    /// Detector score of each mask then each box, in the order of --mask then --box
    /// (default 1.0).
    #[arg(long = "score")]
    pub scores: Vec<f32>,
    /// Skip render-guided re-correspondence.
    #[arg(long)]
    pub no_rrc: bool,
    /// RRC on every instance, also where the first PnP's inliers are sure enough to skip
    /// it (the paper's method; by default RRC runs where they are under 0.15 of the
    /// query's foreground patches).
    #[arg(long)]
    pub rrc_always: bool,
    /// With depth and no detections given: how the depth detector's candidates are
    /// estimated: light (at most 12 verification hypotheses refined; docs/detection.md) or
    /// full (as a given mask).
    #[arg(long, value_enum, default_value_t = crate::estimate::CandidateEffort::default(), requires = "depth")]
    pub candidate_effort: crate::estimate::CandidateEffort,
    /// Refiner after PnP/RRC: none (pass-through), silhouette-depth (scales the depth to
    /// the best silhouette IoU) or contour (aligns the outline with the mask).
    #[arg(long, value_enum, default_value_t = crate::estimate::RefinerKind::default())]
    pub refiner: crate::estimate::RefinerKind,
    #[command(flatten)]
    pub verify: super::verify_args::VerifyArgs,
    /// Templates kept by retrieval.
    #[arg(long, default_value_t = 125)]
    pub k: usize,
    /// Result JSON path.
    #[arg(long)]
    pub out: PathBuf,
    /// Also draw the estimate over the image into this PNG.
    #[arg(long)]
    pub overlay: Option<PathBuf>,
    #[command(flatten)]
    pub search: super::detect_cmd::SearchArgs,
}

pub fn load_mask(path: &Path) -> Result<image::GrayImage> {
    let img = image::open(path).with_context(|| format!("cannot read mask {}", path.display()))?;
    Ok(crate::masks::decode::binarise(&img))
}

fn parse_box(s: &str) -> Result<[f64; 4], String> {
    let v: Vec<f64> = s.split(',').map(|x| x.trim().parse::<f64>().map_err(|e| format!("{x:?}: {e}"))).collect::<Result<_, _>>()?;
    <[f64; 4]>::try_from(v).map_err(|v| format!("expected X,Y,W,H (4 numbers), got {}", v.len()))
}

/// The candidate detections: masks as given, each box as its mask proposals; with the
/// index (masks first, then boxes) of the `--mask` or `--box` each candidate came from.
fn detections(a: &EstimateArgs, image: &image::RgbImage) -> Result<Candidates> {
    let (width, height) = image.dimensions();
    let score = |i: usize| a.scores.get(i).copied().unwrap_or(1.0);
    let mut out = Candidates::default();
    for (i, p) in a.masks.iter().enumerate() {
        let mask = crate::masks::decode::check_size(load_mask(p)?, width, height).and_then(crate::masks::require_nonempty).with_context(|| format!("--mask {}", p.display()))?;
        out.push(i, [Detection::new(mask, score(i))]);
    }
    // Every box cut side by side (a cut is ~60 ms of one core), then reported in order, so
    // that the first bad box named is the first given.
    let cut: Vec<_> = a
        .boxes
        .par_iter()
        .map(|b| {
            let t = std::time::Instant::now();
            (crate::masks::box_masks(image, *b, crate::masks::BoxMask::Propose, &Default::default()), t.elapsed())
        })
        .collect();
    for (j, (b, (proposed, took))) in a.boxes.iter().zip(cut).enumerate() {
        let named = || format!("--box {}", b.map(|v| v.to_string()).join(","));
        let proposed = proposed.with_context(named)?;
        let area = proposed.bbox.area() as f64;
        let fills: Vec<String> = proposed.masks.iter().map(|m| format!("{:.0} %", m.as_raw().iter().filter(|&&v| v > 0).count() as f64 / area * 100.0)).collect();
        let n = fills.len();
        // The other sources are cut where the first proposal's pose does not fit it.
        let more = if proposed.later.is_some() { " (more where its pose does not fit it)" } else { "" };
        println!("box {j}: {n} mask proposal{} filling {} of the box{more}, {:.0} ms", if n == 1 { "" } else { "s" }, fills.join(", "), took.as_secs_f64() * 1e3);
        let index = a.masks.len() + j;
        out.push(index, Detection::from_box_masks(proposed, score(index)));
    }
    Ok(out)
}

/// The estimate from the detector's candidates: the best few instances (each a group of
/// overlapping detections, as the service groups them) estimated, and the one confirmed
/// best at its estimated pose answered (`detect::confirm`), with its confirmation score.
fn estimate_detected(
    a: &EstimateArgs,
    model: &ObjectModel,
    (image, depth): (&image::RgbImage, Option<&crate::depth::DepthImage>),
    k: &Intrinsics,
    estimator: &crate::estimate::Estimator,
    renderer: &crate::render::RenderPool,
    cfg: &EstimateConfig,
) -> Result<(EstimateResult, f32)> {
    let min_score = a.search.min_score;
    let options = candidate_options(&a.search.options());
    let found = super::detect_cmd::detect_object(model, (image, depth), k, &options, renderer)?;
    let refs: Vec<(&image::GrayImage, f64)> = found.iter().map(|d| (&d.mask, d.score as f64)).collect();
    let mut count = 0;
    // With depth, the object's segments are estimated in turn until one is sure, and the best
    // confirmed answered.
    let groups = crate::masks::group_instances(&refs, 0.5);
    let choice = compared_choice(depth.is_some(), groups.len(), 1, Choice::Confirmed { min_score });
    // Segments that cannot be the object are dropped before they are estimated.
    let screen = DepthScreen::of(image, depth, k, &model.mesh, renderer, min_score);
    let answered = estimate_instances(groups, 1, choice, |group| {
        let candidates: Vec<Detection> = group.iter().map(|&i| Detection::new(found[i].mask.clone(), found[i].score)).collect();
        let mut r = estimator.estimate_screened(model, (image, depth), k, &candidates, None, DepthScreen::as_screen(&screen), cfg)?;
        count += 1;
        let mut reviewed = false;
        let chosen = candidates[r.mask_index.unwrap_or(0)].clone();
        let confirmation = match r.pose {
            Some(pose) => {
                let c = confirm(image, depth, k, &model.mesh, &chosen.mask, &pose, renderer)?;
                println!("candidate {count} estimated, confirmed at its pose with {c:.3}");
                // Just short of an answer: a second look beside the depth's own views.
                let looked = match depth {
                    Some(d) => {
                        reviewed_near_miss(estimator, (image, d), k, Candidate { model, detection: &chosen, others: None, pose, confirmation: c }, confirmation_needed(min_score, true), cfg, renderer)?
                    }
                    None => Looked { pose, confirmation: c, reviewed: false, runner_up: None },
                };
                if looked.pose != pose {
                    r.runner_up = looked.runner_up;
                    println!("candidate {count} reviewed beside the views found in the depth, confirmed at its new pose with {:.3}", looked.confirmation);
                }
                (r.pose, reviewed) = (Some(looked.pose), looked.reviewed);
                Some(looked.confirmation)
            }
            None => None,
        };
        anyhow::Ok(((r, chosen, reviewed), confirmation))
    })?;
    match answered.kept.into_iter().next() {
        Some(((mut r, chosen, reviewed), c)) => {
            // The object's answer chosen: its pose judged again beside the depth's views
            // (unless it was reviewed as a near miss).
            if let (Some(d), Some(pose), false) = (depth, r.pose, reviewed) {
                let reviewed = estimator.reviewed_in_depth(model, (image, d), k, &chosen, None, pose, cfg)?;
                if let Some(view) = reviewed.view {
                    println!("answer reviewed beside the views found in the depth: depth view {view} judged better");
                    (r.pose, r.runner_up) = (Some(reviewed.pose), reviewed.runner_up);
                }
            }
            Ok((r, c.unwrap_or(0.0)))
        }
        None => bail!(
            "none of the detector's {} candidate(s) of {} was confirmed at its estimated pose (best {:.3}, needed {:.3} for --min-score {min_score}); give a --mask (or a --box), or lower --min-score",
            answered.tried,
            model.object_id,
            answered.best.unwrap_or(0.0),
            confirmation_needed(min_score, depth.is_some())
        ),
    }
}

pub fn run(a: EstimateArgs) -> Result<()> {
    let given = a.masks.len() + a.boxes.len();
    if a.scores.len() > given {
        bail!("{} --score values for {} --mask files and {} --box values", a.scores.len(), a.masks.len(), a.boxes.len());
    }
    let model = a.target.load()?;
    let image = image::open(&a.image).with_context(|| format!("cannot read image {}", a.image.display()))?.to_rgb8();
    let k = super::camera_file::load_camera_for(&a.camera, Some(image.dimensions()))?;
    let depth = a.depth.as_deref().map(|p| super::depth_file::load_depth(p, a.depth_scale, image.dimensions())).transpose()?;
    let renderer = Arc::new(super::open_renderer(crate::render::RenderPool::DEFAULT_SIZE)?);
    let backbone = a.target.backbone.open()?;
    let estimator = crate::estimate::Estimator::new(backbone, renderer.clone());
    let mut cfg = EstimateConfig {
        rrc: !a.no_rrc,
        refiner: a.refiner,
        verify: a.verify.config(),
        print: a.verify.print_config(),
        box_prior: a.box_prior,
        candidate_effort: a.candidate_effort,
        ..Default::default()
    }
    .with_rrc_always(a.rrc_always);
    cfg.retrieval.k = a.k;
    let (result, confirmation) = if given == 0 {
        let (r, c) = estimate_detected(&a, &model, (&image, depth.as_ref()), &k, &estimator, &renderer, &cfg)?;
        (r, Some(c))
    } else {
        let candidates = detections(&a, &image)?;
        let mut r = estimator.estimate_rgbd(&model, &image, depth.as_ref(), &k, &candidates.masks, None, &cfg)?;
        // Answered as the caller's --mask / --box index, not the proposal's.
        r.mask_index = candidates.owner_of(r.mask_index);
        (r, None)
    };
    let mut doc = result_json(&model, &result);
    if let (Some(c), Some(pose)) = (confirmation, doc["poses"].get_mut(0)) {
        pose["confirmation_score"] = json!(c);
    }
    std::fs::write(&a.out, serde_json::to_vec_pretty(&doc)?).with_context(|| format!("writing {}", a.out.display()))?;
    match &result.pose {
        Some(p) => println!("{}: {}", model.object_id, describe_pose(p, result.score)),
        None => println!("{}: no pose ({})", model.object_id, result.reason.as_deref().unwrap_or("unknown")),
    }
    if let Some(u) = &result.runner_up {
        println!("{}", describe_runner_up(u));
    }
    println!("total {:.0} ms; wrote {}", result.timings.total, a.out.display());
    if let (Some(path), Some(pose)) = (&a.overlay, &result.pose) {
        write_overlay(&image, depth.as_ref(), &renderer, &model, pose, &k, path)?;
        println!("overlay: {}", path.display());
    }
    Ok(())
}

pub fn describe_pose(p: &Pose, score: f32) -> String {
    let r = p.rotation_row_major();
    format!(
        "t = [{:.4}, {:.4}, {:.4}] m, R = [{:.3} {:.3} {:.3}; {:.3} {:.3} {:.3}; {:.3} {:.3} {:.3}], score {:.3}",
        p.translation.x, p.translation.y, p.translation.z, r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8], score
    )
}

/// The runner-up as one line: where it came from, how far, what it lost by; a close call said.
pub fn describe_runner_up(u: &crate::estimate::RunnerUp) -> String {
    let close = if u.close_call() { " — a close call: look again, or from elsewhere" } else { "" };
    format!("runner-up: {} ({:.2}·d from the answer) lost by {:.3}{close}", u.source, u.distance, u.margin)
}

/// PATH: the photo with the pose drawn on it; with depth, hidden where the measured surface
/// stands in front of it (`render::overlay::draw_overlay_seen`).
pub fn write_overlay(image: &image::RgbImage, depth: Option<&DepthImage>, renderer: &crate::render::RenderPool, model: &ObjectModel, pose: &Pose, k: &Intrinsics, path: &Path) -> Result<()> {
    let img = crate::render::overlay::draw_overlay_seen(image, depth, renderer, &model.mesh, pose, k, [0, 255, 0])?;
    img.save(path).with_context(|| format!("writing {}", path.display()))
}

/// RESULT.json: poses (R row-major, t in metres), diagnostics and stage timings.
pub fn result_json(model: &ObjectModel, r: &EstimateResult) -> serde_json::Value {
    let poses: Vec<serde_json::Value> = r
        .pose
        .iter()
        .map(|p| {
            json!({
                "object": model.object_id,
                "R": p.rotation_row_major(),
                "t": [p.translation.x, p.translation.y, p.translation.z],
                "score": r.score,
                "mask_index": r.mask_index,
                // As the service answers: the poses equal to this one (pose ∘ S), and
                // whether the turn about a continuous axis is arbitrary.
                "symmetries": model.symmetries,
                "arbitrary_rotation_about_axis": model.symmetries.as_ref().is_some_and(crate::geometry::symmetry::KnownSymmetries::arbitrary_rotation_about_axis),
                // The best pose judged on the photo that is another answer, as the service
                // answers it.
                "runner_up": r.runner_up.as_ref().map(crate::service::requests::RunnerUpOutput::from),
                "diagnostics": { "hypotheses": r.hypotheses },
            })
        })
        .collect();
    let mut doc = json!({ "poses": poses, "timings_ms": r.timings });
    if r.pose.is_none() {
        doc["reason"] = json!(r.reason);
        doc["diagnostics"] = json!({ "hypotheses": r.hypotheses });
    }
    doc
}
