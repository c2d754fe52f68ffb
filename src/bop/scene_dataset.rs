//! Generated scenes (`eval::scenes`) written as a BOP dataset, scene by scene.
//!
//! On disk (one scene, id 1; lengths in mm as BOP has them):
//! `DATASET/test/000001/{rgb,depth,mask,mask_visib}/…png`, `scene_camera.json`,
//! `scene_gt.json`, `scene_gt_info.json`, `DATASET/test_targets_bop19.json`,
//! `DATASET/models/models_info.json`, and the config as `DATASET/b2tf_scene_config.json`.
//! The object models themselves are not written.

use super::scene_write::{write_models_info, write_test_targets, SceneWriter};
use crate::eval::scenes::{generate_image_over, Background, SceneConfig};
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
    let mut writer = SceneWriter::create(dataset, SCENE_ID)?;
    let mut instances = 0;
    for im_id in 0..cfg.images as u32 {
        let img = generate_image_over(objects, cfg, pool, im_id, backgrounds)?;
        instances += img.instances.len();
        writer.add(im_id, &img)?;
    }
    let scene_dir = writer.dir().to_path_buf();
    write_test_targets(dataset, &writer.finish()?)?;
    write_models_info(dataset, objects)?;
    // Not part of BOP: records how the dataset was made, so results can name it.
    let path = dataset.join(CONFIG_FILE);
    std::fs::write(&path, serde_json::to_string_pretty(cfg)?).with_context(|| format!("writing {}", path.display()))?;
    Ok(DatasetSummary { scene_dir, images: cfg.images, instances })
}

#[cfg(test)]
#[path = "scene_dataset_tests.rs"]
mod tests;
