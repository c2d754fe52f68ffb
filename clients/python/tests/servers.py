"""A real `b2tf serve` child process on loopback, started the way tests/common/mod.rs does:
free ports, its own store, flags as given; ready once /readyz answers 200."""

from __future__ import annotations

import os
import signal
import ssl
import subprocess
import time
import urllib.request
from pathlib import Path
from typing import Dict, List, Optional, Sequence

REPO = Path(__file__).resolve().parents[3]


def b2tf_bin() -> Path:
    """$B2TF_BIN, else the repository's debug then release build. Waits a little when the
    binary is missing for a moment (being rebuilt)."""
    candidates = [Path(os.environ["B2TF_BIN"])] if os.environ.get("B2TF_BIN") else [REPO / "target/debug/b2tf", REPO / "target/release/b2tf"]
    for _ in range(60):
        for c in candidates:
            if c.is_file() and os.access(c, os.X_OK):
                return c
        time.sleep(1)
    raise RuntimeError(f"no b2tf binary at {', '.join(map(str, candidates))}: build it (cargo build) or set B2TF_BIN")


def server_env(extra: Optional[Dict[str, str]] = None) -> Dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("B2TF_") or k in ("B2TF_ORT_LIB",)}
    env.setdefault("XDG_RUNTIME_DIR", "/tmp")  # quiets Mesa on headless machines
    env.update(extra or {})
    return env


def run_cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    """Runs `b2tf ARGS`; raises with its output when it fails."""
    p = subprocess.run([str(b2tf_bin()), *args], env=server_env(), capture_output=True, text=True, timeout=timeout)
    if p.returncode != 0:
        raise RuntimeError(f"b2tf {' '.join(args)} failed ({p.returncode}):\n{p.stdout}\n{p.stderr}")
    return p


class Server:
    def __init__(self, store: str, log: Path, extra: Sequence[str] = (), api_keys: Optional[str] = None, ca_cert: Optional[Path] = None) -> None:
        args: List[str] = [str(b2tf_bin()), "serve", "--http", "127.0.0.1:0", "--grpc", "127.0.0.1:0", "--store", store, "--render-pool", "1", *extra]
        env = server_env({"B2TF_API_KEYS": api_keys} if api_keys else None)
        self.log_path = log
        self._log = open(log, "w")
        self.proc = subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=self._log, text=True)
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        words = line.split()
        http = next((w for w in words if w.startswith(("http://", "https://"))), None)
        grpc = next((w for w in words if w.startswith(("grpc://", "grpcs://"))), None)
        if not http or not grpc:
            self.stop()
            raise RuntimeError(f"b2tf serve printed no addresses: {line!r}; log: {log.read_text()}")
        self.http = http
        self.grpc_url = grpc
        self.address = grpc.split("://", 1)[1]  # host:port
        self.tls = grpc.startswith("grpcs://")
        self._ssl = ssl.create_default_context(cafile=str(ca_cert)) if ca_cert else None
        self._ca_cert = ca_cert
        self._wait_ready()

    def get(self, path: str) -> str:
        with urllib.request.urlopen(self.http + path, timeout=10, context=self._ssl) as r:
            return str(r.read().decode())

    def _wait_ready(self, timeout: float = 120) -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.proc.poll() is not None:
                raise RuntimeError(f"b2tf serve exited with {self.proc.returncode}: {self.log_path.read_text()}")
            try:
                self.get("/readyz")
                break
            except OSError:
                time.sleep(0.1)
        else:
            raise RuntimeError(f"b2tf serve not ready within {timeout} s")
        # The gRPC health check turns SERVING in its own task, a moment after /readyz:
        # a test that asks at once must not see NOT_SERVING.
        import b2tfpose

        with b2tfpose.Client(self.address, ca_cert=self._ca_cert) as c:
            c.wait_ready(timeout=max(1.0, end - time.monotonic()))

    def metric(self, needle: str) -> float:
        """Sum of the Prometheus samples whose line contains ``needle``."""
        total = 0.0
        for line in self.get("/metrics").splitlines():
            if not line.startswith("#") and needle in line:
                total += float(line.rsplit(" ", 1)[1])
        return total

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc.stdout:
            self.proc.stdout.close()
        self._log.close()
