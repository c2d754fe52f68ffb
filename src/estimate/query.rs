//! The query side: crop the image around a detection mask exactly as templates are cropped,
//! encode it, and keep what later stages need (foreground patches, crop map, silhouette).

use crate::features::{crop_query, Backbone, CropInput, FeatureError, FeatureMap};
use crate::geometry::CropBox;
use crate::onboard::model::pack_silhouette;
use image::{GrayImage, RgbImage};

/// One encoded query crop.
pub struct QueryView {
    pub crop_box: CropBox,
    pub features: FeatureMap,
    /// Foreground patch indices and their descriptors (`fg.len() × dim`).
    pub foreground: Vec<usize>,
    pub descriptors: Vec<f32>,
    /// 64×64 crop silhouette, bit-packed like the templates' (empty where `encode_with`
    /// skipped it).
    pub silhouette: Vec<u64>,
    /// For a query turned to meet shared patch rows (`estimate::turned`), the map from its
    /// crop's image coordinates back to the photo's; `None` for the photo as it is.
    pub turn: Option<crate::geometry::Turn>,
}

impl QueryView {
    /// Image-pixel centre of foreground patch number `i` (an index into `foreground`).
    pub fn patch_centre(&self, i: usize) -> (f64, f64) {
        let (cu, cv) = self.features.grid.centre_of(self.foreground[i]);
        let (u, v) = self.crop_box.to_image(cu, cv);
        match &self.turn {
            Some(t) => t.apply(u, v),
            None => (u, v),
        }
    }
}

/// Crops each (image, mask) pair; `None` for an empty mask.
pub fn crop_all(image: &RgbImage, masks: &[&GrayImage], padding: f64, size: u32) -> Vec<Option<(CropInput, CropBox)>> {
    masks.iter().map(|m| crop_query(image, m, padding, size)).collect()
}

/// Encodes crops in one batched backbone call and gathers foreground descriptors.
pub fn encode(backbone: &dyn Backbone, crops: Vec<(CropInput, CropBox)>, min_coverage: f32) -> Result<Vec<QueryView>, FeatureError> {
    encode_with(backbone, crops, min_coverage, Silhouettes::Packed)
}

/// Whether `encode_with` packs each crop's 64×64 silhouette (what retrieval compares), or
/// leaves it empty for crops that are only matched (the turned queries of `estimate::turned`).
#[derive(Clone, Copy, PartialEq, Eq)]
pub enum Silhouettes {
    Packed,
    Skipped,
}

/// `encode`, with the silhouettes packed or skipped.
pub fn encode_with(backbone: &dyn Backbone, crops: Vec<(CropInput, CropBox)>, min_coverage: f32, silhouettes: Silhouettes) -> Result<Vec<QueryView>, FeatureError> {
    let silhouettes: Vec<Vec<u64>> = crops.iter().map(|(c, _)| if silhouettes == Silhouettes::Packed { pack_silhouette(&c.mask) } else { Vec::new() }).collect();
    let (inputs, boxes): (Vec<CropInput>, Vec<CropBox>) = crops.into_iter().unzip();
    let maps = backbone.extract(&inputs)?;
    Ok(maps
        .into_iter()
        .zip(boxes.into_iter().zip(silhouettes))
        .map(|(features, (crop_box, silhouette))| {
            let foreground = features.foreground(min_coverage);
            let descriptors = foreground.iter().flat_map(|&p| features.descriptor(p).iter().copied()).collect();
            QueryView { crop_box, features, foreground, descriptors, silhouette, turn: None }
        })
        .collect())
}
