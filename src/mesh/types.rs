use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};

/// Length unit of a mesh file. glTF is metres by its specification; PLY and OBJ carry no
/// unit, so the caller must say which one the file uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Units {
    Mm,
    Cm,
    M,
}

impl Units {
    /// Metres per file unit.
    pub fn to_metres(self) -> f64 {
        match self {
            Units::Mm => 1e-3,
            Units::Cm => 1e-2,
            Units::M => 1.0,
        }
    }

    pub fn as_str(self) -> &'static str {
        match self {
            Units::Mm => "mm",
            Units::Cm => "cm",
            Units::M => "m",
        }
    }
}

impl std::str::FromStr for Units {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "mm" | "millimetre" | "millimetres" | "millimeter" | "millimeters" => Ok(Units::Mm),
            "cm" | "centimetre" | "centimetres" | "centimeter" | "centimeters" => Ok(Units::Cm),
            "m" | "metre" | "metres" | "meter" | "meters" => Ok(Units::M),
            other => Err(format!("unknown length unit {other:?}: expected mm, cm or m")),
        }
    }
}

/// What went wrong loading or building a mesh. Every variant names the file it concerns.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: {message}")]
    Format { path: PathBuf, message: String },
    #[error("{path}: texture {texture:?} not found or unreadable: {message}")]
    Texture { path: PathBuf, texture: String, message: String },
    #[error("{path}: units must be given for this format (mm, cm or m)")]
    UnitsRequired { path: PathBuf },
    #[error("{path}: unsupported mesh format (expected .ply, .obj, .gltf or .glb)")]
    UnsupportedFormat { path: PathBuf },
}

impl MeshError {
    pub fn format(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        MeshError::Format { path: path.into(), message: message.into() }
    }
}

/// Surface appearance of one part: a base colour (linear RGBA in 0..1, multiplied with the
/// texture and vertex colours, as glTF does) and an optional sRGB texture.
#[derive(Clone, Debug)]
pub struct Material {
    pub name: String,
    pub base_color: [f32; 4],
    pub texture: Option<super::Texture>,
}

impl Default for Material {
    fn default() -> Self {
        Self { name: "default".into(), base_color: [1.0, 1.0, 1.0, 1.0], texture: None }
    }
}

/// A contiguous range of triangles drawn with one material.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Part {
    pub first_triangle: u32,
    pub triangle_count: u32,
    pub material: u32,
}

/// The raw arrays a loader produces; `Mesh::new` validates them.
#[derive(Clone, Debug, Default)]
pub struct MeshData {
    /// Object-frame positions in metres.
    pub positions: Vec<[f32; 3]>,
    /// Unit normals per vertex; computed from the faces when empty.
    pub normals: Vec<[f32; 3]>,
    /// Per-vertex sRGB colours in 0..1, or empty.
    pub colors: Vec<[f32; 3]>,
    /// Per-vertex texture coordinates (u right, v up as in OBJ/PLY; glTF's v-down is
    /// flipped by its loader), or empty.
    pub uvs: Vec<[f32; 2]>,
    pub triangles: Vec<[u32; 3]>,
    /// Empty means one part over all triangles with material 0.
    pub parts: Vec<Part>,
    /// Empty means one default material.
    pub materials: Vec<Material>,
}

static NEXT_MESH_ID: AtomicU64 = AtomicU64::new(1);

/// A validated triangle mesh. Immutable once built, so that its `id` can key GPU caches:
/// a clone shares the id because it shares the content.
#[derive(Clone, Debug)]
pub struct Mesh {
    id: u64,
    name: String,
    source_units: Units,
    data: MeshData,
    bbox_min: [f32; 3],
    bbox_max: [f32; 3],
    diameter: f64,
}

impl Mesh {
    /// Checks the arrays (finite coordinates, attribute lengths, index range, at least one
    /// face, part ranges) and computes what is derived: normals if absent, bounding box and
    /// diameter. `name` is used in error messages (usually the file path).
    pub fn new(name: impl Into<String>, source_units: Units, data: MeshData) -> Result<Self, MeshError> {
        Self::build(name.into(), source_units, data, None)
    }

    /// `new` for a mesh whose diameter was computed before (a stored object's): the O(n·512)
    /// search, 60 % of a textured object's load, is skipped when `diameter` is plausible for
    /// the vertices (between their bounding box's longest side and its diagonal).
    pub fn with_diameter(name: impl Into<String>, source_units: Units, data: MeshData, diameter: f64) -> Result<Self, MeshError> {
        Self::build(name.into(), source_units, data, Some(diameter))
    }

    fn build(name: String, source_units: Units, mut data: MeshData, known_diameter: Option<f64>) -> Result<Self, MeshError> {
        let err = |m: String| MeshError::format(name.clone(), m);
        let n = data.positions.len();
        if n == 0 {
            return Err(err("mesh has no vertices".into()));
        }
        if data.triangles.is_empty() {
            return Err(err("mesh has no faces".into()));
        }
        let (max_vertices, max_triangles) = (crate::limits::MAX_MESH_VERTICES, crate::limits::MAX_MESH_TRIANGLES);
        if n > max_vertices || data.triangles.len() > max_triangles {
            return Err(err(format!("{n} vertices and {} triangles: over the limit of {max_vertices} vertices and {max_triangles} triangles", data.triangles.len())));
        }
        if let Some(i) = data.positions.iter().position(|p| p.iter().any(|c| !c.is_finite())) {
            return Err(err(format!("vertex {i} has a non-finite coordinate {:?}", data.positions[i])));
        }
        for (what, len) in [("normals", data.normals.len()), ("colours", data.colors.len()), ("texture coordinates", data.uvs.len())] {
            if len != 0 && len != n {
                return Err(err(format!("{len} {what} for {n} vertices")));
            }
        }
        if let Some((f, t)) = data.triangles.iter().enumerate().find(|(_, t)| t.iter().any(|&i| i as usize >= n)) {
            return Err(err(format!("face {f} references vertex {:?} but there are only {n} vertices", t)));
        }
        if data.uvs.iter().any(|uv| uv.iter().any(|c| !c.is_finite())) {
            return Err(err("non-finite texture coordinate".into()));
        }
        if data.materials.is_empty() {
            data.materials.push(Material::default());
        }
        if data.parts.is_empty() {
            data.parts.push(Part { first_triangle: 0, triangle_count: data.triangles.len() as u32, material: 0 });
        }
        for (i, p) in data.parts.iter().enumerate() {
            let end = p.first_triangle as u64 + p.triangle_count as u64;
            if end > data.triangles.len() as u64 || p.material as usize >= data.materials.len() {
                return Err(err(format!("part {i} is out of range ({p:?})")));
            }
        }
        if data.normals.is_empty() || data.normals.iter().any(|v| v.iter().any(|c| !c.is_finite())) {
            data.normals = vertex_normals(&data.positions, &data.triangles);
        }
        let (bbox_min, bbox_max) = bounding_box(&data.positions);
        let sides = (0..3).map(|i| (bbox_max[i] - bbox_min[i]) as f64);
        let (longest, diagonal) = (sides.clone().fold(0.0, f64::max), sides.map(|s| s * s).sum::<f64>().sqrt());
        let plausible = |d: &f64| d.is_finite() && *d >= longest * (1.0 - 1e-6) && *d <= diagonal * (1.0 + 1e-6);
        let diameter = known_diameter.filter(plausible).unwrap_or_else(|| diameter(&data.positions));
        Ok(Self { id: NEXT_MESH_ID.fetch_add(1, Ordering::Relaxed), name, source_units, data, bbox_min, bbox_max, diameter })
    }

    /// Process-unique identity of this content (for GPU caches).
    pub fn id(&self) -> u64 {
        self.id
    }
    pub fn name(&self) -> &str {
        &self.name
    }
    pub fn source_units(&self) -> Units {
        self.source_units
    }
    pub fn positions(&self) -> &[[f32; 3]] {
        &self.data.positions
    }
    pub fn normals(&self) -> &[[f32; 3]] {
        &self.data.normals
    }
    /// Per-vertex sRGB colours, if the file had them.
    pub fn colors(&self) -> Option<&[[f32; 3]]> {
        (!self.data.colors.is_empty()).then_some(&self.data.colors[..])
    }
    pub fn uvs(&self) -> Option<&[[f32; 2]]> {
        (!self.data.uvs.is_empty()).then_some(&self.data.uvs[..])
    }
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.data.triangles
    }
    pub fn parts(&self) -> &[Part] {
        &self.data.parts
    }
    pub fn materials(&self) -> &[Material] {
        &self.data.materials
    }
    pub fn data(&self) -> &MeshData {
        &self.data
    }
    pub fn has_texture(&self) -> bool {
        self.uvs().is_some() && self.data.materials.iter().any(|m| m.texture.is_some())
    }

    /// Colours of its own (a texture or vertex colours), which a render can be compared
    /// with a photo by.
    pub fn has_colours(&self) -> bool {
        self.has_texture() || self.colors().is_some()
    }
    /// The same geometry with no texture, no vertex colours and one plain material: what
    /// an untextured CAD model gives (used to simulate the render-to-real gap).
    pub fn without_appearance(&self) -> Mesh {
        let data = MeshData { positions: self.data.positions.clone(), normals: self.data.normals.clone(), triangles: self.data.triangles.clone(), ..Default::default() };
        Mesh::new(format!("{} (untextured)", self.name), self.source_units, data).expect("geometry was valid")
    }

    /// Axis-aligned bounding box in metres (min, max).
    pub fn bbox(&self) -> ([f32; 3], [f32; 3]) {
        (self.bbox_min, self.bbox_max)
    }
    pub fn bbox_center(&self) -> [f64; 3] {
        std::array::from_fn(|i| 0.5 * (self.bbox_min[i] as f64 + self.bbox_max[i] as f64))
    }
    /// Largest distance from the bounding-box centre to a vertex, metres: the radius of a
    /// sphere about `bbox_center` that holds the whole mesh (views and placements fit it).
    pub fn bounding_radius(&self) -> f64 {
        let c = self.bbox_center();
        self.data.positions.iter().map(|p| (0..3).map(|i| (p[i] as f64 - c[i]).powi(2)).sum::<f64>().sqrt()).fold(0.0, f64::max)
    }

    /// Largest distance between two vertices, in metres (the BOP definition).
    pub fn diameter(&self) -> f64 {
        self.diameter
    }
}

/// Axis-aligned bounding box (min, max) of `p`; infinite corners when `p` is empty.
pub fn bounding_box(p: &[[f32; 3]]) -> ([f32; 3], [f32; 3]) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for v in p {
        for i in 0..3 {
            lo[i] = lo[i].min(v[i]);
            hi[i] = hi[i].max(v[i]);
        }
    }
    (lo, hi)
}

/// Area-weighted vertex normals; vertices on no face get +z.
fn vertex_normals(p: &[[f32; 3]], tris: &[[u32; 3]]) -> Vec<[f32; 3]> {
    let mut acc = vec![[0f64; 3]; p.len()];
    for t in tris {
        let [a, b, c] = t.map(|i| p[i as usize].map(|x| x as f64));
        let e1 = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let e2 = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        let n = [e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]];
        for &i in t {
            for k in 0..3 {
                acc[i as usize][k] += n[k];
            }
        }
    }
    acc.iter()
        .map(|n| {
            let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            if l > 0.0 {
                [(n[0] / l) as f32, (n[1] / l) as f32, (n[2] / l) as f32]
            } else {
                [0.0, 0.0, 1.0]
            }
        })
        .collect()
}

/// Vertex diameter without the O(n²) scan (exact up to 2000 vertices): the farthest pair
/// lies on the convex hull, and hull vertices are extreme along some direction, so the
/// candidates are the extremes over 512 directions and the pairwise scan runs over those few
/// points only. Not exact in general: the result is at least cos θ of the true diameter, θ
/// being the angle from the true pair's direction to the nearest sampled one (about 0.1 rad
/// at most for this many directions, so under 1 %); on the point cloud of the test below it
/// equals the brute-force scan.
fn diameter(p: &[[f32; 3]]) -> f64 {
    if p.len() <= 2000 {
        return brute_diameter(p.iter().map(|v| v.map(|x| x as f64)));
    }
    // Fibonacci sphere of directions (both signs are covered by min and max).
    let dirs = 512;
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let mut candidates: Vec<usize> = Vec::with_capacity(dirs * 2);
    for k in 0..dirs {
        let z = 1.0 - (k as f64 + 0.5) / dirs as f64;
        let r = (1.0 - z * z).sqrt();
        let d = [r * (golden * k as f64).cos(), r * (golden * k as f64).sin(), z];
        let (mut imin, mut imax, mut vmin, mut vmax) = (0, 0, f64::INFINITY, f64::NEG_INFINITY);
        for (i, v) in p.iter().enumerate() {
            let s = v[0] as f64 * d[0] + v[1] as f64 * d[1] + v[2] as f64 * d[2];
            if s < vmin {
                vmin = s;
                imin = i;
            }
            if s > vmax {
                vmax = s;
                imax = i;
            }
        }
        candidates.push(imin);
        candidates.push(imax);
    }
    candidates.sort_unstable();
    candidates.dedup();
    brute_diameter(candidates.iter().map(|&i| p[i].map(|x| x as f64)))
}

fn brute_diameter(points: impl Iterator<Item = [f64; 3]>) -> f64 {
    let pts: Vec<[f64; 3]> = points.collect();
    let mut best = 0f64;
    for i in 0..pts.len() {
        for j in i + 1..pts.len() {
            let d = (0..3).map(|k| (pts[i][k] - pts[j][k]).powi(2)).sum::<f64>();
            best = best.max(d);
        }
    }
    best.sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tetra() -> MeshData {
        MeshData { positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], triangles: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], ..Default::default() }
    }

    #[test]
    fn diameter_and_bbox_of_tetrahedron() {
        let m = Mesh::new("t", Units::M, tetra()).unwrap();
        assert!((m.diameter() - 2f64.sqrt()).abs() < 1e-6);
        assert_eq!(m.bbox(), ([0.0; 3], [1.0; 3]));
        assert_eq!(m.normals().len(), 4);
    }

    #[test]
    fn diameter_of_large_sphere_cloud_matches_brute_force() {
        let pts: Vec<[f32; 3]> = (0..5000)
            .map(|i| {
                let a = i as f32 * 0.7;
                let b = i as f32 * 0.13;
                [a.cos() * b.sin() * (1.0 + 0.1 * (i % 7) as f32), a.sin() * b.sin(), b.cos() * 0.5]
            })
            .collect();
        let fast = diameter(&pts);
        let slow = brute_diameter(pts.iter().map(|v| v.map(|x| x as f64)));
        assert!((fast - slow).abs() < 1e-9 * slow.max(1.0), "{fast} vs {slow}");
    }

    #[test]
    fn a_known_diameter_is_kept_when_plausible_else_computed() {
        let exact = 2f64.sqrt();
        let kept = Mesh::with_diameter("t", Units::M, tetra(), exact * 0.99).unwrap();
        assert_eq!(kept.diameter(), exact * 0.99);
        // Beyond the box's diagonal, below its longest side, or not a number: recomputed.
        for wrong in [2.0, 0.5, f64::NAN] {
            assert!((Mesh::with_diameter("t", Units::M, tetra(), wrong).unwrap().diameter() - exact).abs() < 1e-6, "{wrong}");
        }
    }

    #[test]
    fn rejects_bad_arrays() {
        let mut d = tetra();
        d.positions[1][0] = f32::NAN;
        assert!(Mesh::new("t", Units::M, d).unwrap_err().to_string().contains("non-finite"));
        let mut d = tetra();
        d.triangles[0][0] = 9;
        assert!(Mesh::new("t", Units::M, d).unwrap_err().to_string().contains("only 4 vertices"));
        let mut d = tetra();
        d.triangles.clear();
        assert!(Mesh::new("t", Units::M, d).unwrap_err().to_string().contains("no faces"));
    }
}
