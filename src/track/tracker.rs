//! Frame-to-frame tracking of one object instance: from the last pose (moved on by a
//! constant-velocity prior), the contour refiner aligns the object's outline with a
//! foreground probability image from the colour model, with no retrieval, PnP or
//! rendering in the loop. The colour model learns every frame from the pixels either side
//! of the outline at the frame's pose, and from a rendered silhouette every few frames (or
//! at once when the outline agrees only faintly), where the pose is also checked. A frame
//! whose outline agreement falls below a threshold is reported lost and leaves the track
//! where it was, for the caller to re-initialise (a full estimate).
//!
//! With a depth frame the pose is then fitted to the measured surface (`depth_fit`, the
//! estimator's point-to-plane fit) over the model surface seen at the last render, kept as
//! object-frame samples so that no frame renders for it (the ICG/M3T way); a pose the
//! camera sees through (free space), or that no measured surface confirms, is lost.

use super::check::{appearance, silhouette_iou};
use super::colour::{ColourModel, Window};
use super::outline_colours::outline_samples;
use super::photometric::{PhotometricConfig, PhotometricModel};
use super::search::find_by_colour;
use crate::depth::DepthImage;
use crate::estimate::contour::ContourRefiner;
use crate::estimate::depth_fit::{fit, visible_samples, DepthFit, DepthFitConfig, SurfaceSample};
use crate::estimate::refine::{RefineContext, RefineReport, Refiner};
use crate::geometry::{Intrinsics, Pose};
use crate::onboard::ObjectModel;
use crate::render::{RenderOptions, RenderOutput, RenderPool};
use crate::telemetry::ms_since;
use image::{GrayImage, RgbImage};
use nalgebra::{Point3, Vector3};
use std::sync::Arc;
use std::time::Instant;

#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct TrackerConfig {
    /// Below this outline agreement (the contour refiner's, 0–1) a frame is lost.
    pub lost_below: f64,
    /// Weight of each relearnt colour histogram against the running one.
    pub colour_rate: f32,
    /// Frames between silhouette renders that check the pose and relearn the colours, the
    /// texture's points and the surface. With the colours also read along the outline
    /// every frame (`outline_colour_rate`) and doubtful frames checked at once
    /// (`check_below`), every 20 frames kept or raised every MSSD share against every 5
    /// without them, and put the share of frames within 3 ms (one core) from about 80 % to
    /// about 95 % (`b2tf bench track`, HOPE obj_000001 / 2 / 8 and the sample box, RGB and
    /// RGB-D, with and without the occluder; docs/tracking.md, "Colours from the outline").
    pub relearn_every: usize,
    /// A frame whose outline agreement (0–1) is below this checks the pose (and relearns)
    /// at once, not at its turn: a track drifting under an occluder shows it here first.
    pub check_below: f64,
    /// Weight of the colours read across the outline at each tracked frame's pose, blended
    /// into the colour model (M3T's per-frame learning from its correspondence lines; no
    /// render); 0: colours from the relearning renders alone.
    pub outline_colour_rate: f32,
    /// How far across the outline those colours are read, each side, px (less where the
    /// object or the background before it again is narrower there).
    pub outline_colour_reach_px: f64,
    /// Predict each frame's start pose from the last motion.
    pub constant_velocity: bool,
    /// Half-side of the window the colours are learnt and read in, in object radii.
    pub window_radii: f64,
    /// The silhouette check (`check.rs`) at each relearning: below this IoU of the
    /// render's silhouette with the pixels the colours call object, the frame is lost.
    pub min_silhouette_iou: f64,
    /// The appearance check (`check.rs`) at each relearning: below this agreement of the
    /// render's colours and interior edges with the frame's, the frame is lost (a pose
    /// that slid to a wrong turn its outline cannot tell). Meshes with colours only.
    pub min_appearance: f64,
    /// The contour step's line scales, coarse to fine, as factors of the refiner's first
    /// segment length (`ContourRefinerConfig::scale_factors`; empty: the refiner's), read
    /// when the tracker starts. A track starts a frame's motion away, not a retrieval's:
    /// estimation's coarsest scale (1.0) and its middle one only cost time there. Measured
    /// with `b2tf bench track` (HOPE obj_000001 / 2 / 8 and the sample box, RGB and RGB-D,
    /// with and without the occluder; docs/tracking.md, "Where a frame's time goes"):
    /// [0.6, 0.2] kept or raised the MSSD share on 13 of 14 rows at two thirds of the
    /// contour step's time.
    pub contour_scales: Vec<f64>,
    /// Correspondence passes per line scale in the contour step (each builds its lines at
    /// the pose the last left; 0: the refiner's own, estimation's two). One pass a scale
    /// took a quarter off a frame's time and moved the MSSD shares by a frame or so either
    /// way (`b2tf bench track`, HOPE obj_000001 / 2 / 8 and the sample box, RGB and RGB-D,
    /// with and without the occluder; docs/tracking.md, "One pass a scale").
    pub contour_passes: usize,
    /// Keep the predicted pose where the contour step's result agrees less with the
    /// colours than it did (estimation's guard against drifting a good pose away). It costs
    /// a set of lines a frame, and on the same runs it never changed a row: the tracker's
    /// own checks (the outline agreement's floor, the silhouette and appearance checks)
    /// catch what it would.
    pub contour_compares_with_start: bool,
    /// The texture term after each contour step (photometric.rs).
    pub photometric: PhotometricConfig,
    /// With depth frames: Gauss-Newton steps of the depth fit after the contour step.
    pub depth_iterations: usize,
    /// With depth frames: above this share of the measured model surface seen through
    /// (measured behind it) the frame is lost ...
    pub max_free_space: f64,
    /// ... and below this share within the fit's tolerance of it (none of the object is
    /// where the pose says: drifted onto an occluder or the background in front).
    pub min_depth_inliers: f64,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self {
            lost_below: 0.3,
            colour_rate: 0.2,
            relearn_every: 20,
            check_below: 0.5,
            outline_colour_rate: 0.2,
            outline_colour_reach_px: 8.0,
            constant_velocity: true,
            window_radii: 1.6,
            min_silhouette_iou: 0.5,
            min_appearance: 0.3,
            contour_scales: vec![0.6, 0.2],
            contour_passes: 1,
            contour_compares_with_start: false,
            photometric: PhotometricConfig::default(),
            depth_iterations: 6,
            max_free_space: 0.35,
            min_depth_inliers: 0.2,
        }
    }
}

/// What one frame gave.
#[derive(Clone, Debug)]
pub struct TrackStep {
    pub pose: Pose,
    /// Outline agreement at `pose`, 0–1.
    pub quality: f64,
    /// The frame did not confirm the track: `pose` is the last good one.
    pub lost: bool,
    pub report: RefineReport,
    /// The silhouette check's IoU, on the frames that had one.
    pub silhouette_iou: Option<f64>,
    /// The appearance check's agreement, on the frames that had one (meshes with colours).
    pub appearance: Option<f64>,
    pub timings: TrackTimings,
}

/// Where one frame's time went, milliseconds, in the order the stages run.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct TrackTimings {
    /// The colour model's foreground probability over the window, and its learning from
    /// the pixels across the outline at the frame's pose.
    pub colours: f64,
    /// The contour refiner's alignment of the outline.
    pub contour: f64,
    /// The texture term (`photometric`).
    pub photometric: f64,
    /// The fit to the depth frame.
    pub depth: f64,
    /// Every few frames (and on doubtful ones): the render at the pose, its checks, and the
    /// colours, texture and surface learnt again from it.
    pub relearn: f64,
    pub total: f64,
}

impl TrackTimings {
    /// Stage names in `as_row`'s order (the total last, unnamed).
    pub const STAGES: [&'static str; 5] = ["colours", "contour", "photometric", "depth", "relearn"];

    /// The stages in `STAGES`' order, then the total.
    pub fn as_row(&self) -> [f64; 6] {
        [self.colours, self.contour, self.photometric, self.depth, self.relearn, self.total]
    }

    /// Stage name → milliseconds, the total as "total": as answers carry them.
    pub fn by_stage(&self) -> std::collections::BTreeMap<String, f64> {
        Self::STAGES.iter().chain(&["total"]).zip(self.as_row()).map(|(name, ms)| (name.to_string(), ms)).collect()
    }
}

pub struct Tracker {
    model: Arc<ObjectModel>,
    renderer: Arc<RenderPool>,
    refiner: ContourRefiner,
    colours: ColourModel,
    pub config: TrackerConfig,
    pose: Pose,
    /// Camera-frame motion of the last tracked frame (applied before the current pose).
    velocity: Option<Pose>,
    frames: usize,
    /// Pixels of the object's silhouette at the last render: the size a search for the
    /// lost object expects.
    silhouette_area: f64,
    /// The mesh has colours (a texture or vertex colours) for the appearance check.
    coloured: bool,
    texture: PhotometricModel,
    /// The model surface seen at the last render, object frame: what depth frames fit.
    surface: Vec<SurfaceSample>,
}

impl Tracker {
    /// Starts a track at a known `pose` in `image` (e.g. from a full estimate), learning
    /// the colours from the silhouette rendered there.
    pub fn new(model: Arc<ObjectModel>, renderer: Arc<RenderPool>, image: &RgbImage, k: &Intrinsics, pose: Pose, config: TrackerConfig) -> Result<Self, String> {
        let mut refiner = ContourRefiner::new(renderer.clone());
        if !config.contour_scales.is_empty() {
            refiner.config.scale_factors = config.contour_scales.clone();
        }
        if config.contour_passes > 0 {
            refiner.config.passes_per_scale = config.contour_passes;
        }
        refiner.config.compare_with_start = config.contour_compares_with_start;
        let coloured = model.mesh.has_colours();
        let mut t = Self {
            model,
            renderer,
            refiner,
            colours: ColourModel::default(),
            config,
            pose,
            velocity: None,
            frames: 0,
            silhouette_area: 0.0,
            coloured,
            texture: PhotometricModel::default(),
            surface: Vec::new(),
        };
        t.restart(image, k, pose)?;
        Ok(t)
    }

    pub fn pose(&self) -> Pose {
        self.pose
    }

    /// The colour statistics the track has learnt so far.
    pub fn colour_model(&self) -> &ColourModel {
        &self.colours
    }

    /// The line scales the contour step runs (`TrackerConfig::contour_scales`, or the
    /// refiner's own where that is empty).
    pub fn contour_scales(&self) -> &[f64] {
        &self.refiner.config.scale_factors
    }

    /// Correspondence passes per line scale the contour step runs
    /// (`TrackerConfig::contour_passes`, or the refiner's own where that is 0).
    pub fn contour_passes(&self) -> usize {
        self.refiner.config.passes_per_scale
    }

    /// Starts over at `pose` in `image` (a re-initialisation after a loss): colours learnt
    /// afresh, no motion carried over.
    /// On failure (the object not in view at `pose`) the track is left as it was.
    pub fn restart(&mut self, image: &RgbImage, k: &Intrinsics, pose: Pose) -> Result<(), String> {
        let Some((render, window)) = self.render_window(k, &pose)? else {
            return Err("the object is not visible at the restarting pose".into());
        };
        let mut colours = ColourModel::default();
        if !colours.learn(image, &render.mask, window, 1.0) {
            return Err("the object is not visible at the restarting pose".into());
        }
        self.colours = colours;
        self.silhouette_area = mask_area(&render.mask);
        self.learn_texture(image, &render, window, k, &pose);
        self.learn_surface(&render, window, k, &pose);
        self.velocity = None;
        self.frames = 0;
        self.pose = pose;
        Ok(())
    }

    /// The window around the object at `pose`: `radii` bounding radii around its centre
    /// (None when it is behind the camera or outside the image).
    pub fn window(&self, k: &Intrinsics, pose: &Pose, radii: f64) -> Option<Window> {
        let centre = pose.transform_point(&Point3::from(Vector3::from(self.model.mesh.bbox_center())));
        if centre.z <= 0.0 {
            return None;
        }
        let uv = k.project(&centre)?;
        let half = radii * k.fx.max(k.fy) * self.model.mesh.bounding_radius() / centre.z;
        Window::around(uv.x, uv.y, half, k.width, k.height)
    }

    /// The lost object's mask in `image`, found by its colours (search.rs) inside the box
    /// of `radii` bounding radii around its last pose, else anywhere in the frame; with the
    /// box it was found in.
    pub fn search(&self, image: &RgbImage, k: &Intrinsics, radii: f64) -> Option<(GrayImage, Window)> {
        let whole = Window { x0: 0, y0: 0, x1: image.width(), y1: image.height() };
        let near = self.window(k, &self.pose, radii);
        near.into_iter().chain(std::iter::once(whole)).find_map(|w| find_by_colour(&self.colours, image, w, self.silhouette_area).map(|m| (m, w)))
    }

    /// How much the object rendered at `pose` looks like `image` (the appearance check),
    /// for a pose from elsewhere (a re-initialising estimate); None when it is out of view
    /// or the mesh has no colours (no appearance check).
    pub fn appearance_at(&self, image: &RgbImage, k: &Intrinsics, pose: &Pose) -> Result<Option<f64>, String> {
        if !self.coloured {
            return Ok(None);
        }
        Ok(self.render_window(k, pose)?.map(|(render, window)| appearance(&render, image, window)))
    }

    /// New texture points from a render at `pose` checked against `image`.
    fn learn_texture(&mut self, image: &RgbImage, render: &RenderOutput, window: Window, k: &Intrinsics, pose: &Pose) {
        if let (true, Some(wk)) = (self.config.photometric.enabled, window.intrinsics(k)) {
            self.texture.learn(image, render, window, &wk, pose, &self.config.photometric);
        }
    }

    /// Colours read across the outline at `pose` blended into the colour model
    /// (`TrackerConfig::outline_colour_rate`; nothing at 0).
    fn learn_outline_colours(&mut self, image: &RgbImage, k: &Intrinsics, pose: &Pose) -> Result<(), String> {
        if self.config.outline_colour_rate <= 0.0 {
            return Ok(());
        }
        let cm = self.model.contour_model_or_build(&self.renderer).map_err(|e| e.to_string())?;
        let centre = Vector3::from(self.model.mesh.bbox_center());
        let samples = outline_samples(&cm, &centre, pose, k, image, self.config.outline_colour_reach_px);
        self.colours.learn_samples(samples, self.config.outline_colour_rate);
        Ok(())
    }

    /// The surface the render at `pose` shows, for the depth fits of the frames to come.
    fn learn_surface(&mut self, render: &RenderOutput, window: Window, k: &Intrinsics, pose: &Pose) {
        if let Some(wk) = window.intrinsics(k) {
            self.surface = visible_samples(render, pose, &wk);
        }
    }

    /// `pose` fitted to `depth` over the learnt surface points that face the camera there;
    /// None when there are too few to fit.
    fn fit_depth(&self, depth: &DepthImage, k: &Intrinsics, pose: &Pose) -> Option<(Pose, DepthFit)> {
        let facing: Vec<SurfaceSample> = self
            .surface
            .iter()
            .filter(|s| {
                let x = pose.rotation * s.point + pose.translation;
                (pose.rotation * s.normal).dot(&x) < 0.0
            })
            .copied()
            .collect();
        if facing.len() < 12 {
            return None;
        }
        let cfg = DepthFitConfig { iterations: self.config.depth_iterations, start_gate: 0.1, depth_first: false, ..DepthFitConfig::default() };
        Some(fit(&facing, pose, depth, k, self.model.diameter(), &cfg))
    }

    /// Why the depth does not confirm a fit, if it does not.
    fn depth_verdict(&self, f: &DepthFit) -> Option<String> {
        if f.measured_share == 0.0 {
            return None; // nothing measured there: the colours decide alone
        }
        if f.free_space_share > self.config.max_free_space {
            Some(format!("the depth camera sees through {:.0} % of the pose's surface (over {:.0} %)", 100.0 * f.free_space_share, 100.0 * self.config.max_free_space))
        } else if f.inlier_share < self.config.min_depth_inliers {
            Some(format!("only {:.0} % of the pose's surface lies on the measured one (under {:.0} %)", 100.0 * f.inlier_share, 100.0 * self.config.min_depth_inliers))
        } else {
            None
        }
    }

    /// The object rendered at `pose` through its colour window alone: a fraction of the
    /// frame's pixels. None when the window leaves the image.
    fn render_window(&self, k: &Intrinsics, pose: &Pose) -> Result<Option<(RenderOutput, Window)>, String> {
        let Some(window) = self.window(k, pose, self.config.window_radii) else { return Ok(None) };
        let Some(wk) = window.intrinsics(k) else { return Ok(None) };
        let render = self.renderer.render(&self.model.mesh, pose, &wk, &RenderOptions::default()).map_err(|e| e.to_string())?;
        Ok(Some((render, window)))
    }

    /// Tracks the object into the next frame, with the frame's registered depth when the
    /// camera gives one.
    pub fn track(&mut self, image: &RgbImage, depth: Option<&DepthImage>, k: &Intrinsics) -> Result<TrackStep, String> {
        let t = Instant::now();
        let mut timings = TrackTimings::default();
        let mut step = self.step(image, depth, k, &mut timings)?;
        step.timings = TrackTimings { total: ms_since(t), ..timings };
        Ok(step)
    }

    fn step(&mut self, image: &RgbImage, depth: Option<&DepthImage>, k: &Intrinsics, timings: &mut TrackTimings) -> Result<TrackStep, String> {
        if (image.width(), image.height()) != (k.width, k.height) {
            return Err(format!("frame is {}×{} but the intrinsics say {}×{}", image.width(), image.height(), k.width, k.height));
        }
        if let Some(d) = depth.filter(|d| (d.width(), d.height()) != (k.width, k.height)) {
            return Err(format!("depth is {}×{} but the frame is {}×{}", d.width(), d.height(), k.width, k.height));
        }
        let predicted = match (&self.velocity, self.config.constant_velocity) {
            (Some(v), true) => v.compose(&self.pose),
            _ => self.pose,
        };
        let Some(window) = self.window(k, &predicted, self.config.window_radii) else {
            return Ok(self.lost(0.0, RefineReport { note: Some("the object left the image".into()), ..Default::default() }, (None, None)));
        };
        let t = Instant::now();
        let probs = self.colours.probability_image(image, window);
        timings.colours = ms_since(t);
        let ctx = RefineContext { model: &self.model, image, intrinsics: k, mask: &probs, unknown: None, mask_is_probability: true, from_box: None, depth: None };
        let t = Instant::now();
        let mut refined = self.refiner.refine(&ctx, predicted)?;
        timings.contour = ms_since(t);
        let quality = refined.report.agreement;
        if quality < self.config.lost_below {
            return Ok(self.lost(quality, refined.report, (None, None)));
        }
        let t = Instant::now();
        if self.config.photometric.enabled {
            refined.pose = self.texture.align(image, window, k, &refined.pose, &self.config.photometric);
        }
        timings.photometric = ms_since(t);
        let t = Instant::now();
        let fitted = depth.and_then(|d| self.fit_depth(d, k, &refined.pose));
        timings.depth = ms_since(t);
        if let Some((pose, f)) = fitted {
            let verdict = self.depth_verdict(&f);
            refined.report.depth_fit = Some(f);
            if let Some(note) = verdict {
                return Ok(self.lost(quality, RefineReport { note: Some(note), ..refined.report }, (None, None)));
            }
            refined.pose = pose;
        }
        let (mut checked, mut looks) = (None, None);
        let t = Instant::now();
        // A frame whose outline agrees only faintly checks at once rather than at its turn:
        // what drifts under an occluder shows here first.
        let doubtful = quality < self.config.check_below;
        if doubtful || (self.frames + 1).is_multiple_of(self.config.relearn_every.max(1)) {
            if let Some((render, window)) = self.render_window(k, &refined.pose)? {
                let iou = silhouette_iou(&self.colours, image, &render.mask, window);
                checked = Some(iou);
                looks = self.coloured.then(|| appearance(&render, image, window));
                // Where the measured surface confirms the pose, the colours' silhouette has
                // nothing to add (and a colour model gone stale under changing light or an
                // occluder would lose a good track); a turn the surface cannot tell is still
                // for the appearance check.
                let surface_confirms = refined.report.depth_fit.as_ref().is_some_and(|f| f.measured_share >= 0.5 && f.inlier_share >= 0.8 && f.free_space_share <= 0.1);
                let failed = if iou < self.config.min_silhouette_iou && !surface_confirms {
                    Some(format!("the pose's silhouette covers too little of the object's colours (IoU {iou:.2} under {:.2})", self.config.min_silhouette_iou))
                } else if let Some(a) = looks.filter(|&a| a < self.config.min_appearance) {
                    Some(format!("the object rendered at the pose does not look like the frame (appearance {a:.2} under {:.2})", self.config.min_appearance))
                } else {
                    None
                };
                if let Some(note) = failed {
                    return Ok(self.lost(quality, RefineReport { note: Some(note), ..refined.report }, (checked, looks)));
                }
                self.colours.learn(image, &render.mask, window, self.config.colour_rate);
                self.silhouette_area = mask_area(&render.mask);
                self.learn_texture(image, &render, window, k, &refined.pose);
                self.learn_surface(&render, window, k, &refined.pose);
            }
        }
        timings.relearn = ms_since(t);
        let t = Instant::now();
        self.learn_outline_colours(image, k, &refined.pose)?;
        timings.colours += ms_since(t);
        self.velocity = Some(refined.pose.compose(&self.pose.inverse()));
        self.pose = refined.pose;
        self.frames += 1;
        // `track` fills in the timings.
        Ok(TrackStep { pose: refined.pose, quality, lost: false, report: refined.report, silhouette_iou: checked, appearance: looks, timings: TrackTimings::default() })
    }

    /// A frame that did not confirm the track: the last good pose stays, with what the frame
    /// measured (`checks`: the silhouette IoU and appearance, where a check ran), and no
    /// motion is carried into the next frame.
    fn lost(&mut self, quality: f64, report: RefineReport, checks: (Option<f64>, Option<f64>)) -> TrackStep {
        self.velocity = None;
        TrackStep { pose: self.pose, quality, lost: true, report, silhouette_iou: checks.0, appearance: checks.1, timings: TrackTimings::default() }
    }
}

fn mask_area(mask: &GrayImage) -> f64 {
    mask.pixels().filter(|p| p[0] > 0).count() as f64
}
