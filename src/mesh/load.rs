//! Picks the loader from the file extension and enforces the units rule: PLY and OBJ carry no
//! unit, so the caller must give one; glTF is metres by specification.

use super::files::{read_mesh_file, Folder, MeshFiles};
use super::{gltf, obj, ply, Mesh, MeshError, Units};
use std::path::Path;

/// Loads a .ply, .obj, .gltf or .glb mesh (extension case-insensitive) into metres, with the
/// files it refers to from its folder.
pub fn load_mesh(path: &Path, units: Option<Units>) -> Result<Mesh, MeshError> {
    load_mesh_with(path, units, &Folder::beside(path))
}

/// [`load_mesh`] with the files the mesh refers to from `files`.
pub fn load_mesh_with(path: &Path, units: Option<Units>, files: &dyn MeshFiles) -> Result<Mesh, MeshError> {
    format_of(path)?;
    load_mesh_bytes(path, &read_mesh_file(path)?, units, files)
}

/// A mesh from its file's bytes; `path` gives the format (extension) and names the file in
/// errors, `files` gives the files it refers to.
pub fn load_mesh_bytes(path: &Path, bytes: &[u8], units: Option<Units>, files: &dyn MeshFiles) -> Result<Mesh, MeshError> {
    let required = || units.ok_or_else(|| MeshError::UnitsRequired { path: path.to_path_buf() });
    match format_of(path)? {
        "ply" => ply::ply_from_bytes(path, bytes, required()?, files),
        "obj" => obj::obj_from_bytes(path, bytes, required()?, files),
        _ => gltf::gltf_from_bytes(path, bytes, units, files),
    }
}

fn format_of(path: &Path) -> Result<&'static str, MeshError> {
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("ply") => Ok("ply"),
        Some("obj") => Ok("obj"),
        Some("gltf" | "glb") => Ok("gltf"),
        _ => Err(MeshError::UnsupportedFormat { path: path.to_path_buf() }),
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_util::assert_error;
    use super::*;

    const TRIANGLE_PLY: &str = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
                                element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";

    #[test]
    fn dispatches_on_extension_case_insensitively() {
        let dir = tempfile::tempdir().unwrap();
        let ply = dir.path().join("tri.PLY");
        std::fs::write(&ply, TRIANGLE_PLY).unwrap();
        assert_eq!(load_mesh(&ply, Some(Units::Mm)).unwrap().positions()[1], [1e-3, 0.0, 0.0]);
        let obj = dir.path().join("tri.Obj");
        std::fs::write(&obj, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
        assert_eq!(load_mesh(&obj, Some(Units::Cm)).unwrap().positions()[1], [1e-2, 0.0, 0.0]);
    }

    #[test]
    fn ply_and_obj_need_units() {
        let dir = tempfile::tempdir().unwrap();
        for name in ["a.ply", "b.obj"] {
            let path = dir.path().join(name);
            std::fs::write(&path, TRIANGLE_PLY).unwrap();
            let result = load_mesh(&path, None);
            assert!(matches!(result, Err(MeshError::UnitsRequired { .. })));
            assert_error(result, &path, &["units must be given"]);
        }
    }

    #[test]
    fn unknown_extension() {
        let dir = tempfile::tempdir().unwrap();
        for name in ["mesh.stl", "no_extension"] {
            let path = dir.path().join(name);
            let result = load_mesh(&path, Some(Units::M));
            assert!(matches!(result, Err(MeshError::UnsupportedFormat { .. })));
            assert_error(result, &path, &["unsupported mesh format"]);
        }
    }

    #[test]
    fn missing_files_are_io_errors() {
        let dir = tempfile::tempdir().unwrap();
        for name in ["gone.ply", "gone.obj", "gone.glb", "gone.gltf"] {
            let path = dir.path().join(name);
            let result = load_mesh(&path, Some(Units::M));
            assert!(matches!(result, Err(MeshError::Io { .. })), "{name}: {result:?}");
            assert_error(result, &path, &[]);
        }
    }

    /// Loads the real meshes of ../shared/data (not part of the repository; skipped when
    /// absent) and checks the HOPE diameters against the dataset's models_info.json.
    /// `cargo test --release real_data -- --nocapture` prints the table.
    #[test]
    fn real_data() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().join("shared/data");
        if !root.is_dir() {
            println!("skipped: {} not found", root.display());
            return;
        }
        let hope = root.join("hope/models");
        let info: serde_json::Value = serde_json::from_slice(&std::fs::read(hope.join("models_info.json")).unwrap()).unwrap();
        let mut files: Vec<(std::path::PathBuf, Option<Units>)> =
            std::fs::read_dir(&hope).unwrap().map(|e| e.unwrap().path()).filter(|p| p.extension().is_some_and(|e| e == "ply")).map(|p| (p, Some(Units::Mm))).collect();
        files.sort_by(|a, b| a.0.cmp(&b.0));
        let meshes = root.join("meshes");
        files.push((meshes.join("fuze.obj"), Some(Units::M)));
        files.push((meshes.join("fuze.ply"), Some(Units::M)));
        for glb in ["Duck.glb", "BoxTextured.glb", "cubevc.glb"] {
            files.push((meshes.join(glb), None));
        }
        println!("{:<18} {:>8} {:>8} {:>12} {:>12} {:>8} {:>7} {:>8}", "file", "vertices", "faces", "diameter mm", "BOP mm", "texture", "colours", "load ms");
        for (path, units) in files {
            let start = std::time::Instant::now();
            let mesh = load_mesh(&path, units).unwrap_or_else(|e| panic!("{e}"));
            let ms = start.elapsed().as_secs_f64() * 1e3;
            let name = path.file_name().unwrap().to_string_lossy().to_string();
            let id = name.strip_prefix("obj_").and_then(|s| s.strip_suffix(".ply")).map(|s| s.trim_start_matches('0').to_string());
            let bop = id.and_then(|id| info[id.as_str()]["diameter"].as_f64());
            let diameter_mm = mesh.diameter() * 1e3;
            println!(
                "{name:<18} {:>8} {:>8} {diameter_mm:>12.3} {:>12} {:>8} {:>7} {ms:>8.1}",
                mesh.positions().len(),
                mesh.triangles().len(),
                bop.map_or("-".into(), |d| format!("{d:.3}")),
                mesh.has_texture(),
                mesh.colors().is_some(),
            );
            if let Some(bop) = bop {
                assert!((diameter_mm - bop).abs() <= 1e-3 * bop, "{name}: diameter {diameter_mm} mm vs {bop} mm");
            }
        }
    }
}
