//! A `b2tf serve` child process on free loopback ports, for the benchmarks that measure the
//! service from outside; stopped with SIGTERM (a clean shutdown) when dropped.

use anyhow::{anyhow, Context, Result};
use std::io::{BufRead, BufReader};

pub struct ChildServer {
    child: std::process::Child,
    /// `stop` ran: the process is reaped, and its pid may belong to another by now.
    stopped: bool,
    /// HOST:PORT of each listener.
    pub http: String,
    pub grpc: String,
}

impl ChildServer {
    /// Starts this executable's `serve` on `store` with `extra` flags and waits until it
    /// listens (not until it is ready: poll /readyz or gRPC health for that).
    pub fn start(store: &str, extra: &[String]) -> Result<Self> {
        let mut command = std::process::Command::new(std::env::current_exe()?);
        command
            .args(["serve", "--http", "127.0.0.1:0", "--grpc", "127.0.0.1:0", "--store", store])
            .args(extra)
            // Quiet unless asked: a benchmark's figures, not the server's access log.
            .env("B2TF_LOG", std::env::var("B2TF_LOG").unwrap_or_else(|_| "warn".into()));
        Self::listening(command)
    }

    /// Runs `command` and waits for its first stdout line, which names both addresses.
    fn listening(mut command: std::process::Command) -> Result<Self> {
        let mut child = command.stdout(std::process::Stdio::piped()).spawn().context("starting b2tf serve")?;
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
        Ok(Self { child, stopped: false, http, grpc })
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Stops the server as an orchestrator does (SIGTERM) and checks that it shut down
    /// cleanly: a server that crashes in its exit (seen on a GPU, where ONNX Runtime's
    /// CUDA session outlived the driver) is an error here, not a line lost in the log.
    pub fn stop(mut self) -> Result<()> {
        let status = self.terminate().context("waiting for b2tf serve to stop")?;
        if !status.success() {
            anyhow::bail!("b2tf serve did not shut down cleanly on SIGTERM: {status}");
        }
        Ok(())
    }

    fn terminate(&mut self) -> std::io::Result<std::process::ExitStatus> {
        self.stopped = true;
        // SAFETY: kill(2) on our own child's pid, not yet reaped.
        unsafe { libc::kill(self.child.id() as i32, libc::SIGTERM) };
        self.child.wait()
    }
}

impl Drop for ChildServer {
    fn drop(&mut self) {
        if !self.stopped {
            let _ = self.terminate();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A stand-in server: prints the listening line, then exits with `code` on SIGTERM.
    fn stand_in(code: i32) -> ChildServer {
        let mut command = std::process::Command::new("sh");
        command.args(["-c", &format!("trap 'exit {code}' TERM; echo 'listening on http://127.0.0.1:1 grpc://127.0.0.1:2'; while :; do sleep 0.05; done")]);
        ChildServer::listening(command).unwrap()
    }

    #[test]
    fn stop_tells_a_clean_shutdown_from_a_crash() {
        let clean = stand_in(0);
        assert_eq!((clean.http.as_str(), clean.grpc.as_str()), ("127.0.0.1:1", "127.0.0.1:2"));
        clean.stop().unwrap();
        let e = stand_in(134).stop().unwrap_err().to_string();
        assert!(e.contains("did not shut down cleanly") && e.contains("134"), "{e}");
    }
}
