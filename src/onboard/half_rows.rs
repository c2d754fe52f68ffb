//! An object's f16 descriptor rows, owned or memory-mapped. A `dir://` object's tensors
//! file is mapped on load, and its descriptors — most of an object's bytes, of which an
//! estimate reads only the few short-listed templates' rows — are used in place: loading
//! costs little more than opening the file, and only the pages matching touches become
//! resident, as page cache the kernel can drop and share between processes.

use half::f16;
use std::ops::Deref;
use std::sync::Arc;

#[derive(Clone)]
pub enum HalfRows {
    Owned(Vec<f16>),
    /// `len` values at byte `offset` of a read-only mapping of a stored file. Stores never
    /// change a stored file in place (they write new files and rename), so the bytes stay
    /// as decoded for as long as the mapping lives.
    Mapped { map: Arc<memmap2::Mmap>, offset: usize, len: usize },
}

impl HalfRows {
    /// The values of `bytes`, a part of `map`, in place; `None` when they are not there or
    /// not aligned for f16 (the caller copies then).
    pub fn mapped(map: &Arc<memmap2::Mmap>, bytes: &[u8]) -> Option<Self> {
        let offset = (bytes.as_ptr() as usize).checked_sub(map.as_ptr() as usize)?;
        if offset + bytes.len() > map.len() || bytemuck::try_cast_slice::<u8, f16>(bytes).is_err() {
            return None;
        }
        Some(HalfRows::Mapped { map: map.clone(), offset, len: bytes.len() / 2 })
    }

    pub fn is_mapped(&self) -> bool {
        matches!(self, HalfRows::Mapped { .. })
    }

    /// Bytes held on the heap (a mapping's pages are the kernel's page cache).
    pub fn heap_bytes(&self) -> usize {
        match self {
            HalfRows::Owned(v) => v.len() * 2,
            HalfRows::Mapped { .. } => 0,
        }
    }
}

impl Deref for HalfRows {
    type Target = [f16];
    fn deref(&self) -> &[f16] {
        match self {
            HalfRows::Owned(v) => v,
            // Checked in `mapped`: inside the mapping and aligned.
            HalfRows::Mapped { map, offset, len } => bytemuck::cast_slice(&map[*offset..*offset + *len * 2]),
        }
    }
}

impl From<Vec<f16>> for HalfRows {
    fn from(v: Vec<f16>) -> Self {
        HalfRows::Owned(v)
    }
}

impl PartialEq for HalfRows {
    fn eq(&self, other: &Self) -> bool {
        **self == **other
    }
}

impl std::fmt::Debug for HalfRows {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "HalfRows({} values, {})", self.len(), if self.is_mapped() { "mapped" } else { "owned" })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mapped_rows_read_the_file_in_place_and_refuse_what_is_not_theirs() {
        let values: Vec<f16> = (0..100).map(|i| f16::from_f32(i as f32 / 7.0)).collect();
        let mut bytes = vec![0u8; 8];
        bytes.extend_from_slice(bytemuck::cast_slice(&values));
        let file = tempfile::NamedTempFile::new().unwrap();
        std::fs::write(file.path(), &bytes).unwrap();
        // SAFETY: the test's own file, not modified while mapped.
        let map = Arc::new(unsafe { memmap2::Mmap::map(&std::fs::File::open(file.path()).unwrap()) }.unwrap());
        let rows = HalfRows::mapped(&map, &map[8..]).expect("aligned, inside the mapping");
        assert!(rows.is_mapped() && rows.heap_bytes() == 0);
        assert_eq!(&*rows, &values[..]);
        assert_eq!(rows, HalfRows::from(values.clone()));
        assert!(HalfRows::mapped(&map, &map[9..13]).is_none(), "misaligned");
        let elsewhere = vec![0u8; 16];
        assert!(HalfRows::mapped(&map, &elsewhere).is_none(), "not part of the mapping");
    }
}
