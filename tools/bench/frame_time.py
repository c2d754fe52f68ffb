#!/usr/bin/env python3
"""Where a frame's time goes on the one-call RGB-D path, from a debug log of
`b2tf bop run --depth` without --detections:

    B2TF_LOG=info,b2tfpose::bop=debug,b2tfpose::detect::compared=debug \\
        b2tf bop run --dataset DS --out run.csv --store STORE --depth > run.log 2>&1
    tools/bench/frame_time.py run.log

Prints, over the log's images: the detection and estimation phases (wall time), the
screens (wall time), how many candidates were estimated and how many answers reviewed,
and the estimates' stages summed (each estimate's own clock: estimates run side by side,
so the sums exceed the wall time). docs/detection.md quotes its figures. --self-test
checks the parsing on a made-up log.
"""

import re
import sys
from collections import Counter

STAGES = re.compile(r"(\w+): ([\d.]+)")


def summary(lines):
    """The log's figures: a dict of counts and seconds, and the stages' sums (seconds)."""
    out = Counter()
    stages = Counter()
    for line in lines:
        if " estimated " in line and "timings=" in line:
            out["estimated"] += 1
            for name, ms in STAGES.findall(line.split("timings=", 1)[1]):
                stages[name] += float(ms) / 1e3
        elif "answer reviewed" in line:
            out["reviewed"] += 1
        elif "candidates screened" in line:
            m = re.search(r"screen_s=([\d.]+)", line)
            out["screen_s"] += float(m.group(1)) if m else 0.0
        elif "image phases" in line:
            out["images"] += 1
            for key in ("detect_s", "estimate_s"):
                m = re.search(key + r"=([\d.]+)", line)
                out[key] += float(m.group(1)) if m else 0.0
    return out, stages


def report(out, stages):
    n = max(out["images"], 1)
    print(f"{out['images']} images: detection {out['detect_s'] / n:.2f} s a frame, estimation {out['estimate_s'] / n:.2f} s (of which screens {out['screen_s'] / n:.2f} s)")
    print(f"candidates estimated {out['estimated']} ({out['estimated'] / n:.1f} a frame), answers reviewed {out['reviewed']}")
    total = stages.pop("total", 0.0)
    parts = ", ".join(f"{k} {v:.1f} s" for k, v in stages.most_common() if v >= 0.05)
    print(f"estimates' stages summed: {total:.1f} s: {parts}")


def self_test():
    log = [
        "T DEBUG b2tfpose::detect::compared: candidates screened screen_s=0.5 chains=[[0]]",
        "T DEBUG b2tfpose::bop::run: estimated scene_id=0 im_id=1 obj_id=8 masks=2 timings=StageTimings { crop: 2.0, matching: 100.0, rrc: 50.5, total: 200.0 }",
        "T DEBUG b2tfpose::bop::run: estimated scene_id=0 im_id=1 obj_id=9 masks=1 timings=StageTimings { crop: 1.0, matching: 50.0, rrc: 0.0, total: 100.0 }",
        "T DEBUG b2tfpose::bop::run: answer reviewed scene_id=0 im_id=1 obj_id=8 view=None",
        "T DEBUG b2tfpose::bop::run: image phases scene_id=0 im_id=1 detect_s=0.1 estimate_s=1.5",
        "T DEBUG b2tfpose::bop::run: candidate confirmed scene_id=0 im_id=1 obj_id=8 confirmation=0.9",
    ]
    out, stages = summary(log)
    assert (out["images"], out["estimated"], out["reviewed"]) == (1, 2, 1), out
    assert abs(out["screen_s"] - 0.5) < 1e-9 and abs(out["estimate_s"] - 1.5) < 1e-9, out
    assert abs(stages["matching"] - 0.15) < 1e-9 and abs(stages["total"] - 0.3) < 1e-9, stages
    print("frame_time self-test passed")


if __name__ == "__main__":
    if sys.argv[1:] == ["--self-test"]:
        self_test()
    elif len(sys.argv) == 2:
        with open(sys.argv[1]) as f:
            report(*summary(f))
    else:
        sys.exit(__doc__)
