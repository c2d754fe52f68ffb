//! `dir://PATH`: one folder per object, `PATH/<id>/{manifest.json, tensors.safetensors,
//! textures/*.png}`. A put writes a hidden temporary folder, syncs it and renames it into
//! place (a replace swaps the two folders in one `renameat2(RENAME_EXCHANGE)` where the
//! file system has it), so readers see an object whole or not at all; leftovers of killed
//! writers are hidden (dot names) and removed at the next open. The tensors are
//! memory-mapped on load.
//!
//! A reader opens the object's files one after the other, so a replace by another process
//! can land between two of them. Every write carries a random generation in all its files
//! (`codec.rs`), so such a torn read is detected, and `get` reads again.

use super::codec::{self, Encoded};
use super::{info_of, unique_suffix, validate_id, ObjectInfo, ObjectStore, StoreError};
use crate::onboard::ObjectModel;
use std::path::{Path, PathBuf};

const MANIFEST: &str = "manifest.json";
const TENSORS: &str = "tensors.safetensors";

pub struct DirStore {
    root: PathBuf,
}

/// Whether the process that named a temporary folder `.<id>.tmp-<pid>-<n>` still runs.
fn writer_alive(name: &str) -> bool {
    let pid = name.rsplit_once(".tmp-").or_else(|| name.rsplit_once(".old-")).and_then(|(_, s)| s.split('-').next()).and_then(|p| p.parse::<u32>().ok());
    match pid {
        Some(pid) => Path::new(&format!("/proc/{pid}")).exists(),
        None => false,
    }
}

fn dir_bytes(p: &Path) -> u64 {
    std::fs::read_dir(p).map(|rd| rd.flatten().map(|e| if e.path().is_dir() { dir_bytes(&e.path()) } else { e.metadata().map(|m| m.len()).unwrap_or(0) }).sum()).unwrap_or(0)
}

/// Swaps two paths atomically (Linux `renameat2(RENAME_EXCHANGE)`); false where the
/// kernel or file system cannot, so the caller falls back to two renames.
fn exchange(a: &Path, b: &Path) -> bool {
    use std::os::unix::ffi::OsStrExt;
    let (Ok(ca), Ok(cb)) = (std::ffi::CString::new(a.as_os_str().as_bytes()), std::ffi::CString::new(b.as_os_str().as_bytes())) else {
        return false;
    };
    // SAFETY: both arguments are valid NUL-terminated paths that outlive the call.
    unsafe { libc::renameat2(libc::AT_FDCWD, ca.as_ptr(), libc::AT_FDCWD, cb.as_ptr(), libc::RENAME_EXCHANGE) == 0 }
}

/// Reads of one object attempted before a torn read (a replace racing it) is reported.
const READ_ATTEMPTS: u32 = 6;

fn sync_dir(p: &Path) -> Result<(), StoreError> {
    std::fs::File::open(p).and_then(|f| f.sync_all()).map_err(StoreError::io(format!("syncing {}", p.display())))
}

impl DirStore {
    /// Opens (creating) the folder and removes what killed writers left behind.
    pub fn open(root: impl Into<PathBuf>) -> Result<Self, StoreError> {
        let root = root.into();
        std::fs::create_dir_all(&root).map_err(StoreError::io(format!("creating store folder {}", root.display())))?;
        for e in std::fs::read_dir(&root).map_err(StoreError::io(format!("reading {}", root.display())))?.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if name.starts_with('.') && (name.contains(".tmp-") || name.contains(".old-")) && !writer_alive(&name) {
                let _ = std::fs::remove_dir_all(e.path());
            }
        }
        Ok(Self { root })
    }

    /// Opens an existing folder as it is: no folder created, no leftovers removed (their
    /// writer may run in another container, where its pid means nothing here).
    pub fn open_read_only(root: impl Into<PathBuf>) -> Result<Self, StoreError> {
        let root = root.into();
        if !root.is_dir() {
            return Err(StoreError::Io {
                context: format!("opening store folder {} read-only", root.display()),
                source: std::io::Error::new(std::io::ErrorKind::NotFound, "no such folder (a read-only store is never created)"),
            });
        }
        Ok(Self { root })
    }

    fn object_dir(&self, id: &str) -> Result<PathBuf, StoreError> {
        validate_id(id)?;
        Ok(self.root.join(id))
    }

    fn write_encoded(dir: &Path, enc: &Encoded) -> Result<(), StoreError> {
        std::fs::create_dir_all(dir.join("textures")).map_err(StoreError::io(format!("creating {}", dir.display())))?;
        let mut files = vec![(dir.join(MANIFEST), enc.manifest.as_slice()), (dir.join(TENSORS), enc.tensors.as_slice())];
        files.extend(enc.textures.iter().map(|(name, png)| (dir.join(name), png.as_slice())));
        for (path, bytes) in files {
            use std::io::Write;
            let mut f = std::fs::File::create(&path).map_err(StoreError::io(format!("writing {}", path.display())))?;
            f.write_all(bytes).and_then(|()| f.sync_all()).map_err(StoreError::io(format!("writing {}", path.display())))?;
        }
        sync_dir(&dir.join("textures"))?;
        sync_dir(dir)
    }

    /// One attempt at reading an object.
    fn read_once(&self, id: &str, dir: &Path) -> Result<ObjectModel, StoreError> {
        let manifest =
            std::fs::read(dir.join(MANIFEST))
                .map_err(|e| if e.kind() == std::io::ErrorKind::NotFound { StoreError::NotFound(id.into()) } else { StoreError::io(format!("reading object {id:?}"))(e) })?;
        let tpath = dir.join(TENSORS);
        let file = std::fs::File::open(&tpath).map_err(|e| StoreError::Corrupt { object: id.into(), message: format!("{}: {e}", tpath.display()) })?;
        // SAFETY: stored files are never modified in place (puts write a new folder and
        // rename it), so the mapping cannot change under us while it is alive.
        let map = std::sync::Arc::new(unsafe { memmap2::Mmap::map(&file) }.map_err(StoreError::io(format!("mapping {}", tpath.display())))?);
        let mut texture = |name: &str| std::fs::read(dir.join(name)).map_err(|e| e.to_string());
        // The model keeps the mapping: its f16 descriptors are read in place.
        let model = codec::decode_mapped(&manifest, &map, &mut texture).map_err(|e| StoreError::from_codec(id, e))?;
        // The decode copied the small tensors (templates' globals, contour and detector
        // models, mesh arrays) out of the mapping, which left their pages mapped (resident,
        // counted in the process's RSS) though they are never read there again. Unmapping
        // them keeps them in the page cache; the mapped arrays' pages come back on first
        // read, as they would anyway.
        // SAFETY: a read-only mapping of a file never modified in place: pages dropped
        // from it read back the same bytes.
        if let Err(e) = unsafe { map.unchecked_advise(memmap2::UncheckedAdvice::DontNeed) } {
            tracing::debug!("madvise(DONTNEED) on {}: {e}", tpath.display());
        }
        if model.object_id != id {
            return Err(StoreError::Corrupt { object: id.into(), message: format!("its folder holds object {:?}", model.object_id) });
        }
        Ok(model)
    }

    /// Whether a put or delete of `id` is under way (its hidden folders exist).
    fn write_in_progress(&self, id: &str) -> bool {
        let prefix = format!(".{id}.");
        std::fs::read_dir(&self.root).map(|rd| rd.flatten().any(|e| e.file_name().to_string_lossy().starts_with(&prefix))).unwrap_or(false)
    }

    fn info_at(&self, id: &str, dir: &Path) -> Result<ObjectInfo, StoreError> {
        let raw = std::fs::read(dir.join(MANIFEST)).map_err(|e| {
            if e.kind() == std::io::ErrorKind::NotFound {
                StoreError::NotFound(id.into())
            } else {
                StoreError::io(format!("reading {}", dir.display()))(e)
            }
        })?;
        let s = codec::summary(&raw).map_err(|e| StoreError::from_codec(id, e))?;
        Ok(info_of(&s, dir_bytes(dir)))
    }
}

impl ObjectStore for DirStore {
    fn put(&self, model: &ObjectModel, replace: bool) -> Result<ObjectInfo, StoreError> {
        let target = self.object_dir(&model.object_id)?;
        if target.exists() && !replace {
            return Err(StoreError::AlreadyExists(model.object_id.clone()));
        }
        let enc = codec::encode(model).map_err(|e| StoreError::from_codec(&model.object_id, e))?;
        let tmp = self.root.join(format!(".{}.tmp-{}", model.object_id, unique_suffix()));
        let result = Self::write_encoded(&tmp, &enc).and_then(|()| {
            if target.exists() {
                if exchange(&tmp, &target) {
                    // `tmp` now holds the old object.
                    let _ = std::fs::remove_dir_all(&tmp);
                } else {
                    // Two renames: for a moment the object is absent (readers retry).
                    let old = self.root.join(format!(".{}.old-{}", model.object_id, unique_suffix()));
                    std::fs::rename(&target, &old).map_err(StoreError::io(format!("moving {} aside", target.display())))?;
                    std::fs::rename(&tmp, &target).map_err(StoreError::io(format!("renaming into {}", target.display())))?;
                    let _ = std::fs::remove_dir_all(&old);
                }
            } else {
                std::fs::rename(&tmp, &target).map_err(StoreError::io(format!("renaming into {}", target.display())))?;
            }
            sync_dir(&self.root)
        });
        if result.is_err() {
            let _ = std::fs::remove_dir_all(&tmp);
        }
        result?;
        self.info_at(&model.object_id, &target)
    }

    fn get(&self, id: &str) -> Result<ObjectModel, StoreError> {
        let dir = self.object_dir(id)?;
        let mut attempt = 0;
        loop {
            match self.read_once(id, &dir) {
                // A replace may have raced this read: read again while one is under way
                // (and once in any case, since it may just have finished).
                Err(StoreError::Corrupt { .. } | StoreError::NotFound(_)) if attempt + 1 < READ_ATTEMPTS && (attempt == 0 || self.write_in_progress(id)) => {
                    std::thread::sleep(std::time::Duration::from_millis(5 << attempt));
                    attempt += 1;
                }
                other => return other,
            }
        }
    }

    fn list(&self) -> Result<Vec<ObjectInfo>, StoreError> {
        let mut out = Vec::new();
        for e in std::fs::read_dir(&self.root).map_err(StoreError::io(format!("reading {}", self.root.display())))?.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if validate_id(&name).is_ok() && e.path().join(MANIFEST).is_file() {
                match self.info_at(&name, &e.path()) {
                    Ok(i) => out.push(i),
                    // Deleted since the folder was listed.
                    Err(StoreError::NotFound(_)) => {}
                    Err(e) => return Err(e),
                }
            }
        }
        out.sort_by(|a, b| a.id.cmp(&b.id));
        Ok(out)
    }

    fn info(&self, id: &str) -> Result<ObjectInfo, StoreError> {
        let dir = self.object_dir(id)?;
        self.info_at(id, &dir)
    }

    fn delete(&self, id: &str) -> Result<(), StoreError> {
        let dir = self.object_dir(id)?;
        if !dir.join(MANIFEST).exists() {
            return Err(StoreError::NotFound(id.into()));
        }
        // Renamed away first, so the object disappears at once and as a whole.
        let gone = self.root.join(format!(".{id}.old-{}", unique_suffix()));
        std::fs::rename(&dir, &gone).map_err(StoreError::io(format!("deleting {}", dir.display())))?;
        sync_dir(&self.root)?;
        std::fs::remove_dir_all(&gone).map_err(StoreError::io(format!("removing {}", gone.display())))
    }

    fn exists(&self, id: &str) -> Result<bool, StoreError> {
        Ok(self.object_dir(id)?.join(MANIFEST).is_file())
    }

    /// From the manifest file's identity and times: a put writes a new folder (swapped in
    /// by rename), so the manifest of a replaced object is another file.
    fn generation(&self, id: &str) -> Result<Option<u64>, StoreError> {
        use std::hash::{Hash, Hasher};
        use std::os::unix::fs::MetadataExt;
        let path = self.object_dir(id)?.join(MANIFEST);
        match std::fs::metadata(&path) {
            Ok(m) => {
                let mut h = std::collections::hash_map::DefaultHasher::new();
                (m.dev(), m.ino(), m.size(), m.mtime(), m.mtime_nsec(), m.ctime(), m.ctime_nsec()).hash(&mut h);
                Ok(Some(h.finish()))
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(e) => Err(StoreError::io(format!("reading {}", path.display()))(e)),
        }
    }

    fn url(&self) -> String {
        format!("dir://{}", self.root.display())
    }
}
