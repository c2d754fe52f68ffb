"""A `b2tf serve` child process for the reliability tools (load test, crash test).

The binary is $B2TF_BIN, else the checkout's target/release/b2tf, built with
`cargo build --release` when absent so that the tools work from a fresh clone. The
server listens on free loopback ports (port 0) and says which on its first stdout line;
stdout and stderr go to files in the work folder (a pipe nobody reads could block it).
Its TMPDIR is a folder of ours, so that upload staging folders it leaves behind (after a
SIGKILL) can be counted.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import List, Optional, Sequence

REPO = Path(__file__).resolve().parents[2]


def b2tf_bin() -> Path:
    """$B2TF_BIN (relative to the current folder), else target/release/b2tf of the checkout,
    built when missing."""
    given = os.environ.get("B2TF_BIN")
    path = Path(given).resolve() if given else REPO / "target/release/b2tf"
    if not path.is_file():
        if given:
            raise SystemExit(f"B2TF_BIN={given}: no such file")
        print(f"{path} missing: cargo build --release", flush=True)
        subprocess.run(["cargo", "build", "--release"], cwd=REPO, check=True)
    return path


def server_env(tmpdir: Path) -> dict:
    """Our environment without B2TF_* settings (flags decide everything; the ONNX Runtime
    path may stay), Mesa quiet on headless machines, uploads staged under `tmpdir`."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("B2TF_") or k == "B2TF_ORT_LIB"}
    env.setdefault("XDG_RUNTIME_DIR", "/tmp")
    env["TMPDIR"] = str(tmpdir)
    return env


def run_cli(*args: str, timeout: float = 300) -> str:
    """`b2tf ARGS`; its stdout, or an exception with its output when it fails."""
    p = subprocess.run([str(b2tf_bin()), *args], env=server_env(Path(os.environ.get("TMPDIR", "/tmp"))), capture_output=True, text=True, timeout=timeout)
    if p.returncode != 0:
        raise RuntimeError(f"b2tf {' '.join(args)} failed ({p.returncode}):\n{p.stdout}\n{p.stderr}")
    return p.stdout


class Server:
    """`b2tf serve --store STORE EXTRA…` on free loopback ports; `http` is http://HOST:PORT
    and `grpc` HOST:PORT."""

    def __init__(self, store: str, workdir: Path, extra: Sequence[str] = (), name: str = "server", start_timeout: float = 60) -> None:
        workdir.mkdir(parents=True, exist_ok=True)
        self.tmpdir = workdir / "tmp"
        self.tmpdir.mkdir(exist_ok=True)
        self.out_path, self.err_path = workdir / f"{name}.out", workdir / f"{name}.err"
        args: List[str] = [str(b2tf_bin()), "serve", "--http", "127.0.0.1:0", "--grpc", "127.0.0.1:0", "--store", store, *extra]
        with open(self.out_path, "w") as out, open(self.err_path, "w") as err:
            self.proc = subprocess.Popen(args, env=server_env(self.tmpdir), stdout=out, stderr=err, stdin=subprocess.DEVNULL)
        self.pid = self.proc.pid
        end = time.monotonic() + start_timeout
        line = ""
        while "listening" not in line:
            if self.proc.poll() is not None:
                raise RuntimeError(f"b2tf serve exited ({self.proc.returncode}) before listening:\n{self.log_tail()}")
            if time.monotonic() > end:
                self.kill()
                raise RuntimeError(f"b2tf serve printed no address within {start_timeout} s:\n{self.log_tail()}")
            time.sleep(0.05)
            line = self.out_path.read_text()
        http = re.search(r"https?://[0-9.]+:\d+", line)
        grpc = re.search(r"grpcs?://([0-9.]+:\d+)", line)
        if not http or not grpc:
            self.kill()
            raise RuntimeError(f"no addresses in {line!r}")
        self.http, self.grpc = http.group(0), grpc.group(1)

    def wait_ready(self, timeout: float = 60) -> float:
        """Seconds until /readyz answered 200; raises when it does not within `timeout`."""
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            if self.proc.poll() is not None:
                raise RuntimeError(f"b2tf serve exited ({self.proc.returncode}) while warming up:\n{self.log_tail()}")
            try:
                with urllib.request.urlopen(self.http + "/readyz", timeout=5) as r:
                    if r.status == 200:
                        return time.monotonic() - t0
            except (urllib.error.URLError, OSError):
                pass
            time.sleep(0.1)
        raise RuntimeError(f"b2tf serve not ready within {timeout} s:\n{self.log_tail()}")

    def alive(self) -> bool:
        return self.proc.poll() is None

    def kill(self) -> None:
        """SIGKILL, as a crash or the OOM killer would, and reap it."""
        if self.alive():
            self.proc.send_signal(signal.SIGKILL)
        self.proc.wait()

    def stop(self, timeout: float = 60) -> Optional[int]:
        """SIGTERM and wait: its exit status, or None when it did not stop in time (then
        it is killed)."""
        if self.alive():
            self.proc.send_signal(signal.SIGTERM)
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill()
            return None

    def log_tail(self, n: int = 30) -> str:
        lines: List[str] = []
        for p in (self.out_path, self.err_path):
            if p.exists():
                lines += p.read_text(errors="replace").splitlines()[-n:]
        return "\n".join(lines)
