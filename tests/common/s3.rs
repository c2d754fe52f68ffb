//! A real S3 server for the `s3://` store's tests: `s3s-fs` (crates.io, `cargo install
//! s3s-fs --version 0.14.1 --features binary`; scripts/test.sh installs it into
//! .deps/s3s-fs) on a free loopback port, keeping its objects as files in a folder, so a
//! test can look at, damage or age what the store wrote.
//!
//! The binary is `$B2TF_S3S_FS`, else `.deps/s3s-fs/bin/s3s-fs`. Without it the S3 tests
//! skip, unless `B2TF_REQUIRE_S3` is set (scripts/test.sh sets it): then they fail.
#![allow(dead_code)]

use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

pub const BUCKET: &str = "b2tf-test";
const ACCESS_KEY: &str = "b2tf-test-key";
const SECRET_KEY: &str = "b2tf-test-secret";

pub struct S3Server {
    child: Option<Child>,
    /// The folder s3s-fs serves: a bucket is a folder in it, an object a file.
    pub root: PathBuf,
    pub port: u16,
}

impl Drop for S3Server {
    fn drop(&mut self) {
        self.kill();
    }
}

fn binary() -> Option<PathBuf> {
    let p = std::env::var_os("B2TF_S3S_FS").map(PathBuf::from).unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join(".deps/s3s-fs/bin/s3s-fs"));
    if p.is_file() {
        return Some(p);
    }
    assert!(std::env::var_os("B2TF_REQUIRE_S3").is_none(), "B2TF_REQUIRE_S3 is set but the S3 test server {} is missing (scripts/test.sh installs it)", p.display());
    eprintln!("SKIPPED (no S3 test server at {}; scripts/test.sh installs it)", p.display());
    None
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0").expect("a free port").local_addr().expect("address").port()
}

impl S3Server {
    /// A server on a fresh folder under `dir` with the test bucket in it; `None` when
    /// s3s-fs is not installed (and not required).
    pub fn start(dir: &Path) -> Option<Self> {
        binary()?;
        let root = dir.join("s3");
        std::fs::create_dir_all(root.join(BUCKET)).expect("the bucket's folder");
        let mut server = Self { child: None, root, port: free_port() };
        server.restart();
        Some(server)
    }

    /// Starts the server (again) on its port and folder, and waits until it answers.
    pub fn restart(&mut self) {
        self.kill();
        let child = Command::new(binary().expect("s3s-fs"))
            .args(["--host", "127.0.0.1", "--port", &self.port.to_string(), "--access-key", ACCESS_KEY, "--secret-key", SECRET_KEY])
            .arg(&self.root)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("starting s3s-fs");
        self.child = Some(child);
        let began = Instant::now();
        while std::net::TcpStream::connect(("127.0.0.1", self.port)).is_err() {
            assert!(began.elapsed() < Duration::from_secs(30), "s3s-fs did not listen on port {} within 30 s", self.port);
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// SIGKILL: the server disappears as a crashed or unplugged one does.
    pub fn kill(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }

    /// The store URL of `prefix` in `bucket`: endpoint and credentials in the query (so
    /// that child processes get them too), few and quick retries.
    pub fn url_in(&self, bucket: &str, prefix: &str) -> String {
        format!(
            "s3://{bucket}/{prefix}?endpoint=http://127.0.0.1:{}&allow_http=true&region=us-east-1&access_key_id={ACCESS_KEY}&secret_access_key={SECRET_KEY}&max_retries=2&retry_timeout_s=10",
            self.port
        )
    }

    pub fn url(&self, prefix: &str) -> String {
        self.url_in(BUCKET, prefix)
    }

    /// Where s3s-fs keeps the object `key` of the test bucket.
    pub fn file(&self, key: &str) -> PathBuf {
        self.root.join(BUCKET).join(key)
    }

    /// Bytes of uploads s3s-fs is receiving (its `.tmp.*.internal.part` files), largest.
    pub fn upload_in_progress(&self) -> Option<u64> {
        std::fs::read_dir(&self.root).ok()?.flatten().filter(|e| e.file_name().to_string_lossy().ends_with(".internal.part")).filter_map(|e| e.metadata().ok().map(|m| m.len())).max()
    }
}

/// `url` as the store shows it: secrets masked.
pub fn shown(url: &str) -> String {
    url.replace(&format!("secret_access_key={SECRET_KEY}"), "secret_access_key=***")
}
