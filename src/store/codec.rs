//! An `ObjectModel` as bytes, shared by every store backend: a versioned JSON manifest
//! (human-readable metadata), one safetensors buffer (descriptors, points, silhouettes, the
//! mesh arrays; a zero-copy format, so a backend can hand in a memory map) and the mesh
//! textures as PNG files named in the manifest.

use crate::features::BackboneIdentity;
use crate::geometry::symmetry::KnownSymmetries;
use crate::geometry::{Intrinsics, PatchGrid};
use crate::mesh::{Material, Mesh, MeshData, Part, Units};
use crate::onboard::point_grid::{i16_to_unit, unit_to_i16, PointGrid};
use crate::onboard::stored_rows::{HalfRows, StoredRows};
use crate::onboard::{ObjectModel, OnboardConfig, PatchDescriptors, PatchPoints, Template, MODEL_FORMAT_VERSION};
use safetensors::{tensor::TensorView, Dtype, SafeTensors};
use std::sync::Arc;

#[derive(Debug, thiserror::Error)]
pub enum CodecError {
    #[error("{0}")]
    Corrupt(String),
    #[error("model format version {found} is newer than this program understands ({supported}); upgrade b2tfpose")]
    TooNew { found: u32, supported: u32 },
}

fn corrupt(m: impl Into<String>) -> CodecError {
    CodecError::Corrupt(m.into())
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
    /// Since format 2; absent means uncompressed descriptors.
    #[serde(default)]
    pca: Option<crate::onboard::pca::Pca>,
    /// Random per write, also in the tensors' metadata and the texture names, so a reader
    /// that raced a replace and got parts of two writes notices (absent before format 2).
    #[serde(default)]
    generation: Option<u64>,
    /// Since format 3: how the contour model in the `contour_*` tensors was sampled; absent
    /// when the object has none (older formats).
    #[serde(default)]
    contour: Option<crate::onboard::ContourConfig>,
    /// Since format 4: how the detector templates in the `detector_*` tensors were made;
    /// absent when the object has none (older formats).
    #[serde(default)]
    detector: Option<crate::detect::DetectorConfig>,
    /// Since format 5: the object's symmetries and where they came from; absent when
    /// unknown (older formats).
    #[serde(default)]
    symmetries: Option<KnownSymmetries>,
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

/// The encoded parts of one object.
pub struct Encoded {
    /// `manifest.json`.
    pub manifest: Vec<u8>,
    /// `tensors.safetensors`.
    pub tensors: Vec<u8>,
    /// (name as referenced by the manifest, e.g. `textures/0.png`; PNG bytes).
    pub textures: Vec<(String, Vec<u8>)>,
}

/// What listing needs of a stored object, from its manifest alone.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ManifestSummary {
    pub object_id: String,
    pub format_version: u32,
    pub source_units: Units,
    pub diameter_m: f64,
    pub backbone: BackboneIdentity,
    pub templates: usize,
    pub created_unix_s: u64,
    pub symmetries: Option<KnownSymmetries>,
    /// The write it comes from (`Manifest::generation`); `None` before format 2.
    pub generation: Option<u64>,
}

/// A number for one write, different from every other write's (time, pid and a counter).
pub(crate) fn new_generation() -> u64 {
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos() as u64).unwrap_or(0);
    // Mixed with the pid and a counter: two writes in one nanosecond still differ.
    static COUNTER: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n = COUNTER.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    nanos ^ ((std::process::id() as u64) << 40) ^ n.wrapping_mul(0x9E37_79B9_7F4A_7C15)
}

const GENERATION_KEY: &str = "b2tf_generation";

pub fn encode(model: &ObjectModel) -> Result<Encoded, CodecError> {
    let generation = new_generation();
    let mesh = &model.mesh;
    let mut materials = Vec::new();
    let mut textures = Vec::new();
    for (i, m) in mesh.materials().iter().enumerate() {
        let texture_file = match &m.texture {
            Some(texture) => {
                let name = format!("textures/{generation:016x}-{i}.png");
                // A texture read from a store is still its PNG: written back as it is.
                let png = match texture.png() {
                    Some(png) => png.to_vec(),
                    None => {
                        let mut png = Vec::new();
                        let pixels = texture.pixels().map_err(|e| corrupt(format!("texture {i}: {e}")))?;
                        pixels.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png).map_err(|e| corrupt(format!("cannot encode texture {i}: {e}")))?;
                        png
                    }
                };
                textures.push((name.clone(), png));
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
        pca: model.pca.clone(),
        generation: Some(generation),
        contour: model.contours.get().map(|c| c.config),
        detector: model.detector.get().map(|d| d.config),
        symmetries: model.symmetries.clone(),
    };
    let manifest = serde_json::to_vec_pretty(&manifest).map_err(|e| corrupt(e.to_string()))?;

    let d = mesh.data();
    let t = model.templates.len();
    let p = model.patch_points.len();
    let mut tensors: Vec<(&str, Dtype, Vec<usize>, &[u8])> = vec![
        ("global", Dtype::F32, vec![t, model.global_dim], bytemuck::cast_slice(&model.global)),
        ("patch_cells", Dtype::U16, vec![p], bytemuck::cast_slice(&model.patch_cells)),
        ("silhouettes", Dtype::U64, vec![model.silhouettes.len()], bytemuck::cast_slice(&model.silhouettes)),
        ("mesh_positions", Dtype::F32, vec![d.positions.len(), 3], bytemuck::cast_slice(&d.positions)),
        ("mesh_normals", Dtype::F32, vec![d.normals.len(), 3], bytemuck::cast_slice(&d.normals)),
        ("mesh_colors", Dtype::F32, vec![d.colors.len(), 3], bytemuck::cast_slice(&d.colors)),
        ("mesh_uvs", Dtype::F32, vec![d.uvs.len(), 2], bytemuck::cast_slice(&d.uvs)),
        ("mesh_triangles", Dtype::U32, vec![d.triangles.len(), 3], bytemuck::cast_slice(&d.triangles)),
    ];
    match &model.patch_points {
        PatchPoints::Exact(points) => tensors.push(("patch_points", Dtype::F32, vec![p, 3], bytemuck::cast_slice(points))),
        PatchPoints::Grid { grid, steps } => tensors
            .extend([("patch_point_steps", Dtype::U16, vec![p, 3], bytemuck::cast_slice(steps)), ("patch_point_grid", Dtype::F32, vec![2, 3], bytemuck::bytes_of(grid))]
                as [(&str, Dtype, Vec<usize>, &[u8]); 2]),
    }
    match &model.patch_descriptors {
        PatchDescriptors::Half(v) => tensors.push(("patch_descriptors", Dtype::F16, vec![p, model.local_dim], bytemuck::cast_slice(v))),
        PatchDescriptors::Quantized { quantizer, codes } => tensors.extend([
            ("patch_codes", Dtype::U8, vec![p, quantizer.subspaces], &codes[..]),
            ("pq_centroids", Dtype::F32, vec![quantizer.subspaces * crate::onboard::pq::CENTROIDS, quantizer.sub_dim()], bytemuck::cast_slice(&quantizer.centroids)),
        ] as [(&str, Dtype, Vec<usize>, &[u8]); 2]),
        PatchDescriptors::Int8 { codes, scales } => tensors
            .extend([("patch_codes_i8", Dtype::I8, vec![p, model.local_dim], bytemuck::cast_slice(&codes[..])), ("patch_scales", Dtype::F32, vec![p], bytemuck::cast_slice(&scales[..]))]
                as [(&str, Dtype, Vec<usize>, &[u8]); 2]),
    }
    // Format 7: contour points as steps of a grid over the mesh's box (found again from
    // the stored mesh) and normals as 16-bit components.
    let contour_grid = crate::onboard::ContourModel::storage_grid(mesh);
    let contour_steps: Vec<[u16; 3]> = model.contours.get().map_or(vec![], |c| c.points.iter().map(|&p| contour_grid.encode(p)).collect());
    let contour_normals: Vec<[i16; 3]> = model.contours.get().map_or(vec![], |c| c.normals.iter().map(|&n| unit_to_i16(n)).collect());
    if let Some(c) = model.contours.get() {
        let rows = c.points.len();
        tensors.extend([
            ("contour_directions", Dtype::F32, vec![c.directions.len(), 3], bytemuck::cast_slice(&c.directions)),
            ("contour_point_steps", Dtype::U16, vec![rows, 3], bytemuck::cast_slice(&contour_steps)),
            ("contour_normals_i16", Dtype::I16, vec![rows, 3], bytemuck::cast_slice(&contour_normals)),
            ("contour_foreground_m", Dtype::F32, vec![rows], bytemuck::cast_slice(&c.foreground_m)),
            ("contour_background_m", Dtype::F32, vec![rows], bytemuck::cast_slice(&c.background_m)),
        ] as [(&str, Dtype, Vec<usize>, &[u8]); 5]);
        // Only objects with colours have plain runs; an older program ignores the tensor
        // (and, as before, reads no photo edges on a textured object), so the format stays.
        if !c.plain_share.is_empty() {
            tensors.push(("contour_plain_share", Dtype::U8, vec![rows], &c.plain_share));
        }
    }
    if let Some(d) = model.detector.get() {
        tensors.extend([
            ("detector_features", Dtype::I8, vec![d.features.len(), 3], bytemuck::cast_slice(&d.features)),
            ("detector_boxes", Dtype::I8, vec![d.boxes.len(), 4], bytemuck::cast_slice(&d.boxes)),
            ("detector_colours", Dtype::F32, vec![d.colours.len()], bytemuck::cast_slice(&d.colours)),
        ] as [(&str, Dtype, Vec<usize>, &[u8]); 3]);
    }
    let views = tensors.into_iter().map(|(name, dt, shape, bytes)| TensorView::new(dt, shape, bytes).map(|v| (name, v))).collect::<Result<Vec<_>, _>>().map_err(|e| corrupt(e.to_string()))?;
    let metadata = std::collections::HashMap::from([(GENERATION_KEY.to_string(), generation.to_string())]);
    let tensors = safetensors::serialize(views, Some(metadata)).map_err(|e| corrupt(e.to_string()))?;
    Ok(Encoded { manifest, tensors, textures })
}

/// Parses a manifest, refusing a newer format with its own error.
fn parse_manifest(raw: &[u8]) -> Result<Manifest, CodecError> {
    let value: serde_json::Value = serde_json::from_slice(raw).map_err(|e| corrupt(format!("manifest: invalid JSON: {e}")))?;
    let found = value.get("format_version").and_then(|v| v.as_u64()).ok_or_else(|| corrupt("manifest: no format_version"))? as u32;
    if found > MODEL_FORMAT_VERSION {
        return Err(CodecError::TooNew { found, supported: MODEL_FORMAT_VERSION });
    }
    serde_json::from_value(value).map_err(|e| corrupt(format!("manifest: {e}")))
}

pub fn summary(manifest: &[u8]) -> Result<ManifestSummary, CodecError> {
    let m = parse_manifest(manifest)?;
    Ok(ManifestSummary {
        object_id: m.object_id,
        format_version: m.format_version,
        source_units: m.mesh.source_units,
        diameter_m: m.diameter_m,
        backbone: m.backbone,
        templates: m.templates.len(),
        created_unix_s: m.created_unix_s,
        symmetries: m.symmetries,
        generation: m.generation,
    })
}

/// Rebuilds the model; `texture(name)` returns the PNG bytes the manifest names.
pub fn decode(manifest: &[u8], tensors: &[u8], texture: &mut dyn FnMut(&str) -> Result<Vec<u8>, String>) -> Result<ObjectModel, CodecError> {
    decode_inner(manifest, tensors, None, texture)
}

/// `decode` of a memory-mapped tensors file: f16 patch descriptors stay in the mapping
/// (`HalfRows::Mapped`) instead of being copied.
pub fn decode_mapped(manifest: &[u8], tensors: &Arc<memmap2::Mmap>, texture: &mut dyn FnMut(&str) -> Result<Vec<u8>, String>) -> Result<ObjectModel, CodecError> {
    decode_inner(manifest, tensors, Some(tensors), texture)
}

fn decode_inner(manifest: &[u8], tensors: &[u8], map: Option<&Arc<memmap2::Mmap>>, texture: &mut dyn FnMut(&str) -> Result<Vec<u8>, String>) -> Result<ObjectModel, CodecError> {
    let man = parse_manifest(manifest)?;
    if let Some(g) = man.generation {
        let (_, meta) = SafeTensors::read_metadata(tensors).map_err(|e| corrupt(format!("tensors: {e}")))?;
        let found = meta.metadata().as_ref().and_then(|m| m.get(GENERATION_KEY)).and_then(|v| v.parse::<u64>().ok());
        if found != Some(g) {
            return Err(corrupt(format!("manifest (write {g:016x}) and tensors (write {}) come from different writes", found.map_or("unknown".into(), |f| format!("{f:016x}")))));
        }
    }
    let st = SafeTensors::deserialize(tensors).map_err(|e| corrupt(format!("tensors: {e}")))?;
    let get = |name: &str, dt: Dtype, cols: usize| -> Result<&[u8], CodecError> {
        let v = st.tensor(name).map_err(|e| corrupt(format!("tensor {name}: {e}")))?;
        let shape = v.shape();
        // A table of `cols` columns is `[rows, cols]` (`[0, _]` when empty); any other shape,
        // a scalar's `[]` included, is refused.
        let table = cols == 0 || matches!(shape, [_, c] if *c == cols) || shape.first() == Some(&0);
        if v.dtype() != dt || !table {
            return Err(corrupt(format!("tensor {name} has dtype {:?} shape {shape:?}, expected {dt:?} with {cols} columns", v.dtype())));
        }
        Ok(v.data())
    };
    let mut materials = Vec::new();
    for m in &man.mesh.materials {
        let texture = match &m.texture_file {
            Some(f) => {
                // Kept as the PNG and decoded by the GPU uploads that need the pixels.
                let bytes = texture(f).map_err(|e| corrupt(format!("texture {f}: {e}")))?;
                Some(crate::mesh::Texture::from_png(bytes).map_err(|e| corrupt(format!("texture {f}: {e}")))?)
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
    let mesh = Mesh::with_diameter(man.mesh.name.clone(), man.mesh.source_units, data, man.diameter_m).map_err(|e| corrupt(format!("stored mesh: {e}")))?;
    // Format 7 stores the contour points and normals compactly.
    let compact_contour = st.names().contains(&"contour_point_steps");
    let contours = match man.contour {
        Some(config) => {
            let c = crate::onboard::ContourModel {
                config,
                directions: bytemuck::pod_collect_to_vec(get("contour_directions", Dtype::F32, 3)?),
                points: if compact_contour {
                    let grid = crate::onboard::ContourModel::storage_grid(&mesh);
                    bytemuck::pod_collect_to_vec::<u8, [u16; 3]>(get("contour_point_steps", Dtype::U16, 3)?).into_iter().map(|q| grid.decode(q)).collect()
                } else {
                    bytemuck::pod_collect_to_vec(get("contour_points", Dtype::F32, 3)?)
                },
                normals: if compact_contour {
                    bytemuck::pod_collect_to_vec::<u8, [i16; 3]>(get("contour_normals_i16", Dtype::I16, 3)?).into_iter().map(i16_to_unit).collect()
                } else {
                    bytemuck::pod_collect_to_vec(get("contour_normals", Dtype::F32, 3)?)
                },
                foreground_m: bytemuck::pod_collect_to_vec(get("contour_foreground_m", Dtype::F32, 0)?),
                background_m: bytemuck::pod_collect_to_vec(get("contour_background_m", Dtype::F32, 0)?),
                plain_share: if st.names().contains(&"contour_plain_share") { get("contour_plain_share", Dtype::U8, 0)?.to_vec() } else { vec![] },
            };
            std::sync::OnceLock::from(Arc::new(c))
        }
        None => std::sync::OnceLock::new(),
    };
    let detector = match man.detector {
        Some(config) => {
            let d = crate::detect::ShapeModel {
                config,
                features: bytemuck::pod_collect_to_vec(get("detector_features", Dtype::I8, 3)?),
                boxes: bytemuck::pod_collect_to_vec(get("detector_boxes", Dtype::I8, 4)?),
                // Absent: stored without colours (or before they were kept).
                colours: if st.names().contains(&"detector_colours") { bytemuck::pod_collect_to_vec(get("detector_colours", Dtype::F32, 0)?) } else { vec![] },
            };
            std::sync::OnceLock::from(Arc::new(d))
        }
        None => std::sync::OnceLock::new(),
    };
    // Format 6 may store codes and their centroids in place of the f16 rows.
    let local_dim = man.pca.as_ref().map_or(man.backbone.local_dim as usize, |p| p.output_dim);
    let patch_descriptors = if st.names().contains(&"patch_codes") {
        let codes = st.tensor("patch_codes").map_err(|e| corrupt(format!("tensor patch_codes: {e}")))?;
        let subspaces = match codes.shape() {
            [_, m] if *m > 0 && codes.dtype() == Dtype::U8 => *m,
            shape => return Err(corrupt(format!("tensor patch_codes has dtype {:?} shape {shape:?}, expected U8 with a column per subspace", codes.dtype()))),
        };
        if !local_dim.is_multiple_of(subspaces) {
            return Err(corrupt(format!("{subspaces} code subspaces do not split descriptors of {local_dim} values")));
        }
        let quantizer = crate::onboard::pq::ProductQuantizer { dim: local_dim, subspaces, centroids: bytemuck::pod_collect_to_vec(get("pq_centroids", Dtype::F32, local_dim / subspaces)?) };
        quantizer.validate().map_err(|e| corrupt(format!("pq_centroids: {e}")))?;
        PatchDescriptors::Quantized { quantizer, codes: StoredRows::mapped_or_copied(map, codes.data()) }
    } else if st.names().contains(&"patch_codes_i8") {
        PatchDescriptors::Int8 {
            codes: StoredRows::mapped_or_copied(map, get("patch_codes_i8", Dtype::I8, local_dim)?),
            scales: StoredRows::mapped_or_copied(map, get("patch_scales", Dtype::F32, 0)?),
        }
    } else {
        let bytes = get("patch_descriptors", Dtype::F16, 0)?;
        PatchDescriptors::Half(HalfRows::mapped_or_copied(map, bytes))
    };
    // Format 7 stores grid steps in place of the f32 points.
    let patch_points = if st.names().contains(&"patch_point_steps") {
        let rows: Vec<[f32; 3]> = bytemuck::pod_collect_to_vec(get("patch_point_grid", Dtype::F32, 3)?);
        let grid = PointGrid::from_rows(&rows).map_err(|e| corrupt(format!("tensor patch_point_grid: {e}")))?;
        PatchPoints::Grid { grid, steps: StoredRows::mapped_or_copied(map, get("patch_point_steps", Dtype::U16, 3)?) }
    } else {
        PatchPoints::Exact(StoredRows::mapped_or_copied(map, get("patch_points", Dtype::F32, 3)?))
    };
    let model = ObjectModel {
        object_id: man.object_id,
        global_dim: man.backbone.global_dim as usize,
        local_dim,
        pca: man.pca,
        backbone: man.backbone,
        config: man.config,
        render_intrinsics: man.render_intrinsics,
        grid: man.grid,
        mesh,
        templates: man.templates,
        global: bytemuck::pod_collect_to_vec(get("global", Dtype::F32, 0)?),
        patch_descriptors,
        patch_points,
        patch_cells: StoredRows::mapped_or_copied(map, get("patch_cells", Dtype::U16, 0)?),
        silhouettes: StoredRows::mapped_or_copied(map, get("silhouettes", Dtype::U64, 0)?),
        contours,
        detector,
        symmetries: man.symmetries,
    };
    model.validate().map_err(corrupt)?;
    if model.contour_lacks_plain_runs() {
        tracing::warn!("object {:?} was stored before printed objects' plain runs were kept: its outline is fitted to the mask alone; `b2tf objects upgrade` adds them", model.object_id);
    }
    Ok(model)
}

/// Hostile stored objects, from the `store_manifest` fuzz seed that carries tensors (a whole
/// tiny object: `tests/fuzz_seeds`): changed one way each, they are refused with an error.
#[cfg(test)]
mod hostile_tests {
    use super::*;

    /// The seed's manifest, tensors and texture.
    fn seed() -> (String, Vec<u8>, Vec<u8>) {
        let data = std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/fuzz/seeds/store_manifest/tiny_object")).unwrap();
        let parts = crate::fuzzing::split(&data);
        (String::from_utf8(parts[0].to_vec()).unwrap(), parts[1].to_vec(), parts[2].to_vec())
    }

    fn load(manifest: &str, tensors: &[u8], texture: &[u8]) -> Result<ObjectModel, String> {
        decode(manifest.as_bytes(), tensors, &mut |_| Ok(texture.to_vec())).map_err(|e| e.to_string())
    }

    /// `tensors` with `name` replaced (same generation metadata).
    fn with_tensor(tensors: &[u8], name: &str, dtype: Dtype, shape: Vec<usize>, data: &[u8]) -> Vec<u8> {
        let (_, meta) = SafeTensors::read_metadata(tensors).unwrap();
        let st = SafeTensors::deserialize(tensors).unwrap();
        let mut views: Vec<(String, TensorView)> = st.tensors().into_iter().filter(|(n, _)| n != name).collect();
        views.push((name.to_string(), TensorView::new(dtype, shape, data).unwrap()));
        safetensors::serialize(views, meta.metadata().clone()).unwrap()
    }

    #[test]
    fn the_seed_loads() {
        let (manifest, tensors, texture) = seed();
        let model = load(&manifest, &tensors, &texture).unwrap();
        assert_eq!((model.template_count(), model.patch_count(), model.grid.len()), (1, 2, 4));
    }

    /// A scalar (shape `[]`) where a table was expected was indexed as one (`shape[0]`: a
    /// panic).
    #[test]
    fn tables_stored_as_scalars_or_other_shapes_are_refused() {
        let (manifest, tensors, texture) = seed();
        let one = 1f32.to_le_bytes();
        for name in ["mesh_positions", "patch_points", "contour_points"] {
            let scalar = with_tensor(&tensors, name, Dtype::F32, vec![], &one);
            assert!(load(&manifest, &scalar, &texture).unwrap_err().contains(&format!("tensor {name} has dtype F32 shape []")), "{name}");
        }
        let three_d = with_tensor(&tensors, "mesh_positions", Dtype::F32, vec![1, 3, 1], &[one; 3].concat());
        assert!(load(&manifest, &three_d, &texture).unwrap_err().contains("shape [1, 3, 1], expected F32 with 3 columns"));
        // An empty table may have any column count (older writers).
        let empty = with_tensor(&tensors, "mesh_colors", Dtype::F32, vec![0, 7], &[]);
        assert!(load(&manifest, &empty, &texture).is_ok());
    }

    /// Format 6's quantised descriptors: codes and the centroids they index load and
    /// decode; codes that do not split the descriptors, of another type or count, and
    /// missing, short or non-finite centroids are refused.
    #[test]
    fn quantised_descriptors_load_and_bad_ones_are_refused() {
        use crate::onboard::pq::CENTROIDS;
        let (manifest, tensors, texture) = seed();
        let centroids: Vec<f32> = (0..2 * CENTROIDS * 2).map(|i| i as f32 / 1000.0).collect();
        let coded = with_tensor(&tensors, "patch_codes", Dtype::U8, vec![2, 2], &[0, 1, 2, 3]);
        let both = with_tensor(&coded, "pq_centroids", Dtype::F32, vec![2 * CENTROIDS, 2], bytemuck::cast_slice(&centroids));
        let m = load(&manifest, &both, &texture).unwrap();
        let mut row = Vec::new();
        m.patch_descriptors.widen_into(4, 0..1, &mut row);
        // Code 0 of subspace 0 and code 1 of subspace 1 (centroid 257), to unit length.
        let norm = (0.001f32.powi(2) + 0.514f32.powi(2) + 0.515f32.powi(2)).sqrt();
        let want = [0.0, 0.001 / norm, 0.514 / norm, 0.515 / norm];
        assert!(row.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-6), "{row:?}");
        let refused = |t: &[u8], needle: &str| {
            let e = load(&manifest, t, &texture).unwrap_err();
            assert!(e.contains(needle), "{needle:?} not in {e:?}");
        };
        refused(&with_tensor(&both, "patch_codes", Dtype::U8, vec![2, 3], &[0; 6]), "do not split");
        refused(&with_tensor(&both, "patch_codes", Dtype::F32, vec![2, 2], &[0; 16]), "expected U8");
        refused(&with_tensor(&both, "patch_codes", Dtype::U8, vec![3, 2], &[0; 6]), "patch descriptors do not match");
        refused(&coded, "pq_centroids");
        refused(&with_tensor(&coded, "pq_centroids", Dtype::F32, vec![10, 2], &[0; 80]), "centroid values");
        let mut nan = centroids.clone();
        nan[7] = f32::NAN;
        refused(&with_tensor(&coded, "pq_centroids", Dtype::F32, vec![2 * CENTROIDS, 2], bytemuck::cast_slice(&nan)), "not finite");

        // int8 values with a scale per row.
        let codes: [i8; 8] = [127, 0, 0, 0, 0, -127, 0, 0];
        let int8 =
            with_tensor(&with_tensor(&tensors, "patch_codes_i8", Dtype::I8, vec![2, 4], bytemuck::cast_slice(&codes)), "patch_scales", Dtype::F32, vec![2], bytemuck::cast_slice(&[0.5f32, 2.0]));
        let m = load(&manifest, &int8, &texture).unwrap();
        let mut rows = Vec::new();
        m.patch_descriptors.widen_into(4, 0..2, &mut rows);
        assert_eq!(rows, [1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0]);
        refused(&with_tensor(&int8, "patch_codes_i8", Dtype::I8, vec![2, 3], &[0; 6]), "expected I8 with 4 columns");
        refused(&with_tensor(&int8, "patch_scales", Dtype::F32, vec![3], bytemuck::cast_slice(&[1f32; 3])), "patch descriptors do not match");
        refused(&with_tensor(&int8, "patch_scales", Dtype::F32, vec![2], bytemuck::cast_slice(&[1f32, f32::NAN])), "patch descriptors do not match");
    }

    /// Format 7's patch points as grid steps load in place of the f32 ones (the seed is
    /// format 6: it keeps loading its f32 points); a grid that is not two finite rows with
    /// non-negative steps, or steps of another shape or count, are refused. Likewise the
    /// contour's compact points and normals.
    #[test]
    fn grid_coded_patch_points_load_and_bad_ones_are_refused() {
        let (manifest, tensors, texture) = seed();
        assert!(!load(&manifest, &tensors, &texture).unwrap().patch_points.is_grid(), "format 6 keeps f32 points");
        let grid: [[f32; 3]; 2] = [[-0.01, 0.0, 0.02], [1e-6, 2e-6, 0.0]];
        let steps: [[u16; 3]; 2] = [[0, 10, 5], [65535, 0, 9]];
        let with_steps = with_tensor(&tensors, "patch_point_steps", Dtype::U16, vec![2, 3], bytemuck::cast_slice(&steps));
        let coded = with_tensor(&with_steps, "patch_point_grid", Dtype::F32, vec![2, 3], bytemuck::cast_slice(&grid));
        let m = load(&manifest, &coded, &texture).unwrap();
        assert!(m.patch_points.is_grid());
        let mut points = Vec::new();
        m.patch_points.extend_range(0..2, &mut points);
        assert_eq!(points, [[-0.01, 2e-5, 0.02], [-0.01 + 65535.0 * 1e-6, 0.0, 0.02]]);
        let refused = |t: &[u8], needle: &str| {
            let e = load(&manifest, t, &texture).unwrap_err();
            assert!(e.contains(needle), "{needle:?} not in {e:?}");
        };
        refused(&with_steps, "patch_point_grid");
        refused(&with_tensor(&coded, "patch_point_grid", Dtype::F32, vec![1, 3], &[0; 12]), "2 rows");
        refused(&with_tensor(&coded, "patch_point_grid", Dtype::F32, vec![2, 3], bytemuck::cast_slice(&[[0f32; 3], [f32::NAN, 0.0, 0.0]])), "not finite");
        refused(&with_tensor(&coded, "patch_point_grid", Dtype::F32, vec![2, 3], bytemuck::cast_slice(&[[0f32; 3], [-1.0, 0.0, 0.0]])), "non-negative");
        refused(&with_tensor(&coded, "patch_point_steps", Dtype::U16, vec![2, 2], &[0; 8]), "expected U16 with 3 columns");
        refused(&with_tensor(&coded, "patch_point_steps", Dtype::U16, vec![3, 3], &[0; 18]), "patch descriptors do not match");

        // Contour points as steps of the grid over the mesh's box, normals as 16-bit values.
        let old = load(&manifest, &tensors, &texture).unwrap();
        let rows = old.contours.get().unwrap().points.len();
        let grid = crate::onboard::ContourModel::storage_grid(&old.mesh);
        let steps: Vec<[u16; 3]> = (0..rows).map(|i| [i as u16, 0, u16::MAX]).collect();
        let normals: Vec<[i16; 3]> = vec![[0, -32767, 0]; rows];
        let with_steps = with_tensor(&tensors, "contour_point_steps", Dtype::U16, vec![rows, 3], bytemuck::cast_slice(&steps));
        let compact = with_tensor(&with_steps, "contour_normals_i16", Dtype::I16, vec![rows, 3], bytemuck::cast_slice(&normals));
        let c = load(&manifest, &compact, &texture).unwrap().contours.get().unwrap().clone();
        assert_eq!(c.points, steps.iter().map(|&q| grid.decode(q)).collect::<Vec<_>>());
        assert_eq!(c.normals, vec![[0.0, -1.0, 0.0]; rows]);
        refused(&with_steps, "contour_normals_i16");
        refused(&with_tensor(&compact, "contour_point_steps", Dtype::U16, vec![rows, 2], &vec![0; rows * 4]), "expected U16 with 3 columns");
        refused(&with_tensor(&compact, "contour_normals_i16", Dtype::I16, vec![rows + 1, 3], &vec![0; (rows + 1) * 6]), "contour arrays do not match");

        // Plain runs: absent (unknown) before they were kept, one byte per row after.
        assert!(c.plain_share.is_empty());
        let shares: Vec<u8> = (0..rows).map(|i| (i * 37 % 256) as u8).collect();
        let plain = with_tensor(&compact, "contour_plain_share", Dtype::U8, vec![rows], &shares);
        assert_eq!(load(&manifest, &plain, &texture).unwrap().contours.get().unwrap().plain_share, shares);
        refused(&with_tensor(&compact, "contour_plain_share", Dtype::U8, vec![rows + 1], &vec![0; rows + 1]), "contour arrays do not match");
        refused(&with_tensor(&compact, "contour_plain_share", Dtype::F32, vec![rows], &vec![0; rows * 4]), "expected U8");
    }

    /// Symmetries load when they are rotations and axes, and are refused naming what is wrong.
    #[test]
    fn stored_symmetries_load_and_bad_ones_are_refused() {
        let (manifest, tensors, texture) = seed();
        assert!(load(&manifest, &tensors, &texture).unwrap().symmetries.is_none(), "the seed predates symmetries");
        let with = |json: &str| {
            let mut m: serde_json::Value = serde_json::from_str(&manifest).unwrap();
            m["symmetries"] = serde_json::from_str(json).unwrap();
            m.to_string()
        };
        let good = r#"{"source": "models_info", "discrete": [[-1,0,0,0, 0,-1,0,0, 0,0,1,0, 0,0,0,1]], "continuous": [{"axis": [0,0,1], "offset": [0,0,0.01]}]}"#;
        let m = load(&with(good), &tensors, &texture).unwrap();
        let s = m.symmetries.expect("loaded");
        assert_eq!((s.source, s.symmetries.discrete.len(), s.symmetries.continuous[0].offset[2]), (crate::geometry::symmetry::SymmetrySource::ModelsInfo, 1, 0.01));
        for (json, needle) in [
            (r#"{"source": "mesh", "discrete": [[1,0,0]], "continuous": []}"#, "16 values"),
            (r#"{"source": "guess", "discrete": [], "continuous": []}"#, "unknown variant"),
            (r#"{"source": "mesh", "discrete": [[2,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]], "continuous": []}"#, "discrete symmetry 0 is not a rotation"),
            (r#"{"source": "mesh", "discrete": [[-1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]], "continuous": []}"#, "discrete symmetry 0 is not a rotation"),
            (r#"{"source": "mesh", "discrete": [], "continuous": [{"axis": [0,0,0], "offset": [0,0,0]}]}"#, "continuous symmetry 0 has a zero"),
        ] {
            let err = load(&with(json), &tensors, &texture).unwrap_err();
            assert!(err.contains(needle), "{json}: {err}");
        }
    }

    /// A grid side of 65 536 or more overflowed `n · n` (u32) in the patch-cell check; any
    /// grid other than the backbone's would size estimation's crops wrongly.
    #[test]
    fn grids_that_are_not_the_backbones_are_refused() {
        let (manifest, tensors, texture) = seed();
        assert!(manifest.contains("\"n\": 2,"));
        for n in ["3", "65536", "4294967295"] {
            let err = load(&manifest.replace("\"n\": 2,", &format!("\"n\": {n},")), &tensors, &texture).unwrap_err();
            assert!(err.contains(&format!("its {n}² grid of 8 px patches is not the backbone's (16 px input, 8 px patches)")), "{n}: {err}");
        }
        assert_eq!(crate::geometry::PatchGrid { n: u32::MAX, patch: 1 }.len(), u32::MAX as usize * u32::MAX as usize);
    }
}
