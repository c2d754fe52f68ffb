#!/usr/bin/env python3
"""Crash safety of `b2tf serve` and its stores (issue 16, item 4; docs/reliability.md).

For each store backend (dir:// and sqlite://), in a temporary folder: SIGKILL the server
--kills times, in turn during an onboarding's templates, during its put, and during
estimates; after each kill restart it on the same store and check that the store opens,
lists only complete objects (each fetched and estimated to the right pose), and that the
interrupted onboarding is absent (or complete, when its put had finished) and its
operation unknown; at the end the CLI loads every object offline and SQLite passes its
integrity check (tools/reliability/crash.py). Then a put that fills a small tmpfs (or
loop-mounted ext4) must fail cleanly while the server keeps serving
(tools/reliability/disk_full.py; needs root, skipped with the reason otherwise).

Prints a table per backend; exits 1 on any problem. `--short` is the CI mode (3 kills
per backend). Binary: $B2TF_BIN, else target/release/b2tf (built when absent). Needs the
b2tfpose client (clients/python): run it with tools/reliability/python.sh.
"""

from __future__ import annotations

import argparse
import random
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import List

sys.path.insert(0, str(Path(__file__).resolve().parent))

from reliability import crash, disk_full  # noqa: E402
from reliability.stats import verdict  # noqa: E402
from reliability.fixtures import Fixtures  # noqa: E402
from reliability.server import b2tf_bin  # noqa: E402


def parse_args() -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--kills", type=int, default=21, help="kills per backend (default 21: 7 of each kind)")
    p.add_argument("--short", action="store_true", help="CI mode: 3 kills per backend (one of each kind), --in-plane 6")
    p.add_argument("--in-plane", type=int, default=12, help="in-plane rotations of the objects onboarded (x 12 viewpoints; default 12)")
    p.add_argument("--backends", default="dir,sqlite")
    p.add_argument("--no-disk-full", action="store_true", help="skip the full-disk test")
    p.add_argument("--seed", type=int, default=16)
    p.add_argument("--keep", action="store_true", help="keep the work folder (server logs)")
    a = p.parse_args()
    if a.short:
        a.kills, a.in_plane = 3, 6
    return a


def main() -> int:
    started = time.monotonic()
    a = parse_args()
    print(f"b2tf: {b2tf_bin()}", flush=True)
    work = Path(tempfile.mkdtemp(prefix="b2tf-crash-"))
    rng = random.Random(a.seed)
    problems: List[str] = []
    tables: List[str] = []
    try:
        fx = Fixtures.make(work)
        for backend in a.backends.split(","):
            t0 = time.monotonic()
            print(f"{backend}: {a.kills} kills", flush=True)
            bwork = work / backend
            store_dir = bwork / "store"
            url = f"dir://{store_dir}" if backend == "dir" else f"sqlite://{bwork / 'objects.db'}"
            rounds = crash.run_backend(url, store_dir if backend == "dir" else None, bwork, fx, a.kills, rng, a.in_plane)
            uploads = crash.uploads_left(bwork)
            lines = [
                f"### {backend}:// ({len(rounds)} kills, {time.monotonic() - t0:.0f} s)",
                "",
                "| # | killed during | after (s) | under way at the kill | ready again (s) | objects | interrupted object | problems |",
                "|---:|---|---:|---|---:|---:|---|---|",
            ]
            for r in rounds:
                lines.append(f"| {r.n} | {r.kind} | {r.killed_after_s:.2f} | {r.doing} | {r.ready_s:.2f} | {r.objects} | {r.interrupted} | {'; '.join(r.problems) or 'none'} |")
                problems += [f"{backend} round {r.n} ({r.kind}): {p}" for p in r.problems]
            lines.append(f"\nUpload staging folders left in the servers' TMPDIR: {len(uploads)} {uploads[:5]}")
            tables.append("\n".join(lines))
            if len(rounds) < a.kills:
                problems.append(f"{backend}: stopped after {len(rounds)} of {a.kills} kills")
        if not a.no_disk_full:
            rows = [
                "### Full disk during a put",
                "",
                "| backend | file system | used after 1st object (MB) | large put | its error | used after (MB) | 2nd small object | used at the end, after deleting it (MB) | files | problems |",
                "|---|---|---:|---|---|---:|---|---:|---|---|",
            ]
            for backend in a.backends.split(","):
                try:
                    d = disk_full.run(backend, work, fx)
                except disk_full.Skip as e:
                    rows.append(f"| {backend} | skipped: {e} | | | | | | | | |")
                    continue
                rows.append(
                    f"| {backend} | {d.fs} {disk_full.SIZE_MB} MiB | {d.used_after_small_mb:.1f} | {d.large_state} | {d.large_error[:120]} "
                    f"| {d.used_after_failure_mb:.1f} | {d.second_small} | {d.used_end_mb:.1f} | {d.files} | {'; '.join(d.problems) or 'none'} |"
                )
                problems += [f"full disk, {backend}: {p}" for p in d.problems]
            tables.append("\n".join(rows))
    finally:
        print("\n" + "\n\n".join(tables))
        if a.keep:
            print(f"work folder kept: {work}")
        else:
            shutil.rmtree(work, ignore_errors=True)
    return verdict(problems, started, "after every kill the store opened with only complete objects; a full disk failed the put cleanly")


if __name__ == "__main__":
    sys.exit(main())
