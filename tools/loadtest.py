#!/usr/bin/env python3
"""Overload and soak test of `b2tf serve` (issue 16, item 3; docs/reliability.md).

Starts a server on loopback with a small dir:// store in a temporary folder, onboards the
generated sample box, measures its capacity (estimates per second that --max-estimates
closed-loop clients get through), then offers a mix of estimates, onboardings, reads,
bad requests and clients that give up (a 0.3 s hang-up or gRPC deadline) over HTTP and
gRPC at each multiple of that capacity (open loop, Poisson arrivals), sampling its RSS, threads and file descriptors every second. Checks:

- every request gets an answer it may get: beyond capacity and the server's queue only
  429 / RESOURCE_EXHAUSTED, no 5xx, no connection error, no hang (client timeout), no
  wrong pose; accepted onboardings succeed and their objects delete;
- refusals stay fast (p99 under --refused-p99-ms): beyond the queue the server answers
  429 at once, it does not make the client wait;
- accepted estimates' p99 under overload stays within --p99-factor x (1 + queue depth /
  --max-estimates) x the capacity run's: an estimate slowed by the load (at most
  --p99-factor) behind a full queue of such estimates, no more;
- no leaks: threads and file descriptors back to their level before the load once it
  stops; RSS under --rss-max-mb throughout and, when the last phase lasts a minute or
  more, its peak at most --rss-growth-mb above the peak of the load before it (the
  default 2x, 10x, 2x comes back down after the spike: memory the allocator took for the
  spike may stay, but it must not keep growing);
- afterwards the server answers normally: health, correct poses over both protocols,
  all --max-estimates slots free, the store holding only the box, exit 0 on SIGTERM.

Prints Markdown tables (phases, statuses, resources over time); exits 1 on any violation.
`--short` is the CI mode (~35 s: 2x and 10x, 8 s each; too short to judge RSS growth, so
it checks only the ceiling). Binary: $B2TF_BIN, else target/release/b2tf (built when
absent). Needs the b2tfpose client (clients/python) importable: run it with
tools/reliability/python.sh, which provides one.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import List

sys.path.insert(0, str(Path(__file__).resolve().parent))

from reliability import stats  # noqa: E402
from reliability.calls import http_call  # noqa: E402
from reliability.fixtures import Fixtures  # noqa: E402
from reliability.load import ESTIMATE_SHARE, ONBOARDINGS, REQUESTS, closed_loop, open_loop, schedule  # noqa: E402
from reliability.mix import OBJECT, Mix, Outcome  # noqa: E402
from reliability.procstat import Sample, Sampler  # noqa: E402
from reliability.server import Server, b2tf_bin  # noqa: E402


def parse_args() -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--short", action="store_true", help="CI mode: 6 s capacity, 8 s per multiplier")
    p.add_argument("--duration", type=float, default=180, help="seconds per multiplier (default 180)")
    p.add_argument("--capacity-s", type=float, default=30, help="seconds of the capacity run (default 30)")
    p.add_argument("--multipliers", default="2,10,2", help="multiples of capacity to offer, in order (default 2,10,2)")
    p.add_argument("--max-estimates", type=int, default=2, help="the server's --max-estimates (default 2)")
    p.add_argument("--queue-depth", type=int, help="the server's --queue-depth (default: the server's, 8 x --max-estimates)")
    p.add_argument("--refused-p99-ms", type=float, default=500, help="refusals' p99 may be at most this, ms (default 500)")
    p.add_argument("--max-body-mb", type=int, default=2, help="the server's --max-body-mb (default 2; a bad request exceeds it)")
    p.add_argument("--timeout", type=float, default=60, help="client timeout per request, s: longer is a hang (default 60)")
    p.add_argument(
        "--p99-factor",
        type=float,
        default=5.0,
        help="an estimate under overload may be this much slower than in the capacity run: accepted p99 at most this x (1 + queue depth / max estimates) x the capacity p99 (default 5)",
    )
    p.add_argument("--warmup-s", type=float, default=30, help="seconds of mixed load at the first multiplier before the measured phases (default 30)")
    p.add_argument("--rss-growth-mb", type=float, default=64, help="peak RSS of the last phase may exceed the peak before it by this (default 64)")
    p.add_argument("--rss-max-mb", type=float, default=2048, help="RSS may never exceed this (default 2048)")
    p.add_argument("--slack", type=int, default=4, help="threads and fds may end this many above their level before the load (default 4)")
    p.add_argument("--settle-s", type=float, default=20, help="longest wait for threads and fds to come back after the load (default 20)")
    p.add_argument("--interval", type=float, default=1.0, help="seconds between /proc samples (default 1)")
    p.add_argument("--seed", type=int, default=16)
    p.add_argument("--keep", action="store_true", help="keep the work folder (server logs)")
    a = p.parse_args()
    if a.short:
        a.duration, a.capacity_s, a.warmup_s, a.interval, a.multipliers = 8, 6, 0, 0.5, "2,10"
    return a


def settle(sampler: Sampler, base: Sample, slack: int, seconds: float) -> Sample:
    """Waits (up to `seconds`) for threads and fds to come back to `base` + `slack`:
    idle worker threads of the async runtime's blocking pool end after 10 s."""
    end = time.monotonic() + seconds
    while True:
        now = sampler.now()
        if now is None or (now.threads <= base.threads + slack and now.fds <= base.fds + slack) or time.monotonic() > end:
            return now or base
        time.sleep(0.5)


def rss_problems(every: List[Sample], before_last: List[Sample], last: List[Sample], a: argparse.Namespace) -> List[str]:
    """RSS under the ceiling throughout; and, when the last phase lasts a minute or more,
    its peak at most --rss-growth-mb above the peak of all the load before it. The default
    2x, 10x, 2x ends at a lower load than its peak: the allocator has by then reached the
    working size that load needs (glibc keeps adding arenas and fragments for a few
    minutes, more when more threads run), so a leak, which grows with the requests served,
    is what would still push RSS up."""
    out: List[str] = []
    peak = max(every, key=lambda s: s.rss_mb, default=None)
    if peak is not None and peak.rss_mb > a.rss_max_mb:
        out.append(f"RSS reached {peak.rss_mb:.0f} MB at {peak.t:.0f} s ({peak.phase}) > {a.rss_max_mb:g} MB")
    if before_last and last and last[-1].t - last[0].t >= 60:
        was, now = max(s.rss_mb for s in before_last), max(s.rss_mb for s in last)
        print(f"RSS peak: {was:.0f} MB before the last phase, {now:.0f} MB during it", flush=True)
        if now > was + a.rss_growth_mb:
            out.append(f"RSS still growing: peak {was:.0f} MB before the last phase, {now:.0f} MB during it (> +{a.rss_growth_mb:g} MB)")
    return out


def after_checks(mix: Mix, server: Server, max_estimates: int) -> List[str]:
    """The server answers normally after the load: problems found, if any."""
    problems: List[str] = []
    for path in ("/healthz", "/readyz"):
        r = http_call(server.http, "GET", path, timeout=10)
        if r.status != "200":
            problems.append(f"after the load: GET {path} -> {r.status} {r.detail}")
    for o in mix.estimate_http() + mix.estimate_grpc():
        if o.status not in stats.ACCEPTED:
            problems.append(f"after the load: estimate over {o.proto} -> {o.status} {o.detail}")
    # All slots free: as many estimates at once as the limit are all accepted.
    res: List[Outcome] = []
    threads = [threading.Thread(target=lambda i=i: res.extend((mix.estimate_http if i % 2 else mix.estimate_grpc)())) for i in range(max_estimates)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if [o.status for o in res if o.status not in stats.ACCEPTED]:
        problems.append(f"after the load: {max_estimates} estimates at once (the limit) -> {[o.status for o in res]}: a concurrency slot leaked")
    left = sorted(o.id for o in mix.client.list_objects())
    if left != [OBJECT]:
        problems.append(f"after the load: the store holds {left}, expected only [{OBJECT!r}] (every accepted onboarding was deleted)")
    return problems


def main() -> int:
    started = time.monotonic()
    a = parse_args()
    multipliers = [float(m) for m in a.multipliers.split(",")]
    print(f"b2tf: {b2tf_bin()}", flush=True)
    work = Path(tempfile.mkdtemp(prefix="b2tf-loadtest-"))
    fx = Fixtures.make(work)
    depth = 8 * a.max_estimates if a.queue_depth is None else a.queue_depth
    server = Server(f"dir://{work / 'store'}", work, ["--max-estimates", str(a.max_estimates), "--queue-depth", str(depth), "--max-onboardings", "1", "--max-body-mb", str(a.max_body_mb)])
    problems: List[str] = []
    try:
        server.wait_ready()
        mix = Mix(fx, server.http, server.grpc, a.timeout, a.max_body_mb)
        mix.client.onboard(OBJECT, fx.obj, format="obj", units="m", resources=fx.resources, level=0, in_plane=12, timeout=300)
        closed_loop(mix, a.max_estimates, 2)  # warm-up: object loaded, pools started
        # One onboarding of the kind the load sends, alone: the onboardings' capacity.
        warm = mix.onboard()
        if not all(o.ok for o in warm) or len(warm) != 3:
            raise RuntimeError(f"warm-up onboarding failed: {warm}")
        onboard_s = warm[1].seconds
        sampler = Sampler(server.pid, a.interval)
        sampler.start()

        sampler.phase = "capacity"
        t0 = time.monotonic()
        cap_out = closed_loop(mix, a.max_estimates, a.capacity_s)
        cap = stats.summarise("capacity", cap_out, time.monotonic() - t0)
        capacity = cap.accepted_per_s
        onboard_cap = 1.0 / onboard_s  # --max-onboardings 1
        print(
            f"capacity with --max-estimates {a.max_estimates}: {capacity:.2f} estimates/s, p50 {cap.p50_ms:.0f} ms, p99 {cap.p99_ms:.0f} ms; onboardings: {onboard_s:.2f} s each, {onboard_cap:.2f}/s",
            flush=True,
        )
        rows, all_out = [cap], list(cap_out)
        base = sampler.now()
        if base is None:
            raise RuntimeError("the server died during the capacity run")

        phases = [("warm-up", multipliers[0], a.warmup_s)] if a.warmup_s > 0 else []
        for m in multipliers:  # unique labels: "2x", "10x", "2x again"
            label = f"{m:g}x"
            phases.append((label + " again" if any(p == label for p, _, _ in phases) else label, m, a.duration))
        sent = 0
        for phase, m, seconds in phases:
            sampler.phase = phase
            rate = m * capacity / ESTIMATE_SHARE
            arrivals = schedule([(rate, REQUESTS), (m * onboard_cap, ONBOARDINGS)], seconds, a.seed + len(rows))
            run = open_loop(mix, arrivals, seconds, workers=256, drain_s=a.timeout * 5)
            sent += run.sent
            row = stats.summarise(phase, run.outcomes, run.seconds)
            rows.append(row)
            all_out += run.outcomes
            print(
                f"{phase}: {run.sent} requests ({rate:.1f}/s + {m * onboard_cap:.2f} onboardings/s) -> {row.accepted_per_s:.2f} accepted/s, {row.refused_per_s:.2f} refused/s; "
                f"p50 {row.p50_ms:.0f} ms, p99 {row.p99_ms:.0f} ms; most in flight {run.max_in_flight}, worst send lag {run.max_lag_s * 1e3:.0f} ms",
                flush=True,
            )
            if run.unfinished:
                problems.append(f"{phase}: {run.unfinished} requests still unanswered {a.timeout * 5:.0f} s after the phase (hang)")
            if run.max_lag_s > 1.0:
                print(f"warning: {phase}: the generator fell {run.max_lag_s:.1f} s behind its schedule (offered less than asked)", flush=True)
            factor = a.p99_factor * (1 + depth / a.max_estimates)
            if row.p99_ms > factor * cap.p99_ms:
                problems.append(f"{phase}: accepted p99 {row.p99_ms:.0f} ms > {factor:g} x capacity p99 {cap.p99_ms:.0f} ms")
            if row.refused_p99_ms > a.refused_p99_ms:
                problems.append(f"{phase}: refusals' p99 {row.refused_p99_ms:.0f} ms > {a.refused_p99_ms:g} ms: 429s must come at once")
        names = [p for p, _, _ in phases]
        before_last = [s for s in sampler.samples if s.phase in names[:-1]]
        problems += rss_problems(sampler.samples, before_last, sampler.of(names[-1]), a)

        sampler.phase = "after"
        after = settle(sampler, base, a.slack, a.settle_s)
        time.sleep(a.interval * 2)  # a couple of "after" rows for the table
        if after.threads > base.threads + a.slack:
            problems.append(f"threads: {base.threads} before the load, {after.threads} {a.settle_s:g} s after it (thread leak?)")
        if after.fds > base.fds + a.slack:
            problems.append(f"file descriptors: {base.fds} before the load, {after.fds} {a.settle_s:g} s after it (descriptor leak?)")
        problems += after_checks(mix, server, a.max_estimates)
        sampler.stop()
        mix.close()
        if not server.alive():
            problems.append(f"the server died (exit {server.proc.returncode})")
        code = server.stop()
        if code != 0:
            problems.append(f"SIGTERM after the load: exit status {code} (expected 0)")

        print(f"\n## Phases (--max-estimates {a.max_estimates}, --queue-depth {depth}; capacity {capacity:.2f}/s; {sent} requests sent in the open loop)\n\n{stats.phase_table(rows)}")
        print(f"\n## Statuses\n\n{stats.status_table(all_out)}")
        print(
            f"\n## Server resources (before the load: RSS {base.rss_mb:.0f} MB, {base.threads} threads, {base.fds} fds; "
            f"after: {after.rss_mb:.0f} MB, {after.threads} threads, {after.fds} fds)\n\n{stats.resource_table(sampler.samples, 24)}"
        )
        print(f"\nEvery reading, by phase:\n\n{stats.range_table(sampler.samples)}")
        problems = stats.violations(all_out) + problems
    except Exception:
        print(f"server log:\n{server.log_tail()}", file=sys.stderr)
        raise
    finally:
        if server.alive():
            server.kill()
        if not a.keep:
            shutil.rmtree(work, ignore_errors=True)
        else:
            print(f"work folder kept: {work}")
    return stats.verdict(problems, started, "only 429 / RESOURCE_EXHAUSTED beyond capacity, latency bounded, no leaks, serving normally after")


if __name__ == "__main__":
    sys.exit(main())
