//! The child processes of the multi-process checks: their roles, and the parent's handle on
//! each.

use super::*;

/// What a child process does: `big-writer`, `writer` or `reader`.
pub(crate) const ROLE_VAR: &str = "B2TF_STORE_TEST_ROLE";
pub(crate) const URL_VAR: &str = "B2TF_STORE_TEST_URL";
/// The role's number: copies of the big model, or writer rounds.
pub(crate) const COUNT_VAR: &str = "B2TF_STORE_TEST_COUNT";
/// Readers stop after one more pass once this file exists.
pub(crate) const STOP_VAR: &str = "B2TF_STORE_TEST_STOP";
/// Marks a child's report lines among libtest's own output.
pub(crate) const MARK: &str = "@@store-child@@";

/// The objects the writer replaces and the readers read (besides the stable `obj-base`).
pub(crate) const CONTENDED: [&str; 2] = ["obj-a", "obj-b"];
/// Generations the writer puts of each contended object.
pub(crate) const WRITER_ROUNDS: u32 = 40;
/// `exists` and `info` calls a reader makes after each full read of an object.
pub(crate) const LOOKUPS_PER_READ: usize = 25;
/// How long any child may take before the test gives up on it (generous: debug build,
/// two shared cores, other tests running at the same time).
pub(crate) const CHILD_TIMEOUT: Duration = Duration::from_secs(240);

pub(crate) fn env_var(name: &str) -> String {
    std::env::var(name).unwrap_or_else(|_| panic!("child: {name} is not set"))
}

pub(crate) fn report(message: impl std::fmt::Display) {
    let mut out = std::io::stdout().lock();
    writeln!(out, "{MARK} {message}").expect("child: writing to stdout");
    out.flush().expect("child: flushing stdout");
}

/// A running child: its marked stdout lines arrive on a channel; stdout and stderr are
/// collected whole for failure messages.
pub(crate) struct ChildProcess {
    pub(crate) name: String,
    pub(crate) child: Child,
    pub(crate) messages: mpsc::Receiver<String>,
    pub(crate) received: Vec<String>,
    pub(crate) stdout: Option<JoinHandle<String>>,
    pub(crate) stderr: Option<JoinHandle<String>>,
}

/// A child after it ended.
pub(crate) struct Finished {
    pub(crate) status: ExitStatus,
    /// Every marked line, in order.
    pub(crate) messages: Vec<String>,
    /// Everything it wrote, for failure messages.
    pub(crate) output: String,
}

impl ChildProcess {
    pub(crate) fn spawn(name: &str, role: &str, url: &str, env: &[(&str, String)]) -> Self {
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
    pub(crate) fn expect_message(&mut self, prefix: &str, timeout: Duration) -> String {
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

    pub(crate) fn exited(&mut self) -> bool {
        matches!(self.child.try_wait(), Ok(Some(_)))
    }

    /// Waits for the child to end (killing it after `timeout`) and collects its output.
    pub(crate) fn finish(&mut self, timeout: Duration) -> Finished {
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
    pub(crate) fn assert_success(&self, name: &str) {
        assert!(self.status.success(), "child {name} failed ({}); output:\n{}", self.status, self.output);
    }
}
