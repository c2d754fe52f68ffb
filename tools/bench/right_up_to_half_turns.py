#!/usr/bin/env python3
"""How many of a BOP dataset's target instances a `b2tf bop run` CSV answers right, counted
three ways: placed (translation within 0.1·d of the truth), placed and turned right up to a
half-turn about one of the object's axes (rotation within 15° of the truth or of the truth
turned half a turn about x, y or z), and placed and turned right.

On bare meshes a box's or a bottle's half-turn often fits the outline and the surface
alike, and which way such coin flips fall moves BOP's AR by more than a change under test
does; the middle count leaves them out, so it measures what the change can reach
(docs/estimation.md, "Views found in the depth").

    tools/bench/right_up_to_half_turns.py DATASET CSV [CSV ...]

DATASET: a BOP dataset folder (models/models_info.json, test/*/scene_gt.json, and
test_targets_bop19.json where there is one). Needs numpy.
"""

import csv
import json
import math
import os
import sys

import numpy as np

HALF_TURNS = [np.eye(3), np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0])]


def degrees(r, truth):
    return math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(r.T @ truth) - 1.0) / 2.0))))


def targets(ds):
    path = os.path.join(ds, "test_targets_bop19.json")
    if not os.path.exists(path):
        return None
    return {(t["scene_id"], t["im_id"], t["obj_id"]) for t in json.load(open(path))}


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    ds = sys.argv[1]
    diameters = {int(k): v["diameter"] for k, v in json.load(open(os.path.join(ds, "models", "models_info.json"))).items()}
    wanted = targets(ds)
    truth = []
    for scene in sorted(os.listdir(os.path.join(ds, "test"))):
        for im, instances in json.load(open(os.path.join(ds, "test", scene, "scene_gt.json"))).items():
            for i in instances:
                key = (int(scene), int(im), i["obj_id"])
                if wanted is None or key in wanted:
                    truth.append((key, np.array(i["cam_R_m2c"]).reshape(3, 3), np.array(i["cam_t_m2c"])))
    for path in sys.argv[2:]:
        answers = {}
        for row in csv.DictReader(open(path)):
            key = (int(row["scene_id"]), int(row["im_id"]), int(row["obj_id"]))
            r = np.array([float(x) for x in row["R"].split()]).reshape(3, 3)
            t = np.array([float(x) for x in row["t"].split()])
            answers.setdefault(key, []).append((r, t))
        counts = [0, 0, 0]
        for key, r_true, t_true in truth:
            best = (False, False, False)
            for r, t in answers.get(key, []):
                placed = np.linalg.norm(t - t_true) < 0.1 * diameters[key[2]]
                up_to = min(degrees(r @ h, r_true) for h in HALF_TURNS) < 15.0
                exact = degrees(r, r_true) < 15.0
                best = max(best, (placed, placed and up_to, placed and exact))
            counts = [c + int(b) for c, b in zip(counts, best)]
        print(f"{os.path.basename(path)}: {len(truth)} instances; placed {counts[0]}, right up to a half-turn {counts[1]}, right {counts[2]}")


if __name__ == "__main__":
    main()
