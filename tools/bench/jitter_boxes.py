#!/usr/bin/env python3
"""Box-only detections moved as a detector's would be: each side of each box shifted by
a seeded uniform draw within ±JITTER of the box's width (left, right) or height (top,
bottom), rounded to the pixel and kept inside the image and at least 2 px wide.

On the real frames the box path's AR moves by several hundredths with the segmentation's
smallest details (docs/estimation.md, "How much one box run says"): one run on the
pixel-exact boxes says little; several seeds of this give its mean and spread.

    tools/bench/jitter_boxes.py DETECTIONS_BOX.json OUT.json --seed S [--jitter 0.02]
        [--width 640 --height 480]
"""

import argparse
import json
import random


def jittered(box, rng, jitter, width, height):
    x, y, w, h = box
    x0, x1 = x + rng.uniform(-jitter, jitter) * w, x + w + rng.uniform(-jitter, jitter) * w
    y0, y1 = y + rng.uniform(-jitter, jitter) * h, y + h + rng.uniform(-jitter, jitter) * h
    x0, y0 = max(0, round(x0)), max(0, round(y0))
    x1, y1 = min(width, max(x0 + 2, round(x1))), min(height, max(y0 + 2, round(y1)))
    return [x0, y0, x1 - x0, y1 - y0]


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("detections")
    p.add_argument("out")
    p.add_argument("--seed", type=int, required=True)
    p.add_argument("--jitter", type=float, default=0.02, help="largest shift of a side, as a share of the box's side (default 0.02)")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    a = p.parse_args()
    if not 0 <= a.jitter < 0.5:
        p.error(f"--jitter {a.jitter}: expected a share in [0, 0.5)")
    rng = random.Random(a.seed)
    dets = json.load(open(a.detections))
    for d in dets:
        if "bbox" not in d:
            raise SystemExit(f"{a.detections}: a detection without a bbox: {d}")
        d["bbox"] = jittered(d["bbox"], rng, a.jitter, a.width, a.height)
    json.dump(dets, open(a.out, "w"))


if __name__ == "__main__":
    main()
