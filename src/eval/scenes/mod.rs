//! Synthetic test scenes for the estimation and BOP benchmarks, written in the BOP layout.
//!
//! Each image: random intrinsics; 1–3 (up to 8) object instances, rotation uniform over
//! SO(3), placed wholly inside the frame at a distance that makes them fill a chosen share
//! of the image height; each rendered alone (textured as the mesh is, one random light per
//! image), composited by depth over procedural clutter; flat occluders in front of parts of
//! the objects; blur, colour shift and sensor noise (and, where the appearance asks for them,
//! prints that drift from the texture and JPEG). Placements and occluders that leave an
//! instance less than `1 − max_occlusion` visible are drawn again.
//!
//! `render_to_real_gap`: the templates are rendered elsewhere from the bare mesh, so the
//! generator widens the gap the only way it can, by degrading the scenes more (see
//! `Appearance::harsher`). The flag changes no geometry: with the same seed, both datasets
//! hold the same poses, masks and occluders, so they can be compared image by image.
//!
//! On disk (one scene, id 1; lengths in mm as BOP has them):
//! `DATASET/test/000001/{rgb,depth,mask,mask_visib}/…png`, `scene_camera.json`,
//! `scene_gt.json`, `scene_gt_info.json`, `DATASET/test_targets_bop19.json`,
//! `DATASET/models/models_info.json`, and the config as `DATASET/b2tf_scene_config.json`.
//! The object models themselves are not written.

mod appearance;
mod background;
pub(crate) mod bop_write;
mod config;
mod generate;
mod layers;
mod occluders;
mod placement;
mod supersample;
#[cfg(test)]
mod tests;

pub use background::Background;
pub use config::{Appearance, SceneConfig, MAX_OBJECTS_PER_IMAGE, MAX_SUPERSAMPLING};
pub use generate::{generate_image, generate_image_over, SceneImage, SceneInstance};

use crate::mesh::Mesh;
use crate::render::RenderPool;
use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};

/// The scene id generated datasets use.
pub const SCENE_ID: u32 = 1;
/// The `SceneConfig` a dataset was generated with, at the dataset's root.
pub const CONFIG_FILE: &str = "b2tf_scene_config.json";

#[derive(Clone, Debug, PartialEq)]
pub struct DatasetSummary {
    pub scene_dir: PathBuf,
    pub images: usize,
    pub instances: usize,
}

/// Generates `cfg.images` images of `objects` (BOP object id, mesh) into `dataset` as
/// scene `SCENE_ID` of the test split. Image ids run from 0.
pub fn generate_dataset(objects: &[(u32, Mesh)], cfg: &SceneConfig, pool: &RenderPool, dataset: &Path) -> Result<DatasetSummary> {
    generate_dataset_over(objects, cfg, pool, dataset, &[])
}

/// [`generate_dataset`] with each image drawn over one of `backgrounds` (real frames, drawn
/// per image), or over procedural clutter where there are none.
pub fn generate_dataset_over(objects: &[(u32, Mesh)], cfg: &SceneConfig, pool: &RenderPool, dataset: &Path, backgrounds: &[Background]) -> Result<DatasetSummary> {
    cfg.validate().map_err(|e| anyhow::anyhow!("scene config: {e}"))?;
    let mut ids: Vec<u32> = objects.iter().map(|(id, _)| *id).collect();
    ids.sort_unstable();
    if ids.first() == Some(&0) || ids.windows(2).any(|w| w[0] == w[1]) {
        bail!("object ids must be unique and positive (BOP numbers objects from 1), got {ids:?}");
    }
    let mut writer = bop_write::SceneWriter::create(dataset, SCENE_ID)?;
    let mut instances = 0;
    for im_id in 0..cfg.images as u32 {
        let img = generate_image_over(objects, cfg, pool, im_id, backgrounds)?;
        instances += img.instances.len();
        writer.add(im_id, &img)?;
    }
    let scene_dir = writer.dir().to_path_buf();
    bop_write::write_test_targets(dataset, &writer.finish()?)?;
    bop_write::write_models_info(dataset, objects)?;
    // Not part of BOP: records how the dataset was made, so results can name it.
    let path = dataset.join(CONFIG_FILE);
    std::fs::write(&path, serde_json::to_string_pretty(cfg)?).with_context(|| format!("writing {}", path.display()))?;
    Ok(DatasetSummary { scene_dir, images: cfg.images, instances })
}
