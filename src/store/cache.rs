//! Loaded objects kept in memory under a byte budget, least recently used out first, shared
//! by every estimate. Entries are `Arc`s: evicting or invalidating an object never pulls it
//! from under a request that is using it. Each entry remembers the store's generation of
//! the object as it was loaded, so `revalidate` drops objects that another process
//! replaced or deleted since.

use super::{ObjectStore, StoreError};
use crate::onboard::ObjectModel;
use std::collections::HashMap;
use std::sync::{Arc, Mutex};

pub struct ModelCache {
    store: Arc<dyn ObjectStore>,
    budget_bytes: u64,
    inner: Mutex<Inner>,
}

#[derive(Default)]
struct Inner {
    entries: HashMap<String, Entry>,
    clock: u64,
    bytes: u64,
    hits: u64,
    misses: u64,
    stale: u64,
}

struct Entry {
    model: Arc<ObjectModel>,
    bytes: u64,
    last_used: u64,
    /// The store's generation read before loading (None: the read failed), so a write
    /// that lands during the load counts as newer.
    generation: Option<u64>,
}

/// Counters for metrics and tests.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct CacheStats {
    pub objects: usize,
    pub bytes: u64,
    pub hits: u64,
    pub misses: u64,
    /// Objects dropped by `revalidate` because the store's copy changed or went away.
    pub stale: u64,
}

impl ModelCache {
    pub fn new(store: Arc<dyn ObjectStore>, budget_bytes: u64) -> Self {
        Self { store, budget_bytes, inner: Mutex::new(Inner::default()) }
    }

    pub fn store(&self) -> &Arc<dyn ObjectStore> {
        &self.store
    }

    /// The object, from memory or loaded from the store (the lock is not held while
    /// loading, so other objects stay available meanwhile).
    pub fn get(&self, id: &str) -> Result<Arc<ObjectModel>, StoreError> {
        self.fetch(id).map(|(model, _)| model)
    }

    /// The object when it is held already; neither loads it nor counts as a use (for
    /// side requests, such as a thumbnail, that must not evict the working set).
    pub fn held(&self, id: &str) -> Option<Arc<ObjectModel>> {
        self.inner.lock().expect("cache lock").entries.get(id).map(|e| e.model.clone())
    }

    /// `get`, and whether this call loaded the object from the store.
    pub fn fetch(&self, id: &str) -> Result<(Arc<ObjectModel>, bool), StoreError> {
        {
            let mut g = self.inner.lock().expect("cache lock");
            g.clock += 1;
            let now = g.clock;
            if let Some(e) = g.entries.get_mut(id) {
                e.last_used = now;
                let m = e.model.clone();
                g.hits += 1;
                return Ok((m, false));
            }
            g.misses += 1;
        }
        let generation = self.store.generation(id).ok().flatten();
        let model = Arc::new(self.store.get(id)?);
        let bytes = model.memory_bytes() as u64;
        let mut g = self.inner.lock().expect("cache lock");
        g.clock += 1;
        let now = g.clock;
        if let Some(old) = g.entries.insert(id.to_string(), Entry { model: model.clone(), bytes, last_used: now, generation }) {
            g.bytes -= old.bytes;
        }
        g.bytes += bytes;
        // Evict the least recently used others until within budget; the object just loaded
        // stays even when it alone exceeds the budget (the caller needs it).
        while g.bytes > self.budget_bytes {
            let victim = g.entries.iter().filter(|(k, _)| k.as_str() != id).min_by_key(|(_, e)| e.last_used).map(|(k, _)| k.clone());
            match victim {
                Some(k) => {
                    let e = g.entries.remove(&k).expect("present");
                    g.bytes -= e.bytes;
                }
                None => break,
            }
        }
        Ok((model, true))
    }

    /// Forgets an object (after it was replaced or deleted in the store).
    pub fn invalidate(&self, id: &str) {
        let mut g = self.inner.lock().expect("cache lock");
        if let Some(e) = g.entries.remove(id) {
            g.bytes -= e.bytes;
        }
    }

    /// Drops every held object whose generation in the store is no longer the one it was
    /// loaded at (replaced or deleted by another process); the next request loads it
    /// afresh. One cheap store read per held object, none under the lock. Returns how
    /// many were dropped.
    pub fn revalidate(&self) -> usize {
        let held: Vec<(String, Option<u64>)> = self.inner.lock().expect("cache lock").entries.iter().map(|(id, e)| (id.clone(), e.generation)).collect();
        let mut dropped = 0;
        for (id, loaded_at) in held {
            let now = match self.store.generation(&id) {
                Ok(g) => g,
                Err(e) => {
                    tracing::warn!(object_id = %id, "revalidating the cached object: {e}");
                    continue;
                }
            };
            if now.is_some() && now == loaded_at {
                continue;
            }
            let mut g = self.inner.lock().expect("cache lock");
            // Only the copy that was checked: one reloaded meanwhile is newer.
            if g.entries.get(&id).is_some_and(|e| e.generation == loaded_at) {
                let e = g.entries.remove(&id).expect("present");
                g.bytes -= e.bytes;
                g.stale += 1;
                dropped += 1;
                tracing::info!(object_id = %id, deleted = now.is_none(), "the store's copy changed: dropped from the cache");
            }
        }
        dropped
    }

    pub fn stats(&self) -> CacheStats {
        let g = self.inner.lock().expect("cache lock");
        CacheStats { objects: g.entries.len(), bytes: g.bytes, hits: g.hits, misses: g.misses, stale: g.stale }
    }
}
