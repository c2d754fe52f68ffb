//! glTF 2.0 (.gltf with external or data-URI buffers and images, or .glb) via the `gltf` crate.
//! The default scene's node hierarchy is baked into the positions and normals; each triangle
//! primitive becomes one part.
//!
//! Conventions: glTF lengths are metres by specification; texture v is flipped
//! (v = 1 - v_gltf) to the OBJ/PLY convention shared by all loaders; COLOR_0 is linear in glTF
//! and converted to sRGB, which is what `MeshData::colors` holds.

use super::assemble::{Assembler, Piece};
use super::files::{Folder, MeshFiles};
use super::texture::{decode_texture, texture_error};
use super::{Material, Mesh, MeshError, Units};
use crate::limits::{MAX_MESH_TRIANGLES, MAX_MESH_VERTICES};
use ::gltf::buffer;
use ::gltf::mesh::Mode;
use base64::Engine as _;
use nalgebra::{Matrix3, Matrix4, Point3, Vector3};
use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

/// Deeper hierarchies than this are refused (the recursion's stack stays small).
const MAX_NODE_DEPTH: usize = 256;

/// Loads a .gltf or .glb file. `units` may only be `None` or metres: glTF fixes its unit, and
/// silently ignoring a different request would hide a caller's mistake.
pub fn load_gltf(path: &Path, units: Option<Units>) -> Result<Mesh, MeshError> {
    gltf_from_bytes(path, &super::files::read_mesh_file(path)?, units, &Folder::beside(path))
}

/// A .gltf or .glb file's bytes, the buffers and images it names from `files`; `path`
/// names it in errors.
pub(super) fn gltf_from_bytes(path: &Path, bytes: &[u8], units: Option<Units>, files: &dyn MeshFiles) -> Result<Mesh, MeshError> {
    if let Some(u) = units.filter(|&u| u != Units::M) {
        return Err(MeshError::format(path, format!("glTF is in metres by specification; units {:?} cannot be applied", u.as_str())));
    }
    check_before_gltf_crate(bytes).map_err(|e| MeshError::format(path, format!("invalid glTF: {e}")))?;
    let ::gltf::Gltf { document, mut blob } = ::gltf::Gltf::from_slice(bytes).map_err(|e| MeshError::format(path, format!("invalid glTF: {e}")))?;
    let mut buffers = Vec::new();
    for b in document.buffers() {
        let data = match b.source() {
            buffer::Source::Bin => blob.take().ok_or_else(|| "the file has no binary chunk".to_string()),
            buffer::Source::Uri(uri) => read_uri(uri, files),
        };
        let data = data.map_err(|e| MeshError::format(path, format!("buffer {} ({}): {e}", b.index(), describe(b.source()))))?;
        if data.len() < b.length() {
            return Err(MeshError::format(path, format!("buffer {} has {} bytes, the file declares {}", b.index(), data.len(), b.length())));
        }
        buffers.push(data);
    }
    let mut loader = Loader {
        path,
        files,
        buffers: &buffers,
        assembler: Assembler::new(),
        materials: Vec::new(),
        material_index: HashMap::new(),
        images: HashMap::new(),
        visited: vec![false; document.nodes().count()],
    };
    match document.default_scene().or_else(|| document.scenes().next()) {
        Some(scene) => {
            for node in scene.nodes() {
                loader.node(node, Matrix4::identity(), 0)?;
            }
        }
        // A file without scenes still defines meshes; show them untransformed.
        None => {
            for mesh in document.meshes() {
                loader.mesh(mesh, &Matrix4::identity())?;
            }
        }
    }
    let Loader { assembler, materials, .. } = loader;
    if assembler.is_empty() {
        return Err(MeshError::format(path, "no faces: the scene has no triangle primitives"));
    }
    Mesh::new(path.display().to_string(), Units::M, assembler.finish(materials))
}

/// What the gltf crates panic on while reading the document (both found by fuzzing): a
/// GLB header declaring fewer than its own 12 bytes (gltf subtracts 12 unchecked), and a
/// primitive's POSITION naming an accessor that does not exist (gltf-json's validation
/// indexes the accessors with it before checking it).
fn check_before_gltf_crate(bytes: &[u8]) -> Result<(), String> {
    let json = match bytes.get(8..12).filter(|_| bytes.starts_with(b"glTF")) {
        Some(length) if u32::from_le_bytes(length.try_into().expect("4 bytes")) < 12 => return Err("GLB header declares fewer than its own 12 bytes".into()),
        // The JSON chunk: its length at 12, its type at 16, its data from 20.
        Some(_) => bytes.get(12..16).and_then(|n| bytes.get(20..20 + u32::from_le_bytes(n.try_into().expect("4 bytes")) as usize)),
        None => Some(bytes),
    };
    // Read as the gltf crate reads it: the first JSON value whatever follows (a padded
    // chunk), unknown fields skipped unchecked (even invalid UTF-8 in their strings). What
    // does not read so, the gltf crate refuses itself.
    #[derive(serde::Deserialize, Default)]
    #[serde(default)]
    struct Doc {
        accessors: Vec<serde::de::IgnoredAny>,
        meshes: Vec<DocMesh>,
    }
    #[derive(serde::Deserialize, Default)]
    #[serde(default)]
    struct DocMesh {
        primitives: Vec<DocPrimitive>,
    }
    #[derive(serde::Deserialize, Default)]
    #[serde(default)]
    struct DocPrimitive {
        attributes: DocAttributes,
    }
    #[derive(serde::Deserialize, Default)]
    #[serde(default)]
    struct DocAttributes {
        #[serde(rename = "POSITION")]
        position: Option<u64>,
    }
    let first = |j: &[u8]| serde_json::Deserializer::from_slice(j).into_iter::<Doc>().next().and_then(Result::ok);
    let Some(doc) = json.and_then(first) else { return Ok(()) };
    for (m, mesh) in doc.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            if let Some(i) = prim.attributes.position.filter(|&i| i >= doc.accessors.len() as u64) {
                return Err(format!("mesh {m} primitive {p}: POSITION accessor {i} does not exist"));
            }
        }
    }
    Ok(())
}

/// The bytes a buffer or image URI names: base64 `data:` URIs, `file:` paths, and paths
/// relative to the glTF file (percent-encoded). Our own rather than the gltf crate's,
/// which reads any path it is given and panics on a name that is not UTF-8 once decoded.
fn read_uri(uri: &str, files: &dyn MeshFiles) -> Result<Vec<u8>, String> {
    if let Some(rest) = uri.strip_prefix("data:") {
        let (header, data) = rest.split_once(',').ok_or("data URI without a comma")?;
        if !header.ends_with(";base64") {
            return Err("only base64 data URIs are supported".into());
        }
        let lenient =
            base64::engine::GeneralPurpose::new(&base64::alphabet::STANDARD, base64::engine::GeneralPurposeConfig::new().with_decode_padding_mode(base64::engine::DecodePaddingMode::Indifferent));
        return lenient.decode(data).map_err(|e| format!("data URI is not valid base64: {e}"));
    }
    let path = match uri.strip_prefix("file://").or_else(|| uri.strip_prefix("file:")) {
        Some(path) => path,
        None if uri.contains(':') => return Err("unsupported URI scheme (expected data:, file: or a relative path)".into()),
        None => uri,
    };
    files.read(&crate::percent::decode(path, crate::percent::Malformed::Keep)?)
}

/// Names a buffer source for messages without dumping a whole data URI.
fn describe(source: buffer::Source) -> String {
    match source {
        buffer::Source::Bin => "GLB binary chunk".into(),
        buffer::Source::Uri(uri) if uri.starts_with("data:") => "data URI".into(),
        buffer::Source::Uri(uri) => format!("{uri:?}"),
    }
}

struct Loader<'a> {
    path: &'a Path,
    files: &'a dyn MeshFiles,
    buffers: &'a [Vec<u8>],
    assembler: Assembler,
    materials: Vec<Material>,
    /// glTF material index (None: the spec's default material) to ours.
    material_index: HashMap<Option<usize>, u32>,
    images: HashMap<usize, Arc<image::RgbaImage>>,
    /// Nodes already placed: glTF's hierarchy is a tree, and a node reached twice (a cycle,
    /// or shared children) could multiply the work exponentially with depth.
    visited: Vec<bool>,
}

impl Loader<'_> {
    fn node(&mut self, node: ::gltf::Node, parent: Matrix4<f64>, depth: usize) -> Result<(), MeshError> {
        if depth > MAX_NODE_DEPTH {
            return Err(MeshError::format(self.path, format!("node hierarchy deeper than {MAX_NODE_DEPTH} at node {}", node.index())));
        }
        if std::mem::replace(&mut self.visited[node.index()], true) {
            return Err(MeshError::format(self.path, format!("node {} is reached twice: the node hierarchy must be a tree", node.index())));
        }
        let local = node.transform().matrix();
        let world = parent * Matrix4::from_fn(|r, c| local[c][r] as f64);
        if let Some(mesh) = node.mesh() {
            self.mesh(mesh, &world)?;
        }
        for child in node.children() {
            self.node(child, world, depth + 1)?;
        }
        Ok(())
    }

    fn mesh(&mut self, mesh: ::gltf::Mesh, world: &Matrix4<f64>) -> Result<(), MeshError> {
        let path = self.path;
        for prim in mesh.primitives() {
            let at = |e: String| MeshError::format(path, format!("mesh {} primitive {}: {e}", mesh.index(), prim.index()));
            if !matches!(prim.mode(), Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan) {
                tracing::warn!("{}: mesh {} primitive {} skipped: {:?} has no surface", self.path.display(), mesh.index(), prim.index(), prim.mode());
                continue;
            }
            let material = self.material(prim.material())?;
            let uv_set = self.materials[material as usize].texture.as_ref().and(texcoord_set(&prim.material()));
            let piece = self.piece(&prim, world, uv_set, material).map_err(at)?;
            self.assembler.push(piece).map_err(at)?;
        }
        Ok(())
    }

    fn piece(&self, prim: &::gltf::Primitive, world: &Matrix4<f64>, uv_set: Option<u32>, material: u32) -> Result<Piece, String> {
        use ::gltf::accessor::{DataType as T, Dimensions as D};
        use ::gltf::Semantic as S;
        for (semantic, accessor) in prim.attributes() {
            // The attributes read below, with the shapes the reader takes (it panics on others).
            let shape: (&[D], &[T]) = match semantic {
                S::Positions | S::Normals => (&[D::Vec3], &[T::F32]),
                S::Colors(_) => (&[D::Vec3, D::Vec4], &[T::U8, T::U16, T::F32]),
                S::TexCoords(_) => (&[D::Vec2], &[T::U8, T::U16, T::F32]),
                _ => continue,
            };
            check_accessor(&accessor, shape, MAX_MESH_VERTICES, self.buffers).map_err(|e| format!("{semantic:?} accessor {}: {e}", accessor.index()))?;
        }
        if let Some(indices) = prim.indices() {
            let shape: (&[D], &[T]) = (&[D::Scalar], &[T::U8, T::U16, T::U32]);
            check_accessor(&indices, shape, 3 * MAX_MESH_TRIANGLES, self.buffers).map_err(|e| format!("index accessor {}: {e}", indices.index()))?;
        }
        let reader = prim.reader(|b| self.buffers.get(b.index()).map(|d| &d[..]));
        let positions: Vec<[f32; 3]> = reader
            .read_positions()
            .ok_or("no POSITION attribute")?
            .map(|p| {
                let q = world.transform_point(&Point3::new(p[0] as f64, p[1] as f64, p[2] as f64));
                [q.x as f32, q.y as f32, q.z as f32]
            })
            .collect();
        // Normals transform with the inverse transpose; a singular transform (zero scale)
        // leaves them to be recomputed.
        let linear: Matrix3<f64> = world.fixed_view::<3, 3>(0, 0).into_owned();
        let normal_matrix = linear.try_inverse().map(|m| m.transpose());
        let normals = reader.read_normals().zip(normal_matrix).map(|(it, m)| {
            it.map(|n| {
                let v = (m * Vector3::new(n[0] as f64, n[1] as f64, n[2] as f64)).normalize();
                [v.x as f32, v.y as f32, v.z as f32]
            })
            .collect()
        });
        let colors = reader.read_colors(0).map(|c| c.into_rgb_f32().map(|c| c.map(linear_to_srgb)).collect());
        let uvs = uv_set.and_then(|set| reader.read_tex_coords(set)).map(|t| t.into_f32().map(|[u, v]| [u, 1.0 - v]).collect());
        let indices: Vec<u32> = match reader.read_indices() {
            Some(i) => i.into_u32().collect(),
            None => (0..positions.len() as u32).collect(),
        };
        let mut triangles = triangulate(prim.mode(), &indices);
        // A mirroring transform turns counter-clockwise faces clockwise; swap to keep them front.
        if linear.determinant() < 0.0 {
            triangles.iter_mut().for_each(|t| t.swap(1, 2));
        }
        Ok(Piece { positions, normals, colors, uvs, triangles, material })
    }

    /// Our index for a glTF material, converting it (and decoding its texture) on first use.
    fn material(&mut self, m: ::gltf::Material) -> Result<u32, MeshError> {
        if let Some(&i) = self.material_index.get(&m.index()) {
            return Ok(i);
        }
        let name = m.name().map(String::from).unwrap_or_else(|| m.index().map_or("default".into(), |i| format!("material {i}")));
        // Specular-glossiness materials put their colour in `diffuse`.
        let (base_color, texture) = match m.pbr_specular_glossiness() {
            Some(sg) => (sg.diffuse_factor(), sg.diffuse_texture()),
            None => (m.pbr_metallic_roughness().base_color_factor(), m.pbr_metallic_roughness().base_color_texture()),
        };
        let texture = match texture {
            Some(info) => Some(self.image(info.texture().source())?.into()),
            None => None,
        };
        self.materials.push(Material { name, base_color, texture });
        let i = self.materials.len() as u32 - 1;
        self.material_index.insert(m.index(), i);
        Ok(i)
    }

    fn image(&mut self, image: ::gltf::Image) -> Result<Arc<image::RgbaImage>, MeshError> {
        if let Some(decoded) = self.images.get(&image.index()) {
            return Ok(decoded.clone());
        }
        let (name, bytes) = match image.source() {
            ::gltf::image::Source::View { view, .. } => {
                let name = format!("image {} (buffer view {})", image.index(), view.index());
                let data = &self.buffers[view.buffer().index()];
                let bytes = view.offset().checked_add(view.length()).and_then(|end| data.get(view.offset()..end));
                let bytes = bytes.ok_or_else(|| texture_error(self.path, &name, "buffer view beyond its buffer".into()))?;
                (name, bytes.to_vec())
            }
            ::gltf::image::Source::Uri { uri, .. } => {
                let name = if uri.starts_with("data:") { format!("image {} (data URI)", image.index()) } else { uri.to_string() };
                let data = read_uri(uri, self.files).map_err(|e| texture_error(self.path, &name, e))?;
                (name, data)
            }
        };
        let decoded = decode_texture(self.path, &name, &bytes)?;
        self.images.insert(image.index(), decoded.clone());
        Ok(decoded)
    }
}

/// Checks what the gltf crate's accessor reader takes on trust (it panics on a count of 0,
/// a stride shorter than an item or a shape other than `shape`'s dimensions and component
/// types, and a sparse accessor without a buffer view makes `count` items out of nothing),
/// and bounds `count` by `max` before anything is read.
fn check_accessor(a: &::gltf::Accessor, shape: (&[::gltf::accessor::Dimensions], &[::gltf::accessor::DataType]), max: usize, buffers: &[Vec<u8>]) -> Result<(), String> {
    if !shape.0.contains(&a.dimensions()) || !shape.1.contains(&a.data_type()) {
        return Err(format!("{:?} of {:?} is not a type this attribute may have", a.dimensions(), a.data_type()));
    }
    if a.count() == 0 || a.count() > max {
        return Err(format!("count {} is outside 1..={max}", a.count()));
    }
    let view_ok = |view: &::gltf::buffer::View, item: usize| {
        let fits = view.offset().checked_add(view.length()).is_some_and(|end| end <= buffers.get(view.buffer().index()).map_or(0, Vec::len));
        fits && view.stride().is_none_or(|s| s >= item)
    };
    if let Some(view) = a.view() {
        if !view_ok(&view, a.size()) {
            return Err(format!("buffer view {} is beyond its buffer or its stride is shorter than an item", view.index()));
        }
    }
    if let Some(sparse) = a.sparse() {
        let (indices, values) = (sparse.indices(), sparse.values());
        if sparse.count() == 0 || sparse.count() > a.count() || !view_ok(&indices.view(), indices.index_type().size()) || !view_ok(&values.view(), a.size()) {
            return Err("malformed sparse storage".into());
        }
    }
    Ok(())
}

/// The TEXCOORD set the material's colour texture reads.
fn texcoord_set(m: &::gltf::Material) -> Option<u32> {
    match m.pbr_specular_glossiness() {
        Some(sg) => sg.diffuse_texture().map(|t| t.tex_coord()),
        None => m.pbr_metallic_roughness().base_color_texture().map(|t| t.tex_coord()),
    }
}

fn triangulate(mode: Mode, idx: &[u32]) -> Vec<[u32; 3]> {
    let n = idx.len();
    match mode {
        Mode::Triangles => idx.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect(),
        // Every other strip triangle is reversed so that all keep the first one's winding.
        Mode::TriangleStrip => (0..n.saturating_sub(2)).map(|i| if i % 2 == 0 { [idx[i], idx[i + 1], idx[i + 2]] } else { [idx[i + 1], idx[i], idx[i + 2]] }).collect(),
        Mode::TriangleFan => (1..n.saturating_sub(1)).map(|i| [idx[0], idx[i], idx[i + 1]]).collect(),
        _ => Vec::new(),
    }
}

fn linear_to_srgb(c: f32) -> f32 {
    let c = c.clamp(0.0, 1.0);
    if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_util::{assert_close, assert_error, write_png};
    use super::*;
    use serde_json::{json, Value};
    use std::path::PathBuf;

    /// Collects binary data and the bufferViews/accessors describing it (buffer 0).
    #[derive(Default)]
    struct Bin {
        bytes: Vec<u8>,
        views: Vec<Value>,
        accessors: Vec<Value>,
    }

    impl Bin {
        fn view(&mut self, data: &[u8]) -> usize {
            self.bytes.resize(self.bytes.len().next_multiple_of(4), 0);
            self.views.push(json!({"buffer": 0, "byteOffset": self.bytes.len(), "byteLength": data.len()}));
            self.bytes.extend_from_slice(data);
            self.views.len() - 1
        }
        fn floats<const N: usize>(&mut self, data: &[[f32; N]]) -> usize {
            let bytes: Vec<u8> = data.iter().flatten().flat_map(|f| f.to_le_bytes()).collect();
            let view = self.view(&bytes);
            let ty = ["SCALAR", "VEC2", "VEC3", "VEC4"][N - 1];
            // POSITION accessors must carry bounds; NaN is left out of them.
            let min: Vec<f32> = (0..N).map(|k| data.iter().map(|v| v[k]).fold(f32::INFINITY, f32::min)).collect();
            let max: Vec<f32> = (0..N).map(|k| data.iter().map(|v| v[k]).fold(f32::NEG_INFINITY, f32::max)).collect();
            self.accessors.push(json!({"bufferView": view, "componentType": 5126, "count": data.len(), "type": ty, "min": min, "max": max}));
            self.accessors.len() - 1
        }
        fn indices(&mut self, data: &[u16]) -> usize {
            let bytes: Vec<u8> = data.iter().flat_map(|i| i.to_le_bytes()).collect();
            let view = self.view(&bytes);
            self.accessors.push(json!({"bufferView": view, "componentType": 5123, "count": data.len(), "type": "SCALAR"}));
            self.accessors.len() - 1
        }
    }

    fn base64(bytes: &[u8]) -> String {
        const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
        let mut out = String::new();
        for chunk in bytes.chunks(3) {
            let n = chunk.iter().enumerate().fold(0u32, |n, (i, &b)| n | (b as u32) << (16 - 8 * i));
            for k in 0..4 {
                out.push(if k <= chunk.len() { ALPHABET[(n >> (18 - 6 * k) & 63) as usize] as char } else { '=' });
            }
        }
        out
    }

    const TRIANGLE: [[f32; 3]; 3] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];

    /// A textured triangle drawn twice: under node 0 (translation) → node 1 (scale), and
    /// by node 2 (a matrix); node 3 is outside the scene and must not be drawn. Returns the
    /// document, the binary buffer, and the index of a spare view holding `image` if given.
    fn textured_scene(positions: [[f32; 3]; 3], indices: &[u16], image: Option<&[u8]>) -> (Value, Bin, Option<usize>) {
        let mut bin = Bin::default();
        let pos = bin.floats(&positions);
        let normal = bin.floats(&[[0.0, 0.0, 1.0f32]; 3]);
        let uv = bin.floats(&[[0.0, 0.0f32], [1.0, 0.0], [0.0, 1.0]]);
        let idx = bin.indices(indices);
        let image_view = image.map(|bytes| bin.view(bytes));
        let translate_10_x = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 10.0, 0.0, 0.0, 1.0];
        let doc = json!({
            "asset": {"version": "2.0"},
            "scene": 0,
            "scenes": [{"nodes": [0, 2]}],
            "nodes": [
                {"translation": [1.0, 2.0, 3.0], "children": [1]},
                {"scale": [2.0, 2.0, 2.0], "mesh": 0},
                {"matrix": translate_10_x, "mesh": 0},
                {"mesh": 0}
            ],
            "meshes": [{"primitives": [{"attributes": {"POSITION": pos, "NORMAL": normal, "TEXCOORD_0": uv}, "indices": idx, "material": 0}]}],
            "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.25, 1.0, 1.0], "baseColorTexture": {"index": 0}}}],
            "textures": [{"source": 0}],
        });
        (doc, bin, image_view)
    }

    fn png_bytes() -> Vec<u8> {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.png");
        write_png(&path, 3, 2);
        std::fs::read(path).unwrap()
    }

    fn write_json(dir: &Path, name: &str, mut doc: Value, buffer: Value, image: Value) -> PathBuf {
        doc["buffers"] = json!([buffer]);
        doc["images"] = json!([image]);
        let path = dir.join(name);
        std::fs::write(&path, serde_json::to_vec_pretty(&doc).unwrap()).unwrap();
        path
    }

    fn write_glb(path: &Path, mut doc: Value, bin: &[u8]) {
        let mut json = serde_json::to_vec(&doc.take()).unwrap();
        json.resize(json.len().next_multiple_of(4), b' ');
        let mut bin = bin.to_vec();
        bin.resize(bin.len().next_multiple_of(4), 0);
        let mut glb = Vec::new();
        glb.extend(b"glTF");
        glb.extend(2u32.to_le_bytes());
        glb.extend(((12 + 8 + json.len() + 8 + bin.len()) as u32).to_le_bytes());
        glb.extend((json.len() as u32).to_le_bytes());
        glb.extend(b"JSON");
        glb.extend(json);
        glb.extend((bin.len() as u32).to_le_bytes());
        glb.extend(b"BIN\0");
        glb.extend(bin);
        std::fs::write(path, glb).unwrap();
    }

    /// What every variant of the textured scene must load as.
    fn check_textured(mesh: &Mesh) {
        assert_eq!(mesh.positions().len(), 6, "two drawn instances, the unattached node is not drawn");
        let expected = [[1.0, 2.0, 3.0], [3.0, 2.0, 3.0], [1.0, 4.0, 3.0], [10.0, 0.0, 0.0], [11.0, 0.0, 0.0], [10.0, 1.0, 0.0]];
        for (p, e) in mesh.positions().iter().zip(expected) {
            assert_close(p, &e);
        }
        assert_eq!(mesh.triangles(), &[[0, 1, 2], [3, 4, 5]]);
        assert_close(&mesh.uvs().unwrap()[0], &[0.0, 1.0]);
        assert_close(&mesh.uvs().unwrap()[2], &[0.0, 0.0]);
        assert_close(&mesh.normals()[1], &[0.0, 0.0, 1.0]);
        assert_eq!(mesh.materials().len(), 1);
        assert_eq!(mesh.parts().len(), 2);
        assert_close(&mesh.materials()[0].base_color, &[0.5, 0.25, 1.0, 1.0]);
        assert!(mesh.has_texture());
        assert_eq!(mesh.materials()[0].texture.as_ref().unwrap().pixels().unwrap().get_pixel(2, 1).0, [20, 10, 7, 255]);
        assert_eq!(mesh.source_units(), Units::M);
    }

    fn external_files(dir: &Path) -> PathBuf {
        let (doc, bin, _) = textured_scene(TRIANGLE, &[0, 1, 2], None);
        std::fs::write(dir.join("geo data.bin"), &bin.bytes).unwrap();
        std::fs::write(dir.join("tex.png"), png_bytes()).unwrap();
        let mut doc = doc;
        doc["bufferViews"] = json!(bin.views);
        doc["accessors"] = json!(bin.accessors);
        write_json(dir, "scene.gltf", doc, json!({"uri": "geo%20data.bin", "byteLength": bin.bytes.len()}), json!({"uri": "tex.png"}))
    }

    #[test]
    fn external_buffer_and_image_with_node_transforms() {
        let dir = tempfile::tempdir().unwrap();
        let path = external_files(dir.path());
        check_textured(&load_gltf(&path, None).unwrap());
        check_textured(&load_gltf(&path, Some(Units::M)).unwrap());
    }

    #[test]
    fn data_uris() {
        let dir = tempfile::tempdir().unwrap();
        let (mut doc, bin, _) = textured_scene(TRIANGLE, &[0, 1, 2], None);
        doc["bufferViews"] = json!(bin.views);
        doc["accessors"] = json!(bin.accessors);
        let buffer = json!({"uri": format!("data:application/octet-stream;base64,{}", base64(&bin.bytes)), "byteLength": bin.bytes.len()});
        let image = json!({"uri": format!("data:image/png;base64,{}", base64(&png_bytes()))});
        check_textured(&load_gltf(&write_json(dir.path(), "inline.gltf", doc, buffer, image), None).unwrap());
    }

    #[test]
    fn glb_with_embedded_image() {
        let dir = tempfile::tempdir().unwrap();
        let png = png_bytes();
        let (mut doc, bin, view) = textured_scene(TRIANGLE, &[0, 1, 2], Some(&png));
        doc["bufferViews"] = json!(bin.views);
        doc["accessors"] = json!(bin.accessors);
        doc["buffers"] = json!([{"byteLength": bin.bytes.len()}]);
        doc["images"] = json!([{"bufferView": view.unwrap(), "mimeType": "image/png"}]);
        let path = dir.path().join("packed.GLB");
        write_glb(&path, doc, &bin.bytes);
        check_textured(&load_gltf(&path, None).unwrap());
    }

    #[test]
    fn vertex_colours_become_srgb_and_strips_triangulate() {
        let dir = tempfile::tempdir().unwrap();
        let mut bin = Bin::default();
        let pos = bin.floats(&[[0.0, 0.0, 0.0f32], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]]);
        let colour = bin.floats(&[[1.0, 0.5, 0.0f32], [0.0, 0.0, 0.0], [0.2, 0.2, 0.2], [1.0, 1.0, 1.0]]);
        let doc = json!({
            "asset": {"version": "2.0"},
            "scenes": [{"nodes": [0]}],
            "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": pos, "COLOR_0": colour}, "mode": 5}]}],
            "bufferViews": bin.views,
            "accessors": bin.accessors,
            "buffers": [{"byteLength": bin.bytes.len()}],
        });
        let path = dir.path().join("vc.glb");
        write_glb(&path, doc, &bin.bytes);
        let mesh = load_gltf(&path, None).unwrap();
        assert_eq!(mesh.triangles(), &[[0, 1, 2], [2, 1, 3]]);
        let colours = mesh.colors().unwrap();
        assert_close(&colours[0], &[1.0, 0.735_357, 0.0]);
        assert_close(&colours[2], &[0.484_529; 3]);
        assert!(!mesh.has_texture());
    }

    // ---- errors

    #[test]
    fn units_other_than_metres_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = external_files(dir.path());
        assert_error(load_gltf(&path, Some(Units::Mm)), &path, &["metres by specification", "\"mm\""]);
    }

    #[test]
    fn missing_buffer_and_image() {
        let dir = tempfile::tempdir().unwrap();
        let path = external_files(dir.path());
        std::fs::remove_file(dir.path().join("tex.png")).unwrap();
        let result = load_gltf(&path, None);
        assert!(matches!(result, Err(MeshError::Texture { .. })));
        assert_error(result, &path, &["\"tex.png\"", "not found"]);
        std::fs::remove_file(dir.path().join("geo data.bin")).unwrap();
        assert_error(load_gltf(&path, None), &path, &["buffer 0", "geo%20data.bin"]);
    }

    #[test]
    fn short_buffer() {
        let dir = tempfile::tempdir().unwrap();
        let path = external_files(dir.path());
        let bin = dir.path().join("geo data.bin");
        let bytes = std::fs::read(&bin).unwrap();
        std::fs::write(&bin, &bytes[..bytes.len() - 8]).unwrap();
        assert_error(load_gltf(&path, None), &path, &["buffer 0 has", "declares"]);
    }

    #[test]
    fn bad_geometry() {
        let dir = tempfile::tempdir().unwrap();
        let glb = |name: &str, positions, indices: &[u16]| {
            let (mut doc, bin, _) = textured_scene(positions, indices, None);
            doc["bufferViews"] = json!(bin.views);
            doc["accessors"] = json!(bin.accessors);
            doc["buffers"] = json!([{"byteLength": bin.bytes.len()}]);
            doc["materials"] = json!([{}]);
            doc.as_object_mut().unwrap().remove("textures");
            let path = dir.path().join(name);
            write_glb(&path, doc, &bin.bytes);
            path
        };
        let path = glb("range.glb", TRIANGLE, &[0, 1, 7]);
        assert_error(load_gltf(&path, None), &path, &["mesh 0 primitive 0", "beyond the 3 vertices"]);
        let mut nan = TRIANGLE;
        nan[1][2] = f32::NAN;
        let path = glb("nan.glb", nan, &[0, 1, 2]);
        assert_error(load_gltf(&path, None), &path, &["non-finite"]);
        let path = glb("ok.glb", TRIANGLE, &[0, 1, 2]);
        let bytes = std::fs::read(&path).unwrap();
        let cut = dir.path().join("cut.glb");
        std::fs::write(&cut, &bytes[..bytes.len() - 10]).unwrap();
        assert_error(load_gltf(&cut, None), &cut, &["invalid glTF"]);
        let json = dir.path().join("bad.gltf");
        std::fs::write(&json, "{\"asset\": {\"version\": \"2.0\"}, \"meshes\": [").unwrap();
        assert_error(load_gltf(&json, None), &json, &["invalid glTF"]);
    }

    #[test]
    fn no_triangles() {
        let dir = tempfile::tempdir().unwrap();
        let mut bin = Bin::default();
        let pos = bin.floats(&TRIANGLE);
        let doc = json!({
            "asset": {"version": "2.0"},
            "scenes": [{"nodes": [0]}],
            "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": pos}, "mode": 0}]}],
            "bufferViews": bin.views,
            "accessors": bin.accessors,
            "buffers": [{"byteLength": bin.bytes.len()}],
        });
        let path = dir.path().join("points.glb");
        write_glb(&path, doc, &bin.bytes);
        assert_error(load_gltf(&path, None), &path, &["no faces"]);
    }
}
