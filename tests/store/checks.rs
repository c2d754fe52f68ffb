//! The shared checks of one store through the `ObjectStore` trait: round trip, replace,
//! listing, read-only, bad ids, damage.

use super::*;

/// A put then a get gives back every field; the returned info describes the object; the
/// object is there for another handle opened from the same URL.
pub(crate) fn check_round_trip(url: &str) {
    let Some(m) = model() else { return };
    let started = now_unix_s();
    let store = store::open(url).expect("open");
    assert_eq!(store.url(), if is_s3(url) { s3_server::shown(url) } else { url.to_string() });
    assert!(store.list().expect("list").is_empty(), "a new store is empty");

    let info = store.put(m, false).expect("put");
    assert_eq!((info.id.as_str(), info.units, info.templates), ("obj-a", m.mesh.source_units(), m.templates.len()));
    assert_eq!(info.backbone, m.backbone);
    assert!((info.diameter_m - m.diameter()).abs() < 1e-12, "diameter {} vs {}", info.diameter_m, m.diameter());
    assert!(info.bytes > tensor_bytes(m) as u64, "{} bytes stored for {} bytes of tensors", info.bytes, tensor_bytes(m));
    assert!((started..=now_unix_s()).contains(&info.created_at), "created_at {} not between {started} and now", info.created_at);
    assert_eq!(store.info("obj-a").expect("info"), info);
    assert_eq!(info.symmetries, m.symmetries, "listing shows the symmetries");

    let back = store.get("obj-a").expect("get");
    back.validate().expect("loaded model is consistent");
    assert_same(m, &back);
    // dir:// reads the per-patch arrays in place from the mapped tensors file; the others
    // copy them. The texture stays its PNG in every store.
    let PatchDescriptors::Half(rows) = &back.patch_descriptors else { panic!("f16 descriptors") };
    let mapped = [rows.is_mapped(), back.patch_points.is_mapped(), back.patch_cells.is_mapped(), back.silhouettes.is_mapped()];
    assert_eq!(mapped, [url.starts_with("dir://"); 4], "{url}: descriptors, points, cells, silhouettes mapped");
    assert!(back.mesh.materials().iter().filter_map(|t| t.texture.as_ref()).all(|t| t.png().is_some()), "{url}: textures kept encoded");
    assert!(back.memory_bytes() < m.memory_bytes(), "{url}: mapped rows and encoded textures are not heap");

    let other = store::open(url).expect("second handle");
    assert_same(m, &other.get("obj-a").expect("get through a second handle"));
    assert_eq!(other.list().expect("list").len(), 1);

    // The onboarded object's descriptors are f16 rows (the default); quantised ones
    // (`--descriptors pq4`) round-trip too, in less room.
    let mut coded = with_id(m, "obj-pq");
    b2tfpose::onboard::apply_coding(&mut coded, b2tfpose::onboard::DescriptorCoding::Pq4).expect("quantise");
    let PatchDescriptors::Quantized { codes, .. } = &coded.patch_descriptors else { panic!("pq4 quantises") };
    assert_eq!(codes.len(), m.patch_count() * m.local_dim / 4);
    store.put(&coded, false).expect("put pq4");
    let back = store.get("obj-pq").expect("get pq4");
    assert_same(&coded, &back);
    let PatchDescriptors::Quantized { codes, .. } = &back.patch_descriptors else { panic!("pq4 read back") };
    assert_eq!(codes.is_mapped(), url.starts_with("dir://"), "{url}: codes mapped");
    assert!(store.info("obj-pq").unwrap().bytes < info.bytes, "codes take less room than f16 rows");
    let mut int8 = with_id(m, "obj-i8");
    b2tfpose::onboard::apply_coding(&mut int8, b2tfpose::onboard::DescriptorCoding::I8).expect("int8");
    store.put(&int8, false).expect("put i8");
    assert_same(&int8, &store.get("obj-i8").expect("get i8"));
    assert!(store.info("obj-i8").unwrap().bytes < info.bytes, "int8 takes less room than f16 rows");
}

/// A put without `replace` never overwrites; with `replace` it does, as a whole.
pub(crate) fn check_replace(url: &str) {
    let Some(m) = model() else { return };
    let store = store::open(url).expect("open");
    let first = generation(m, "obj-a", 1);
    let second = generation(m, "obj-a", 2);
    assert_eq!(store.generation("obj-a").expect("generation"), None, "no object, no generation");
    store.put(&first, false).expect("put");
    let written = store.generation("obj-a").expect("generation").expect("stored");
    match store.put(&second, false) {
        Err(StoreError::AlreadyExists(id)) => assert_eq!(id, "obj-a"),
        other => panic!("put over an existing object without replace: expected AlreadyExists, got {:?}", other.map(|i| i.id)),
    }
    assert_same(&first, &store.get("obj-a").expect("get after the refused put"));
    assert_eq!(store.generation("obj-a").expect("generation"), Some(written), "reads and refused puts leave it");

    let info = store.put(&second, true).expect("replace");
    assert_eq!(info.id, "obj-a");
    let replaced = store.generation("obj-a").expect("generation").expect("stored");
    assert_ne!(replaced, written, "a replace is a new generation");
    store.put(&second, true).expect("the same object again");
    assert_ne!(store.generation("obj-a").expect("generation"), Some(replaced), "every put is");
    assert!(matches!(store.generation("../x"), Err(StoreError::BadId(_))));
    assert_same(&second, &store.get("obj-a").expect("get after replace"));
    assert_eq!(store.list().expect("list").len(), 1, "a replace does not add an object");
    // Replacing an object that does not exist is a plain put.
    store.put(&with_id(m, "obj-new"), true).expect("put with replace of a new id");
    assert!(store.exists("obj-new").expect("exists"));
}

/// list (sorted, matching info), exists, delete, and NotFound for what is not there; all of
/// it kept across reopening.
pub(crate) fn check_list_info_exists_delete(url: &str) {
    let Some(m) = model() else { return };
    let store = store::open(url).expect("open");
    for id in ["obj-b", "obj-c", "obj-a"] {
        store.put(&with_id(m, id), false).expect("put");
    }
    let list = store.list().expect("list");
    assert_eq!(list.iter().map(|i| i.id.as_str()).collect::<Vec<_>>(), ["obj-a", "obj-b", "obj-c"], "list is sorted by id");
    for i in &list {
        assert_eq!(store.info(&i.id).expect("info"), *i, "info and list agree");
        assert!(store.exists(&i.id).expect("exists"));
    }

    store.delete("obj-b").expect("delete");
    assert!(!store.exists("obj-b").expect("exists after delete"));
    assert!(matches!(store.get("obj-b"), Err(StoreError::NotFound(id)) if id == "obj-b"));
    assert!(matches!(store.info("obj-b"), Err(StoreError::NotFound(id)) if id == "obj-b"));
    assert!(matches!(store.delete("obj-b"), Err(StoreError::NotFound(id)) if id == "obj-b"));
    for id in ["never-stored", "obj"] {
        assert!(!store.exists(id).expect("exists"));
        assert!(matches!(store.get(id), Err(StoreError::NotFound(i)) if i == id), "get {id}");
        assert!(matches!(store.info(id), Err(StoreError::NotFound(i)) if i == id), "info {id}");
        assert!(matches!(store.delete(id), Err(StoreError::NotFound(i)) if i == id), "delete {id}");
    }
    let ids = |s: &dyn ObjectStore| s.list().expect("list").into_iter().map(|i| i.id).collect::<Vec<_>>();
    assert_eq!(ids(&*store), ["obj-a", "obj-c"]);
    drop(store);

    let store = store::open(url).expect("reopen");
    assert_eq!(ids(&*store), ["obj-a", "obj-c"], "the store keeps its objects across reopening");
    assert_same(&with_id(m, "obj-c"), &store.get("obj-c").expect("get after reopen"));
    // A deleted id can be used again.
    store.put(&with_id(m, "obj-b"), false).expect("put of a deleted id");
    assert_same(&with_id(m, "obj-b"), &store.get("obj-b").expect("get"));
}

/// A read-only store (replicas serving a store another process writes) reads what the
/// writer put, before and after it opened, refuses puts and deletes naming the store, and
/// neither creates a missing store nor removes a writer's leftovers.
pub(crate) fn check_read_only(url: &str) {
    let Some(m) = model() else { return };
    // An S3 store is missing when its bucket is (buckets are made by their owner).
    let missing = if is_s3(url) { url.replacen(s3_server::BUCKET, "b2tf-missing", 1) } else { url.to_string() };
    assert!(store::open_read_only(&missing).is_err(), "a missing store is refused");
    assert!(!store_path(&missing).exists(), "a read-only open created {}", store_path(&missing).display());
    let writer = store::open(url).expect("open");
    writer.put(&with_id(m, "obj-a"), false).expect("put");
    let leftover = plant_abandoned_write(url);
    let ro = store::open_read_only(url).expect("open read-only");
    assert!(leftover.as_ref().is_none_or(|p| p.exists()), "a read-only open removed a writer's unfinished put");
    assert_same(&with_id(m, "obj-a"), &ro.get("obj-a").expect("get"));
    assert_eq!(ro.info("obj-a").expect("info"), writer.info("obj-a").expect("info"));
    // Objects the writer adds later are served without reopening.
    writer.put(&with_id(m, "obj-b"), false).expect("put");
    assert_eq!(ro.list().expect("list").iter().map(|i| i.id.as_str()).collect::<Vec<_>>(), ["obj-a", "obj-b"]);
    let refused = |r: Result<(), StoreError>, what: &str| match r {
        Err(e @ StoreError::ReadOnly(_)) => assert!(e.to_string().contains(&store_label(url)), "{what}: {e}"),
        other => panic!("{what} on a read-only store: {other:?}"),
    };
    refused(ro.put(&with_id(m, "obj-c"), false).map(|_| ()), "put");
    refused(ro.put(&with_id(m, "obj-a"), true).map(|_| ()), "replacing put");
    refused(ro.delete("obj-a"), "delete");
    assert!(ro.exists("obj-a").expect("exists") && !writer.exists("obj-c").expect("exists"));
}

/// Puts what a writer in another container left mid-put long ago (its pid means nothing
/// here, so only a writer's open may judge it abandoned): dir, a temporary folder; S3,
/// parts of a write without a manifest, two hours old. `None` for SQLite (its transaction
/// simply never commits).
pub(crate) fn plant_abandoned_write(url: &str) -> Option<PathBuf> {
    if is_sqlite(url) {
        return None;
    }
    if is_s3(url) {
        let part = store_path(url).join("obj-z/parts/00000000000000ff/tensors.safetensors");
        std::fs::create_dir_all(part.parent().unwrap()).expect("parts folder");
        let f = std::fs::File::create(&part).expect("abandoned part");
        f.set_modified(SystemTime::now() - Duration::from_secs(7200)).expect("aging it");
        return Some(part);
    }
    let leftover = store_path(url).join(".obj-z.tmp-999999999-0");
    std::fs::create_dir(&leftover).expect("leftover");
    Some(leftover)
}

/// Ids that could escape the store (traversal, separators, hidden names) or are out of
/// bounds are refused with BadId by every operation, and nothing on disk changes.
pub(crate) fn check_bad_ids(url: &str) {
    let store = store::open(url).expect("open");
    let folder = test_folder(url);
    let before = tree(&folder);
    let too_long = "x".repeat(65);
    let bad = ["../evil", "a/b", "", ".hidden", "..", ".", "/abs", "a\\b", "a b", "née", "a\0b", too_long.as_str()];
    for id in bad {
        let is_bad = |r: Result<(), StoreError>, op: &str| match r {
            Err(StoreError::BadId(got)) => assert_eq!(got, id, "{op}"),
            Err(e) => panic!("{op} {id:?}: expected BadId, got {e}"),
            Ok(()) => panic!("{op} {id:?}: expected BadId, succeeded"),
        };
        is_bad(store.get(id).map(drop), "get");
        is_bad(store.info(id).map(drop), "info");
        is_bad(store.exists(id).map(drop), "exists");
        is_bad(store.delete(id), "delete");
        if let Some(m) = model() {
            is_bad(store.put(&with_id(m, id), false).map(drop), "put");
            is_bad(store.put(&with_id(m, id), true).map(drop), "put with replace");
        }
    }
    assert_eq!(tree(&folder), before, "refused ids must not touch the disk");
    assert!(store.list().expect("list").is_empty());

    // The bounds themselves are fine: 64 characters, inner dots, dashes, underscores.
    if let Some(m) = model() {
        for id in ["x".repeat(64), "a.b-c_D9".to_string()] {
            store.put(&with_id(m, &id), false).unwrap_or_else(|e| panic!("put {id:?}: {e}"));
            assert_same(&with_id(m, &id), &store.get(&id).expect("get"));
        }
    }
}

/// Damaged objects give an error naming them, while an intact object beside them still
/// loads and a damaged one can be replaced.
pub(crate) fn check_damage(url: &str) {
    let Some(m) = model() else { return };
    let store = store::open(url).expect("open");
    let damaged = [("obj-garbled", Damage::GarbledTensors), ("obj-torn", Damage::TruncatedTensors), ("obj-bad-json", Damage::GarbledManifest), ("obj-torn-json", Damage::TruncatedManifest)];
    for id in damaged.iter().map(|(id, _)| *id).chain(["obj-intact"]) {
        store.put(&with_id(m, id), false).expect("put");
    }
    for (id, how) in damaged {
        damage(url, id, how);
    }
    for (id, how) in damaged {
        let e = store.get(id).err().unwrap_or_else(|| panic!("{how:?} of {id}: loaded without an error"));
        let text = e.to_string();
        eprintln!("{url}: {how:?}: {text}");
        assert!(matches!(&e, StoreError::Corrupt { object, .. } if object == id), "{how:?} of {id}: expected Corrupt naming it, got {text}");
        assert!(text.contains(id), "{how:?}: the message does not name {id}: {text}");
        // Still counted as present: it is there, only damaged.
        assert!(store.exists(id).expect("exists"), "{how:?}");
    }
    assert_same(&with_id(m, "obj-intact"), &store.get("obj-intact").expect("the intact object still loads"));
    // Listing either still works (the damage is in bytes list does not read) or fails
    // naming the damaged object; it never hides the others silently.
    match store.list() {
        Ok(list) => {
            let ids: Vec<&str> = list.iter().map(|i| i.id.as_str()).collect();
            assert!(ids.contains(&"obj-intact"), "{ids:?}");
        }
        Err(e) => assert!(["obj-bad-json", "obj-torn-json"].iter().any(|id| e.to_string().contains(id)), "list failed without naming a damaged object: {e}"),
    }
    // A fresh handle opens fine and sees the same.
    let reopened = store::open(url).expect("the store opens with damaged objects in it");
    assert!(matches!(reopened.get("obj-torn"), Err(StoreError::Corrupt { object, .. }) if object == "obj-torn"));
    // Replacing repairs.
    for (id, _) in damaged {
        reopened.put(&with_id(m, id), true).unwrap_or_else(|e| panic!("replacing damaged {id}: {e}"));
        assert_same(&with_id(m, id), &reopened.get(id).expect("get after repair"));
    }
    assert_eq!(reopened.list().expect("list after repair").len(), damaged.len() + 1);
}
