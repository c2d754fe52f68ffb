//! Generated sequences as a BOP dataset, one scene per sequence (scene ids from 1, image
//! ids = frame indices from 0), with each frame's true pose, full and visible masks and
//! depth, so that BOP tools, `b2tf bop eval` and `b2tf track` read them like any other
//! video dataset. How each scene was made goes in `b2tf_sequences.json` at the root.

use super::sequence::{Sequence, SequenceConfig};
use crate::bop::scene_write::{write_models_info, write_test_targets, SceneWriter};
use crate::eval::scenes::{SceneImage, SceneInstance};
use crate::geometry::Intrinsics;
use crate::mesh::Mesh;
use crate::render::RenderPool;
use anyhow::{Context, Result};
use std::path::Path;

/// What the root records of each scene.
pub const SEQUENCES_FILE: &str = "b2tf_sequences.json";

/// One sequence to write: its object (BOP id and mesh) and how it moves.
pub struct SequenceSpec<'a> {
    pub obj_id: u32,
    pub mesh: &'a Mesh,
    pub config: SequenceConfig,
}

#[derive(serde::Serialize)]
struct SceneRecord<'a> {
    scene_id: u32,
    obj_id: u32,
    mesh: &'a str,
    config: &'a SequenceConfig,
}

/// Writes every sequence into `dataset`'s test split; returns the frames written.
pub fn write_sequences(dataset: &Path, k: &Intrinsics, specs: &[SequenceSpec<'_>], pool: &RenderPool) -> Result<usize> {
    let (mut targets, mut records, mut frames) = (Vec::new(), Vec::new(), 0);
    for (i, spec) in specs.iter().enumerate() {
        let scene_id = i as u32 + 1;
        let mut writer = SceneWriter::create(dataset, scene_id)?;
        let seq = Sequence::new(spec.mesh, k, &spec.config);
        for f in 0..seq.len() {
            let made = seq.frame(f, pool).with_context(|| format!("scene {scene_id}, frame {f}"))?;
            let count = |m: &image::GrayImage| m.as_raw().iter().filter(|&&v| v > 0).count();
            let instance = SceneInstance {
                obj_id: spec.obj_id,
                pose: made.frame.truth,
                px_count_all: count(&made.silhouette),
                px_count_visib: count(&made.frame.visible),
                mask: made.silhouette,
                mask_visib: made.frame.visible,
            };
            writer.add(f as u32, &SceneImage { cam: *k, rgb: made.frame.rgb, depth: made.frame.depth, instances: vec![instance] })?;
            frames += 1;
        }
        targets.extend(writer.finish()?);
        records.push(SceneRecord { scene_id, obj_id: spec.obj_id, mesh: spec.mesh.name(), config: &spec.config });
    }
    write_test_targets(dataset, &targets)?;
    let mut objects: Vec<(u32, Mesh)> = Vec::new();
    for s in specs {
        if !objects.iter().any(|(id, _)| *id == s.obj_id) {
            objects.push((s.obj_id, s.mesh.clone()));
        }
    }
    write_models_info(dataset, &objects)?;
    let path = dataset.join(SEQUENCES_FILE);
    std::fs::write(&path, serde_json::to_string_pretty(&records)?).with_context(|| format!("writing {}", path.display()))?;
    Ok(frames)
}
