//! The shared test suite of the object stores (`src/store`): every check is one function
//! `check_*(url)` that runs against every backend, `dir://`, `sqlite://` and `s3://` (a
//! real S3 server, `s3s-fs`, on loopback; see `shared_suite!` at the end), through the
//! `ObjectStore` trait; only the deliberate damage to stored bytes and the look at what a
//! killed writer left are backend specific.
//!
//! The multi-process checks (a writer killed mid-put, readers beside a writer) re-run this
//! test binary as the child processes: `child_entry` is an ignored test that returns at once
//! unless `ROLE_VAR` is set, and the parent starts
//! `<this binary> --exact child_entry --include-ignored --nocapture` with the role in the
//! environment. A child reports through stdout lines that carry `MARK`.
#![cfg(unix)]

use b2tfpose::geometry::symmetry::{ContinuousSymmetry, DiscreteSymmetry, KnownSymmetries, ObjectSymmetries, SymmetrySource};
use b2tfpose::onboard::{ObjectModel, PatchDescriptors, PatchPoints, Template};
use b2tfpose::store::{self, codec, ModelCache, ObjectStore, StoreError};
use std::collections::BTreeSet;
use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::process::ExitStatusExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::{mpsc, Arc, OnceLock};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

#[path = "../common/s3.rs"]
mod s3_server;
#[path = "../common/stalling_proxy.rs"]
mod stalling_proxy;

mod cache;
mod checks;
mod children;
mod locations;
mod objects;
mod processes;
mod s3_only;

use cache::*;
use checks::*;
use children::*;
use locations::*;
use objects::*;
use processes::*;

/// The entry point of every child process; a no-op in a normal test run.
#[test]
#[ignore = "runs only as a child process started by the multi-process checks"]
fn child_entry() {
    let Ok(role) = std::env::var(ROLE_VAR) else { return };
    let url = env_var(URL_VAR);
    let store = store::open(&url).unwrap_or_else(|e| panic!("child: opening {url}: {e}"));
    // Children take their objects from the store, so that they do not onboard again.
    let base = store.get("obj-base").unwrap_or_else(|e| panic!("child: loading obj-base: {e}"));
    let count = || env_var(COUNT_VAR).parse::<usize>().expect("child: count");
    match role.as_str() {
        // One put of a big object, to be killed in the middle.
        "big-writer" => {
            let big = enlarged(&base, "obj-big", count());
            report("putting");
            store.put(&big, false).unwrap_or_else(|e| panic!("child: putting obj-big: {e}"));
            report("done");
        }
        // Replaces the contended objects generation by generation, and puts and deletes a
        // scratch object each round.
        "writer" => {
            let rounds = count() as u32;
            for g in 1..=rounds {
                for id in CONTENDED {
                    store.put(&generation(&base, id, g), true).unwrap_or_else(|e| panic!("writer: putting {id} generation {g}: {e}"));
                }
                store.put(&with_id(&base, "obj-scratch"), false).unwrap_or_else(|e| panic!("writer: putting obj-scratch: {e}"));
                store.delete("obj-scratch").unwrap_or_else(|e| panic!("writer: deleting obj-scratch: {e}"));
            }
            report(format!("wrote {rounds}"));
        }
        // Reads every contended object (and lists the store) in a loop until told to stop,
        // checking that each object read is one complete generation and that generations
        // never go backwards.
        "reader" => {
            let stop = PathBuf::from(env_var(STOP_VAR));
            let mut last = [0u32; CONTENDED.len()];
            let mut seen = BTreeSet::new();
            let mut reads = 0usize;
            let mut pass = |last: &mut [u32; CONTENDED.len()]| {
                for (k, id) in CONTENDED.iter().enumerate() {
                    let got = store.get(id).unwrap_or_else(|e| panic!("reader: get {id} after {reads} reads: {e}"));
                    got.validate().unwrap_or_else(|e| panic!("reader: {id} is inconsistent: {e}"));
                    let g = generation_of(&got);
                    assert_same(&generation(&base, id, g), &got);
                    assert!(g >= last[k], "reader: {id} went back from generation {} to {g}", last[k]);
                    last[k] = g;
                    seen.insert(g);
                    reads += 1;
                    // Cheap look-ups between the full reads, many of them: an object that is
                    // replaced is never absent, not even for a moment.
                    for _ in 0..LOOKUPS_PER_READ {
                        assert!(store.exists(id).unwrap_or_else(|e| panic!("reader: exists {id}: {e}")), "reader: {id} is absent during a replace");
                        let info = store.info(id).unwrap_or_else(|e| panic!("reader: info {id} after {reads} reads: {e}"));
                        assert_eq!(info.id, *id);
                    }
                }
                let listed: BTreeSet<String> = store.list().unwrap_or_else(|e| panic!("reader: list after {reads} reads: {e}")).into_iter().map(|i| i.id).collect();
                for id in CONTENDED.iter().chain(&["obj-base"]) {
                    assert!(listed.contains(*id), "reader: list misses {id}: {listed:?}");
                }
            };
            pass(&mut last);
            assert_eq!(last, [0; CONTENDED.len()], "reader: the first pass runs before the writer starts");
            report("ready");
            loop {
                let stopping = stop.exists();
                pass(&mut last);
                if stopping {
                    break;
                }
            }
            report(format!("reads {reads} last {} generations {}", last.iter().map(u32::to_string).collect::<Vec<_>>().join(","), seen.len()));
        }
        other => panic!("child: unknown role {other:?}"),
    }
}

/// Runs each check against every backend, each in a fresh temporary folder (S3: its own
/// server).
macro_rules! shared_suite {
    ($($name:ident => $check:ident),+ $(,)?) => {
        mod dir {
            $(
                #[test]
                fn $name() {
                    let tmp = tempfile::tempdir().expect("temp dir");
                    super::$check(&format!("dir://{}", tmp.path().join("objects").display()));
                }
            )+
        }
        mod sqlite {
            $(
                #[test]
                fn $name() {
                    let tmp = tempfile::tempdir().expect("temp dir");
                    super::$check(&format!("sqlite://{}", tmp.path().join("objects.db").display()));
                }
            )+
        }
        mod s3 {
            $(
                #[test]
                fn $name() {
                    let tmp = tempfile::tempdir().expect("temp dir");
                    let Some(server) = super::s3_server::S3Server::start(tmp.path()) else { return };
                    super::S3_ROOTS.lock().unwrap().push((server.port, server.root.clone()));
                    super::$check(&server.url("objects"));
                }
            )+
        }
    };
}

shared_suite! {
    round_trip_keeps_every_field => check_round_trip,
    put_replaces_only_when_asked => check_replace,
    list_info_exists_delete => check_list_info_exists_delete,
    bad_ids_are_refused_before_touching_disk => check_bad_ids,
    damage_names_the_object_and_spares_the_others => check_damage,
    writer_killed_mid_put_leaves_no_object => check_killed_put,
    two_readers_beside_a_writer => check_readers_beside_a_writer,
    cache_over_the_store => check_cache,
    read_only_reads_and_refuses_writes => check_read_only,
}

#[test]
fn open_refuses_unknown_urls() {
    for url in ["", "objects.db", "ftp://host/objects", "dir://", "sqlite://", "sqlite://:memory:", "file:///tmp/x"] {
        assert!(matches!(store::open(url), Err(StoreError::BadUrl(_))), "{url:?}");
        assert!(matches!(store::open_read_only(url), Err(StoreError::BadUrl(_))), "{url:?}");
    }
}
