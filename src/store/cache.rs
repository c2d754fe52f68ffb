//! Loaded objects kept in memory under a byte budget, least recently used out first, shared
//! by every estimate. Entries are `Arc`s: evicting or invalidating an object never pulls it
//! from under a request that is using it.

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
}

struct Entry {
    model: Arc<ObjectModel>,
    bytes: u64,
    last_used: u64,
}

/// Counters for metrics and tests.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct CacheStats {
    pub objects: usize,
    pub bytes: u64,
    pub hits: u64,
    pub misses: u64,
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
        {
            let mut g = self.inner.lock().expect("cache lock");
            g.clock += 1;
            let now = g.clock;
            if let Some(e) = g.entries.get_mut(id) {
                e.last_used = now;
                let m = e.model.clone();
                g.hits += 1;
                return Ok(m);
            }
            g.misses += 1;
        }
        let model = Arc::new(self.store.get(id)?);
        let bytes = model.memory_bytes() as u64;
        let mut g = self.inner.lock().expect("cache lock");
        g.clock += 1;
        let now = g.clock;
        if let Some(old) = g.entries.insert(id.to_string(), Entry { model: model.clone(), bytes, last_used: now }) {
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
        Ok(model)
    }

    /// Forgets an object (after it was replaced or deleted in the store).
    pub fn invalidate(&self, id: &str) {
        let mut g = self.inner.lock().expect("cache lock");
        if let Some(e) = g.entries.remove(id) {
            g.bytes -= e.bytes;
        }
    }

    pub fn stats(&self) -> CacheStats {
        let g = self.inner.lock().expect("cache lock");
        CacheStats { objects: g.entries.len(), bytes: g.bytes, hits: g.hits, misses: g.misses }
    }
}
