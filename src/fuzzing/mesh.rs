//! The mesh loaders on bytes: the mesh file, then the files it refers to, handed out in
//! the order the loader asks for them whatever their names (so the fuzzer need not guess
//! names to reach the MTL, texture and buffer parsers).

use crate::mesh::{load_mesh_bytes, MeshFiles, Units};
use std::cell::Cell;
use std::path::Path;

struct InOrder<'a> {
    files: Vec<&'a [u8]>,
    next: Cell<usize>,
}

impl MeshFiles for InOrder<'_> {
    fn read(&self, name: &str) -> Result<Vec<u8>, String> {
        let i = self.next.replace(self.next.get() + 1);
        self.files.get(i).map(|f| f.to_vec()).ok_or_else(|| format!("{name:?}: not found"))
    }
}

fn load(name: &str, data: &[u8], units: Option<Units>) {
    let parts = super::split(data);
    let files = InOrder { files: parts[1..].to_vec(), next: Cell::new(0) };
    if let Ok(mesh) = load_mesh_bytes(Path::new(name), parts[0], units, &files) {
        assert!(mesh.positions().len() <= crate::limits::MAX_MESH_VERTICES && mesh.triangles().len() <= crate::limits::MAX_MESH_TRIANGLES);
        assert!(mesh.diameter().is_finite(), "a loaded mesh has finite coordinates");
    }
}

pub fn mesh_ply(data: &[u8]) {
    load("fuzz.ply", data, Some(Units::Mm));
}

pub fn mesh_obj(data: &[u8]) {
    load("fuzz.obj", data, Some(Units::Mm));
}

pub fn mesh_gltf(data: &[u8]) {
    load("fuzz.glb", data, None);
}
