//! Shared checks across processes: a writer killed mid-put, readers beside a writer.

use super::*;

/// Bytes of a put of `id` by process `pid` that are on disk already (`None`: nothing yet).
/// dir: the writer's hidden temporary folder's tensors file; sqlite: growth of the WAL
/// beyond `wal_before` (the uncommitted transaction's pages); S3: the upload the server is
/// receiving (the tensors come first).
pub(crate) fn partial_write_bytes(url: &str, id: &str, pid: u32, wal_before: u64) -> Option<u64> {
    let path = store_path(url);
    if is_s3(url) {
        let root = s3_root(url);
        std::fs::read_dir(&root).ok()?.flatten().filter(|e| e.file_name().to_string_lossy().ends_with(".internal.part")).filter_map(|e| e.metadata().ok().map(|m| m.len())).max()
    } else if is_sqlite(url) {
        let wal = std::fs::metadata(format!("{}-wal", path.display())).map(|m| m.len()).unwrap_or(0);
        wal.checked_sub(wal_before).filter(|&n| n > 0)
    } else {
        let prefix = format!(".{id}.tmp-{pid}-");
        let tmp = std::fs::read_dir(&path).ok()?.flatten().find(|e| e.file_name().to_string_lossy().starts_with(&prefix))?;
        std::fs::metadata(tmp.path().join("tensors.safetensors")).ok().map(|m| m.len())
    }
}

/// A writer process killed with SIGKILL in the middle of a put leaves the object absent, the
/// store opening cleanly, the objects put before it intact, and the id free for a new put.
///
/// The kill point is taken from what is on disk rather than from a clock: the child is
/// killed once at least `KILL_AT` of the object's bytes are written but not yet committed
/// (a time fraction alone could fall into the encoding, before anything touches the disk,
/// and test nothing); over S3 a stalling proxy holds the upload there. The put is then repeated to completion and timed, and the kill's
/// share of that time is printed.
pub(crate) fn check_killed_put(url: &str) {
    const KILL_AT: f64 = 0.5;
    let Some(m) = model() else { return };
    let store = store::open(url).expect("open");
    let earlier = with_id(m, "obj-a");
    store.put(&earlier, false).expect("put of the earlier object");
    store.put(&with_id(m, "obj-base"), false).expect("put of the child's base object");

    let copies = big_copies(m);
    let big = enlarged(m, "obj-big", copies);
    let enc = codec::encode(&big).expect("encoding the big object");
    // What `partial_write_bytes` can see grow: the tensors file, or the WAL (manifest and tensors).
    let expected = (if is_sqlite(url) { enc.manifest.len() + enc.tensors.len() } else { enc.tensors.len() }) as u64;
    drop(enc);
    let wal_before = std::fs::metadata(format!("{}-wal", store_path(url).display())).map(|m| m.len()).unwrap_or(0);

    // Over S3 the child's upload goes through a proxy that stalls it three quarters in: a
    // loopback upload can otherwise finish between two looks at the server's folder.
    let (child_url, mut stall) = if is_s3(url) {
        let (u, p) = s3_through_stalling_proxy(url, expected * 3 / 4);
        (u, Some(p))
    } else {
        (url.to_string(), None)
    };
    let mut child = ChildProcess::spawn("big-writer", "big-writer", &child_url, &[(COUNT_VAR, copies.to_string())]);
    let pid = child.child.id();
    child.expect_message("putting", CHILD_TIMEOUT);
    let put_began = Instant::now();
    let written = loop {
        if let Some(n) = partial_write_bytes(url, "obj-big", pid, wal_before) {
            if n as f64 >= KILL_AT * expected as f64 {
                break n;
            }
        }
        assert!(!child.exited(), "the writer finished its put before it could be interrupted: make the big object bigger");
        assert!(put_began.elapsed() < CHILD_TIMEOUT, "no partial write of obj-big seen within {CHILD_TIMEOUT:?}");
        std::thread::sleep(Duration::from_millis(1));
    };
    child.child.kill().expect("SIGKILL to the writer");
    if let Some(proxy) = stall.as_mut() {
        // A killed process's connections close; the stalled proxy would hold them open.
        proxy.stop();
    }
    let killed_after = put_began.elapsed();
    let out = child.finish(Duration::from_secs(30));
    assert_eq!(out.status.signal(), Some(9), "the writer must die of SIGKILL, not exit ({}); output:\n{}", out.status, out.output);
    assert!(!out.messages.iter().any(|l| l == "done"), "the put finished before the kill; output:\n{}", out.output);
    if url.starts_with("dir://") {
        // Still in its temporary folder: the kill came before the rename that commits.
        assert!(partial_write_bytes(url, "obj-big", pid, 0).is_some(), "the killed writer's temporary folder is gone: was the put complete?");
    }
    drop(store);

    let store = store::open(url).expect("the store opens cleanly after a writer was killed mid-put");
    assert!(!store.exists("obj-big").expect("exists"), "a killed put must leave no object");
    assert!(matches!(store.get("obj-big"), Err(StoreError::NotFound(id)) if id == "obj-big"));
    assert!(matches!(store.info("obj-big"), Err(StoreError::NotFound(_))));
    let ids: Vec<String> = store.list().expect("list after the kill").into_iter().map(|i| i.id).collect();
    assert_eq!(ids, ["obj-a", "obj-base"]);
    assert_same(&earlier, &store.get("obj-a").expect("the object put earlier is intact"));
    if is_sqlite(url) {
        let c = raw_db(url);
        let check: String = c.query_row("PRAGMA integrity_check", [], |r| r.get(0)).expect("integrity check");
        assert_eq!(check, "ok");
        let orphans: i64 = c.query_row("SELECT COUNT(*) FROM chunks WHERE object_id = 'obj-big'", [], |r| r.get(0)).expect("count");
        assert_eq!(orphans, 0, "no chunks of the killed put survive");
    } else if url.starts_with("dir://") {
        let leftovers: Vec<PathBuf> = tree(&store_path(url)).into_iter().filter(|p| p.to_string_lossy().starts_with('.')).collect();
        assert!(leftovers.is_empty(), "opening removes what the killed writer left: {leftovers:?}");
    }

    let began = Instant::now();
    store.put(&big, false).expect("a later put of the same id succeeds");
    let full_put = began.elapsed();
    // For the record only: the child's put also encoded the object and shared the CPUs with
    // other tests, so the share of time is rough; the byte count is what placed the kill.
    eprintln!(
        "{url}: killed {killed_after:.2?} into the child's put, with {:.0} of {:.0} MB written (a complete put here: {full_put:.2?}, so ~{:.0} %)",
        written as f64 / 1e6,
        expected as f64 / 1e6,
        100.0 * killed_after.as_secs_f64() / full_put.as_secs_f64(),
    );
    let back = store.get("obj-big").expect("get of the big object");
    assert_same(&big, &back);
}

/// Two reader processes and one writer process at once. The writer replaces two objects
/// generation by generation (and puts and deletes a third); the readers get, list and look
/// them up in a loop. The readers never fail, never find a replaced object absent, never
/// see a half-written object or one mixed from two generations, never see an object go
/// back in time, and see both the first and the last generation (the writer starts after
/// their first pass and they stop after its last put, so their reads span the writes).
///
/// A race in a backend shows up here only when a read happens to fall into it, so a broken
/// backend may pass a single run; each reader makes many cheap look-ups between its full
/// reads to make that unlikely.
pub(crate) fn check_readers_beside_a_writer(url: &str) {
    let Some(m) = model() else { return };
    let store = store::open(url).expect("open");
    store.put(&with_id(m, "obj-base"), false).expect("put");
    for id in CONTENDED {
        store.put(&generation(m, id, 0), false).expect("put");
    }
    let stop = test_folder(url).join("stop-readers");
    let mut readers: Vec<ChildProcess> = (0..2).map(|i| ChildProcess::spawn(&format!("reader {i}"), "reader", url, &[(STOP_VAR, stop.display().to_string())])).collect();
    // The writer starts once both readers have read generation 0.
    for r in &mut readers {
        r.expect_message("ready", CHILD_TIMEOUT);
    }
    let mut writer = ChildProcess::spawn("writer", "writer", url, &[(COUNT_VAR, WRITER_ROUNDS.to_string())]);
    let w = writer.finish(CHILD_TIMEOUT);
    w.assert_success("writer");
    assert!(w.messages.contains(&format!("wrote {WRITER_ROUNDS}")), "writer: {:?}", w.messages);
    std::fs::write(&stop, b"").expect("stop file");

    for (i, r) in readers.iter_mut().enumerate() {
        let name = format!("reader {i}");
        let done = r.finish(CHILD_TIMEOUT);
        done.assert_success(&name);
        let summary = done.messages.iter().find(|l| l.starts_with("reads ")).unwrap_or_else(|| panic!("{name} gave no summary:\n{}", done.output));
        eprintln!("{url}: {name}: {summary}");
        // Their last pass began after the writer had finished.
        let last = vec![WRITER_ROUNDS.to_string(); CONTENDED.len()].join(",");
        assert!(summary.contains(&format!(" last {last} ")), "{name} did not end on the last generation: {summary}");
    }
    for id in CONTENDED {
        assert_same(&generation(m, id, WRITER_ROUNDS), &store.get(id).expect("final state"));
    }
    assert!(!store.exists("obj-scratch").expect("exists"));
}
