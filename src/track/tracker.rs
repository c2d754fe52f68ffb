//! Frame-to-frame tracking of one object instance: from the last pose (moved on by a
//! constant-velocity prior), the contour refiner aligns the object's outline with a
//! foreground probability image from the colour model, with no retrieval, PnP or
//! rendering in the loop. The colour model is relearnt from a rendered silhouette every
//! few frames. A frame whose outline agreement falls below a threshold is reported lost
//! and leaves the track where it was, for the caller to re-initialise (a full estimate).

use super::colour::{ColourModel, Window};
use crate::estimate::contour::ContourRefiner;
use crate::estimate::refine::{RefineContext, RefineReport, Refiner};
use crate::geometry::{Intrinsics, Pose};
use crate::onboard::ObjectModel;
use crate::render::{RenderOptions, RenderPool};
use image::RgbImage;
use nalgebra::{Point3, Vector3};
use std::sync::Arc;

#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct TrackerConfig {
    /// Below this outline agreement (the contour refiner's, 0–1) a frame is lost.
    pub lost_below: f64,
    /// Weight of each relearnt colour histogram against the running one.
    pub colour_rate: f32,
    /// Frames between silhouette renders that relearn the colours (and check the pose).
    pub relearn_every: usize,
    /// Predict each frame's start pose from the last motion.
    pub constant_velocity: bool,
    /// Half-side of the window the colours are learnt and read in, in object radii.
    pub window_radii: f64,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self { lost_below: 0.3, colour_rate: 0.2, relearn_every: 5, constant_velocity: true, window_radii: 1.6 }
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
}

impl Tracker {
    /// Starts a track at a known `pose` in `image` (e.g. from a full estimate), learning
    /// the colours from the silhouette rendered there.
    pub fn new(model: Arc<ObjectModel>, renderer: Arc<RenderPool>, image: &RgbImage, k: &Intrinsics, pose: Pose, config: TrackerConfig) -> Result<Self, String> {
        let refiner = ContourRefiner::new(renderer.clone());
        let mut t = Self { model, renderer, refiner, colours: ColourModel::default(), config, pose, velocity: None, frames: 0 };
        t.restart(image, k, pose)?;
        Ok(t)
    }

    pub fn pose(&self) -> Pose {
        self.pose
    }

    /// Starts over at `pose` in `image` (a re-initialisation after a loss): colours learnt
    /// afresh, no motion carried over.
    /// On failure (the object not in view at `pose`) the track is left as it was.
    pub fn restart(&mut self, image: &RgbImage, k: &Intrinsics, pose: Pose) -> Result<(), String> {
        let kept = std::mem::take(&mut self.colours);
        if !self.relearn(image, k, &pose, 1.0)? {
            self.colours = kept;
            return Err("the object is not visible at the restarting pose".into());
        }
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

    fn relearn(&mut self, image: &RgbImage, k: &Intrinsics, pose: &Pose, rate: f32) -> Result<bool, String> {
        let Some(window) = self.window(k, pose, self.config.window_radii) else { return Ok(false) };
        // Rendered through the window only: a fraction of the frame's pixels.
        let Some(wk) = window.intrinsics(k) else { return Ok(false) };
        let silhouette = self.renderer.render(&self.model.mesh, pose, &wk, &RenderOptions::default()).map_err(|e| e.to_string())?.mask;
        Ok(self.colours.learn(image, &silhouette, window, rate))
    }

    /// Tracks the object into the next frame.
    pub fn track(&mut self, image: &RgbImage, k: &Intrinsics) -> Result<TrackStep, String> {
        if (image.width(), image.height()) != (k.width, k.height) {
            return Err(format!("frame is {}×{} but the intrinsics say {}×{}", image.width(), image.height(), k.width, k.height));
        }
        let predicted = match (&self.velocity, self.config.constant_velocity) {
            (Some(v), true) => v.compose(&self.pose),
            _ => self.pose,
        };
        let Some(window) = self.window(k, &predicted, self.config.window_radii) else {
            return Ok(TrackStep { pose: self.pose, quality: 0.0, lost: true, report: RefineReport { note: Some("the object left the image".into()), ..Default::default() } });
        };
        let probs = self.colours.probability_image(image, window);
        let ctx = RefineContext { model: &self.model, image, intrinsics: k, mask: &probs, unknown: None, mask_is_probability: true };
        let refined = self.refiner.refine(&ctx, predicted)?;
        let quality = refined.report.agreement;
        if quality < self.config.lost_below {
            self.velocity = None;
            return Ok(TrackStep { pose: self.pose, quality, lost: true, report: refined.report });
        }
        self.velocity = Some(refined.pose.compose(&self.pose.inverse()));
        self.pose = refined.pose;
        self.frames += 1;
        if self.frames.is_multiple_of(self.config.relearn_every.max(1)) {
            self.relearn(image, k, &refined.pose, self.config.colour_rate)?;
        }
        Ok(TrackStep { pose: refined.pose, quality, lost: false, report: refined.report })
    }
}
