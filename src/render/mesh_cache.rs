//! Least-recently-used cache of uploaded meshes, keyed by `Mesh::id()`. Generic over the
//! stored value so the policy is testable without a GPU.

pub(crate) struct MeshCache<V> {
    entries: Vec<Entry<V>>,
    capacity: usize,
    clock: u64,
    uploads: u64,
}

struct Entry<V> {
    id: u64,
    value: V,
    last_used: u64,
}

impl<V> MeshCache<V> {
    /// `capacity` is clamped to at least 1: the mesh being drawn must stay resident.
    pub fn new(capacity: usize) -> Self {
        Self { entries: Vec::new(), capacity: capacity.max(1), clock: 0, uploads: 0 }
    }

    /// The cached value for `id`, or the one `upload` builds (evicting the least recently
    /// used entry when full). Capacities are small, so a linear scan beats a map.
    pub fn get_or_insert_with(&mut self, id: u64, upload: impl FnOnce() -> V) -> &V {
        self.clock += 1;
        let i = match self.entries.iter().position(|e| e.id == id) {
            Some(i) => i,
            None => {
                if self.entries.len() >= self.capacity {
                    let oldest = (0..self.entries.len()).min_by_key(|&i| self.entries[i].last_used).unwrap();
                    self.entries.swap_remove(oldest);
                }
                self.uploads += 1;
                self.entries.push(Entry { id, value: upload(), last_used: 0 });
                self.entries.len() - 1
            }
        };
        self.entries[i].last_used = self.clock;
        &self.entries[i].value
    }

    /// Drops `id` (e.g. after its upload raised a GPU error, so the entry may be unusable).
    pub fn remove(&mut self, id: u64) {
        self.entries.retain(|e| e.id != id);
    }

    /// Whether `id` is held, without counting as a use.
    pub fn contains(&self, id: u64) -> bool {
        self.entries.iter().any(|e| e.id == id)
    }

    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// How many times a value was built, over the cache's lifetime.
    pub fn uploads(&self) -> u64 {
        self.uploads
    }
}

#[cfg(test)]
mod tests {
    use super::MeshCache;

    #[test]
    fn reuses_and_evicts_least_recently_used() {
        let mut c = MeshCache::new(2);
        assert_eq!(*c.get_or_insert_with(1, || "a"), "a");
        assert_eq!(*c.get_or_insert_with(2, || "b"), "b");
        assert_eq!(*c.get_or_insert_with(1, || "a2"), "a", "hit must not rebuild");
        assert_eq!(c.uploads(), 2);
        c.get_or_insert_with(3, || "c"); // evicts 2, the least recently used
        assert_eq!(c.len(), 2);
        assert_eq!(*c.get_or_insert_with(1, || "a3"), "a");
        assert_eq!(*c.get_or_insert_with(2, || "b2"), "b2");
        assert_eq!(c.uploads(), 4);
        assert!(c.contains(1) && c.contains(2) && !c.contains(3));
        c.remove(2);
        assert_eq!(c.len(), 1);
        assert!(!c.contains(2));
    }
}
