//! Writes a `Mesh` as OBJ + MTL + PNG textures (metres), so that generated sample objects
//! can be fed to the same loaders and commands as a user's CAD files.

use super::types::{Mesh, MeshError};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Writes `dir/name.obj`, `dir/name.mtl` and one PNG per textured material; returns the OBJ path.
pub fn write_obj(mesh: &Mesh, dir: &Path, name: &str) -> Result<PathBuf, MeshError> {
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| MeshError::Io { path, source }
    };
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let mut mtl = String::new();
    for (i, m) in mesh.materials().iter().enumerate() {
        let _ = writeln!(mtl, "newmtl m{i}\nKd {} {} {}", m.base_color[0], m.base_color[1], m.base_color[2]);
        if let Some(tex) = &m.texture {
            let file = format!("{name}_m{i}.png");
            let path = dir.join(&file);
            let error = |message: String| MeshError::Texture { path: path.clone(), texture: file.clone(), message };
            tex.pixels().map_err(error)?.save(&path).map_err(|e| error(e.to_string()))?;
            let _ = writeln!(mtl, "map_Kd {file}");
        }
    }
    let mtl_path = dir.join(format!("{name}.mtl"));
    std::fs::write(&mtl_path, mtl).map_err(io(&mtl_path))?;

    let mut obj = format!("# written by b2tfpose; units: metres\nmtllib {name}.mtl\n");
    for p in mesh.positions() {
        let _ = writeln!(obj, "v {} {} {}", p[0], p[1], p[2]);
    }
    for n in mesh.normals() {
        let _ = writeln!(obj, "vn {} {} {}", n[0], n[1], n[2]);
    }
    let uvs = mesh.uvs();
    for uv in uvs.unwrap_or(&[]) {
        let _ = writeln!(obj, "vt {} {}", uv[0], uv[1]);
    }
    for part in mesh.parts() {
        let _ = writeln!(obj, "usemtl m{}", part.material);
        let tris = &mesh.triangles()[part.first_triangle as usize..(part.first_triangle + part.triangle_count) as usize];
        for t in tris {
            let idx = t.map(|i| i + 1);
            if uvs.is_some() {
                let _ = writeln!(obj, "f {0}/{0}/{0} {1}/{1}/{1} {2}/{2}/{2}", idx[0], idx[1], idx[2]);
            } else {
                let _ = writeln!(obj, "f {0}//{0} {1}//{1} {2}//{2}", idx[0], idx[1], idx[2]);
            }
        }
    }
    let obj_path = dir.join(format!("{name}.obj"));
    std::fs::write(&obj_path, obj).map_err(io(&obj_path))?;
    Ok(obj_path)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{load_mesh, procedural::textured_box, Units};

    #[test]
    fn written_box_loads_back_identically() {
        let m = textured_box([0.1, 0.06, 0.16], 5);
        let dir = tempfile::tempdir().unwrap();
        let path = write_obj(&m, dir.path(), "box").unwrap();
        let back = load_mesh(&path, Some(Units::M)).unwrap();
        assert_eq!(back.triangles().len(), m.triangles().len());
        assert!(back.has_texture());
        assert!((back.diameter() - m.diameter()).abs() < 1e-6);
        assert_eq!(back.materials()[0].texture.as_ref().unwrap().dimensions(), m.materials()[0].texture.as_ref().unwrap().dimensions());
    }
}
