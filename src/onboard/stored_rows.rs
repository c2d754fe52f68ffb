//! An object's large arrays, owned or memory-mapped. A `dir://` object's tensors file is
//! mapped on load, and its per-patch arrays — the descriptors (f16 rows or codes), the
//! patch points and cells, the template silhouettes: nearly all of an object's bytes, of
//! which an estimate reads only the few short-listed templates' rows — are used in place:
//! loading costs little more than opening the file, and only the pages an estimate touches
//! become resident, as page cache the kernel can drop and share between processes.

use bytemuck::Pod;
use std::marker::PhantomData;
use std::ops::Deref;
use std::sync::Arc;

#[derive(Clone)]
pub enum StoredRows<T: Pod> {
    Owned(Vec<T>),
    /// `len` values at byte `offset` of a read-only mapping of a stored file. Stores never
    /// change a stored file in place (they write new files and rename), so the bytes stay
    /// as decoded for as long as the mapping lives.
    Mapped {
        map: Arc<memmap2::Mmap>,
        offset: usize,
        len: usize,
        values: PhantomData<T>,
    },
}

/// f16 descriptor rows.
pub type HalfRows = StoredRows<half::f16>;

impl<T: Pod> StoredRows<T> {
    /// The values of `bytes`, a part of `map`, in place; `None` when they are not there, not
    /// a whole number of values, or not aligned for `T` (the caller copies then).
    pub fn mapped(map: &Arc<memmap2::Mmap>, bytes: &[u8]) -> Option<Self> {
        let offset = (bytes.as_ptr() as usize).checked_sub(map.as_ptr() as usize)?;
        if offset + bytes.len() > map.len() || bytemuck::try_cast_slice::<u8, T>(bytes).is_err() {
            return None;
        }
        Some(StoredRows::Mapped { map: map.clone(), offset, len: bytes.len() / std::mem::size_of::<T>(), values: PhantomData })
    }

    /// The values of `bytes` in place when `map` holds them (see `mapped`), else a copy.
    pub fn mapped_or_copied(map: Option<&Arc<memmap2::Mmap>>, bytes: &[u8]) -> Self {
        map.and_then(|m| Self::mapped(m, bytes)).unwrap_or_else(|| bytemuck::pod_collect_to_vec(bytes).into())
    }

    pub fn is_mapped(&self) -> bool {
        matches!(self, StoredRows::Mapped { .. })
    }

    /// Bytes held on the heap (a mapping's pages are the kernel's page cache).
    pub fn heap_bytes(&self) -> usize {
        match self {
            StoredRows::Owned(v) => std::mem::size_of_val(v.as_slice()),
            StoredRows::Mapped { .. } => 0,
        }
    }

    /// A copy of the rows in `rows` (each `per_row` values), in that order.
    pub fn gather(&self, rows: &[std::ops::Range<usize>], per_row: usize) -> StoredRows<T> {
        let mut out = Vec::with_capacity(rows.iter().map(|r| r.len() * per_row).sum());
        for r in rows {
            out.extend_from_slice(&self[r.start * per_row..r.end * per_row]);
        }
        out.into()
    }

    /// The values to change, copied out of the mapping first when mapped.
    pub fn to_mut(&mut self) -> &mut Vec<T> {
        if let StoredRows::Mapped { .. } = self {
            *self = StoredRows::Owned(self.to_vec());
        }
        match self {
            StoredRows::Owned(v) => v,
            StoredRows::Mapped { .. } => unreachable!("replaced by an owned copy above"),
        }
    }
}

impl<T: Pod> Deref for StoredRows<T> {
    type Target = [T];
    fn deref(&self) -> &[T] {
        match self {
            StoredRows::Owned(v) => v,
            // Checked in `mapped`: inside the mapping and aligned.
            StoredRows::Mapped { map, offset, len, .. } => bytemuck::cast_slice(&map[*offset..*offset + *len * std::mem::size_of::<T>()]),
        }
    }
}

impl<T: Pod> Default for StoredRows<T> {
    fn default() -> Self {
        StoredRows::Owned(Vec::new())
    }
}

impl<T: Pod> From<Vec<T>> for StoredRows<T> {
    fn from(v: Vec<T>) -> Self {
        StoredRows::Owned(v)
    }
}

impl<T: Pod + PartialEq> PartialEq for StoredRows<T> {
    fn eq(&self, other: &Self) -> bool {
        **self == **other
    }
}

impl<T: Pod> std::fmt::Debug for StoredRows<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "StoredRows<{}>({} values, {})", std::any::type_name::<T>(), self.len(), if self.is_mapped() { "mapped" } else { "owned" })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use half::f16;

    #[test]
    fn mapped_rows_read_the_file_in_place_and_refuse_what_is_not_theirs() {
        let values: Vec<f16> = (0..100).map(|i| f16::from_f32(i as f32 / 7.0)).collect();
        let points: Vec<[f32; 3]> = (0..10).map(|i| [i as f32, 0.5, -1.0]).collect();
        let mut bytes = vec![0u8; 8];
        bytes.extend_from_slice(bytemuck::cast_slice(&values));
        bytes.extend_from_slice(bytemuck::cast_slice(&points));
        let file = tempfile::NamedTempFile::new().unwrap();
        std::fs::write(file.path(), &bytes).unwrap();
        // SAFETY: the test's own file, not modified while mapped.
        let map = Arc::new(unsafe { memmap2::Mmap::map(&std::fs::File::open(file.path()).unwrap()) }.unwrap());
        let rows = HalfRows::mapped(&map, &map[8..208]).expect("aligned, inside the mapping");
        assert!(rows.is_mapped() && rows.heap_bytes() == 0);
        assert_eq!(&*rows, &values[..]);
        assert_eq!(rows, HalfRows::from(values.clone()));
        let mut mapped_points = StoredRows::<[f32; 3]>::mapped_or_copied(Some(&map), &map[208..]);
        assert!(mapped_points.is_mapped() && *mapped_points == points[..]);
        // Changing mapped values copies them out first; the file is untouched.
        mapped_points.to_mut()[0][0] = 42.0;
        assert!(!mapped_points.is_mapped() && mapped_points.heap_bytes() == 120 && mapped_points[0] == [42.0, 0.5, -1.0]);
        assert_eq!(bytemuck::cast_slice::<u8, [f32; 3]>(&map[208..])[0], [0.0, 0.5, -1.0]);
        assert!(HalfRows::mapped(&map, &map[9..13]).is_none(), "misaligned");
        assert!(StoredRows::<[f32; 3]>::mapped(&map, &map[8..18]).is_none(), "not whole values");
        let elsewhere = vec![0u8; 16];
        assert!(HalfRows::mapped(&map, &elsewhere).is_none(), "not part of the mapping");
        assert!(!StoredRows::<f16>::mapped_or_copied(Some(&map), &elsewhere).is_mapped(), "copied");
    }
}
