#!/usr/bin/env python3
"""Which kinds of verification hypothesis are right, from `b2tf bench estimate` CSVs.

    tools/hypothesis_sources.py C.csv [C2.csv ...] [--per-instance I.csv --half-turn-ids 2,3,5]

For each `--per-candidate` CSV: the instances where any verified hypothesis is right
(MSSD < 0.1·d, the oracle), and per kind of hypothesis (the pipeline's pose with its
flips and spins, the first five retrieved templates, the sixth to tenth, the templates
placed by their matches, the second look's flips) the instances where one of that kind is right and those where
only that kind is, and the print agreement (edges and colour, as `verify::appearance`) of
the rendered right and wrong hypotheses. With `--per-instance`: the share of half-turns (rotation error of
150–180°) with RRC among the instances of the objects `--half-turn-ids` names (the
bench's object ids, 1-based in `--mesh` order).

Standard library only.
"""

import argparse
import csv
import math
from collections import defaultdict

KINDS = ["pipeline/flip/spin", "template 0-4", "template 5-9", "matched", "second look"]


def kind(source: str) -> str:
    if source.startswith("matched"):
        return "matched"
    if source.startswith("print-flip"):
        return "second look"
    if source.startswith("template"):
        return "template 0-4" if int(source.split("-")[1]) < 5 else "template 5-9"
    return "pipeline/flip/spin"


def number(s: str) -> float:
    return float(s) if s else float("inf")


def instance(row: dict) -> tuple:
    # One object may appear twice in an image: its size tells the two apart.
    return (row["image"], row["obj_id"], row["size_px"])


def print_agreement(row: dict) -> float:
    """verify::appearance at colour share 0.5: the rendered print's edges and colour
    (NaN where not rendered)."""
    edges, colour = number(row["edges"] or "nan"), number(row["colour"] or "nan")
    return edges if math.isnan(colour) else 0.5 * edges + 0.5 * colour


def sources(path: str) -> None:
    right = defaultdict(set)
    seen = set()
    prints = {True: [], False: []}
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            seen.add(instance(row))
            ok = number(row["mssd_over_diameter"]) < 0.1
            if ok:
                right[instance(row)].add(kind(row["source"]))
            p = print_agreement(row)
            if not math.isnan(p):
                prints[ok].append(p)
    print(f"{path}: {len(seen)} instances, a right hypothesis in {sum(1 for k in seen if right[k])}")
    for name in KINDS:
        has = sum(1 for k in seen if name in right[k])
        only = sum(1 for k in seen if right[k] == {name})
        print(f"  {name:20} right in {has:4}, the only right kind in {only:4}")
    for ok, label in ((True, "right"), (False, "wrong")):
        v = sorted(prints[ok])
        if v:
            low = sum(1 for p in v if p < 0.1) / len(v)
            print(f"  print agreement of rendered {label} hypotheses ({len(v)}): 5th percentile {v[int(0.05 * (len(v) - 1))]:.2f}, median {v[len(v) // 2]:.2f}, below 0.1: {100 * low:.1f} %")


def half_turns(path: str, ids: set) -> None:
    with open(path, newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["setting"] == "with RRC" and r["obj_id"] in ids]
    turned = [r for r in rows if number(r["rot_err_deg"]) >= 150]
    share = 100 * len(turned) / max(len(rows), 1)
    print(f"{path}: {len(turned)} of {len(rows)} instances half-turned ({share:.1f} %) with RRC")
    for r in turned:
        print(f"  image {r['image']} object {r['obj_id']}, {r['size_px']} px, best hypothesis {r['best_candidate_mssd_over_diameter']}·d")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("per_candidate", nargs="*", help="--per-candidate CSVs")
    ap.add_argument("--per-instance", action="append", default=[], help="--per-instance CSV (repeatable)")
    ap.add_argument("--half-turn-ids", default="", help="object ids counted for half-turns, comma-separated")
    a = ap.parse_args()
    if a.per_instance and not a.half_turn_ids:
        ap.error("--per-instance needs --half-turn-ids")
    for p in a.per_candidate:
        sources(p)
    ids = {s.strip() for s in a.half_turn_ids.split(",") if s.strip()}
    for p in a.per_instance:
        half_turns(p, ids)


if __name__ == "__main__":
    main()
