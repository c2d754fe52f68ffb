//! The shared check of the LRU model cache over a store.

use super::*;

/// The LRU cache over a store: hits and misses, eviction of the least recently used under
/// the byte budget, `revalidate` after another writer's replace or delete, `invalidate`
/// after this process' own, and `Arc`s that outlive their entry.
pub(crate) fn check_cache(url: &str) {
    let Some(m) = model() else { return };
    let store = store::open(url).expect("open");
    for id in ["obj-a", "obj-b", "obj-c"] {
        store.put(&with_id(m, id), false).expect("put");
    }
    // What one loaded object holds (dir://: less than the onboarded one, its descriptors
    // stay in the mapped file).
    let one = store.get("obj-a").expect("get").memory_bytes() as u64;
    // Room for two objects, not three.
    let cache = ModelCache::new(store.clone(), 2 * one + one / 2);
    let stats = |c: &ModelCache| {
        let s = c.stats();
        (s.objects, s.hits, s.misses)
    };

    let a = cache.get("obj-a").expect("get a");
    assert_same(&with_id(m, "obj-a"), &a);
    let a_again = cache.get("obj-a").expect("get a again");
    assert!(Arc::ptr_eq(&a, &a_again), "a hit hands out the same object");
    assert_eq!(stats(&cache), (1, 1, 1));
    let c_held = cache.get("obj-c").expect("get c");
    assert_eq!(stats(&cache), (2, 1, 2));
    cache.get("obj-a").expect("touch a"); // c is now the least recently used
    cache.get("obj-b").expect("get b"); // over budget: c goes
    assert_eq!(stats(&cache), (2, 2, 3));
    assert!(cache.stats().bytes <= 2 * one + one / 2, "{:?}", cache.stats());
    cache.get("obj-a").expect("a is still cached");
    assert_eq!(stats(&cache), (2, 3, 3));
    // The Arc taken before c was evicted stays whole.
    assert_same(&with_id(m, "obj-c"), &c_held);
    let c_new = cache.get("obj-c").expect("c loads again"); // a miss; b goes
    assert_eq!(stats(&cache), (2, 3, 4));
    assert!(!Arc::ptr_eq(&c_held, &c_new));

    // A replace by another writer (its own handle, as another process has) is served stale
    // until `revalidate` compares generations and drops the entry; a second pass finds
    // nothing more to drop.
    let writer = store::open(url).expect("second handle");
    assert_eq!(cache.revalidate(), 0, "nothing changed yet");
    let replaced = generation(m, "obj-a", 7);
    writer.put(&replaced, true).expect("replace a");
    assert_same(&with_id(m, "obj-a"), &cache.get("obj-a").expect("stale hit"));
    assert_eq!(cache.revalidate(), 1);
    assert_same(&replaced, &cache.get("obj-a").expect("get after revalidate"));
    assert_eq!(stats(&cache), (2, 4, 5));
    assert_eq!((cache.revalidate(), cache.stats().stale), (0, 1));
    assert_same(&with_id(m, "obj-a"), &a); // the old version, still held
                                           // This process' own replace: `invalidate` at once.
    store.put(&with_id(m, "obj-a"), true).expect("put a back");
    cache.invalidate("obj-a");
    assert_same(&with_id(m, "obj-a"), &cache.get("obj-a").expect("get after invalidate"));
    assert_eq!(stats(&cache), (2, 4, 6));
    // A delete by the other writer drops the entry too; the object is gone for good.
    writer.delete("obj-c").expect("delete c");
    assert_eq!(cache.revalidate(), 1);
    assert!(matches!(cache.get("obj-c"), Err(StoreError::NotFound(_))));
    assert_eq!(cache.stats().objects, 1);

    // Errors are passed on and cache nothing.
    assert!(matches!(cache.get("obj-missing"), Err(StoreError::NotFound(id)) if id == "obj-missing"));
    assert!(matches!(cache.get("../evil"), Err(StoreError::BadId(_))));
    assert_eq!(cache.stats().objects, 1);

    // An object larger than the whole budget is still handed out (and kept, alone).
    let tiny = ModelCache::new(store.clone(), 1);
    tiny.get("obj-a").expect("get a");
    tiny.get("obj-b").expect("get b");
    let s = tiny.stats();
    assert_eq!((s.objects, s.misses), (1, 2), "{s:?}");
}
