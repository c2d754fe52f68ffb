#!/usr/bin/env python3
"""Why each wrong answer is wrong, from one `b2tf bench estimate` run's two CSVs.

    tools/miss_classes.py I.csv C.csv [I2.csv C2.csv ...] [--setting "with RRC"] [--list]

I.csv is the run's `--per-instance` file, C.csv its `--per-candidate` file. Every instance
answered wrong (MSSD >= 0.1·d, or no pose) falls in one class:

- "no right hypothesis": none of the verified hypotheses was within 0.1·d, so no choice
  among them could have been right: generation lost it;
- "outscored": a right hypothesis was rendered and judged on the photo, and lost the vote;
- "never rendered": a right hypothesis was refined but its outline agreement kept it from
  being rendered, so it was never judged on the photo.

Within "no right hypothesis" it counts the depth misses: rotation within 5° of the truth,
the error all along the line of sight (the apparent size off by a pixel or two), which
better scoring cannot fix either. Which class dominates says where a change can pay:
generation, the vote, or the choice of what to render.

`--self-test` checks the classes on built-in rows and exits. Standard library only.
"""

import argparse
import csv
import math
import os
import sys
import tempfile
from collections import Counter

# The same reading of a CSV cell and of an instance's key as the candidate-source tool.
from hypothesis_sources import instance, number

RIGHT = 0.1
DEPTH_MISS_DEG = 5.0
CLASSES = ["no right hypothesis", "outscored", "never rendered"]


def right_ones(path: str) -> tuple:
    """The instances with a right hypothesis, and those with a right one that was rendered."""
    right, rendered = set(), set()
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            if number(row["mssd_over_diameter"]) < RIGHT:
                right.add(instance(row))
                if math.isfinite(number(row["iou"])):
                    rendered.add(instance(row))
    return right, rendered


def classify(per_instance: str, per_candidate: str, setting: str) -> tuple:
    """The count of `setting`'s instances, and (instance row, class, depth miss?) for
    every wrong answer among them."""
    right, rendered = right_ones(per_candidate)
    misses = []
    with open(per_instance, newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["setting"] == setting]
    if not rows:
        raise SystemExit(f"{per_instance}: no rows of setting {setting!r}")
    for r in rows:
        if number(r["mssd_over_diameter"]) < RIGHT:
            continue
        key = instance(r)
        cls = "outscored" if key in rendered else "never rendered" if key in right else "no right hypothesis"
        depth = cls == "no right hypothesis" and number(r["rot_err_deg"]) < DEPTH_MISS_DEG
        misses.append((r, cls, depth))
    return len(rows), misses


def report(pairs: list, setting: str, listed: bool) -> Counter:
    total, counts, depth = 0, Counter(), 0
    for per_instance, per_candidate in pairs:
        n, misses = classify(per_instance, per_candidate, setting)
        total += n
        for r, cls, d in misses:
            counts[cls] += 1
            depth += d
            if listed:
                print(
                    f"  {per_instance}: image {r['image']} object {r['obj_id']}, {r['size_px']} px, visible {r['visible']}, rotation {r['rot_err_deg']}°, depth {r['depth_err_mm']} mm, {r['mssd_over_diameter']}·d: {cls}{' (depth)' if d else ''}"
                )
    wrong = sum(counts.values())
    print(f"{total} instances ({setting}), {wrong} wrong:")
    for cls in CLASSES:
        extra = f", of which {depth} depth misses (rotation within {DEPTH_MISS_DEG:g}°)" if cls == CLASSES[0] else ""
        print(f"  {cls:20} {counts[cls]:4}{extra}")
    counts["depth"] = depth
    return counts


def self_test() -> None:
    inst_head = "image,obj_id,setting,size_px,visible,found,rot_err_deg,trans_err_mm,depth_err_mm,mssd_over_diameter\n"
    cand_head = "image,obj_id,size_px,mask,source,mssd_over_diameter,iou\n"
    inst = inst_head + "".join(
        [
            "0,1,with RRC,50,1.0,1,1.0,1,1,0.02\n",  # right
            "1,1,with RRC,50,1.0,1,2.0,20,20,0.15\n",  # depth miss, nothing right
            "2,1,with RRC,50,1.0,1,90,5,5,0.8\n",  # turned, nothing right
            "3,1,with RRC,50,1.0,1,170,5,5,0.9\n",  # a right one rendered and beaten
            "4,1,with RRC,50,1.0,1,45,5,5,0.5\n",  # a right one never rendered
            "4,1,with RRC,90,1.0,0,,,,\n",  # no pose; a second instance of object 1
            "0,1,without RRC,50,1.0,1,90,5,5,0.8\n",  # another setting: not counted
        ]
    )
    cand = cand_head + "".join(
        [
            "0,1,50,0,pipeline,0.02,0.9\n",
            "1,1,50,0,pipeline,0.15,0.9\n",
            "2,1,50,0,pipeline,0.8,0.9\n",
            "3,1,50,0,pipeline,0.9,0.9\n",
            "3,1,50,0,flip-2,0.03,0.8\n",
            "4,1,50,0,pipeline,0.5,0.9\n",
            "4,1,50,0,template-3,0.05,NaN\n",
            "4,1,90,0,template-0,0.5,NaN\n",
        ]
    )
    with tempfile.TemporaryDirectory() as d:
        i, c = os.path.join(d, "i.csv"), os.path.join(d, "c.csv")
        open(i, "w").write(inst)
        open(c, "w").write(cand)
        got = report([(i, c)], "with RRC", listed=False)
        want = Counter({"no right hypothesis": 3, "outscored": 1, "never rendered": 1, "depth": 1})
        assert got == want, got
        try:
            report([(i, c)], "no such setting", listed=False)
        except SystemExit as e:
            assert "no rows of setting" in str(e)
        else:
            raise AssertionError("a missing setting must be refused")
    print("miss_classes self-test passed")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("files", nargs="*", help="pairs of --per-instance and --per-candidate CSVs of one run")
    ap.add_argument("--setting", default="with RRC")
    ap.add_argument("--list", action="store_true", help="print every wrong answer with its class")
    ap.add_argument("--self-test", action="store_true")
    a = ap.parse_args()
    if a.self_test:
        self_test()
        return
    if not a.files or len(a.files) % 2:
        ap.error("give the CSVs in pairs: I.csv C.csv [I2.csv C2.csv ...]")
    report(list(zip(a.files[0::2], a.files[1::2])), a.setting, a.list)


if __name__ == "__main__":
    sys.exit(main())
