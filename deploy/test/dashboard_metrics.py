#!/usr/bin/env python3
"""Checks that every b2tf_* metric a Grafana dashboard queries exists in a /metrics text
(the smoke test scrapes it from the running image): a renamed metric fails here, not on a
factory's empty panel.

usage: dashboard_metrics.py DASHBOARD.json METRICS.txt
"""

import json
import re
import sys


def main(dashboard: str, metrics: str) -> None:
    with open(dashboard) as f:
        exprs = [t["expr"] for p in json.load(f)["panels"] for t in p.get("targets", [])]
    with open(metrics) as f:
        exposed = {line.split()[2] for line in f if line.startswith("# TYPE ")}
    used = {re.sub(r"_(bucket|sum|count)$", "", m) for e in exprs for m in re.findall(r"\bb2tf_[a-z_]+", e)}
    missing = sorted(used - exposed)
    if missing:
        sys.exit(f"{dashboard} queries metrics /metrics does not have: {', '.join(missing)}")
    print(f"dashboard: {len(exprs)} queries over {len(used)} metrics, all exposed by the server")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(*sys.argv[1:])
