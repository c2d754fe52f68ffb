//! The one core behind both adapters (HTTP and gRPC): the object store and its
//! cache, the backbone, the render pool, the estimator and the onboarding operations. The
//! adapters only parse, call these methods and map `ServiceError` to their status codes.
//! Methods here block (rendering, features, PnP); async adapters call them on blocking
//! threads after taking a slot (estimates wait for one in `estimate_queue`; onboardings
//! beyond their limit are refused at once).

use super::detect_requests::DetectionOutput;
use super::error::{ErrorKind, ServiceError};
use super::operations::{OperationState, OperationStatus, Operations};
use super::requests::{EstimateRequest, EstimateResponse, InstanceResult, OnboardRequest, PoseOutput, RunnerUpOutput};
use crate::detect::compared::{answer_objects, reviewed, Comparison, ObjectCandidates};
use crate::detect::confirm::{candidate_options, confirm, confirmation_needed, one_per_place, Choice};
use crate::estimate::candidates::representative;
use crate::estimate::near_miss::{reviewed_near_miss, Candidate};
use crate::estimate::{Candidates, Detection, EstimateConfig, Estimator};
use crate::estimate::{CoarseCheck, DepthScreen, Screen};
use crate::features::Backbone;
use crate::geometry::ViewSampling;
use crate::masks::OtherMasks;
use crate::onboard::{onboard_profiled, OnboardConfig, OnboardError};
use crate::render::{RenderPool, RendererConfig};
use crate::store::{ModelCache, ObjectInfo, ObjectStore};
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Instant;

#[derive(Clone, Debug)]
pub struct CoreConfig {
    pub store_url: String,
    pub render_pool: usize,
    /// Objects' meshes each render context keeps uploaded (`RendererConfig::max_cached_meshes`).
    pub render_meshes: usize,
    /// Memory for loaded objects (LRU beyond it).
    pub cache_bytes: u64,
    /// Estimates (and detections) running at once; more wait in line.
    pub max_estimates: usize,
    /// Threads one request's instances are estimated on side by side (the caller's
    /// detections; the detector's candidates with depth are screened on them and estimated
    /// object by object, `detect::compared`).
    pub instance_threads: usize,
    /// Estimates waiting at most; more are refused (429 / RESOURCE_EXHAUSTED).
    pub queue_depth: usize,
    /// Longest an estimate waits in line before it is refused.
    pub queue_timeout: std::time::Duration,
    /// Onboardings running at once; more are refused the same way.
    pub max_onboardings: usize,
    /// Most crops in one backbone pass of the shared batching queue (0: no queue, every
    /// request calls the backbone itself).
    pub backbone_batch: usize,
    /// Longest a queued pass waits after its first request for more (0: none).
    pub backbone_max_wait: std::time::Duration,
    /// The backbone and, for an ONNX one, where it runs.
    pub backbone: crate::features::BackboneChoice,
    pub device: crate::features::Device,
    /// Serve a store another process writes: open it read-only, refuse onboard and delete.
    pub read_only: bool,
    /// Tracking sessions (HTTP sessions and gRPC streams) open at once; more are refused.
    pub max_track_sessions: usize,
    /// A tracking session with no frame for this long is closed.
    pub track_idle_timeout: std::time::Duration,
}

impl Default for CoreConfig {
    fn default() -> Self {
        Self {
            store_url: crate::store::default_url(),
            render_pool: RenderPool::DEFAULT_SIZE,
            render_meshes: RendererConfig::default().max_cached_meshes,
            cache_bytes: 4_000_000_000,
            max_estimates: 2,
            instance_threads: crate::parallel::instance_threads(2),
            queue_depth: 16,
            queue_timeout: std::time::Duration::from_secs(30),
            max_onboardings: 1,
            backbone_batch: 32,
            backbone_max_wait: std::time::Duration::ZERO,
            backbone: Default::default(),
            device: Default::default(),
            read_only: false,
            max_track_sessions: 8,
            track_idle_timeout: std::time::Duration::from_secs(60),
        }
    }
}

/// A taken slot, released on drop (it may travel to the thread doing the work).
pub struct Slot(Arc<AtomicUsize>);

impl Drop for Slot {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::AcqRel);
    }
}

fn take_slot(counter: &Arc<AtomicUsize>, max: usize) -> Option<Slot> {
    counter.fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| (n < max).then_some(n + 1)).ok().map(|_| Slot(counter.clone()))
}

pub struct Core {
    pub config: CoreConfig,
    pub(super) store: Arc<dyn ObjectStore>,
    pub(super) cache: Arc<ModelCache>,
    backbone: Arc<dyn Backbone>,
    /// The batching queue in front of the backbone, when configured (for its stats).
    queue: Option<Arc<crate::features::BatchingBackbone>>,
    pub(super) pool: Arc<RenderPool>,
    pub(super) estimator: Estimator,
    operations: Operations,
    pub(super) tracks: super::track_sessions::TrackSessions,
    pub(super) estimates: Arc<super::estimate_queue::EstimateQueue>,
    onboardings_running: Arc<AtomicUsize>,
    pub(super) thumbnails: super::thumbnails::Thumbnails,
}

impl Core {
    /// Opens the store, loads the backbone and starts the render pool.
    pub fn new(config: CoreConfig) -> Result<Self, ServiceError> {
        let store = if config.read_only { crate::store::open_read_only(&config.store_url)? } else { crate::store::open(&config.store_url)? };
        let inner = crate::features::open_backbone(&config.backbone, &config.device).map_err(|e| ServiceError::new(ErrorKind::Unavailable, format!("backbone {}: {e}", config.backbone)))?;
        let queue = (config.backbone_batch > 0).then(|| Arc::new(crate::features::BatchingBackbone::with_max_wait(inner.clone(), config.backbone_batch, config.backbone_max_wait)));
        let backbone: Arc<dyn Backbone> = match &queue {
            Some(q) => q.clone(),
            None => inner,
        };
        let pool = Arc::new(
            RenderPool::new(config.render_pool.max(1), RendererConfig { max_cached_meshes: config.render_meshes, ..RendererConfig::default() })
                .map_err(|e| ServiceError::new(ErrorKind::Unavailable, e.to_string()))?,
        );
        let estimator = Estimator::new(backbone.clone(), pool.clone());
        let cache = Arc::new(ModelCache::new(store.clone(), config.cache_bytes));
        let tracks = super::track_sessions::TrackSessions::new(config.max_track_sessions, config.track_idle_timeout);
        let estimates =
            super::estimate_queue::EstimateQueue::new(super::estimate_queue::QueueConfig { running: config.max_estimates.max(1), depth: config.queue_depth, timeout: config.queue_timeout });
        Ok(Self {
            config,
            store,
            cache,
            backbone,
            queue,
            pool,
            estimator,
            operations: Operations::default(),
            tracks,
            estimates,
            onboardings_running: Arc::new(AtomicUsize::new(0)),
            thumbnails: Default::default(),
        })
    }

    /// One render and one backbone pass, so the first request does not pay for shader
    /// compilation and allocation; readiness waits for it.
    pub fn warm_up(&self) -> Result<(), ServiceError> {
        let mesh = crate::mesh::procedural::textured_box([0.1, 0.06, 0.16], 3);
        let k = crate::geometry::Intrinsics::new(200.0, 200.0, 63.5, 63.5, 128, 128).map_err(|e| ServiceError::internal(e.to_string()))?;
        let pose = crate::geometry::views::view_pose(&nalgebra::Vector3::z(), 0.0, &nalgebra::Vector3::zeros(), 0.5);
        let r = self.pool.render(&mesh, &pose, &k, &Default::default()).map_err(|e| ServiceError::internal(e.to_string()))?;
        let size = self.backbone.identity().input_size;
        if let Some((crop, _)) = crate::features::crop_query(&r.rgb, &r.mask, 0.1, size) {
            self.backbone.extract(&[crop]).map_err(|e| ServiceError::internal(e.to_string()))?;
        }
        Ok(())
    }

    /// An object from the cache (the store on a miss), in a span of its own.
    pub(super) fn load(&self, id: &str) -> Result<Arc<crate::onboard::ObjectModel>, ServiceError> {
        Ok(self.fetch(id)?.0)
    }

    /// `load` for a request that will render the object (an estimate, a track). One just
    /// loaded, or whose mesh a render context no longer holds (more objects in use than
    /// `render_meshes`), is uploaded to the render pool on a thread of its own meanwhile:
    /// the upload (for a textured mesh mostly its texture's decode, about 40 ms for 2048²)
    /// then overlaps the request's feature extraction and retrieval instead of delaying its
    /// first render, and the texture is decoded once for all renderers rather than once each.
    pub(super) fn load_to_render(&self, id: &str) -> Result<Arc<crate::onboard::ObjectModel>, ServiceError> {
        let (model, loaded) = self.fetch(id)?;
        if loaded || self.pool.lacks(&model.mesh) {
            let (pool, model) = (self.pool.clone(), model.clone());
            let span = tracing::info_span!("render.prepare", object_id = id);
            let started = std::thread::Builder::new().name("render-prepare".into()).spawn(move || {
                if let Err(e) = span.in_scope(|| pool.prepare(&model.mesh)) {
                    // The request's own renders upload it again (and answer the error).
                    tracing::warn!(object_id = model.object_id, "uploading the mesh ahead of its renders failed: {e}");
                }
            });
            if let Err(e) = started {
                tracing::warn!("no thread to upload the mesh ahead of its renders: {e}");
            }
        }
        Ok(model)
    }

    fn fetch(&self, id: &str) -> Result<(Arc<crate::onboard::ObjectModel>, bool), ServiceError> {
        Ok(tracing::info_span!("store.get", object_id = id).in_scope(|| self.cache.fetch(id))?)
    }

    pub fn store_url(&self) -> String {
        self.store.url()
    }

    /// Drops cached objects that another process replaced or deleted in the store since
    /// they were loaded (`ModelCache::revalidate`); how many.
    pub fn revalidate_cache(&self) -> usize {
        self.cache.revalidate()
    }

    pub fn cache_stats(&self) -> crate::store::cache::CacheStats {
        self.cache.stats()
    }

    pub fn queue_stats(&self) -> Option<crate::features::batch_queue::QueueStats> {
        self.queue.as_ref().map(|q| q.stats())
    }

    pub fn render_mesh_uploads(&self) -> u64 {
        self.pool.mesh_uploads()
    }

    pub fn onboardings_running(&self) -> usize {
        self.onboardings_running.load(Ordering::Acquire)
    }

    pub fn list_objects(&self) -> Result<Vec<ObjectInfo>, ServiceError> {
        Ok(self.store.list()?)
    }

    pub fn get_object(&self, id: &str) -> Result<ObjectInfo, ServiceError> {
        Ok(self.store.info(id)?)
    }

    /// Removes the object; estimates already using it finish with their copy.
    pub fn delete_object(&self, id: &str) -> Result<(), ServiceError> {
        self.refuse_if_read_only("delete")?;
        if self.operations.running_for(id) {
            return Err(ServiceError::new(ErrorKind::AlreadyExists, format!("object {id:?} is being onboarded; cancel that operation first")));
        }
        self.store.delete(id)?;
        self.cache.invalidate(id);
        Ok(())
    }

    /// Writes are refused by a read-only server before any upload is decoded.
    fn refuse_if_read_only(&self, what: &str) -> Result<(), ServiceError> {
        if self.config.read_only {
            return Err(ServiceError::new(ErrorKind::PermissionDenied, format!("this server is read-only (--read-only / B2TF_READ_ONLY): it cannot {what} objects; do that with a writer on the same store ({}), e.g. `b2tf onboard --store URL` or a server without --read-only", self.store.url())));
        }
        Ok(())
    }

    /// Validates the upload and starts onboarding on its own thread; returns at once.
    pub fn start_onboard(&self, req: OnboardRequest, request_id: Option<&crate::telemetry::RequestId>) -> Result<OperationStatus, ServiceError> {
        self.refuse_if_read_only("onboard")?;
        crate::store::validate_id(&req.object_id)?;
        let views = ViewSampling { level: req.options.level, in_plane_steps: req.options.in_plane };
        views.validate().map_err(|e| ServiceError::invalid(format!("options: {e}")))?;
        req.options.pca.check(self.backbone.identity().local_dim as usize).map_err(|e| ServiceError::invalid(format!("options: {e}")))?;
        if !req.replace && self.store.exists(&req.object_id)? {
            return Err(ServiceError::new(ErrorKind::AlreadyExists, format!("object {:?} already exists (set replace to overwrite it)", req.object_id)));
        }
        if self.operations.running_for(&req.object_id) {
            return Err(ServiceError::new(ErrorKind::AlreadyExists, format!("object {:?} is already being onboarded", req.object_id)));
        }
        let staging = std::env::temp_dir().join(format!("b2tf-upload-{}-{}", std::process::id(), crate::store::unique_suffix()));
        std::fs::create_dir_all(&staging).map_err(|e| ServiceError::internal(format!("staging the upload: {e}")))?;
        let mesh = req.mesh.load(&staging);
        let _ = std::fs::remove_dir_all(&staging);
        let mesh = mesh?;
        let config = OnboardConfig { views, pca: req.options.pca, descriptors: req.options.descriptors, patch_rows: req.options.patch_rows, ..Default::default() };
        let total = (crate::geometry::icosphere(views.level).len() as u32 * views.in_plane_steps) as u64;
        // The slot is taken now (refusing at once) and held by the worker thread.
        let slot = take_slot(&self.onboardings_running, self.config.max_onboardings)
            .ok_or_else(|| ServiceError::new(ErrorKind::ResourceExhausted, format!("{} onboarding(s) already running; retry later", self.config.max_onboardings)))?;
        let op = self.operations.start(&req.object_id, total);
        let (backbone, pool, store, cache) = (self.backbone.clone(), self.pool.clone(), self.store.clone(), self.cache.clone());
        let status = op.status();
        let replace = req.replace;
        tracing::info!(operation = %op.id, object_id = %op.object_id, templates = total, "onboarding started");
        // The onboarding outlives the request that started it: its own root span, linked to
        // the request's, with the same request id in its log lines.
        let span = tracing::info_span!(parent: None, "onboarding", request_id = request_id.map(|r| r.as_str()), operation = %op.id, object_id = %op.object_id);
        span.follows_from(tracing::Span::current());
        std::thread::spawn(move || {
            let _entered = span.enter();
            let progress = |p: crate::onboard::Progress| op.done.store(p.templates_done as u64, Ordering::Relaxed);
            let result = onboard_profiled(&op.object_id, &mesh, &config, backbone.as_ref(), &pool, &progress, &op.cancel);
            if let Ok((_, profile)) = &result {
                tracing::info!(?profile, "onboarding stages");
            }
            let (state, error, info) = match result {
                Ok((model, _)) => match tracing::info_span!("store.put").in_scope(|| store.put(&model, replace)) {
                    Ok(info) => {
                        // A replaced object must not be served from the cache's old copy.
                        cache.invalidate(&op.object_id);
                        (OperationState::Succeeded, None, Some(info))
                    }
                    Err(e) => (OperationState::Failed, Some(e.to_string()), None),
                },
                Err(OnboardError::Cancelled) => (OperationState::Cancelled, None, None),
                Err(e) => (OperationState::Failed, Some(e.to_string()), None),
            };
            // The slot is free before anyone can see the operation end, so a client that
            // starts its next onboarding on seeing it finish is not refused.
            drop(slot);
            tracing::info!(state = ?state, error = error.as_deref(), "onboarding finished");
            op.finish(state, error, info);
        });
        Ok(status)
    }

    pub fn operation(&self, id: &str) -> Result<OperationStatus, ServiceError> {
        let op = self.operations.get(id).ok_or_else(|| ServiceError::not_found(format!("operation {id:?} not found")))?;
        Ok(op.status())
    }

    /// Asks a running onboarding to stop; nothing of it is stored.
    pub fn cancel_operation(&self, id: &str) -> Result<OperationStatus, ServiceError> {
        let op = self.operations.get(id).ok_or_else(|| ServiceError::not_found(format!("operation {id:?} not found")))?;
        op.cancel.store(true, Ordering::Relaxed);
        Ok(op.status())
    }

    /// At shutdown: cancels running onboardings (they store nothing) and waits up to
    /// `wait` for their threads to stop, so none is cut off mid-write by the exit.
    pub fn stop_onboardings(&self, wait: std::time::Duration) -> usize {
        let asked = self.operations.cancel_all();
        let t = Instant::now();
        while self.onboardings_running() > 0 && t.elapsed() < wait {
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        asked
    }

    /// Runs the pipeline for every object named by the detections, or for every instance
    /// the detector finds of the named objects. Blocking. Past `deadline` it stops before
    /// the next instance.
    pub fn estimate(&self, req: &EstimateRequest, deadline: Option<Instant>) -> Result<EstimateResponse, ServiceError> {
        let t0 = Instant::now();
        req.check_limits()?;
        let (image, k) = super::wire::decode_image(&req.image, &req.intrinsics)?;
        let depth = req.depth.as_ref().map(|d| d.decode(k.width, k.height)).transpose()?;
        tracing::debug!(width = k.width, height = k.height, detections = req.detections.len(), objects = req.objects.len(), "estimate request");
        let o = &req.options;
        if o.k == 0 || o.max_masks == 0 || o.instances_per_object == 0 {
            return Err(ServiceError::invalid("options: k, max_masks and instances_per_object must be positive"));
        }
        // The detector's findings are answered as they are (RLE), and their masks moved on.
        let (masks, detected) = if req.objects.is_empty() {
            (decode_masks(req, &image)?, None)
        } else {
            // Candidates below the caller's threshold too: confirmation decides.
            let report = self.run_detector((&image, depth.as_ref()), &k, &req.objects, &candidate_options(&req.detect), deadline)?;
            let outputs: Vec<DetectionOutput> = report.detections.iter().map(DetectionOutput::from).collect();
            let masks = report.detections.into_iter().map(|d| (d.object_id, vec![Detection::new(d.mask, d.score)])).collect();
            (masks, Some((outputs, report.reason)))
        };
        let ids: Vec<String> = masks.iter().map(|(id, _)| id.clone()).collect();
        let mut by_object: BTreeMap<&str, Vec<(usize, Vec<Detection>)>> = BTreeMap::new();
        for (i, ((_, candidates), id)) in masks.into_iter().zip(&ids).enumerate() {
            by_object.entry(id.as_str()).or_default().push((i, candidates));
        }
        // Every object must exist before any work starts.
        let models: BTreeMap<&str, _> = by_object.keys().map(|&id| Ok((id, self.load_to_render(id)?))).collect::<Result<_, ServiceError>>()?;
        let mut cfg = EstimateConfig { rrc: o.rrc, max_masks: o.max_masks, refiner: o.refiner, ..Default::default() }.with_rrc_always(o.rrc_always);
        cfg.retrieval.k = o.k;
        cfg.verify.enabled = o.verify;
        cfg.verify.templates = o.verify_templates;
        cfg.verify.spin_steps = o.spin_steps;
        cfg.verify.matched_templates = o.verify_matched;
        cfg.verify.nudge_degrees = o.nudge_degrees;
        cfg.verify.depth_views = o.depth_views;
        cfg.box_prior = o.box_prior;
        // The detector's candidates are confirmed at their estimated poses: a few more than
        // wanted are estimated, and the confirmed ones kept (`detect::confirm`).
        let choice = if detected.is_some() { Choice::Confirmed { min_score: req.detect.min_score } } else { Choice::Given };
        // The depth detector's candidates are compared (in turn until one is sure), and each
        // segment answered once across objects after every object's are in
        // (`detect::confirm::one_per_place`).
        let compared = depth.is_some() && detected.is_some();
        let kind = if compared { OtherMasks::DepthSegments } else { OtherMasks::Detections };
        // Instances estimated so far, for the deadline's message.
        let estimated = AtomicUsize::new(0);
        // One instance: its estimate and, for the detector's candidates, its confirmation.
        let past_deadline = || -> Result<(), ServiceError> {
            match deadline.is_some_and(|d| Instant::now() >= d) {
                true => Err(ServiceError::new(ErrorKind::DeadlineExceeded, format!("deadline passed after {} instance(s)", estimated.load(Ordering::Relaxed)))),
                false => Ok(()),
            }
        };
        let gather = |object_id: &str, group: &[usize]| {
            let dets = &by_object[object_id];
            Candidates::gather(group.iter().map(|&g| (dets[g].0, dets[g].1.as_slice())))
        };
        // A group's screen scores, one per candidate mask (`Estimator::screen_scores`).
        let screen_group = |object_id: &str, group: &[usize], check: &dyn CoarseCheck| -> Result<Vec<f32>, ServiceError> {
            past_deadline()?;
            Ok(self.estimator.screen_scores(&models[object_id], (&image, depth.as_ref()), &k, &gather(object_id, group).masks, check, &cfg)?)
        };
        // An instance's answer and its confirmation.
        let estimate_one = |object_id: &str, instance: usize, group: &[usize], screen: Screen<'_>| -> Result<(Answered, Option<f32>), ServiceError> {
            past_deadline()?;
            let model = &models[object_id];
            let gathered = gather(object_id, group);
            let candidates = &gathered.masks;
            let others = others_mask(&by_object, object_id, group, kind, k.width, k.height);
            let span = tracing::info_span!("instance", object_id, instance, masks = candidates.len());
            let mut r = span.in_scope(|| self.estimator.estimate_screened(model, (&image, depth.as_ref()), &k, candidates, others.as_ref(), screen, &cfg))?;
            estimated.fetch_add(1, Ordering::Relaxed);
            let confirmation = match (&r.pose, choice) {
                (Some(pose), Choice::Confirmed { .. } | Choice::Compared { .. }) => {
                    let mask = &candidates[r.mask_index.unwrap_or(0)].mask;
                    Some(
                        span.in_scope(|| confirm(&image, depth.as_ref(), &k, &model.mesh, mask, pose, &self.pool))
                            .map_err(|e| ServiceError::internal(format!("object {object_id:?}: confirming: {e}")))?,
                    )
                }
                _ => None,
            };
            // The depth detector's candidate confirmed just short of an answer gets a second look.
            let mut reviewed = false;
            let confirmation = match (r.pose, confirmation, depth.as_ref().filter(|_| compared)) {
                (Some(pose), Some(c), Some(d)) => {
                    let candidate = Candidate { model, detection: &candidates[r.mask_index.unwrap_or(0)], others: others.as_ref(), pose, confirmation: c };
                    let looked = span.in_scope(|| reviewed_near_miss(&self.estimator, (&image, d), &k, candidate, confirmation_needed(req.detect.min_score, true), &cfg, &self.pool))?;
                    if looked.pose != pose {
                        r.runner_up = looked.runner_up;
                    }
                    (r.pose, reviewed) = (Some(looked.pose), looked.reviewed);
                    Some(looked.confirmation)
                }
                _ => confirmation,
            };
            span.in_scope(|| tracing::debug!(found = r.pose.is_some(), score = r.score, confirmation, ms = r.timings.total, "instance estimated"));
            let result = InstanceResult {
                object_id: object_id.to_string(),
                instance,
                pose: r.pose.as_ref().map(PoseOutput::from),
                score: r.score,
                confirmation_score: confirmation,
                detection_index: gathered.owner_of(r.mask_index),
                reason: r.reason.clone(),
                diagnostics: serde_json::to_value(&r.hypotheses).unwrap_or_default(),
                timings_ms: r.timings.by_stage(),
                symmetries: model.symmetries.clone(),
                arbitrary_rotation_about_axis: InstanceResult::arbitrary_rotation(model.symmetries.as_ref()),
                runner_up: r.runner_up.as_ref().map(RunnerUpOutput::from),
            };
            let mask = candidates[r.mask_index.unwrap_or(0)].mask.clone();
            Ok((Answered { result, mask, group: group.to_vec(), index: r.mask_index.unwrap_or(0), reviewed }, confirmation))
        };
        let groups_of = |dets: &[(usize, Vec<Detection>)]| {
            let refs: Vec<(&image::GrayImage, f64)> = dets.iter().map(|(_, c)| representative(c)).collect();
            crate::masks::group_instances(&refs, 0.5)
        };
        let (answers, tried): (Vec<Vec<(InstanceResult, f32)>>, usize) = if choice == Choice::Given {
            // The caller's instances are all answered: every object's estimated side by side.
            let jobs: Vec<(&str, usize, Vec<usize>)> = by_object
                .iter()
                .flat_map(|(&object_id, dets)| groups_of(dets).into_iter().take(o.instances_per_object).enumerate().map(move |(instance, group)| (object_id, instance, group)))
                .collect();
            let owners: Vec<&str> = jobs.iter().map(|j| j.0).collect();
            let done = crate::parallel::ordered_map(jobs, self.config.instance_threads, |(object_id, instance, group)| estimate_one(object_id, instance, &group, Screen::Off))?;
            let tried = done.len();
            let mut answers: Vec<Vec<(InstanceResult, f32, image::GrayImage)>> = by_object.keys().map(|_| Vec::new()).collect();
            let slot: BTreeMap<&str, usize> = by_object.keys().enumerate().map(|(i, &id)| (id, i)).collect();
            for (owner, (a, _)) in owners.into_iter().zip(done) {
                answers[slot[owner]].push((a.result, 0.0, a.mask));
            }
            (answers.into_iter().map(|a| a.into_iter().map(|(r, c, _)| (r, c)).collect()).collect(), tried)
        } else {
            // The detector's candidates, screened with depth (those that cannot be their
            // object not estimated), compared across objects and estimated in turn until
            // enough are sure (`detect::compared`).
            let screens: Vec<Option<DepthScreen>> =
                by_object.keys().map(|id| if compared { DepthScreen::of(&image, depth.as_ref(), &k, &models[id].mesh, &self.pool, req.detect.min_score) } else { None }).collect();
            let ids: Vec<&str> = by_object.keys().copied().collect();
            let detections: Vec<&Vec<(usize, Vec<Detection>)>> = by_object.values().collect();
            let objects: Vec<ObjectCandidates> =
                detections.iter().zip(&screens).map(|(dets, s)| ObjectCandidates { groups: groups_of(dets), wanted: o.instances_per_object, screened: s.is_some() }).collect();
            let how = Comparison { compared, choice, threads: self.config.instance_threads };
            let answered = answer_objects(
                &objects,
                how,
                |n, d| representative(&detections[n][d].1).0,
                |n, group| screens[n].as_ref().map_or(Ok(None), |check| screen_group(ids[n], group, check).map(Some)),
                |n, instance, c| estimate_one(ids[n], instance, &c.group, DepthScreen::scored(&screens[n], c.scores.as_deref())),
                |t| Some(&t.mask),
            )?;
            let tried = answered.iter().map(|i| i.tried).sum();
            let answers: Vec<Vec<_>> = answered
                .into_iter()
                .map(|i| {
                    i.kept
                        .into_iter()
                        .map(|(mut a, c)| {
                            // `one_per_place` holds the mask beside the answer; nothing
                            // reads the answer's own after it (moved, not copied).
                            let mask = std::mem::take(&mut a.mask);
                            (a, c.unwrap_or(0.0), mask)
                        })
                        .collect()
                })
                .collect();
            // Which object each place holds is settled (`one_per_place`): with depth the
            // answers are looked at again beside the depth's own views
            // (`Estimator::reviewed_in_depth`), unless reviewed already as near misses.
            let per_object = match depth.as_ref().filter(|_| compared) {
                Some(d) => reviewed(one_per_place(answers, &vec![o.instances_per_object; by_object.len()]), self.config.instance_threads, |n, mut a: Answered| {
                    past_deadline()?;
                    let Some(pose) = a.result.pose.as_ref().map(|p| crate::geometry::Pose::from_row_major(&p.r, p.t)).filter(|_| !a.reviewed) else { return Ok(a) };
                    let candidates = gather(ids[n], &a.group).masks;
                    let others = others_mask(&by_object, ids[n], &a.group, kind, k.width, k.height);
                    let reviewed = self.estimator.reviewed_in_depth(&models[ids[n]], (&image, d), &k, &candidates[a.index], others.as_ref(), pose, &cfg)?;
                    tracing::debug!(object_id = ids[n], view = reviewed.view, "answer reviewed");
                    if reviewed.view.is_some() {
                        // The runner-up and close call now compare the answer the review
                        // chose; the diagnostics stay the estimate's (what it judged).
                        a.result.pose = Some(PoseOutput::from(&reviewed.pose));
                        a.result.runner_up = reviewed.runner_up.as_ref().map(RunnerUpOutput::from);
                    }
                    Ok::<_, ServiceError>(a)
                })?,
                None => answers.into_iter().map(|a| a.into_iter().map(|(t, c, _)| (t, c)).collect()).collect(),
            };
            (per_object.into_iter().map(|a| a.into_iter().map(|(a, c)| (a.result, c)).collect()).collect(), tried)
        };
        let mut results = Vec::new();
        for kept in answers {
            // Instances are numbered in the answer's order, best confirmed first.
            results.extend(kept.into_iter().enumerate().map(|(n, (r, _))| InstanceResult { instance: n, ..r }));
        }
        let unconfirmed = tried - results.len();
        let (detections, mut reason) = detected.unwrap_or_default();
        if choice != Choice::Given && results.is_empty() && reason.is_none() {
            reason = Some(format!(
                "none of the {unconfirmed} candidate(s) estimated was confirmed at its pose with a score of {:.3} or more (for min_score {})",
                confirmation_needed(req.detect.min_score, compared),
                req.detect.min_score
            ));
        }
        let overlay_png = if o.overlay { Some(draw_answer(&image, depth.as_ref(), &k, &results, &models, &self.pool)?.into()) } else { None };
        Ok(EstimateResponse { results, detections, reason, overlay_png, total_ms: t0.elapsed().as_secs_f64() * 1e3 })
    }
}

/// An instance's answer, the mask it was estimated from and where that came from (its
/// candidate group, the mask's index among the group's candidates).
struct Answered {
    result: InstanceResult,
    mask: image::GrayImage,
    group: Vec<usize>,
    index: usize,
    /// Whether it was reviewed in the depth already (a near miss: `estimate::near_miss`).
    reviewed: bool,
}

/// The photo with every answered pose drawn on it (`render::overlay`), one colour per
/// result, hidden where the request's depth stands in front of it, as PNG.
fn draw_answer(
    image: &image::RgbImage,
    depth: Option<&crate::depth::DepthImage>,
    k: &crate::geometry::Intrinsics,
    results: &[InstanceResult],
    models: &BTreeMap<&str, Arc<crate::onboard::ObjectModel>>,
    pool: &RenderPool,
) -> Result<Vec<u8>, ServiceError> {
    const COLOURS: [[u8; 3]; 6] = [[0, 230, 118], [255, 196, 0], [0, 176, 255], [255, 64, 129], [178, 255, 89], [224, 64, 251]];
    let _span = tracing::info_span!("overlay", results = results.len()).entered();
    let mut out = image.clone();
    for (i, r) in results.iter().enumerate() {
        let (Some(p), Some(model)) = (&r.pose, models.get(r.object_id.as_str())) else { continue };
        let pose = crate::geometry::Pose::from_row_major(&p.r, p.t);
        out =
            crate::render::overlay::draw_overlay_seen(&out, depth, pool, &model.mesh, &pose, k, COLOURS[i % COLOURS.len()]).map_err(|e| ServiceError::internal(format!("drawing the overlay: {e}")))?;
    }
    super::thumbnails::png(&out)
}

/// The request's detections as (object id, candidates): a mask as it is, a box without a
/// mask as the box's mask proposals (`masks::proposals`).
fn decode_masks(req: &EstimateRequest, image: &image::RgbImage) -> Result<Vec<(String, Vec<Detection>)>, ServiceError> {
    let _span = tracing::info_span!("masks", detections = req.detections.len()).entered();
    // On all cores (a box's proposals take tens of ms of one core each); the first bad
    // detection in the request's order is the one answered.
    let decoded: Vec<Result<(String, Vec<Detection>), ServiceError>> = req
        .detections
        .par_iter()
        .enumerate()
        .map(|(i, d)| {
            if !d.score.is_finite() {
                return Err(ServiceError::invalid(format!("detections[{i}].score is not a finite number")));
            }
            crate::store::validate_id(&d.object_id).map_err(|e| ServiceError::invalid(format!("detections[{i}].object_id: {e}")))?;
            Ok((d.object_id.clone(), d.candidates(i, image)?))
        })
        .collect();
    decoded.into_iter().collect()
}

/// Union of every detection's mask except those of `object_id`'s instance `group` (and
/// those that are the same thing, `masks::OtherMasks` of `kind`): where another detection
/// is, this instance may be hidden. `None` when there is no other.
fn others_mask(by_object: &BTreeMap<&str, Vec<(usize, Vec<Detection>)>>, object_id: &str, group: &[usize], kind: OtherMasks, width: u32, height: u32) -> Option<image::GrayImage> {
    let others = by_object.iter().flat_map(|(&id, dets)| dets.iter().enumerate().filter(move |(g, _)| !(id == object_id && group.contains(g))).map(|(_, (_, c))| representative(c).0));
    let own = representative(&by_object[object_id][group[0]].1).0;
    crate::masks::occluders(own, others, kind, width, height)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dot(x: u32) -> image::GrayImage {
        let mut m = image::GrayImage::new(4, 1);
        m.put_pixel(x, 0, image::Luma([255]));
        m
    }

    /// An object loaded for rendering is uploaded to every renderer without a render; one
    /// loaded otherwise (a detection, an object listing) is not.
    #[test]
    fn an_object_loaded_to_render_is_uploaded_to_every_renderer() {
        let Some(model) = crate::onboard::test_model::small_model() else { return };
        let dir = tempfile::tempdir().unwrap();
        let store_url = format!("dir://{}", dir.path().display());
        let core = Core::new(CoreConfig { store_url, render_pool: 2, ..Default::default() }).unwrap();
        for id in ["a", "b"] {
            core.store.put(&crate::onboard::ObjectModel { object_id: id.into(), ..model.clone() }, false).unwrap();
        }
        core.load("a").unwrap();
        core.load_to_render("b").unwrap();
        wait_for_uploads(&core, 2);
        std::thread::sleep(std::time::Duration::from_millis(200));
        assert_eq!(core.render_mesh_uploads(), 2, "one upload per renderer, of b only");
        core.load_to_render("b").unwrap();
        std::thread::sleep(std::time::Duration::from_millis(200));
        assert_eq!(core.render_mesh_uploads(), 2, "a loaded object is not uploaded again");
    }

    /// More objects in turn than a renderer keeps (`render_meshes`): an object already
    /// loaded whose mesh the others pushed off the renderers is uploaded again ahead of
    /// its renders, as on its first load.
    #[test]
    fn an_object_pushed_off_the_renderers_is_uploaded_again_ahead() {
        let Some(model) = crate::onboard::test_model::small_model() else { return };
        let dir = tempfile::tempdir().unwrap();
        let store_url = format!("dir://{}", dir.path().display());
        let core = Core::new(CoreConfig { store_url, render_pool: 2, render_meshes: 1, ..Default::default() }).unwrap();
        for id in ["a", "b"] {
            core.store.put(&crate::onboard::ObjectModel { object_id: id.into(), ..model.clone() }, false).unwrap();
        }
        for (id, uploads) in [("a", 2), ("b", 4), ("a", 6)] {
            core.load_to_render(id).unwrap();
            wait_for_uploads(&core, uploads);
        }
    }

    /// Waits (a minute at most) until the renderers have uploaded `n` meshes in all.
    fn wait_for_uploads(core: &Core, n: u64) {
        let t = Instant::now();
        while core.render_mesh_uploads() < n {
            assert!(t.elapsed().as_secs() < 60, "{} mesh uploads, never {n}", core.render_mesh_uploads());
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
    }

    #[test]
    fn others_are_every_detection_but_the_instance_itself() {
        let one = |x: u32| vec![Detection::new(dot(x), 1.0)];
        let mut by_object: BTreeMap<&str, Vec<(usize, Vec<Detection>)>> = BTreeMap::new();
        by_object.insert("a", vec![(0, one(0)), (1, one(1))]);
        by_object.insert("b", vec![(2, one(2))]);
        let o = others_mask(&by_object, "a", &[0], OtherMasks::Detections, 4, 1).unwrap();
        assert_eq!(o.as_raw(), &vec![0, 255, 255, 0]);
        let o = others_mask(&by_object, "b", &[0], OtherMasks::Detections, 4, 1).unwrap();
        assert_eq!(o.as_raw(), &vec![255, 255, 0, 0]);
        let alone: BTreeMap<&str, Vec<(usize, Vec<Detection>)>> = BTreeMap::from([("a", vec![(0, one(0))])]);
        assert!(others_mask(&alone, "a", &[0], OtherMasks::Detections, 4, 1).is_none());
    }
}

#[cfg(test)]
#[path = "core_instances_tests.rs"]
mod instances_tests;
