//! The final refinement stage. The paper uses MegaPose (a trained network); here a
//! `Refiner` is any pose → pose step, and the default passes the pose through unchanged.

use crate::geometry::{Intrinsics, Pose};
use crate::onboard::ObjectModel;
use image::{GrayImage, RgbImage};

/// What a refiner may look at.
pub struct RefineContext<'a> {
    pub model: &'a ObjectModel,
    pub image: &'a RgbImage,
    pub intrinsics: &'a Intrinsics,
    pub mask: &'a GrayImage,
}

pub trait Refiner: Send + Sync {
    fn name(&self) -> &str;
    fn refine(&self, ctx: &RefineContext<'_>, pose: Pose) -> Result<Pose, String>;
}

/// Returns the pose unchanged.
pub struct PassThrough;

impl Refiner for PassThrough {
    fn name(&self) -> &str {
        "none"
    }

    fn refine(&self, _: &RefineContext<'_>, pose: Pose) -> Result<Pose, String> {
        Ok(pose)
    }
}
