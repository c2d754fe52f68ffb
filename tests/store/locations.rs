//! Where each backend keeps its bytes, and the deliberate damage and inspection that are
//! backend specific.

use super::*;

/// The file system path behind a store URL.
pub(crate) fn store_path(url: &str) -> PathBuf {
    if let Some(rest) = url.strip_prefix("s3://") {
        let (location, _) = rest.split_once('?').unwrap_or((rest, ""));
        let (bucket, prefix) = location.split_once('/').unwrap_or((location, ""));
        return s3_root(url).join(bucket).join(prefix);
    }
    let p = url.strip_prefix("dir://").or_else(|| url.strip_prefix("sqlite://")).unwrap_or_else(|| panic!("unexpected store URL {url}"));
    PathBuf::from(p)
}

/// The temporary folder a test's store lives in (scratch files go there too).
pub(crate) fn test_folder(url: &str) -> PathBuf {
    store_path(url).parent().expect("store path has a parent").to_path_buf()
}

pub(crate) fn is_sqlite(url: &str) -> bool {
    url.starts_with("sqlite://")
}

pub(crate) fn is_s3(url: &str) -> bool {
    url.starts_with("s3://")
}

/// The folders the S3 test servers of this process serve, by port.
pub(crate) static S3_ROOTS: std::sync::Mutex<Vec<(u16, PathBuf)>> = std::sync::Mutex::new(Vec::new());

/// The folder of the S3 server an `s3://` URL's endpoint names.
fn s3_port(url: &str) -> u16 {
    url.split("127.0.0.1:").nth(1).and_then(|r| r.split('&').next()).and_then(|p| p.parse().ok()).unwrap_or_else(|| panic!("no test server port in {url}"))
}

pub(crate) fn s3_root(url: &str) -> PathBuf {
    let port = s3_port(url);
    S3_ROOTS.lock().unwrap().iter().find(|(p, _)| *p == port).map(|(_, r)| r.clone()).unwrap_or_else(|| panic!("no S3 test server on port {port}"))
}

/// How the store names itself in `url()` and in errors: its URL (secrets masked) or path.
pub(crate) fn store_label(url: &str) -> String {
    if is_s3(url) {
        s3_server::shown(url)
    } else {
        store_path(url).display().to_string()
    }
}

/// A plain connection to a SQLite store's file, for inspecting or damaging it by hand.
pub(crate) fn raw_db(url: &str) -> rusqlite::Connection {
    let c = rusqlite::Connection::open(store_path(url)).expect("raw connection to the store database");
    c.busy_timeout(Duration::from_secs(10)).expect("busy timeout");
    c
}

/// Every path under `root`, relative, sorted (to show that nothing was created).
pub(crate) fn tree(root: &Path) -> Vec<PathBuf> {
    pub(crate) fn walk(root: &Path, dir: &Path, out: &mut Vec<PathBuf>) {
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
pub(crate) fn garbage(len: usize) -> Vec<u8> {
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
pub(crate) enum Damage {
    /// The tensor bytes replaced by garbage of the same length: only decoding can tell.
    GarbledTensors,
    /// The tensor bytes cut to half their length (a torn write).
    TruncatedTensors,
    /// The manifest's first byte changed (same length): invalid JSON.
    GarbledManifest,
    /// The manifest cut to half its length.
    TruncatedManifest,
}

pub(crate) fn damage(url: &str, id: &str, how: Damage) {
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

/// `url` (an S3 test server's) reached through a proxy that passes `pass_bytes` of the
/// client's bytes and then stalls; the proxy's port is registered as the same server so
/// the helpers above find its folder. Keep the proxy alive while the URL is in use.
pub(crate) fn s3_through_stalling_proxy(url: &str, pass_bytes: u64) -> (String, stalling_proxy::StallingProxy) {
    let port = s3_port(url);
    let proxy = stalling_proxy::StallingProxy::start(port, pass_bytes);
    let root = s3_root(url);
    S3_ROOTS.lock().unwrap().push((proxy.port, root));
    (url.replace(&format!("127.0.0.1:{port}"), &format!("127.0.0.1:{}", proxy.port)), proxy)
}
