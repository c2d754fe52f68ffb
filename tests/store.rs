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

use b2tfpose::onboard::{ObjectModel, PatchDescriptors, PatchPoints, Template};
use b2tfpose::store::{self, codec, ModelCache, ObjectStore, StoreError};
use std::collections::BTreeSet;
use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::process::ExitStatusExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use b2tfpose::geometry::symmetry::{ContinuousSymmetry, DiscreteSymmetry, KnownSymmetries, ObjectSymmetries, SymmetrySource};
use std::sync::{mpsc, Arc, OnceLock};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

#[path = "common/s3.rs"]
mod s3_server;

// ---------------------------------------------------------------------------------------
// Test objects
// ---------------------------------------------------------------------------------------

/// The small real object every check uses, onboarded once per process (a textured box, 24
/// templates at 128 px). `None` without a GPU adapter (the check then skips) unless
/// `B2TF_REQUIRE_GPU` is set, as in the crate's other GPU tests.
fn model() -> Option<&'static ObjectModel> {
    static MODEL: OnceLock<Option<ObjectModel>> = OnceLock::new();
    MODEL
        .get_or_init(|| {
            let mut m = b2tfpose::onboard::test_model::small_model()?.clone();
            assert!(m.mesh.has_texture(), "the test object should carry a texture, so that textures are stored too");
            // Symmetries of every kind, so that storing and listing them is checked (the
            // textured box itself has none).
            let flip = DiscreteSymmetry::from_row_major_4x4(&[1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.01, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
            let axis = ContinuousSymmetry { axis: [0.0, 0.0, 1.0], offset: [0.0, 0.005, 0.0] };
            m.symmetries = Some(KnownSymmetries { source: SymmetrySource::ModelsInfo, symmetries: ObjectSymmetries { discrete: vec![flip], continuous: vec![axis] } });
            Some(m)
        })
        .as_ref()
}

fn with_id(m: &ObjectModel, id: &str) -> ObjectModel {
    ObjectModel { object_id: id.to_string(), ..m.clone() }
}

/// Version `generation` of object `id`, marked in both halves of the encoded form: the
/// manifest (`config.render_size`) and the tensors (the first silhouette word). A reader
/// that combined a manifest of one version with tensors of another fails `assert_same`
/// against the version its manifest names.
fn generation(base: &ObjectModel, id: &str, generation: u32) -> ObjectModel {
    let mut m = with_id(base, id);
    m.config.render_size = 1000 + generation;
    m.silhouettes.to_mut()[0] = u64::from(generation);
    m
}

/// The generation a loaded object claims in its manifest.
fn generation_of(m: &ObjectModel) -> u32 {
    m.config.render_size.checked_sub(1000).unwrap_or_else(|| panic!("object {:?} carries no generation mark", m.object_id))
}

/// Bytes of the model's tensor arrays (what dominates its encoded size).
fn tensor_bytes(m: &ObjectModel) -> usize {
    m.global.len() * 4 + m.patch_descriptors.memory_bytes() + m.patch_points.len() * 12 + m.patch_cells.len() * 2 + m.silhouettes.len() * 8
}

/// Size of the big object of the kill test: large enough that its put takes a good fraction
/// of a second even where writes are fast, small enough for a debug build.
const BIG_OBJECT_BYTES: usize = 150 << 20;

/// How many copies of the small model make the big one.
fn big_copies(m: &ObjectModel) -> usize {
    BIG_OBJECT_BYTES.div_ceil(tensor_bytes(m).max(1))
}

/// A valid, honestly bigger model: the templates with their patches, descriptors and
/// silhouettes repeated `copies` times, each copy's templates pointing at its own patch rows
/// (what `ObjectModel::validate` requires to stay consistent).
fn enlarged(m: &ObjectModel, id: &str, copies: usize) -> ObjectModel {
    let patches = u32::try_from(m.patch_count()).expect("patch count");
    let mut big = with_id(m, id);
    big.templates = (0..copies as u32)
        .flat_map(|k| m.templates.iter().map(move |t| Template { patch_start: t.patch_start + k * patches, ..t.clone() }))
        .collect();
    big.global = m.global.repeat(copies);
    big.patch_descriptors = match &m.patch_descriptors {
        PatchDescriptors::Half(v) => PatchDescriptors::Half(v.repeat(copies).into()),
        PatchDescriptors::Quantized { quantizer, codes } => PatchDescriptors::Quantized { quantizer: quantizer.clone(), codes: codes.repeat(copies).into() },
        PatchDescriptors::Int8 { codes, scales } => PatchDescriptors::Int8 { codes: codes.repeat(copies).into(), scales: scales.repeat(copies).into() },
    };
    big.patch_points = match &m.patch_points {
        PatchPoints::Exact(p) => PatchPoints::Exact(p.repeat(copies).into()),
        PatchPoints::Grid { grid, steps } => PatchPoints::Grid { grid: *grid, steps: steps.repeat(copies).into() },
    };
    big.patch_cells = m.patch_cells.repeat(copies).into();
    big.silhouettes = m.silhouettes.repeat(copies).into();
    big.validate().expect("the enlarged model is consistent");
    big
}

/// Every field of a model that the store keeps, compared.
#[track_caller]
fn assert_same(expected: &ObjectModel, got: &ObjectModel) {
    let id = &expected.object_id;
    assert_eq!(got.object_id, *id);
    assert_eq!(got.backbone, expected.backbone, "{id}: backbone");
    assert_eq!(got.config, expected.config, "{id}: config");
    assert_eq!(got.render_intrinsics, expected.render_intrinsics, "{id}: render intrinsics");
    assert_eq!(got.grid, expected.grid, "{id}: grid");
    assert_eq!((got.global_dim, got.local_dim), (expected.global_dim, expected.local_dim), "{id}: descriptor sizes");
    assert!(got.templates == expected.templates, "{id}: templates differ");
    assert!(got.global == expected.global, "{id}: global descriptors differ");
    assert!(got.patch_descriptors == expected.patch_descriptors, "{id}: patch descriptors differ");
    assert!(got.patch_points == expected.patch_points, "{id}: patch points differ");
    assert!(got.patch_cells == expected.patch_cells, "{id}: patch cells differ");
    assert!(got.silhouettes == expected.silhouettes, "{id}: silhouettes differ");
    assert!(got.contours.get() == expected.contours.get(), "{id}: contour models differ");
    assert_eq!(got.symmetries, expected.symmetries, "{id}: symmetries");
    let (a, b) = (&expected.mesh, &got.mesh);
    assert_eq!(b.name(), a.name(), "{id}: mesh name");
    assert_eq!(b.source_units(), a.source_units(), "{id}: mesh units");
    assert!(b.positions() == a.positions() && b.normals() == a.normals() && b.triangles() == a.triangles(), "{id}: mesh geometry differs");
    assert!(b.colors() == a.colors() && b.uvs() == a.uvs() && b.parts() == a.parts(), "{id}: mesh attributes differ");
    assert_eq!(b.materials().len(), a.materials().len(), "{id}: materials");
    for (i, (ma, mb)) in a.materials().iter().zip(b.materials()).enumerate() {
        assert_eq!((&mb.name, mb.base_color), (&ma.name, ma.base_color), "{id}: material {i}");
        let pixels = |m: &b2tfpose::mesh::Material| m.texture.as_ref().map(|t| (t.dimensions(), t.pixels().unwrap().as_raw().clone()));
        assert!(pixels(mb) == pixels(ma), "{id}: texture of material {i} differs");
    }
}

fn now_unix_s() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).expect("clock after 1970").as_secs()
}

// ---------------------------------------------------------------------------------------
// Store locations and backend-specific access (damage, inspection)
// ---------------------------------------------------------------------------------------

/// The file system path behind a store URL.
fn store_path(url: &str) -> PathBuf {
    if let Some(rest) = url.strip_prefix("s3://") {
        let (location, _) = rest.split_once('?').unwrap_or((rest, ""));
        let (bucket, prefix) = location.split_once('/').unwrap_or((location, ""));
        return s3_root(url).join(bucket).join(prefix);
    }
    let p = url.strip_prefix("dir://").or_else(|| url.strip_prefix("sqlite://")).unwrap_or_else(|| panic!("unexpected store URL {url}"));
    PathBuf::from(p)
}

/// The temporary folder a test's store lives in (scratch files go there too).
fn test_folder(url: &str) -> PathBuf {
    store_path(url).parent().expect("store path has a parent").to_path_buf()
}

fn is_sqlite(url: &str) -> bool {
    url.starts_with("sqlite://")
}

fn is_s3(url: &str) -> bool {
    url.starts_with("s3://")
}

/// The folders the S3 test servers of this process serve, by port.
static S3_ROOTS: std::sync::Mutex<Vec<(u16, PathBuf)>> = std::sync::Mutex::new(Vec::new());

/// The folder of the S3 server an `s3://` URL's endpoint names.
fn s3_root(url: &str) -> PathBuf {
    let port: u16 = url.split("127.0.0.1:").nth(1).and_then(|r| r.split('&').next()).and_then(|p| p.parse().ok()).unwrap_or_else(|| panic!("no test server port in {url}"));
    S3_ROOTS.lock().unwrap().iter().find(|(p, _)| *p == port).map(|(_, r)| r.clone()).unwrap_or_else(|| panic!("no S3 test server on port {port}"))
}

/// How the store names itself in `url()` and in errors: its URL (secrets masked) or path.
fn store_label(url: &str) -> String {
    if is_s3(url) {
        s3_server::shown(url)
    } else {
        store_path(url).display().to_string()
    }
}

/// A plain connection to a SQLite store's file, for inspecting or damaging it by hand.
fn raw_db(url: &str) -> rusqlite::Connection {
    let c = rusqlite::Connection::open(store_path(url)).expect("raw connection to the store database");
    c.busy_timeout(Duration::from_secs(10)).expect("busy timeout");
    c
}

/// Every path under `root`, relative, sorted (to show that nothing was created).
fn tree(root: &Path) -> Vec<PathBuf> {
    fn walk(root: &Path, dir: &Path, out: &mut Vec<PathBuf>) {
        for e in std::fs::read_dir(dir).expect("read_dir").flatten() {
            out.push(e.path().strip_prefix(root).expect("under root").to_path_buf());
            if e.file_type().map(|t| t.is_dir()).unwrap_or(false) {
                walk(root, &e.path(), out);
            }
        }
    }
    let mut out = Vec::new();
    walk(root, root, &mut out);
    out.sort();
    out
}

/// Deterministic garbage (xorshift), so that a failure reproduces.
fn garbage(len: usize) -> Vec<u8> {
    let mut x: u64 = 0x9e37_79b9_7f4a_7c15;
    (0..len)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x as u8
        })
        .collect()
}

/// How an object is damaged in `check_damage`.
#[derive(Clone, Copy, Debug)]
enum Damage {
    /// The tensor bytes replaced by garbage of the same length: only decoding can tell.
    GarbledTensors,
    /// The tensor bytes cut to half their length (a torn write).
    TruncatedTensors,
    /// The manifest's first byte changed (same length): invalid JSON.
    GarbledManifest,
    /// The manifest cut to half its length.
    TruncatedManifest,
}

fn damage(url: &str, id: &str, how: Damage) {
    if is_sqlite(url) {
        // Schema: migrations/0001_objects.sql (objects.manifest; chunks of part 'tensors').
        let sql = match how {
            Damage::GarbledTensors => "UPDATE chunks SET data = randomblob(length(data)) WHERE object_id = ?1 AND part = 'tensors' AND seq = 0",
            Damage::TruncatedTensors => {
                "UPDATE chunks SET data = substr(data, 1, length(data) / 2) WHERE object_id = ?1 AND part = 'tensors' \
                 AND seq = (SELECT MAX(seq) FROM chunks WHERE object_id = ?1 AND part = 'tensors')"
            }
            Damage::GarbledManifest => "UPDATE objects SET manifest = '[' || substr(manifest, 2) WHERE id = ?1",
            Damage::TruncatedManifest => "UPDATE objects SET manifest = substr(manifest, 1, length(manifest) / 2) WHERE id = ?1",
        };
        let changed = raw_db(url).execute(sql, [id]).expect("damaging the database");
        assert_eq!(changed, 1, "{how:?} of {id} changed {changed} rows");
    } else {
        let dir = store_path(url).join(id);
        // S3: the parts of the object's one write.
        let tensors = if is_s3(url) {
            let writes: Vec<_> = std::fs::read_dir(dir.join("parts")).expect("parts").flatten().collect();
            assert_eq!(writes.len(), 1, "one write of {id}");
            writes[0].path().join("tensors.safetensors")
        } else {
            dir.join("tensors.safetensors")
        };
        let (file, bytes) = match how {
            Damage::GarbledTensors => {
                let f = tensors.clone();
                let len = std::fs::metadata(&f).expect("tensors file").len() as usize;
                (f, garbage(len))
            }
            Damage::TruncatedTensors => {
                let f = tensors.clone();
                let b = std::fs::read(&f).expect("tensors file");
                (f, b[..b.len() / 2].to_vec())
            }
            Damage::GarbledManifest => {
                let f = dir.join("manifest.json");
                let mut b = std::fs::read(&f).expect("manifest");
                b[0] = b'[';
                (f, b)
            }
            Damage::TruncatedManifest => {
                let f = dir.join("manifest.json");
                let b = std::fs::read(&f).expect("manifest");
                (f, b[..b.len() / 2].to_vec())
            }
        };
        std::fs::write(&file, bytes).expect("damaging the file");
    }
}

// ---------------------------------------------------------------------------------------
// Child processes
// ---------------------------------------------------------------------------------------

/// What a child process does: `big-writer`, `writer` or `reader`.
const ROLE_VAR: &str = "B2TF_STORE_TEST_ROLE";
const URL_VAR: &str = "B2TF_STORE_TEST_URL";
/// The role's number: copies of the big model, or writer rounds.
const COUNT_VAR: &str = "B2TF_STORE_TEST_COUNT";
/// Readers stop after one more pass once this file exists.
const STOP_VAR: &str = "B2TF_STORE_TEST_STOP";
/// Marks a child's report lines among libtest's own output.
const MARK: &str = "@@store-child@@";

/// The objects the writer replaces and the readers read (besides the stable `obj-base`).
const CONTENDED: [&str; 2] = ["obj-a", "obj-b"];
/// Generations the writer puts of each contended object.
const WRITER_ROUNDS: u32 = 40;
/// `exists` and `info` calls a reader makes after each full read of an object.
const LOOKUPS_PER_READ: usize = 25;
/// How long any child may take before the test gives up on it (generous: debug build,
/// two shared cores, other tests running at the same time).
const CHILD_TIMEOUT: Duration = Duration::from_secs(240);

fn env_var(name: &str) -> String {
    std::env::var(name).unwrap_or_else(|_| panic!("child: {name} is not set"))
}

fn report(message: impl std::fmt::Display) {
    let mut out = std::io::stdout().lock();
    writeln!(out, "{MARK} {message}").expect("child: writing to stdout");
    out.flush().expect("child: flushing stdout");
}

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

/// A running child: its marked stdout lines arrive on a channel; stdout and stderr are
/// collected whole for failure messages.
struct ChildProcess {
    name: String,
    child: Child,
    messages: mpsc::Receiver<String>,
    received: Vec<String>,
    stdout: Option<JoinHandle<String>>,
    stderr: Option<JoinHandle<String>>,
}

/// A child after it ended.
struct Finished {
    status: ExitStatus,
    /// Every marked line, in order.
    messages: Vec<String>,
    /// Everything it wrote, for failure messages.
    output: String,
}

impl ChildProcess {
    fn spawn(name: &str, role: &str, url: &str, env: &[(&str, String)]) -> Self {
        let exe = std::env::current_exe().expect("test binary path");
        let mut cmd = Command::new(exe);
        cmd.args(["--exact", "child_entry", "--include-ignored", "--nocapture", "--test-threads=1"])
            .env(ROLE_VAR, role)
            .env(URL_VAR, url)
            .env("XDG_RUNTIME_DIR", "/tmp")
            .env("RUST_BACKTRACE", "1")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        for (k, v) in env {
            cmd.env(k, v);
        }
        let mut child = cmd.spawn().unwrap_or_else(|e| panic!("starting child {name}: {e}"));
        let (tx, messages) = mpsc::channel();
        let out = child.stdout.take().expect("piped stdout");
        let stdout = std::thread::spawn(move || {
            let mut all = String::new();
            for line in BufReader::new(out).lines() {
                let Ok(line) = line else { break };
                // libtest may print its "test child_entry ..." on the same line.
                if let Some(i) = line.find(MARK) {
                    let _ = tx.send(line[i + MARK.len()..].trim().to_string());
                }
                all.push_str(&line);
                all.push('\n');
            }
            all
        });
        let mut err = child.stderr.take().expect("piped stderr");
        let stderr = std::thread::spawn(move || {
            let mut all = String::new();
            let _ = err.read_to_string(&mut all);
            all
        });
        Self { name: name.to_string(), child, messages, received: Vec::new(), stdout: Some(stdout), stderr: Some(stderr) }
    }

    /// Waits for the next marked line that starts with `prefix`; fails the test (with the
    /// child's output) if the child ends or times out first.
    fn expect_message(&mut self, prefix: &str, timeout: Duration) -> String {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.messages.recv_timeout(left) {
                Ok(m) => {
                    self.received.push(m.clone());
                    if m.starts_with(prefix) {
                        return m;
                    }
                }
                Err(e) => {
                    let name = self.name.clone();
                    let _ = self.child.kill();
                    let done = self.finish(Duration::from_secs(30));
                    panic!("child {name}: no {prefix:?} message ({e:?}); status {}; output:\n{}", done.status, done.output);
                }
            }
        }
    }

    fn exited(&mut self) -> bool {
        matches!(self.child.try_wait(), Ok(Some(_)))
    }

    /// Waits for the child to end (killing it after `timeout`) and collects its output.
    fn finish(&mut self, timeout: Duration) -> Finished {
        let deadline = Instant::now() + timeout;
        let status = loop {
            if let Some(s) = self.child.try_wait().expect("try_wait") {
                break s;
            }
            if Instant::now() > deadline {
                let _ = self.child.kill();
                let s = self.child.wait().expect("wait");
                eprintln!("child {} did not end within {timeout:?}; killed", self.name);
                break s;
            }
            std::thread::sleep(Duration::from_millis(5));
        };
        let join = |h: Option<JoinHandle<String>>| h.map(|h| h.join().unwrap_or_default()).unwrap_or_default();
        let stdout = join(self.stdout.take());
        let stderr = join(self.stderr.take());
        let mut messages = std::mem::take(&mut self.received);
        messages.extend(self.messages.try_iter());
        Finished { status, messages, output: format!("--- stdout ---\n{stdout}--- stderr ---\n{stderr}") }
    }
}

/// A child still running when its test fails (a reader waiting for a stop file that will
/// never come) is killed rather than left behind.
impl Drop for ChildProcess {
    fn drop(&mut self) {
        if matches!(self.child.try_wait(), Ok(None)) {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

impl Finished {
    #[track_caller]
    fn assert_success(&self, name: &str) {
        assert!(self.status.success(), "child {name} failed ({}); output:\n{}", self.status, self.output);
    }
}

// ---------------------------------------------------------------------------------------
// The shared checks
// ---------------------------------------------------------------------------------------

/// A put then a get gives back every field; the returned info describes the object; the
/// object is there for another handle opened from the same URL.
fn check_round_trip(url: &str) {
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
fn check_replace(url: &str) {
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
fn check_list_info_exists_delete(url: &str) {
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
fn check_read_only(url: &str) {
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
fn plant_abandoned_write(url: &str) -> Option<PathBuf> {
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
fn check_bad_ids(url: &str) {
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
fn check_damage(url: &str) {
    let Some(m) = model() else { return };
    let store = store::open(url).expect("open");
    let damaged = [
        ("obj-garbled", Damage::GarbledTensors),
        ("obj-torn", Damage::TruncatedTensors),
        ("obj-bad-json", Damage::GarbledManifest),
        ("obj-torn-json", Damage::TruncatedManifest),
    ];
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

/// Bytes of a put of `id` by process `pid` that are on disk already (`None`: nothing yet).
/// dir: the writer's hidden temporary folder's tensors file; sqlite: growth of the WAL
/// beyond `wal_before` (the uncommitted transaction's pages); S3: the upload the server is
/// receiving (the tensors come first).
fn partial_write_bytes(url: &str, id: &str, pid: u32, wal_before: u64) -> Option<u64> {
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
/// and test nothing). The put is then repeated to completion and timed, and the kill's
/// share of that time is printed.
fn check_killed_put(url: &str) {
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

    let mut child = ChildProcess::spawn("big-writer", "big-writer", url, &[(COUNT_VAR, copies.to_string())]);
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
fn check_readers_beside_a_writer(url: &str) {
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

/// The LRU cache over a store: hits and misses, eviction of the least recently used under
/// the byte budget, `revalidate` after another writer's replace or delete, `invalidate`
/// after this process' own, and `Arc`s that outlive their entry.
fn check_cache(url: &str) {
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

// ---------------------------------------------------------------------------------------
// S3 only: what a network store adds
// ---------------------------------------------------------------------------------------

/// A server of this test's own (registered for the URL helpers), `None` when s3s-fs is
/// not installed and not required.
fn s3_test_server(dir: &Path) -> Option<s3_server::S3Server> {
    let server = s3_server::S3Server::start(dir)?;
    S3_ROOTS.lock().unwrap().push((server.port, server.root.clone()));
    Some(server)
}

/// The S3 server dies (SIGKILL) while a big put uploads: the put returns an error instead
/// of hanging, calls fail while the server is away, and once it is back the object is
/// absent, the earlier one intact, and the id free.
#[test]
fn s3_server_that_disappears_mid_put_leaves_no_object() {
    let Some(m) = model() else { return };
    let tmp = tempfile::tempdir().expect("temp dir");
    let Some(mut server) = s3_test_server(tmp.path()) else { return };
    let url = server.url("objects");
    let store = store::open(&url).expect("open");
    store.put(&with_id(m, "obj-a"), false).expect("put");
    let big = enlarged(m, "obj-big", big_copies(m));
    let expected = codec::encode(&big).expect("encode").tensors.len() as u64;
    let writer = {
        let (store, big) = (store.clone(), big.clone());
        std::thread::spawn(move || store.put(&big, false).map(|i| i.id))
    };
    let began = Instant::now();
    while partial_write_bytes(&url, "obj-big", 0, 0).is_none_or(|n| n < expected / 2) {
        assert!(!writer.is_finished(), "the put finished before the server could be stopped: make the object bigger");
        assert!(began.elapsed() < CHILD_TIMEOUT, "no upload of obj-big seen within {CHILD_TIMEOUT:?}");
        std::thread::sleep(Duration::from_millis(1));
    }
    server.kill();
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
fn s3_abandoned_and_replaced_writes_are_removed() {
    let Some(m) = model() else { return };
    let tmp = tempfile::tempdir().expect("temp dir");
    let Some(server) = s3_test_server(tmp.path()) else { return };
    let url = server.url("objects");
    let store = store::open(&url).expect("open");
    // Write folders that still hold a part (S3 has no folders; s3s-fs leaves empty ones).
    let writes = |id: &str| tree(&store_path(&url).join(id).join("parts")).iter().filter(|p| p.components().count() > 1 && store_path(&url).join(id).join("parts").join(p).is_file()).filter_map(|p| p.components().next()).collect::<BTreeSet<_>>().len();
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
fn s3_open_names_what_is_wrong() {
    let tmp = tempfile::tempdir().expect("temp dir");
    let Some(mut server) = s3_test_server(tmp.path()) else { return };
    let url = server.url("objects");
    let cases = [
        (url.replacen(s3_server::BUCKET, "no-such-bucket", 1), "NoSuchBucket"),
        (url.replace("secret_access_key=b2tf-test-secret", "secret_access_key=wrong"), "SignatureDoesNotMatch"),
    ];
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
