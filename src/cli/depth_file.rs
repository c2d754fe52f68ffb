//! Depth PNGs named on the command line (`--depth`), read and checked against the image
//! they must be registered to.

use anyhow::Result;
use std::path::Path;

/// A depth PNG checked against the image it must be registered to (`size`); values ×
/// `scale_mm` are millimetres.
pub fn load_depth(path: &Path, scale_mm: f64, size: (u32, u32)) -> Result<crate::depth::DepthImage> {
    crate::depth::DepthImage::read_png_for(path, scale_mm, size, &format!("--depth-scale {scale_mm}")).map_err(|e| anyhow::anyhow!("--depth: {e}"))
}
