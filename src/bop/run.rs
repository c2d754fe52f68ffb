//! `b2tf bop run`: every target of a BOP split through the estimator, with that image's
//! detections of that object (from a detections file, or found by the training-free
//! detector), into the BOP results CSV.
//!
//! Per target (image, object, `inst_count`): the object's detections in the image are
//! grouped into instances by mask overlap (`masks::instances`); box-only detections are
//! segmented inside their box (`masks::segment`); the `inst_count` best groups are
//! estimated, each group's masks being the candidates of the paper's multi-mask selection.
//! Without a detections file the detector finds the candidates, and a few more than
//! `inst_count` are estimated; those confirmed at their estimated pose
//! (`detect::confirm`) are kept, best first, their confirmation being the row's score.
//! `time` is the wall time of the whole image (decoding included), on every row of it.
//! Results are appended image by image, and images already in the CSV are skipped, so an
//! interrupted run resumes where it stopped.

use super::dataset::{load_rgb, load_scene_cameras, load_targets, ImageCamera};
use super::detections::{DetectionIndex, DetectionRecord};
use super::format::{scene_dir, TargetRecord};
use super::results_csv::{done_images, ResultRow, ResultsWriter};
use crate::detect::compared::{answer_objects, reviewed, Comparison, ObjectCandidates};
use crate::detect::confirm::{candidate_options, confirm, confirmation_needed, one_per_place, Choice};
use crate::detect::{detect, DetectOptions, Target};
use crate::estimate::candidates::representative;
use crate::estimate::near_miss::{reviewed_near_miss, Candidate, Looked};
use crate::estimate::{Candidates, Detection, EstimateConfig, EstimateError, Estimator};
use crate::estimate::{CoarseCheck, DepthScreen, Screen};
use crate::geometry::Pose;
use crate::masks::OtherMasks;
use crate::masks::{group_instances, BoxMask};
use crate::onboard::ObjectModel;
use crate::render::RenderPool;
use anyhow::{Context, Result};
use image::GrayImage;
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Instant;

#[derive(Clone, Debug)]
pub struct RunOptions {
    pub split: String,
    pub estimate: EstimateConfig,
    /// Masks of one object overlapping their group's best mask at least this much are
    /// treated as candidates for the same instance.
    pub same_instance_iou: f64,
    /// How box-only detections become masks, and the proposals' sources.
    pub box_mask: BoxMask,
    pub proposals: crate::masks::ProposalConfig,
    /// Each image's depth (`depth/` beside `rgb/`, with its camera's `depth_scale`) goes to
    /// the estimator with it.
    pub depth: bool,
    /// Threads an image's instances are estimated on side by side (a file's detections; the
    /// detector's candidates go in turn, until enough are sure).
    pub instance_threads: usize,
}

impl Default for RunOptions {
    fn default() -> Self {
        Self { split: "test".into(), estimate: EstimateConfig::default(), same_instance_iou: 0.5, box_mask: BoxMask::Propose, proposals: Default::default(), depth: false, instance_threads: 1 }
    }
}

/// What a run did; targets that could not be estimated are counted, not fatal.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct RunSummary {
    pub images: usize,
    /// Images found in the CSV already and skipped.
    pub images_done_before: usize,
    pub targets: usize,
    /// Sum of `inst_count` over the targets run.
    pub instances_requested: usize,
    pub estimates_written: usize,
    /// Targets without any detection of their object in their image.
    pub targets_without_detection: usize,
    /// Detections that could not be used (bad size, empty mask), each counted.
    pub unusable_detections: usize,
    /// Instances asked for (`inst_count`) without a pose written: fewer candidates than
    /// instances, no pose from the estimator, or (own detections) none confirmed.
    pub instances_without_pose: usize,
    /// Estimator complaints about the input, by message, e.g. a detection the estimator refused.
    pub failures: BTreeMap<String, usize>,
}

/// An instance's pose with the candidate group it was estimated from and the index of its
/// mask among the group's candidates.
struct Estimated {
    pose: Pose,
    /// Its candidate group and the index of the mask it was estimated from there.
    group: Vec<usize>,
    mask: usize,
    /// Whether it was reviewed in the depth already (a near miss: `estimate::near_miss`).
    reviewed: bool,
}

/// One instance's answer: what was estimated, its score (the confirmation with the
/// detector's candidates, else the estimator's) and the mask it was estimated from.
type Answer = (Estimated, f32, GrayImage);

/// Where each image's detections come from.
pub enum DetectionSource<'a> {
    /// A default-detections file (CNOS's, or `b2tf detect`'s), indexed.
    File(&'a DetectionIndex),
    /// The training-free detector, run on each image for its targets' objects; what it
    /// found is appended to `found` (as a default-detections file would hold it).
    Detector { pool: &'a RenderPool, options: DetectOptions, found: &'a mut Vec<DetectionRecord> },
}

/// Runs the split's targets; `model` returns the onboarded object for a BOP object id
/// (loading or onboarding it on first use); `progress(done, total)` is called per image.
pub fn run(
    dataset: &Path,
    detections: DetectionSource,
    out_csv: &Path,
    estimator: &Estimator,
    model: &mut dyn FnMut(u32) -> Result<Arc<ObjectModel>>,
    opts: &RunOptions,
    progress: &dyn Fn(usize, usize),
) -> Result<RunSummary> {
    let targets = load_targets(dataset)?;
    let mut by_image: BTreeMap<(u32, u32), Vec<TargetRecord>> = BTreeMap::new();
    for t in targets {
        by_image.entry((t.scene_id, t.im_id)).or_default().push(t);
    }
    let done = if out_csv.exists() { done_images(out_csv)? } else { Default::default() };
    let mut writer = ResultsWriter::open(out_csv)?;
    let mut cameras: BTreeMap<u32, BTreeMap<u32, ImageCamera>> = BTreeMap::new();
    let mut summary = RunSummary::default();
    let total = by_image.len();
    let mut source = detections;
    for (n, ((scene_id, im_id), targets)) in by_image.into_iter().enumerate() {
        progress(n, total);
        if done.contains(&(scene_id, im_id)) {
            summary.images_done_before += 1;
            continue;
        }
        let scene_cameras = match cameras.entry(scene_id) {
            std::collections::btree_map::Entry::Occupied(e) => e.into_mut(),
            std::collections::btree_map::Entry::Vacant(e) => e.insert(load_scene_cameras(&scene_dir(dataset, &opts.split, scene_id))?),
        };
        let camera = scene_cameras.get(&im_id).with_context(|| format!("scene {scene_id}: no camera for image {im_id}, which {} lists", super::format::TEST_TARGETS))?;
        let started = Instant::now();
        let rgb = load_rgb(&camera.rgb_path)?;
        let depth = if opts.depth { Some(super::dataset::load_depth(camera, rgb.dimensions())?) } else { None };
        let detected;
        let detections = match &mut source {
            DetectionSource::File(index) => *index,
            DetectionSource::Detector { pool, options, found } => {
                let records = detect_targets((&rgb, depth.as_ref()), &camera.cam, (scene_id, im_id), &targets, model, pool, options, started)?;
                found.extend(records.iter().cloned());
                detected = DetectionIndex::new(records);
                &detected
            }
        };
        let detected_at = started.elapsed();
        let mut rows = Vec::new();
        // Every target's candidates first: each instance's refiner learns where the other
        // detections of the image are (it may be hidden there).
        // Cut on all cores: a box's proposals take tens of ms of one core each.
        let decoded_or_not: Vec<Vec<Result<Vec<Detection>, String>>> =
            targets.par_iter().map(|t| detections.get(scene_id, im_id, t.obj_id).par_iter().map(|d| d.candidates(&rgb, opts.box_mask, &opts.proposals)).collect()).collect();
        let mut decoded: Vec<Vec<Vec<Detection>>> = Vec::with_capacity(targets.len());
        for found in decoded_or_not {
            summary.unusable_detections += found.iter().filter(|c| c.is_err()).count();
            decoded.push(found.into_iter().filter_map(Result::ok).collect());
        }
        let compared = depth.is_some() && matches!(source, DetectionSource::Detector { .. });
        // The detector's own candidates are confirmed at their estimated poses, a few more
        // than wanted estimated so that confirmation can choose.
        let (choice, pool) = match &source {
            DetectionSource::Detector { pool, options, .. } => (Choice::Confirmed { min_score: options.min_score }, Some(*pool)),
            DetectionSource::File(_) => (Choice::Given, None),
        };
        let kind = if compared { OtherMasks::DepthSegments } else { OtherMasks::Detections };
        // Estimator complaints about the input, by message (instances may run side by side).
        let failures: Mutex<BTreeMap<String, usize>> = Mutex::default();
        // Complaints about the input are counted, not raised (the instance goes without).
        let refused = |e: EstimateError, ti: usize| -> Result<()> {
            match e {
                EstimateError::BadInput(msg) => {
                    *failures.lock().unwrap_or_else(|e| e.into_inner()).entry(msg).or_default() += 1;
                    Ok(())
                }
                e => Err(anyhow::Error::new(e).context(format!("scene {scene_id}, image {im_id}, object {}", targets[ti].obj_id))),
            }
        };
        let candidates_of = |ti: usize, group: &[usize]| Candidates::gather(group.iter().map(|&i| (i, decoded[ti][i].as_slice()))).masks;
        // A group's screen scores, one per candidate mask (`Estimator::screen_scores`).
        let screen_group = |ti: usize, m: &ObjectModel, group: &[usize], check: &dyn CoarseCheck| -> Result<Option<Vec<f32>>> {
            match estimator.screen_scores(m, (&rgb, depth.as_ref()), &camera.cam, &candidates_of(ti, group), check, &opts.estimate) {
                Ok(scores) => Ok(Some(scores)),
                Err(e) => refused(e, ti).map(|()| None),
            }
        };
        let others_of = |ti: usize, group: &[usize]| {
            let others = decoded.iter().enumerate().flat_map(|(tj, ms)| ms.iter().enumerate().filter(move |(i, _)| !(tj == ti && group.contains(i))).map(|(_, c)| representative(c).0));
            crate::masks::occluders(representative(&decoded[ti][group[0]]).0, others, kind, camera.cam.width, camera.cam.height)
        };
        // One instance (`group` of target `ti`'s candidates): its pose, score and mask, and
        // its confirmation with the detector's candidates.
        let estimate_group = |ti: usize, m: &ObjectModel, group: &[usize], screen: Screen<'_>| -> Result<(Option<Answer>, Option<f32>)> {
            let t = &targets[ti];
            let candidates = candidates_of(ti, group);
            let others = others_of(ti, group);
            let r = match estimator.estimate_screened(m, (&rgb, depth.as_ref()), &camera.cam, &candidates, others.as_ref(), screen, &opts.estimate) {
                Ok(r) => r,
                Err(e) => return refused(e, ti).map(|()| (None, None)),
            };
            // Where an estimate's time goes, per stage (box proposals against masks), and by
            // how much it beat its runner-up (whether a close call means the same from boxes).
            let runner_up_margin = r.runner_up.as_ref().map(|u| u.margin);
            tracing::debug!(scene_id, im_id, obj_id = t.obj_id, masks = candidates.len(), runner_up_margin = ?runner_up_margin, timings = ?r.timings, "estimated");
            let Some(pose) = r.pose else {
                return Ok((None, None));
            };
            let mask = &candidates[r.mask_index.unwrap_or(0)].mask;
            let estimated = |pose, reviewed| Estimated { pose, group: group.to_vec(), mask: r.mask_index.unwrap_or(0), reviewed };
            let Some(pool) = pool else {
                return Ok((Some((estimated(pose, false), r.score, mask.clone())), None));
            };
            let c = confirm(&rgb, depth.as_ref(), &camera.cam, &m.mesh, mask, &pose, pool).with_context(|| format!("scene {scene_id}, image {im_id}, object {}: confirming", t.obj_id))?;
            // The depth detector's candidate confirmed just short of an answer gets a second look.
            let looked = match (depth.as_ref().filter(|_| compared), choice) {
                (Some(d), Choice::Confirmed { min_score }) => {
                    let candidate = Candidate { model: m, detection: &candidates[r.mask_index.unwrap_or(0)], others: others.as_ref(), pose, confirmation: c };
                    reviewed_near_miss(estimator, (&rgb, d), &camera.cam, candidate, confirmation_needed(min_score, true), &opts.estimate, pool)?
                }
                _ => Looked { pose, confirmation: c, reviewed: false, runner_up: None },
            };
            let (pose, c) = (looked.pose, looked.confirmation);
            // For `tools/bench/candidate_ranks.py`.
            tracing::debug!(
                scene_id,
                im_id,
                obj_id = t.obj_id,
                x_mm = pose.translation.x * 1e3,
                y_mm = pose.translation.y * 1e3,
                z_mm = pose.translation.z * 1e3,
                rotation = ?pose.rotation_row_major(),
                cosine = r.hypotheses.iter().map(|h| h.top_template_cosine).fold(0.0f32, f32::max),
                estimate_score = r.score,
                screened = screen.best_score(),
                confirmation = c,
                "candidate confirmed"
            );
            Ok((Some((estimated(pose, looked.reviewed), c, mask.clone())), Some(c)))
        };
        let groups_of = |masks: &[Vec<Detection>]| group_instances(&masks.iter().map(|c| representative(c)).collect::<Vec<_>>(), opts.same_instance_iou);
        // The targets with candidates, their objects loaded (or onboarded) first.
        let mut work = Vec::new();
        for (ti, (t, masks)) in targets.iter().zip(&decoded).enumerate() {
            summary.targets += 1;
            summary.instances_requested += t.inst_count as usize;
            if masks.is_empty() {
                summary.targets_without_detection += 1;
                continue;
            }
            work.push((ti, model(t.obj_id)?));
        }
        let mut answers: Vec<(u32, usize, Vec<Answer>)> = work.iter().map(|(ti, _)| (targets[*ti].obj_id, targets[*ti].inst_count as usize, Vec::new())).collect();
        if choice == Choice::Given {
            // The file's instances are all answered: every target's estimated side by side.
            let jobs: Vec<_> = work.iter().enumerate().flat_map(|(n, w)| groups_of(&decoded[w.0]).into_iter().take(answers[n].1).map(move |g| (n, w, g))).collect();
            let owners: Vec<usize> = jobs.iter().map(|j| j.0).collect();
            let done = crate::parallel::ordered_map(jobs, opts.instance_threads, |(_, (ti, m), group)| estimate_group(*ti, m, &group, Screen::Off))?;
            for (owner, (estimated, _)) in owners.into_iter().zip(done) {
                answers[owner].2.extend(estimated);
            }
        } else {
            // The detector's candidates, screened with depth (those that cannot be their
            // object not estimated), compared across objects and estimated in turn until
            // enough are sure (`detect::compared`).
            let screens: Vec<Option<DepthScreen>> = work
                .iter()
                .map(|(_, m)| match (&source, compared) {
                    (DetectionSource::Detector { pool, options, .. }, true) => DepthScreen::of(&rgb, depth.as_ref(), &camera.cam, &m.mesh, pool, options.min_score),
                    _ => None,
                })
                .collect();
            let objects: Vec<ObjectCandidates> =
                work.iter().zip(&answers).zip(&screens).map(|(((ti, _), a), s)| ObjectCandidates { groups: groups_of(&decoded[*ti]), wanted: a.1, screened: s.is_some() }).collect();
            let how = Comparison { compared, choice, threads: opts.instance_threads };
            let answered = answer_objects(
                &objects,
                how,
                |n, d| representative(&decoded[work[n].0][d]).0,
                |n, group| screens[n].as_ref().map_or(Ok(None), |check| screen_group(work[n].0, &work[n].1, group, check)),
                |n, _, c| estimate_group(work[n].0, &work[n].1, &c.group, DepthScreen::scored(&screens[n], c.scores.as_deref())),
                |a| a.as_ref().map(|a| &a.2),
            )?;
            for (a, instances) in answers.iter_mut().zip(answered) {
                a.2 = instances.kept.into_iter().filter_map(|(p, _)| p).collect();
            }
        }
        for (msg, n) in failures.into_inner().unwrap_or_else(|e| e.into_inner()) {
            *summary.failures.entry(msg).or_default() += n;
        }
        // A row's score: the confirmation with the detector's candidates, else the estimator's.
        let wanted: Vec<usize> = answers.iter().map(|a| a.1).collect();
        let obj_ids: Vec<u32> = answers.iter().map(|a| a.0).collect();
        let per_object: Vec<Vec<(Estimated, f32)>> =
            if compared { one_per_place(answers.into_iter().map(|a| a.2).collect(), &wanted) } else { answers.into_iter().map(|a| a.2.into_iter().map(|(p, s, _)| (p, s)).collect()).collect() };
        // Which object each place holds is settled: the answers are looked at again beside
        // the depth's own views (`Estimator::reviewed_in_depth`).
        let per_object = match depth.as_ref().filter(|_| compared) {
            Some(d) => reviewed(per_object, opts.instance_threads, |n, e: Estimated| {
                if e.reviewed {
                    return Ok(e);
                }
                let (ti, m) = (work[n].0, &work[n].1);
                let r = estimator.reviewed_in_depth(m, (&rgb, d), &camera.cam, &candidates_of(ti, &e.group)[e.mask], others_of(ti, &e.group).as_ref(), e.pose, &opts.estimate)?;
                tracing::debug!(scene_id, im_id, obj_id = targets[ti].obj_id, view = r.view, moved_mm = (r.pose.translation - e.pose.translation).norm() * 1e3, "answer reviewed");
                Ok::<_, anyhow::Error>(Estimated { pose: r.pose, reviewed: true, ..e })
            })?,
            None => per_object,
        };
        for ((obj_id, wanted), poses) in obj_ids.into_iter().zip(wanted).zip(per_object) {
            summary.instances_without_pose += wanted.saturating_sub(poses.len());
            rows.extend(poses.into_iter().map(|(e, score)| ResultRow { scene_id, im_id, obj_id, score: score as f64, pose: e.pose, time: 0.0 }));
        }
        let seconds = started.elapsed().as_secs_f64();
        // Where the image's time went: detection (with decoding), and the rest (screens in
        // `detect::compared`'s log).
        tracing::debug!(scene_id, im_id, detect_s = detected_at.as_secs_f64(), estimate_s = seconds - detected_at.as_secs_f64(), "image phases");
        for r in &mut rows {
            r.time = seconds;
        }
        writer.append_image(&rows)?;
        summary.estimates_written += rows.len();
        summary.images += 1;
    }
    progress(total, total);
    Ok(summary)
}

/// The detector's findings of the targets' objects in one image, as detection records.
#[allow(clippy::too_many_arguments)]
fn detect_targets(
    (rgb, depth): (&image::RgbImage, Option<&crate::depth::DepthImage>),
    cam: &crate::geometry::Intrinsics,
    (scene_id, image_id): (u32, u32),
    targets: &[TargetRecord],
    model: &mut dyn FnMut(u32) -> Result<Arc<ObjectModel>>,
    pool: &RenderPool,
    options: &DetectOptions,
    started: Instant,
) -> Result<Vec<DetectionRecord>> {
    let models: Vec<(u32, Arc<ObjectModel>)> = targets.iter().map(|t| Ok((t.obj_id, model(t.obj_id)?))).collect::<Result<_>>()?;
    let shapes = models.iter().map(|(_, m)| m.shape_model_or_build(pool)).collect::<Result<Vec<_>, _>>()?;
    let detect_targets: Vec<Target> = models.iter().zip(&shapes).map(|((_, m), s)| Target { id: &m.object_id, shape: s, mesh: &m.mesh }).collect();
    // Instances wanted in all, so that a busy image keeps enough detections.
    let wanted: usize = targets.iter().map(|t| t.inst_count as usize).sum();
    // Candidates below the final threshold too: confirmation at the estimated pose decides.
    let options = DetectOptions { max_detections: options.max_detections.max(2 * wanted).min(crate::limits::MAX_DETECTIONS), ..candidate_options(options) };
    let report = detect(rgb, depth, cam, &detect_targets, &options, pool).with_context(|| format!("detecting in scene {scene_id}, image {image_id}"))?;
    let obj_of: BTreeMap<&str, u32> = models.iter().map(|(id, m)| (m.object_id.as_str(), *id)).collect();
    let time = started.elapsed().as_secs_f64();
    Ok(report
        .detections
        .iter()
        .map(|d| DetectionRecord { scene_id, image_id, obj_id: obj_of[d.object_id.as_str()], bbox: d.bbox, score: d.score as f64, time, segmentation: Some(crate::masks::Rle::encode(&d.mask)) })
        .collect())
}
