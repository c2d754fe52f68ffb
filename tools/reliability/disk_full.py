"""A put that runs out of disk: the store on a small file system of its own (a tmpfs, else
a loop-mounted ext4 image; both need root), a first small object that fits, then one too
large for what is left. The onboarding must end FAILED with an error saying why, nothing
of it may stay (listed or on disk), the server must keep serving, a small object must fit
again afterwards (the space was given back), deleting must work on the full disk (how an
operator makes room), and the store must reopen whole."""

from __future__ import annotations

import os
import shutil
import subprocess
from dataclasses import dataclass, field
from pathlib import Path
from typing import List, Optional

import b2tfpose

from . import onboarding, store_check
from .calls import http_call
from .fixtures import Fixtures
from .server import Server

SIZE_MB = 16
SMALL = (0, 1)  # 12 templates, ~5 MB: fits
LARGE = (1, 6)  # 252 templates with rows per template, ~20 MB: does not (per view, the default, would)


class Skip(Exception):
    """No small file system could be mounted here (the reason is the message)."""


def mount_small(where: Path, mb: int) -> str:
    """Mounts a file system of `mb` MiB at `where`: "tmpfs" or "ext4 image"."""
    where.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0:
        raise Skip("mounting needs root")
    t = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={mb}m", "tmpfs", str(where)], capture_output=True, text=True)
    if t.returncode == 0:
        return "tmpfs"
    img = where.with_suffix(".img")
    try:
        subprocess.run(["truncate", "-s", f"{mb}M", str(img)], check=True, capture_output=True)
        subprocess.run(["mkfs.ext4", "-q", "-F", str(img)], check=True, capture_output=True)
        subprocess.run(["mount", "-o", "loop", str(img), str(where)], check=True, capture_output=True, text=True)
        return "ext4 image"
    except (subprocess.CalledProcessError, FileNotFoundError) as e:
        raise Skip(f"tmpfs: {t.stderr.strip()}; loop-mounted ext4: {getattr(e, 'stderr', '') or e}") from None


def unmount(where: Path) -> None:
    subprocess.run(["umount", str(where)], capture_output=True)
    img = where.with_suffix(".img")
    if img.exists():
        img.unlink()


def used_mb(where: Path) -> float:
    st = os.statvfs(where)
    return (st.f_blocks - st.f_bfree) * st.f_frsize / 2**20


@dataclass
class DiskFullRun:
    backend: str
    fs: str = ""
    used_after_small_mb: float = 0.0
    large_state: str = ""
    large_error: str = ""
    used_after_failure_mb: float = 0.0
    second_small: str = ""
    used_end_mb: float = 0.0
    files: str = ""  # what holds the space at the end
    problems: List[str] = field(default_factory=list)


def run(backend: str, work: Path, fx: Fixtures) -> DiskFullRun:
    res = DiskFullRun(backend)
    mnt = work / f"full-{backend}"
    res.fs = mount_small(mnt, SIZE_MB)
    server: Optional[Server] = None
    try:
        store_dir = mnt / "store"
        url = f"dir://{store_dir}" if backend == "dir" else f"sqlite://{mnt / 'objects.db'}"
        server = Server(url, work / f"full-{backend}-logs", ["--max-onboardings", "1"])
        server.wait_ready()
        client = b2tfpose.Client(server.grpc, timeout=120, retry=b2tfpose.NO_RETRY)
        first = onboarding.onboard(server.http, client, fx, "small-1", *SMALL)
        if first["state"] != "succeeded":
            raise RuntimeError(f"the first small object does not fit in {SIZE_MB} MiB: {first}")
        res.used_after_small_mb = used_mb(mnt)

        large = onboarding.onboard(server.http, client, fx, "large", *LARGE, how="grpc", patch_rows="per-template")
        res.large_state, res.large_error = large["state"], str(large.get("error"))
        res.used_after_failure_mb = used_mb(mnt)
        if large["state"] != "failed":
            res.problems.append(f"the large put on a full disk ended {large['state']} (expected failed): {large}"[:400])
        elif not any(w in res.large_error.lower() for w in ("space", "full", "os error 28")):
            res.problems.append(f"the failed put's error does not say the disk is full: {res.large_error}"[:400])
        if backend == "dir" and (hidden := store_check.hidden_folders(store_dir)):
            res.problems.append(f"left on disk after the failed put: {hidden}")
        if store_check.listed(server.http) != ["small-1"]:
            res.problems.append(f"after the failed put the store lists {store_check.listed(server.http)}")
        res.problems += store_check.check_served(server.http, fx, {"small-": 12})
        if http_call(server.http, "GET", "/healthz").status != "200":
            res.problems.append("not healthy after the failed put")

        second = onboarding.onboard(server.http, client, fx, "small-2", *SMALL, how="multipart")
        res.second_small = second["state"]
        if second["state"] != "succeeded":
            res.problems.append(f"a small object no longer fits after the failed put (space not given back?): {second}"[:400])
        # Deleting is how an operator makes room on a full disk: it must work.
        d = http_call(server.http, "DELETE", "/v1/objects/small-2", timeout=60)
        if d.status != "204":
            res.problems.append(f"deleting on the full disk: {d.status} {d.body!r}"[:300])
        res.used_end_mb = used_mb(mnt)
        res.files = ", ".join(f"{p.name} {p.stat().st_size / 2**20:.1f} MB" for p in sorted(mnt.iterdir()) if p.is_file()) or "-"
        client.close()

        # The store reopens whole in a new process.
        code = server.stop()
        if code != 0:
            res.problems.append(f"SIGTERM: exit status {code}")
        server = Server(url, work / f"full-{backend}-logs", ["--max-onboardings", "1"], name="server-2")
        server.wait_ready()
        res.problems += store_check.check_served(server.http, fx, {"small-": 12})
        if store_check.listed(server.http) != ["small-1"]:
            res.problems.append(f"reopened, the store lists {store_check.listed(server.http)} (expected only small-1)")
        server.stop()
        res.problems += store_check.check_offline(url)
    finally:
        if server is not None and server.alive():
            server.kill()
        unmount(mnt)
        shutil.rmtree(mnt, ignore_errors=True)
    return res
