#!/usr/bin/env python3
"""Replays hypothesis verification's choice offline on `b2tf bench estimate --per-candidate`.

Each row of the CSV is one verified hypothesis with its error and verification terms. This
script re-scores them as src/estimate/verify.rs does (which hypotheses get a render, the
weighted score) under other weights, colour shares or render caps, and prints the share of
instances whose pick has MSSD < 0.1·d, and the "oracle" share (any hypothesis right).
Only hypotheses rendered in the run have IoU and appearance: run the bench with
`--verify-max-rendered 100` to study every one.

    tools/replay_verification.py CANDIDATES.csv [--colour-share 0 0.5 1] [--max-rendered 8 12]
        [--feature-share 0 0.5]

The feature-metric term (`features`) is in the CSV only where the run computed it
(`--feature-share` above 0 in the bench).

It also prints each term's separation of right from wrong hypotheses: the within-instance
AUC, the chance that a right hypothesis of an instance scores above a wrong one of the same
instance (ties count half), over the rendered hypotheses of instances that have both.
"""

import argparse
import csv
import math
from collections import OrderedDict


def load(path):
    instances = OrderedDict()
    with open(path) as f:
        for row in csv.DictReader(f):
            key = (row["image"], row["obj_id"], row["mask"])
            instances.setdefault(key, []).append({k: (v if k == "source" else float(v)) for k, v in row.items()})
    return instances


def pick(cands, weights, colour_share, rendered, tie, max_rendered, feature_share=0.0):
    s = sorted(cands, key=lambda d: -d["contour"])
    best = s[0]["contour"]
    chosen = [i for i in range(len(s)) if i < rendered or s[i]["contour"] >= best - tie][: max(max_rendered, rendered)]
    chosen += [i for i, d in enumerate(s) if d["source"] == "pipeline" and i not in chosen]

    def score(i):
        d = s[i]
        if i not in chosen or math.isnan(d["iou"]):
            return d["contour"] * sum(weights) - 1.0
        appearance = d["edges"] if math.isnan(d["colour"]) else (1 - colour_share) * d["edges"] + colour_share * d["colour"]
        features = d.get("features", math.nan)
        if feature_share > 0 and not math.isnan(features):
            appearance = (1 - feature_share) * appearance + feature_share * features
        return weights[0] * d["iou"] + weights[1] * d["contour"] + weights[2] * appearance

    return s[max(range(len(s)), key=score)]


TERMS = ["contour", "iou", "edges", "colour", "features", "score"]


def separation(instances, term, right):
    """Within-instance AUC of `term` (right above wrong), and the pairs it counts."""
    wins, pairs = 0.0, 0
    for cands in instances.values():
        scored = [d for d in cands if not math.isnan(d.get(term, math.nan)) and not math.isnan(d["iou"])]
        good = [d[term] for d in scored if right(d)]
        bad = [d[term] for d in scored if not right(d)]
        for g in good:
            for b in bad:
                wins += 1.0 if g > b else 0.5 if g == b else 0.0
                pairs += 1
    return (wins / pairs if pairs else math.nan), pairs


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("csv")
    ap.add_argument("--colour-share", type=float, nargs="+", default=[0.0, 0.25, 0.5, 0.75, 1.0])
    ap.add_argument("--max-rendered", type=int, nargs="+", default=[8, 12])
    ap.add_argument("--feature-share", type=float, nargs="+", default=[0.0])
    ap.add_argument("--weights", type=float, nargs=3, default=[0.4, 0.3, 0.3])
    ap.add_argument("--rendered", type=int, default=3)
    ap.add_argument("--tie", type=float, default=0.05)
    a = ap.parse_args()
    inst = load(a.csv)
    right = lambda d: d["mssd_over_diameter"] < 0.1
    print(f"{len(inst)} instances; oracle {sum(any(right(d) for d in c) for c in inst.values()) / len(inst):.1%}")
    for term in TERMS:
        auc, pairs = separation(inst, term, right)
        print(f"AUC {term}: " + ("– (not in the run)" if math.isnan(auc) else f"{auc:.3f} over {pairs} right/wrong pairs"))
    for f in a.feature_share:
        for m in a.max_rendered:
            cells = [f"colour {c}: {sum(right(pick(v, a.weights, c, a.rendered, a.tie, m, f)) for v in inst.values()) / len(inst):.1%}" for c in a.colour_share]
            print(f"features {f}, max rendered {m}: " + ", ".join(cells))


if __name__ == "__main__":
    main()
