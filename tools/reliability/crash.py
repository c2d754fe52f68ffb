"""SIGKILL of `b2tf serve` in the middle of its work, over and over, on one store: each
round starts the server on the store left by the previous one, sets it working, kills it,
and checks what the next start finds.

Three kinds of round, in turn:
- "onboard": an onboarding (HTTP JSON, multipart or gRPC in turn) with estimates beside
  it, killed at a random point while templates are rendered;
- "put": the same, killed while the object is written to the store: at a random point
  between the first sign of the write (a dir:// store's hidden `.ID.tmp-…` folder
  appearing, a SQLite store's -wal file changing) and 1.3 times the time the put took for
  the first object, so that some kills fall just after it;
- "estimate": four clients estimating back to back (HTTP and gRPC), killed at a random
  point.
After each kill the store must open (the server gets ready), list only complete objects
(each fetched with its template count and estimated to the right pose), and the
interrupted object must be absent, or present and complete when its put had finished; its
operation is unknown to the new process (404). A dir:// store must have no hidden
temporary folder left once reopened."""

from __future__ import annotations

import os
import random
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import List, Optional

import b2tfpose

from . import onboarding, store_check
from .calls import http_call
from .fixtures import Fixtures
from .mix import GRPC_EST, HTTP_EST, OBJECT, Mix
from .server import Server

LEVEL = 0  # 12 viewpoints x in_plane rotations (12 by default: 144 templates, 13 MB, a
# few seconds: long enough to be hit mid-way)
SERVE_FLAGS = ["--max-estimates", "2", "--max-onboardings", "1"]


@dataclass
class Round:
    n: int
    kind: str
    killed_after_s: float
    doing: str  # what was under way when the kill came
    ready_s: float = 0.0  # restart to ready
    objects: int = 0
    interrupted: str = ""  # "absent" | "complete" | "-"
    problems: List[str] = field(default_factory=list)


class Estimators:
    """`n` threads estimating back to back (HTTP and gRPC in turn) until stopped or the
    server dies; `in_flight` counts requests sent and not yet answered."""

    def __init__(self, mix: Mix, n: int) -> None:
        self.mix, self.stop_flag, self.in_flight = mix, threading.Event(), 0
        self.errors: List[str] = []
        self.lock = threading.Lock()
        self.threads = [threading.Thread(target=self.run, args=(i,), daemon=True) for i in range(n)]
        for t in self.threads:
            t.start()

    def run(self, i: int) -> None:
        while not self.stop_flag.is_set():
            with self.lock:
                self.in_flight += 1
            res = (self.mix.estimate_http if i % 2 == 0 else self.mix.estimate_grpc)()
            with self.lock:
                self.in_flight -= 1
            # Before the kill only answers a request may get are allowed.
            if not self.stop_flag.is_set():
                self.errors += [f"before the kill: {o.kind}/{o.proto} {o.status} {o.detail}" for o in res if o.status not in HTTP_EST | GRPC_EST]

    def join(self) -> None:
        self.stop_flag.set()
        for t in self.threads:
            t.join(timeout=120)


def run_backend(store_url: str, store_dir: Optional[Path], work: Path, fx: Fixtures, kills: int, rng: random.Random, in_plane: int = 12, log=print) -> List[Round]:
    """`kills` rounds on one store; the first server onboards OBJECT, which the
    estimates name."""
    server = Server(store_url, work, SERVE_FLAGS, name="server-0")
    server.wait_ready()
    client = b2tfpose.Client(server.grpc, timeout=120, retry=b2tfpose.NO_RETRY)
    r, op = onboarding.start(server.http, client, fx, OBJECT, LEVEL, in_plane, "json")
    if op is None:
        raise RuntimeError(f"onboarding {OBJECT}: {r.status} {r.body!r}")
    # How long the work before the put takes, and the put itself (from the first sign of
    # the write to the operation's end), to aim kills at either.
    t0 = time.monotonic()
    if not wait_for_write(store_url, OBJECT, server.http, op):
        raise RuntimeError(f"onboarding {OBJECT}: its write to the store was not seen: {onboarding.state(server.http, op)}")
    t_write = time.monotonic()
    s = onboarding.wait(server.http, op, poll=0.005)
    if s["state"] != "succeeded":
        raise RuntimeError(f"onboarding {OBJECT}: {s}")
    before_s, put_s = t_write - t0, time.monotonic() - t_write
    log(f"  {OBJECT} onboarded: {before_s:.2f} s before its put, {put_s * 1e3:.0f} ms from the first write to the end")
    client.close()

    rounds: List[Round] = []
    for n in range(kills):
        kind = ("onboard", "put", "estimate")[n % 3]
        client = b2tfpose.Client(server.grpc, timeout=120, retry=b2tfpose.NO_RETRY)
        mix = Mix(fx, server.http, server.grpc, 120, 64)
        oid, op, put_seen = f"crash-{n}", None, False
        est = Estimators(mix, 4 if kind == "estimate" else 2)
        t0 = time.monotonic()
        if kind == "estimate":
            time.sleep(rng.uniform(0.3, 1.5))
            doing = f"{est.in_flight} estimates in flight"
        else:
            r, op = onboarding.start(server.http, client, fx, oid, LEVEL, in_plane, onboarding.WAYS[n % 3])
            if op is None:
                raise RuntimeError(f"round {n}: onboarding {oid} refused: {r.status} {r.detail} {r.body!r}")
            if kind == "onboard":
                time.sleep(rng.uniform(0.05, 0.9) * before_s)
            elif wait_for_write(store_url, oid, server.http, op):
                # Most kills inside the put; some just after it ended (the object must
                # then be there, whole).
                time.sleep(rng.uniform(0, 1.3 * put_s))
                put_seen = True
            s = onboarding.state(server.http, op)
            doing = f"onboarding {s['state']} {s.get('templates_done')}/{s.get('templates_total')}{', store write seen' if put_seen else ''}, {est.in_flight} estimates in flight"
        killed_after = time.monotonic() - t0
        est.stop_flag.set()  # no new requests; those in flight die with the server
        server.kill()
        est.join()
        client.close()
        mix.close()
        rd = Round(n, kind, killed_after, doing, problems=est.errors[:3] + ([f"and {len(est.errors) - 3} more"] if len(est.errors) > 3 else []))

        server = Server(store_url, work, SERVE_FLAGS, name=f"server-{n + 1}")
        try:
            rd.ready_s = server.wait_ready()
        except RuntimeError as e:
            rd.problems.append(f"the store did not open: {e}"[:600])
            rounds.append(rd)
            break
        ids = store_check.listed(server.http)
        rd.objects = len(ids)
        rd.problems += store_check.check_served(server.http, fx, {OBJECT: 12 * in_plane, "crash-": 12 * in_plane})
        if OBJECT not in ids:
            rd.problems.append(f"{OBJECT} is gone")
        rd.interrupted = "-" if op is None else ("complete" if oid in ids else "absent")
        if op is not None:
            g = http_call(server.http, "GET", f"/v1/operations/{op}", timeout=30)
            if g.status != "404":
                rd.problems.append(f"the interrupted operation {op}: {g.status} {g.body!r} after the restart (expected 404)"[:300])
        if store_dir is not None and (hidden := store_check.hidden_folders(store_dir)):
            rd.problems.append(f"hidden temporary folders left after the restart: {hidden}")
        log(
            f"  {n:2d} {kind:8s} killed after {killed_after:.2f} s ({doing}); ready in {rd.ready_s:.2f} s; {rd.objects} objects; "
            f"interrupted: {rd.interrupted}; {'OK' if not rd.problems else 'PROBLEMS: ' + '; '.join(rd.problems)}"
        )
        rounds.append(rd)

    code = server.stop()
    last = rounds[-1] if rounds else Round(0, "-", 0, "-")
    if code != 0:
        last.problems.append(f"SIGTERM at the end: exit status {code}")
    last.problems += store_check.check_offline(store_url)
    return rounds


def wait_for_write(store_url: str, oid: str, http: str, op: str, timeout: float = 120) -> bool:
    """Returns once the store shows the put of `oid` under way (True), or the operation
    has ended or a new put could not be recognised in time (False)."""
    if store_url.startswith("dir://"):
        root = Path(store_url[len("dir://") :])
        seen = lambda: any(n.startswith(f".{oid}.tmp-") for n in os.listdir(root))  # noqa: E731
    else:
        wal = Path(store_url[len("sqlite://") :] + "-wal")
        stamp = lambda: (wal.stat().st_size, wal.stat().st_mtime_ns) if wal.exists() else None  # noqa: E731
        before = stamp()
        seen = lambda: stamp() != before  # noqa: E731
    end, polled = time.monotonic() + timeout, time.monotonic()
    while time.monotonic() < end:
        if seen():
            return True
        if time.monotonic() - polled > 0.1:  # now and then: is it still running?
            polled = time.monotonic()
            if onboarding.state(http, op)["state"] != "running":
                return False
        time.sleep(0.001)
    return False


def uploads_left(work: Path) -> List[str]:
    """Upload staging folders the killed servers left in their TMPDIR (not in the store)."""
    tmp = work / "tmp"
    return sorted(p.name for p in tmp.iterdir()) if tmp.is_dir() else []
