//! The detector a frame gets: with a registered depth image, the depth detector
//! (`depth_detector`: surfaces standing off the table, of the objects' size); without,
//! the colour detector (`detector`: shapes and colours of the photo).

use super::depth_detector::detect_with_depth;
use super::detector::{detect_in_colour, DetectError, DetectOptions, DetectReport, Target};
use crate::depth::DepthImage;
use crate::geometry::Intrinsics;
use crate::render::RenderPool;
use image::RgbImage;

/// Looks for every target in `image`, in its registered `depth` where the camera gives one.
pub fn detect(image: &RgbImage, depth: Option<&DepthImage>, k: &Intrinsics, targets: &[Target], opts: &DetectOptions, renderer: &RenderPool) -> Result<DetectReport, DetectError> {
    match depth {
        Some(depth) => detect_with_depth(image, depth, k, targets, opts),
        None => detect_in_colour(image, k, targets, opts, renderer),
    }
}
