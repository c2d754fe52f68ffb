//! Writes a `Mesh` as a BOP model: ASCII PLY in millimetres with normals, per-vertex
//! `texture_u`/`texture_v` and a `comment TextureFile` naming the PNG written beside it
//! (the layout of BOP's `models/obj_NNNNNN.ply`). Synthetic BOP datasets and tests use it
//! to turn generated objects into BOP models.

use super::types::{Mesh, MeshError};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Writes `dir/name.ply` (and `dir/name.png` for a textured mesh); returns the PLY path.
/// PLY holds one texture, so a mesh with several textured materials is refused; a single
/// untextured material's base colour becomes vertex colours.
pub fn write_bop_ply(mesh: &Mesh, dir: &Path, name: &str) -> Result<PathBuf, MeshError> {
    let ply_path = dir.join(format!("{name}.ply"));
    let textures: Vec<_> = mesh.materials().iter().filter_map(|m| m.texture.as_ref()).collect();
    if textures.len() > 1 {
        return Err(MeshError::format(&ply_path, format!("{} textured materials; a PLY model holds one texture", textures.len())));
    }
    std::fs::create_dir_all(dir).map_err(|source| MeshError::Io { path: dir.to_path_buf(), source })?;
    let texture_file = format!("{name}.png");
    if let Some(tex) = textures.first() {
        let path = dir.join(&texture_file);
        let error = |message: String| MeshError::Texture { path: ply_path.clone(), texture: texture_file.clone(), message };
        tex.pixels().map_err(error)?.save(&path).map_err(|e| error(e.to_string()))?;
    }
    let uvs = mesh.uvs().filter(|_| !textures.is_empty());
    let base = mesh.materials().first().map_or([1.0; 4], |m| m.base_color);
    let colors: Option<Vec<[f32; 3]>> = match mesh.colors() {
        Some(c) => Some(c.to_vec()),
        None if textures.is_empty() && mesh.materials().len() == 1 && base[..3] != [1.0, 1.0, 1.0] => Some(vec![[base[0], base[1], base[2]]; mesh.positions().len()]),
        None => None,
    };

    let mut out = String::from("ply\nformat ascii 1.0\ncomment written by b2tfpose; units: mm\n");
    if uvs.is_some() {
        let _ = writeln!(out, "comment TextureFile {texture_file}");
    }
    let _ = writeln!(out, "element vertex {}", mesh.positions().len());
    out.push_str("property float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\n");
    if colors.is_some() {
        out.push_str("property uchar red\nproperty uchar green\nproperty uchar blue\n");
    }
    if uvs.is_some() {
        out.push_str("property float texture_u\nproperty float texture_v\n");
    }
    let _ = writeln!(out, "element face {}\nproperty list uchar int vertex_indices\nend_header", mesh.triangles().len());
    for (i, (p, n)) in mesh.positions().iter().zip(mesh.normals()).enumerate() {
        let _ = write!(out, "{} {} {} {} {} {}", p[0] * 1000.0, p[1] * 1000.0, p[2] * 1000.0, n[0], n[1], n[2]);
        if let Some(c) = &colors {
            let byte = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
            let _ = write!(out, " {} {} {}", byte(c[i][0]), byte(c[i][1]), byte(c[i][2]));
        }
        if let Some(uv) = uvs {
            let _ = write!(out, " {} {}", uv[i][0], uv[i][1]);
        }
        out.push('\n');
    }
    for t in mesh.triangles() {
        let _ = writeln!(out, "3 {} {} {}", t[0], t[1], t[2]);
    }
    std::fs::write(&ply_path, out).map_err(|source| MeshError::Io { path: ply_path.clone(), source })?;
    Ok(ply_path)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{load_mesh, procedural::textured_box, Units};

    #[test]
    fn written_box_loads_back_in_mm_with_its_texture() {
        let m = textured_box([0.1, 0.06, 0.16], 5);
        let dir = tempfile::tempdir().unwrap();
        let path = write_bop_ply(&m, dir.path(), "obj_000001").unwrap();
        let back = load_mesh(&path, Some(Units::Mm)).unwrap();
        assert_eq!(back.triangles(), m.triangles());
        for (a, b) in back.positions().iter().zip(m.positions()) {
            assert!((0..3).all(|k| (a[k] - b[k]).abs() < 1e-6), "{a:?} vs {b:?}");
        }
        assert!(back.has_texture());
        assert_eq!(back.uvs().unwrap(), m.uvs().unwrap());
    }
}
