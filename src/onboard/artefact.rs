//! The on-disk form of an `ObjectModel`: one folder per object holding `manifest.json`
//! (versioned, human-readable metadata), `tensors.safetensors` (descriptors, points,
//! silhouettes, the mesh arrays) and the mesh textures as PNG. Written to a temporary
//! folder and renamed into place, so a reader never sees half an object.

use super::model::{ObjectModel, OnboardConfig, Template, MODEL_FORMAT_VERSION};
use crate::features::BackboneIdentity;
use crate::geometry::{Intrinsics, PatchGrid};
use crate::mesh::{Material, Mesh, MeshData, Part, Units};
use safetensors::{tensor::TensorView, Dtype, SafeTensors};
use std::path::{Path, PathBuf};
use std::sync::Arc;

const MANIFEST: &str = "manifest.json";
const TENSORS: &str = "tensors.safetensors";

#[derive(Debug, thiserror::Error)]
pub enum ArtefactError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: {message}")]
    Corrupt { path: PathBuf, message: String },
    #[error("{path}: model format version {found} is newer than this program understands ({supported}); upgrade b2tfpose")]
    TooNew { path: PathBuf, found: u32, supported: u32 },
}

#[derive(serde::Serialize, serde::Deserialize)]
struct Manifest {
    format_version: u32,
    object_id: String,
    created_unix_s: u64,
    backbone: BackboneIdentity,
    config: OnboardConfig,
    render_intrinsics: Intrinsics,
    grid: PatchGrid,
    diameter_m: f64,
    mesh: MeshManifest,
    templates: Vec<Template>,
}

#[derive(serde::Serialize, serde::Deserialize)]
struct MeshManifest {
    name: String,
    source_units: Units,
    materials: Vec<MaterialManifest>,
    /// (first_triangle, triangle_count, material)
    parts: Vec<(u32, u32, u32)>,
}

#[derive(serde::Serialize, serde::Deserialize)]
struct MaterialManifest {
    name: String,
    base_color: [f32; 4],
    texture_file: Option<String>,
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> ArtefactError + '_ {
    move |source| ArtefactError::Io { path: path.to_path_buf(), source }
}

/// Writes `model` as `dir/<object_id>/`, replacing an existing one only if `replace`.
pub fn save(model: &ObjectModel, dir: &Path, replace: bool) -> Result<PathBuf, ArtefactError> {
    let target = dir.join(&model.object_id);
    if target.exists() && !replace {
        return Err(ArtefactError::Io {
            path: target,
            source: std::io::Error::new(std::io::ErrorKind::AlreadyExists, "object already exists (pass replace to overwrite)"),
        });
    }
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let tmp = dir.join(format!(".{}.tmp-{}", model.object_id, std::process::id()));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(io(&tmp))?;
    }
    std::fs::create_dir_all(tmp.join("textures")).map_err(io(&tmp))?;
    let result = write_contents(model, &tmp).and_then(|()| {
        if target.exists() {
            let old = dir.join(format!(".{}.old-{}", model.object_id, std::process::id()));
            std::fs::rename(&target, &old).map_err(io(&target))?;
            std::fs::rename(&tmp, &target).map_err(io(&target))?;
            std::fs::remove_dir_all(&old).map_err(io(&old))
        } else {
            std::fs::rename(&tmp, &target).map_err(io(&target))
        }
    });
    if result.is_err() {
        let _ = std::fs::remove_dir_all(&tmp);
    }
    result.map(|()| target)
}

fn write_contents(model: &ObjectModel, tmp: &Path) -> Result<(), ArtefactError> {
    let mesh = &model.mesh;
    let mut materials = Vec::new();
    for (i, m) in mesh.materials().iter().enumerate() {
        let texture_file = match &m.texture {
            Some(img) => {
                let name = format!("textures/{i}.png");
                let path = tmp.join(&name);
                img.save(&path).map_err(|e| ArtefactError::Corrupt { path, message: format!("cannot write texture: {e}") })?;
                Some(name)
            }
            None => None,
        };
        materials.push(MaterialManifest { name: m.name.clone(), base_color: m.base_color, texture_file });
    }
    let manifest = Manifest {
        format_version: MODEL_FORMAT_VERSION,
        object_id: model.object_id.clone(),
        created_unix_s: std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0),
        backbone: model.backbone.clone(),
        config: model.config.clone(),
        render_intrinsics: model.render_intrinsics,
        grid: model.grid,
        diameter_m: model.diameter(),
        mesh: MeshManifest {
            name: mesh.name().to_string(),
            source_units: mesh.source_units(),
            materials,
            parts: mesh.parts().iter().map(|p| (p.first_triangle, p.triangle_count, p.material)).collect(),
        },
        templates: model.templates.clone(),
    };
    let mpath = tmp.join(MANIFEST);
    let json = serde_json::to_vec_pretty(&manifest).map_err(|e| ArtefactError::Corrupt { path: mpath.clone(), message: e.to_string() })?;
    std::fs::write(&mpath, json).map_err(io(&mpath))?;

    let d = mesh.data();
    let t = model.templates.len();
    let p = model.patch_points.len();
    let tensors: Vec<(&str, Dtype, Vec<usize>, &[u8])> = vec![
        ("global", Dtype::F32, vec![t, model.global_dim], bytemuck::cast_slice(&model.global)),
        ("patch_descriptors", Dtype::F16, vec![p, model.local_dim], bytemuck::cast_slice(&model.patch_descriptors)),
        ("patch_points", Dtype::F32, vec![p, 3], bytemuck::cast_slice(&model.patch_points)),
        ("patch_cells", Dtype::U16, vec![p], bytemuck::cast_slice(&model.patch_cells)),
        ("silhouettes", Dtype::U64, vec![model.silhouettes.len()], bytemuck::cast_slice(&model.silhouettes)),
        ("mesh_positions", Dtype::F32, vec![d.positions.len(), 3], bytemuck::cast_slice(&d.positions)),
        ("mesh_normals", Dtype::F32, vec![d.normals.len(), 3], bytemuck::cast_slice(&d.normals)),
        ("mesh_colors", Dtype::F32, vec![d.colors.len(), 3], bytemuck::cast_slice(&d.colors)),
        ("mesh_uvs", Dtype::F32, vec![d.uvs.len(), 2], bytemuck::cast_slice(&d.uvs)),
        ("mesh_triangles", Dtype::U32, vec![d.triangles.len(), 3], bytemuck::cast_slice(&d.triangles)),
    ];
    let tpath = tmp.join(TENSORS);
    let views = tensors
        .into_iter()
        .map(|(name, dt, shape, bytes)| TensorView::new(dt, shape, bytes).map(|v| (name, v)))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| ArtefactError::Corrupt { path: tpath.clone(), message: e.to_string() })?;
    safetensors::serialize_to_file(views, None, &tpath).map_err(|e| ArtefactError::Corrupt { path: tpath.clone(), message: e.to_string() })?;
    // Make the bytes durable before the rename publishes them.
    for f in [&tpath, &mpath] {
        std::fs::File::open(f).and_then(|f| f.sync_all()).map_err(io(f))?;
    }
    Ok(())
}

/// Loads the object model stored in folder `path` (as written by `save`).
pub fn load(path: &Path) -> Result<ObjectModel, ArtefactError> {
    let mpath = path.join(MANIFEST);
    let corrupt = |p: &Path, m: String| ArtefactError::Corrupt { path: p.to_path_buf(), message: m };
    let raw = std::fs::read(&mpath).map_err(io(&mpath))?;
    // Read the version alone first, so a newer layout is refused with a clear message.
    let version: serde_json::Value = serde_json::from_slice(&raw).map_err(|e| corrupt(&mpath, format!("invalid JSON: {e}")))?;
    let found = version.get("format_version").and_then(|v| v.as_u64()).ok_or_else(|| corrupt(&mpath, "no format_version".into()))? as u32;
    if found > MODEL_FORMAT_VERSION {
        return Err(ArtefactError::TooNew { path: mpath, found, supported: MODEL_FORMAT_VERSION });
    }
    let man: Manifest = serde_json::from_value(version).map_err(|e| corrupt(&mpath, format!("invalid manifest: {e}")))?;

    let tpath = path.join(TENSORS);
    let bytes = std::fs::read(&tpath).map_err(io(&tpath))?;
    let st = SafeTensors::deserialize(&bytes).map_err(|e| corrupt(&tpath, e.to_string()))?;
    let get = |name: &str, dt: Dtype, cols: usize| -> Result<&[u8], ArtefactError> {
        let v = st.tensor(name).map_err(|e| corrupt(&tpath, format!("tensor {name}: {e}")))?;
        let shape = v.shape();
        if v.dtype() != dt || (cols > 0 && shape.get(1).copied().unwrap_or(0) != cols && shape[0] != 0) {
            return Err(corrupt(&tpath, format!("tensor {name} has dtype {:?} shape {shape:?}, expected {dt:?} with {cols} columns", v.dtype())));
        }
        Ok(v.data())
    };

    let mut materials = Vec::new();
    for m in &man.mesh.materials {
        let texture = match &m.texture_file {
            Some(f) => {
                let p = path.join(f);
                let img = image::open(&p).map_err(|e| corrupt(&p, format!("texture: {e}")))?.to_rgba8();
                Some(Arc::new(img))
            }
            None => None,
        };
        materials.push(Material { name: m.name.clone(), base_color: m.base_color, texture });
    }
    let data = MeshData {
        positions: bytemuck::pod_collect_to_vec(get("mesh_positions", Dtype::F32, 3)?),
        normals: bytemuck::pod_collect_to_vec(get("mesh_normals", Dtype::F32, 3)?),
        colors: bytemuck::pod_collect_to_vec(get("mesh_colors", Dtype::F32, 3)?),
        uvs: bytemuck::pod_collect_to_vec(get("mesh_uvs", Dtype::F32, 2)?),
        triangles: bytemuck::pod_collect_to_vec(get("mesh_triangles", Dtype::U32, 3)?),
        parts: man.mesh.parts.iter().map(|&(first_triangle, triangle_count, material)| Part { first_triangle, triangle_count, material }).collect(),
        materials,
    };
    let mesh = Mesh::new(man.mesh.name.clone(), man.mesh.source_units, data).map_err(|e| corrupt(&tpath, format!("stored mesh: {e}")))?;
    let model = ObjectModel {
        object_id: man.object_id,
        global_dim: man.backbone.global_dim as usize,
        local_dim: man.backbone.local_dim as usize,
        backbone: man.backbone,
        config: man.config,
        render_intrinsics: man.render_intrinsics,
        grid: man.grid,
        mesh,
        templates: man.templates,
        global: bytemuck::pod_collect_to_vec(get("global", Dtype::F32, 0)?),
        patch_descriptors: bytemuck::pod_collect_to_vec(get("patch_descriptors", Dtype::F16, 0)?),
        patch_points: bytemuck::pod_collect_to_vec(get("patch_points", Dtype::F32, 3)?),
        patch_cells: bytemuck::pod_collect_to_vec(get("patch_cells", Dtype::U16, 0)?),
        silhouettes: bytemuck::pod_collect_to_vec(get("silhouettes", Dtype::U64, 0)?),
    };
    model.validate().map_err(|m| corrupt(path, m))?;
    Ok(model)
}

/// Total size in bytes of the files of a stored object.
pub fn stored_bytes(path: &Path) -> u64 {
    fn walk(p: &Path) -> u64 {
        std::fs::read_dir(p)
            .map(|rd| rd.flatten().map(|e| if e.path().is_dir() { walk(&e.path()) } else { e.metadata().map(|m| m.len()).unwrap_or(0) }).sum())
            .unwrap_or(0)
    }
    walk(path)
}
