//! The `Backbone` trait: a batch of square crops in, one feature map per crop out.

use super::crop::CropInput;
use crate::geometry::PatchGrid;

/// What produced a set of features. Stored with every onboarded object: features of two
/// different backbones (or settings) are not comparable, so estimation refuses a mismatch.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct BackboneIdentity {
    pub name: String,
    /// Hash of the weights or, for the embedded backbone, of its parameters.
    pub weights_hash: String,
    /// Which layers give the local and global descriptors.
    pub layers: String,
    pub input_size: u32,
    pub patch_size: u32,
    pub local_dim: u32,
    pub global_dim: u32,
}

/// Descriptors of one crop on its patch grid.
#[derive(Clone, Debug)]
pub struct FeatureMap {
    pub grid: PatchGrid,
    pub local_dim: usize,
    /// `grid.len() × local_dim`, row-major by patch index `i·n + j`; L2-normalised rows
    /// (zero rows for patches with no signal).
    pub local: Vec<f32>,
    /// Mean of the foreground local descriptors (or the backbone's own global token), L2-normalised.
    pub global: Vec<f32>,
    /// Object coverage of each patch in 0..1, from the crop mask.
    pub coverage: Vec<f32>,
}

impl FeatureMap {
    pub fn descriptor(&self, patch: usize) -> &[f32] {
        &self.local[patch * self.local_dim..(patch + 1) * self.local_dim]
    }

    /// Patches whose object coverage reaches `min_coverage`.
    pub fn foreground(&self, min_coverage: f32) -> Vec<usize> {
        (0..self.grid.len()).filter(|&k| self.coverage[k] >= min_coverage).collect()
    }
}

#[derive(Debug, thiserror::Error)]
pub enum FeatureError {
    #[error("crop {index} is {width}×{height}, the backbone expects {expected}×{expected}")]
    WrongSize { index: usize, width: u32, height: u32, expected: u32 },
    #[error("backbone failed: {0}")]
    Backend(String),
}

pub trait Backbone: Send + Sync {
    fn identity(&self) -> BackboneIdentity;
    /// One feature map per crop, in order. Crops must be `input_size` square, or
    /// `reduced_input_size` square where the backbone has one.
    fn extract(&self, crops: &[CropInput]) -> Result<Vec<FeatureMap>, FeatureError>;
    /// The side of a smaller crop the backbone also encodes, on a grid of as many patches
    /// (each covering the same share of the crop): for queries encoded many times over
    /// (the turned queries of objects that share patch rows per view), where the photo
    /// rarely holds more detail than the smaller crop keeps. `None`: `input_size` only.
    fn reduced_input_size(&self) -> Option<u32> {
        None
    }
}

/// Shared check of crop sizes for backbones: each crop `expected` square, or `reduced`.
pub fn check_sizes(crops: &[CropInput], expected: u32, reduced: Option<u32>) -> Result<(), FeatureError> {
    for (index, c) in crops.iter().enumerate() {
        let (width, height) = c.rgb.dimensions();
        let known = width == expected || Some(width) == reduced;
        if !known || height != width || c.mask.dimensions() != (width, height) {
            return Err(FeatureError::WrongSize { index, width, height, expected });
        }
    }
    Ok(())
}

/// Per-patch object coverage: the mean mask value over each patch.
pub fn patch_coverage(mask: &image::GrayImage, grid: &PatchGrid) -> Vec<f32> {
    let n = grid.n as usize;
    let p = grid.patch as usize;
    let w = mask.width() as usize;
    let raw = mask.as_raw();
    let mut cov = vec![0f32; n * n];
    for y in 0..n * p {
        let row = &raw[y * w..y * w + n * p];
        for (j, chunk) in row.chunks_exact(p).enumerate() {
            cov[(y / p) * n + j] += chunk.iter().map(|&m| m as u32).sum::<u32>() as f32;
        }
    }
    let norm = 1.0 / (255.0 * (p * p) as f32);
    cov.iter_mut().for_each(|c| *c *= norm);
    cov
}

/// L2-normalises in place; leaves an all-zero vector as is.
pub fn l2_normalize(v: &mut [f32]) {
    let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    if n > 1e-12 {
        v.iter_mut().for_each(|x| *x /= n);
    }
}

/// Mean of the descriptors of patches with coverage ≥ `min_coverage`, L2-normalised.
pub fn mean_descriptor(local: &[f32], dim: usize, coverage: &[f32], min_coverage: f32) -> Vec<f32> {
    let mut g = vec![0f32; dim];
    for (k, &c) in coverage.iter().enumerate() {
        if c >= min_coverage {
            for (a, b) in g.iter_mut().zip(&local[k * dim..(k + 1) * dim]) {
                *a += b;
            }
        }
    }
    l2_normalize(&mut g);
    g
}
