//! A `b2tf serve` child process on free loopback ports, for the benchmarks that measure the
//! service from outside; stopped with SIGTERM (a clean shutdown) when dropped.

use anyhow::{anyhow, Context, Result};
use std::io::{BufRead, BufReader};

pub struct ChildServer {
    child: std::process::Child,
    /// HOST:PORT of each listener.
    pub http: String,
    pub grpc: String,
}

impl ChildServer {
    /// Starts this executable's `serve` on `store` with `extra` flags and waits until it
    /// listens (not until it is ready: poll /readyz or gRPC health for that).
    pub fn start(store: &str, extra: &[String]) -> Result<Self> {
        let mut child = std::process::Command::new(std::env::current_exe()?)
            .args(["serve", "--http", "127.0.0.1:0", "--grpc", "127.0.0.1:0", "--store", store])
            .args(extra)
            // Quiet unless asked: a benchmark's figures, not the server's access log.
            .env("B2TF_LOG", std::env::var("B2TF_LOG").unwrap_or_else(|_| "warn".into()))
            .stdout(std::process::Stdio::piped())
            .spawn()
            .context("starting b2tf serve")?;
        let mut line = String::new();
        BufReader::new(child.stdout.take().ok_or_else(|| anyhow!("no stdout"))?).read_line(&mut line)?;
        let word = |scheme: &str| line.split_whitespace().find_map(|w| w.strip_prefix(scheme)).map(str::to_string).ok_or_else(|| anyhow!("the server said {line:?}"));
        let (http, grpc) = match (word("http://"), word("grpc://")) {
            (Ok(h), Ok(g)) => (h, g),
            (Err(e), _) | (_, Err(e)) => {
                let _ = child.kill();
                let _ = child.wait();
                return Err(e);
            }
        };
        Ok(Self { child, http, grpc })
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }
}

impl Drop for ChildServer {
    fn drop(&mut self) {
        // SAFETY: kill(2) on our own child's pid.
        unsafe { libc::kill(self.child.id() as i32, libc::SIGTERM) };
        let _ = self.child.wait();
    }
}
