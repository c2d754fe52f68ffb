//! Concatenates per-object pieces (OBJ models, glTF primitives) into one `MeshData`, one part
//! per piece. Pieces may disagree on which attributes they carry; a mesh's attributes are
//! all-or-nothing, so gaps are filled with neutral values (white, uv 0) — except normals,
//! which are dropped entirely so that `Mesh::new` computes consistent ones for every vertex.

use super::{Material, MeshData, Part};

/// One piece: positions already in metres, triangles indexing into this piece's vertices.
pub(super) struct Piece {
    pub positions: Vec<[f32; 3]>,
    pub normals: Option<Vec<[f32; 3]>>,
    pub colors: Option<Vec<[f32; 3]>>,
    pub uvs: Option<Vec<[f32; 2]>>,
    pub triangles: Vec<[u32; 3]>,
    pub material: u32,
}

const WHITE: [f32; 3] = [1.0; 3];

pub(super) struct Assembler {
    data: MeshData,
    all_have_normals: bool,
}

impl Assembler {
    pub(super) fn new() -> Self {
        Self { data: MeshData::default(), all_have_normals: true }
    }

    /// Appends a piece; the error says which attribute is inconsistent (the caller adds which
    /// piece it was).
    pub(super) fn push(&mut self, piece: Piece) -> Result<(), String> {
        let n = piece.positions.len();
        for (what, len) in [("normals", piece.normals.as_ref().map(Vec::len)), ("colours", piece.colors.as_ref().map(Vec::len)), ("texture coordinates", piece.uvs.as_ref().map(Vec::len))] {
            if let Some(len) = len.filter(|&len| len != n) {
                return Err(format!("{len} {what} for {n} vertices"));
            }
        }
        if let Some(t) = piece.triangles.iter().find(|t| t.iter().any(|&i| i as usize >= n)) {
            return Err(format!("triangle {t:?} references a vertex beyond the {n} vertices"));
        }
        if piece.triangles.is_empty() {
            return Ok(());
        }
        let d = &mut self.data;
        let (max_vertices, max_triangles) = (crate::limits::MAX_MESH_VERTICES, crate::limits::MAX_MESH_TRIANGLES);
        if d.positions.len() + n > max_vertices || d.triangles.len() + piece.triangles.len() > max_triangles {
            return Err(format!("the mesh grows past the limit of {max_vertices} vertices or {max_triangles} triangles"));
        }
        let base = d.positions.len();
        match piece.normals {
            Some(normals) if self.all_have_normals => d.normals.extend(normals),
            _ => {
                self.all_have_normals = false;
                d.normals = Vec::new();
            }
        }
        extend_or_fill(&mut d.colors, piece.colors, base, n, WHITE);
        extend_or_fill(&mut d.uvs, piece.uvs, base, n, [0.0; 2]);
        d.positions.extend(piece.positions);
        let first_triangle = d.triangles.len() as u32;
        let offset = base as u32;
        d.triangles.extend(piece.triangles.iter().map(|t| t.map(|i| i + offset)));
        let triangle_count = d.triangles.len() as u32 - first_triangle;
        d.parts.push(Part { first_triangle, triangle_count, material: piece.material });
        Ok(())
    }

    pub(super) fn is_empty(&self) -> bool {
        self.data.triangles.is_empty()
    }

    pub(super) fn finish(self, materials: Vec<Material>) -> MeshData {
        MeshData { materials, ..self.data }
    }
}

/// Keeps `all` (currently `base` long if non-empty) aligned with the positions: the first piece
/// that has the attribute back-fills earlier vertices, later pieces without it get `fill`.
fn extend_or_fill<T: Copy>(all: &mut Vec<T>, piece: Option<Vec<T>>, base: usize, n: usize, fill: T) {
    match piece {
        Some(values) => {
            all.resize(base, fill);
            all.extend(values);
        }
        None if !all.is_empty() => all.resize(base + n, fill),
        None => {}
    }
}
