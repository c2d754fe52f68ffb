//! S3 only: what a network store adds.

use super::*;

/// A server of this test's own (registered for the URL helpers), `None` when s3s-fs is
/// not installed and not required.
pub(crate) fn s3_test_server(dir: &Path) -> Option<s3_server::S3Server> {
    let server = s3_server::S3Server::start(dir)?;
    S3_ROOTS.lock().unwrap().push((server.port, server.root.clone()));
    Some(server)
}

/// The S3 server dies (SIGKILL) while a big put uploads: the put returns an error instead
/// of hanging, calls fail while the server is away, and once it is back the object is
/// absent, the earlier one intact, and the id free.
#[test]
pub(crate) fn s3_server_that_disappears_mid_put_leaves_no_object() {
    let Some(m) = model() else { return };
    let tmp = tempfile::tempdir().expect("temp dir");
    let Some(mut server) = s3_test_server(tmp.path()) else { return };
    let url = server.url("objects");
    let store = store::open(&url).expect("open");
    store.put(&with_id(m, "obj-a"), false).expect("put");
    let big = enlarged(m, "obj-big", big_copies(m));
    let expected = codec::encode(&big).expect("encode").tensors.len() as u64;
    // The put goes through a proxy that stalls it three quarters in, so it is surely
    // half-way when the server dies; killing the server and then the proxy drops every
    // connection of the put as a crashed server's host would.
    let (stalled_url, mut proxy) = s3_through_stalling_proxy(&url, expected * 3 / 4);
    let writer = {
        let (store, big) = (store::open(&stalled_url).expect("open through the proxy"), big.clone());
        std::thread::spawn(move || store.put(&big, false).map(|i| i.id))
    };
    let began = Instant::now();
    while partial_write_bytes(&url, "obj-big", 0, 0).is_none_or(|n| n < expected / 2) {
        assert!(!writer.is_finished(), "the put finished before the server could be stopped: {:?}", writer.join());
        assert!(began.elapsed() < CHILD_TIMEOUT, "no upload of obj-big seen within {CHILD_TIMEOUT:?}");
        std::thread::sleep(Duration::from_millis(1));
    }
    server.kill();
    proxy.stop();
    let killed = Instant::now();
    let outcome = writer.join().expect("the writer thread");
    eprintln!("the put answered {:.2?} after the server died: {outcome:?}", killed.elapsed());
    match outcome {
        Err(e @ StoreError::Remote { .. }) => assert!(e.to_string().contains("obj-big"), "{e}"),
        other => panic!("a put whose server died: expected a Remote error, got {other:?}"),
    }
    // Retries are bounded (the URL allows 2 in 10 s): generous, only to catch a hang.
    assert!(killed.elapsed() < Duration::from_secs(120), "the put took {:.0?} to give up", killed.elapsed());
    assert!(matches!(store.list(), Err(StoreError::Remote { .. })), "list while the server is down");
    assert!(matches!(store.exists("obj-a"), Err(StoreError::Remote { .. })), "exists while the server is down");

    server.restart();
    assert!(!store.exists("obj-big").expect("exists"), "an interrupted put leaves no object");
    assert_eq!(store.list().expect("list").into_iter().map(|i| i.id).collect::<Vec<_>>(), ["obj-a"]);
    assert_same(&with_id(m, "obj-a"), &store.get("obj-a").expect("the earlier object is intact"));
    store.put(&big, false).expect("the same put again, with the server back");
    assert_same(&big, &store.get("obj-big").expect("get"));
}

/// Parts of writes that never got their manifest (killed puts) are removed by a writer's
/// open once old enough, never by a read-only one; a replace removes the old write.
#[test]
pub(crate) fn s3_abandoned_and_replaced_writes_are_removed() {
    let Some(m) = model() else { return };
    let tmp = tempfile::tempdir().expect("temp dir");
    let Some(server) = s3_test_server(tmp.path()) else { return };
    let url = server.url("objects");
    let store = store::open(&url).expect("open");
    // Write folders that still hold a part (S3 has no folders; s3s-fs leaves empty ones).
    let writes = |id: &str| {
        tree(&store_path(&url).join(id).join("parts"))
            .iter()
            .filter(|p| p.components().count() > 1 && store_path(&url).join(id).join("parts").join(p).is_file())
            .filter_map(|p| p.components().next())
            .collect::<BTreeSet<_>>()
            .len()
    };
    store.put(&with_id(m, "obj-a"), false).expect("put");
    store.put(&generation(m, "obj-a", 2), true).expect("replace");
    assert_eq!(writes("obj-a"), 1, "a replace removes the old write");

    let old = plant_abandoned_write(&url).expect("an abandoned write");
    let young = store_path(&url).join("obj-y/parts/00000000000000aa/tensors.safetensors");
    std::fs::create_dir_all(young.parent().unwrap()).expect("folder");
    std::fs::write(&young, b"uploading").expect("a young part");
    store::open_read_only(&url).expect("read-only open");
    assert!(old.exists() && young.exists(), "a read-only open removes nothing");
    store::open(&url).expect("writer open");
    assert!(!old.exists(), "a writer's open removes parts abandoned an hour ago");
    assert!(young.exists(), "a young part may be a put under way elsewhere");
    b2tfpose::store::s3::S3Store::open_with_orphan_age(&url, Duration::ZERO).expect("open");
    assert!(!young.exists());
    assert_eq!(store.list().expect("list").into_iter().map(|i| i.id).collect::<Vec<_>>(), ["obj-a"]);
    assert_same(&generation(m, "obj-a", 2), &store.get("obj-a").expect("get"));
}

/// A wrong bucket, wrong credentials or no server at all fail the open with the store's
/// URL (secrets masked) and S3's reason, quickly; malformed URLs are refused before any
/// request.
#[test]
pub(crate) fn s3_open_names_what_is_wrong() {
    let tmp = tempfile::tempdir().expect("temp dir");
    let Some(mut server) = s3_test_server(tmp.path()) else { return };
    let url = server.url("objects");
    let cases = [(url.replacen(s3_server::BUCKET, "no-such-bucket", 1), "NoSuchBucket"), (url.replace("secret_access_key=b2tf-test-secret", "secret_access_key=wrong"), "SignatureDoesNotMatch")];
    for (bad, says) in &cases {
        for (what, r) in [("open", store::open(bad).map(drop)), ("read-only open", store::open_read_only(bad).map(drop))] {
            match r {
                Err(e @ StoreError::Remote { .. }) => {
                    let text = e.to_string();
                    assert!(text.contains(says) && !text.contains("wrong") && !text.contains("b2tf-test-secret"), "{what} of {bad}: {text}");
                }
                other => panic!("{what} of {bad}: expected a Remote error, got {:?}", other.err()),
            }
        }
    }
    server.kill();
    let began = Instant::now();
    match store::open(&url) {
        Err(e @ StoreError::Remote { .. }) => assert!(e.to_string().contains(&format!("127.0.0.1:{}", server.port)), "{e}"),
        other => panic!("open without a server: {:?}", other.err()),
    }
    assert!(began.elapsed() < Duration::from_secs(60), "giving up took {:.0?}", began.elapsed());
    for bad in ["s3://", "s3://UPPER/x", "s3://bucket/a/../b", "s3://bucket/x?colour=blue", "s3://bucket/x?max_retries=lots"] {
        assert!(matches!(store::open(bad), Err(StoreError::BadUrl(_))), "{bad}");
        assert!(matches!(store::open_read_only(bad), Err(StoreError::BadUrl(_))), "{bad}");
    }
}
