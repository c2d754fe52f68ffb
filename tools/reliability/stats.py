"""Percentiles, per-phase summaries and Markdown tables of the load test's outcomes, and
the verdict line both scripts end with."""

from __future__ import annotations

import math
import time
from collections import Counter
from dataclasses import dataclass
from typing import Dict, List, Sequence

from .mix import Outcome
from .procstat import Sample

ACCEPTED = ("200", "OK")
REFUSED = ("429", "RESOURCE_EXHAUSTED")


def percentile(values: Sequence[float], p: float) -> float:
    """Nearest-rank percentile (NaN for no values)."""
    if not values:
        return math.nan
    v = sorted(values)
    return v[min(len(v) - 1, max(0, math.ceil(p / 100 * len(v)) - 1))]


@dataclass
class PhaseSummary:
    phase: str
    seconds: float
    offered_per_s: float  # estimates sent per second
    accepted: int
    refused: int
    accepted_per_s: float
    refused_per_s: float
    p50_ms: float
    p90_ms: float
    p99_ms: float
    max_ms: float
    refused_p99_ms: float
    onboards_accepted: int
    onboards_refused: int
    onboard_p50_s: float
    bad: int
    violations: int


def summarise(phase: str, outcomes: List[Outcome], seconds: float) -> PhaseSummary:
    est = [o for o in outcomes if o.kind == "estimate"]
    acc = [o.seconds * 1e3 for o in est if o.status in ACCEPTED]
    ref = [o.seconds * 1e3 for o in est if o.status in REFUSED]
    ob = [o for o in outcomes if o.kind == "onboard"]
    done = [o.seconds for o in outcomes if o.kind == "onboard-done" and o.ok]
    return PhaseSummary(
        phase,
        seconds,
        len(est) / seconds,
        len(acc),
        len(ref),
        len(acc) / seconds,
        len(ref) / seconds,
        percentile(acc, 50),
        percentile(acc, 90),
        percentile(acc, 99),
        max(acc, default=math.nan),
        percentile(ref, 99),
        sum(o.status in ("202", "OK") for o in ob),
        sum(o.status in REFUSED for o in ob),
        percentile(done, 50),
        sum(o.kind == "bad" for o in outcomes),
        sum(not o.ok for o in outcomes),
    )


def phase_table(rows: Sequence[PhaseSummary]) -> str:
    head = "| phase | s | estimates offered/s | accepted/s | 429/s | accepted p50 ms | p90 | p99 | max | 429 p99 ms | onboardings accepted / 429 | onboarding p50 s | bad requests | violations |"
    lines = [head, "|" + "---|" * 14]
    for r in rows:
        lines.append(
            f"| {r.phase} | {r.seconds:.0f} | {r.offered_per_s:.2f} | {r.accepted_per_s:.2f} | {r.refused_per_s:.2f} | {r.p50_ms:.0f} | {r.p90_ms:.0f} | {r.p99_ms:.0f} "
            f"| {r.max_ms:.0f} | {r.refused_p99_ms:.1f} | {r.onboards_accepted} / {r.onboards_refused} | {r.onboard_p50_s:.2f} | {r.bad} | {r.violations} |"
        )
    return "\n".join(lines)


def status_table(outcomes: List[Outcome]) -> str:
    """Counts by request kind, protocol and status."""
    c = Counter((o.kind, o.proto, o.status) for o in outcomes)
    lines = ["| request | protocol | status | count |", "|---|---|---|---:|"]
    lines += [f"| {k} | {p} | {s} | {n} |" for (k, p, s), n in sorted(c.items())]
    return "\n".join(lines)


def resource_table(samples: List[Sample], rows: int) -> str:
    """About `rows` evenly spaced readings, plus each phase's first and last."""
    if not samples:
        return "(no samples)"
    step = max(1, len(samples) // rows)
    keep = set(range(0, len(samples), step)) | {len(samples) - 1}
    for i in range(1, len(samples)):
        if samples[i].phase != samples[i - 1].phase:
            keep |= {i - 1, i}
    lines = ["| t (s) | phase | RSS (MB) | threads | fds |", "|---:|---|---:|---:|---:|"]
    lines += [f"| {s.t:.0f} | {s.phase} | {s.rss_mb:.0f} | {s.threads} | {s.fds} |" for i, s in enumerate(samples) if i in keep]
    return "\n".join(lines)


def range_table(samples: List[Sample]) -> str:
    """Per phase, over every reading: RSS min / median / max, threads and fds min-max."""
    phases: Dict[str, List[Sample]] = {}
    for x in samples:
        phases.setdefault(x.phase, []).append(x)
    lines = ["| phase | readings | RSS min / median / max (MB) | threads | fds |", "|---|---:|---|---|---|"]
    for ph, xs in phases.items():
        rss = sorted(x.rss_mb for x in xs)
        th, fd = [x.threads for x in xs], [x.fds for x in xs]
        lines.append(f"| {ph} | {len(xs)} | {rss[0]:.0f} / {rss[len(rss) // 2]:.0f} / {rss[-1]:.0f} | {min(th)}–{max(th)} | {min(fd)}–{max(fd)} |")
    return "\n".join(lines)


def violations(outcomes: List[Outcome], limit: int = 12) -> List[str]:
    bad = [o for o in outcomes if not o.ok]
    by: Dict[str, int] = Counter(f"{o.kind}/{o.proto}/{o.status}" for o in bad)
    out = [f"{k}: {n}" for k, n in sorted(by.items())]
    out += [f"  e.g. {o.kind}/{o.proto} {o.status} after {o.seconds:.2f} s: {o.detail}" for o in bad[:limit]]
    return out


def verdict(problems: list, started: float, ok: str) -> int:
    """Prints the run's outcome (every problem, or `ok`) with its duration; the exit status."""
    took = f"{time.monotonic() - started:.0f} s"
    if problems:
        print(f"\nFAILED ({took}):\n" + "\n".join(problems))
        return 1
    print(f"\nOK: {ok} ({took})")
    return 0
