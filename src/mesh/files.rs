//! Where the files a mesh refers to come from (OBJ's material libraries and textures, PLY's
//! TextureFile, glTF's buffers and images): a folder on disk, or bytes held in memory. The
//! loaders read only through [`MeshFiles`], so they run on bytes alone (fuzzing, tests) and
//! a hostile name cannot make them read a device or a file outside an upload.

use super::MeshError;
use crate::limits::MAX_MESH_RESOURCE_BYTES;
use std::collections::HashMap;
use std::io::Read;
use std::path::{Component, Path, PathBuf};

/// The files a mesh may refer to.
pub trait MeshFiles {
    /// The bytes of the file the mesh calls `name`, a path relative to the mesh's folder.
    /// The error names the file and says what is wrong ("… not found").
    fn read(&self, name: &str) -> Result<Vec<u8>, String>;
}

/// Files in a folder. Only regular files of at most [`MAX_MESH_RESOURCE_BYTES`] are read:
/// a name like `/dev/zero` would otherwise be read until memory runs out.
pub struct Folder {
    dir: PathBuf,
    /// Refuse names that leave the folder (absolute, `..`): for uploads, whose files are
    /// all in the folder and which must not read the server's.
    confined: bool,
}

impl Folder {
    /// The folder of the mesh file `mesh`; names may point anywhere (local files).
    pub fn beside(mesh: &Path) -> Self {
        Self { dir: mesh.parent().unwrap_or(Path::new("")).to_path_buf(), confined: false }
    }

    /// `dir`, refusing names that leave it.
    pub fn confined(dir: &Path) -> Self {
        Self { dir: dir.to_path_buf(), confined: true }
    }
}

impl MeshFiles for Folder {
    fn read(&self, name: &str) -> Result<Vec<u8>, String> {
        let inside = Path::new(name).components().all(|c| matches!(c, Component::Normal(_) | Component::CurDir));
        if self.confined && !inside {
            return Err(format!("{name:?}: refused, only names inside the upload are allowed"));
        }
        let path = self.dir.join(name);
        let shown = path.display();
        let meta = std::fs::metadata(&path).map_err(|e| match e.kind() {
            std::io::ErrorKind::NotFound => format!("{shown}: not found"),
            _ => format!("{shown}: unreadable ({e})"),
        })?;
        if !meta.is_file() {
            return Err(format!("{shown}: not a regular file"));
        }
        let too_large = || format!("{shown}: over the limit of {MAX_MESH_RESOURCE_BYTES} bytes");
        if meta.len() > MAX_MESH_RESOURCE_BYTES {
            return Err(too_large());
        }
        // Bounded again while reading, in case the file grows meanwhile.
        let mut bytes = Vec::with_capacity(meta.len() as usize);
        let file = std::fs::File::open(&path).map_err(|e| format!("{shown}: unreadable ({e})"))?;
        file.take(MAX_MESH_RESOURCE_BYTES + 1).read_to_end(&mut bytes).map_err(|e| format!("{shown}: unreadable ({e})"))?;
        if bytes.len() as u64 > MAX_MESH_RESOURCE_BYTES {
            return Err(too_large());
        }
        Ok(bytes)
    }
}

/// Files held in memory by name (exactly as the mesh names them).
#[derive(Default)]
pub struct InMemory(pub HashMap<String, Vec<u8>>);

impl MeshFiles for InMemory {
    fn read(&self, name: &str) -> Result<Vec<u8>, String> {
        self.0.get(name).cloned().ok_or_else(|| format!("{name:?}: not found"))
    }
}

/// The mesh file itself, named by the caller (not by a file), so read as it is.
pub(super) fn read_mesh_file(path: &Path) -> Result<Vec<u8>, MeshError> {
    std::fs::read(path).map_err(|source| MeshError::Io { path: path.to_path_buf(), source })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn folders_read_regular_files_only_and_confined_ones_stay_inside() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("sub")).unwrap();
        std::fs::write(dir.path().join("sub/a.mtl"), "x").unwrap();
        let open = Folder::beside(&dir.path().join("m.obj"));
        assert_eq!(open.read("sub/a.mtl").unwrap(), b"x");
        assert!(open.read("gone.png").unwrap_err().ends_with("gone.png: not found"));
        assert!(open.read("/dev/zero").unwrap_err().ends_with("/dev/zero: not a regular file"));
        assert!(open.read("sub").unwrap_err().ends_with("not a regular file"));
        let upload = Folder::confined(&dir.path().join("sub"));
        assert_eq!(upload.read("a.mtl").unwrap(), b"x");
        for name in ["../sub/a.mtl", "/etc/passwd", "/dev/zero"] {
            assert!(upload.read(name).unwrap_err().contains("only names inside the upload"), "{name}");
        }
        let memory = InMemory(HashMap::from([("a.mtl".to_string(), b"y".to_vec())]));
        assert_eq!(memory.read("a.mtl").unwrap(), b"y");
        assert_eq!(memory.read("b.mtl").unwrap_err(), "\"b.mtl\": not found");
    }
}
