#!/usr/bin/env python3
"""Does the runner-up's margin tell right answers from wrong ones in a `b2tf bop run`?

Reads `bop run` results and the run's debug log (`B2TF_LOG=warn,b2tfpose=debug`, whose
`estimated … runner_up_margin=…` lines hold each answer's margin), scores every answer by
BOP's MSSD (the largest distance of the model's vertices, the least over its symmetries
from models_info.json, continuous ones in 10° steps) against the dataset's ground truth, and
prints, per run and over all runs given, how many answers are right (MSSD < 0.1·d) in bins of
the margin (a close call is below 0.03, `estimate::runner_up::CLOSE_CALL`).

    B2TF_LOG=warn,b2tfpose=debug b2tf bop run --dataset DS --detections D.json --out RUN.csv \
        --store URL 2> RUN.log
    tools/bench/margins_from_bop_run.py DS RUN [RUN ...]     (RUN.csv and RUN.log each)

DS: a BOP dataset folder (models/*.ply with binary or ASCII vertices, models_info.json,
test/*/scene_gt.json). Needs numpy. A benchmark, not a test.
"""

import csv
import glob
import json
import math
import os
import re
import sys

import numpy as np

BINS = [(0.0, 0.01), (0.01, 0.03), (0.03, 0.1), (0.1, math.inf)]
TYPES = {"float": "<f4", "double": "<f8", "uchar": "u1", "uint8": "u1", "int": "<i4", "uint": "<u4", "short": "<i2", "ushort": "<u2"}


def vertices(path):
    """The PLY's vertex positions (every vertex property read, x y z kept)."""
    data = open(path, "rb").read()
    end = data.index(b"end_header") + len(b"end_header")
    end = data.index(b"\n", end) + 1
    header = data[:end].decode("ascii", "replace").splitlines()
    n, props, in_vertex = 0, [], False
    for line in header:
        w = line.split()
        if w[:2] == ["element", "vertex"]:
            n, in_vertex = int(w[2]), True
        elif w and w[0] == "element":
            in_vertex = False
        elif in_vertex and w and w[0] == "property":
            props.append((w[2], TYPES[w[1]]))
    if "binary_little_endian" in data[:end].decode("ascii", "replace"):
        a = np.frombuffer(data, dtype=np.dtype(props), count=n, offset=end)
        return np.stack([a["x"], a["y"], a["z"]], axis=1).astype(np.float64)
    rows = data[end:].decode().split("\n")[:n]
    names = [p for p, _ in props]
    idx = [names.index(c) for c in "xyz"]
    return np.array([[float(r.split()[i]) for i in idx] for r in rows])


def symmetries(info):
    """The model's symmetry transforms (4×4), the identity first."""
    out = [np.eye(4)] + [np.array(m, float).reshape(4, 4) for m in info.get("symmetries_discrete", [])]
    for c in info.get("symmetries_continuous", []):
        axis = np.array(c["axis"], float) / np.linalg.norm(c["axis"])
        offset = np.array(c["offset"], float)
        k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        for a in np.linspace(0, 2 * math.pi, 36, endpoint=False):
            r = np.eye(3) + math.sin(a) * k + (1 - math.cos(a)) * k @ k
            t = np.eye(4)
            t[:3, :3], t[:3, 3] = r, offset - r @ offset
            out.append(t)
    return out


def margins(log):
    """(scene, image, object) → the logged margin, None where there was no runner-up."""
    out = {}
    pattern = re.compile(r"scene_id=(\d+) im_id=(\d+) obj_id=(\d+) masks=\d+ runner_up_margin=(None|Some\(([-\d.e+]+)\))")
    for line in open(log, errors="replace"):
        m = pattern.search(line)
        if m:
            out[(int(m[1]), int(m[2]), int(m[3]))] = float(m[5]) if m[5] else None
    return out


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    ds, runs = sys.argv[1], sys.argv[2:]
    info = json.load(open(os.path.join(ds, "models", "models_info.json")))
    truth = {}
    for path in glob.glob(os.path.join(ds, "test", "*", "scene_gt.json")):
        scene = int(os.path.basename(os.path.dirname(path)))
        for im, gts in json.load(open(path)).items():
            for g in gts:
                truth[(scene, int(im), g["obj_id"])] = (np.array(g["cam_R_m2c"]).reshape(3, 3), np.array(g["cam_t_m2c"]))
    models = {}
    total = {b: [0, 0] for b in BINS + [None]}
    for run in runs:
        logged = margins(run + ".log")
        counts = {b: [0, 0] for b in BINS + [None]}
        for row in csv.DictReader(open(run + ".csv")):
            key = (int(row["scene_id"]), int(row["im_id"]), int(row["obj_id"]))
            if key not in truth:
                continue
            if key[2] not in models:
                points = vertices(os.path.join(ds, "models", f"obj_{key[2]:06d}.ply"))
                models[key[2]] = (points[:: max(1, len(points) // 2000)], symmetries(info[str(key[2])]))
            points, syms = models[key[2]]
            r = np.array([float(x) for x in row["R"].split()]).reshape(3, 3)
            t = np.array([float(x) for x in row["t"].split()])
            rt, tt = truth[key]
            placed = points @ r.T + t
            mssd = min(np.max(np.linalg.norm(placed - ((points @ s[:3, :3].T + s[:3, 3]) @ rt.T + tt), axis=1)) for s in syms)
            right = mssd < 0.1 * info[str(key[2])]["diameter"]
            margin = logged.get(key)
            b = None if margin is None else next(b for b in BINS if b[0] <= margin < b[1])
            for c in (counts, total):
                c[b][0] += right
                c[b][1] += 1
        print(f"{run}: " + report(counts))
    if len(runs) > 1:
        print("all: " + report(total))


def report(counts):
    label = lambda b: "no runner-up" if b is None else f"margin {b[0]:g}–{b[1]:g}"
    right = sum(c[0] for c in counts.values())
    n = sum(c[1] for c in counts.values())
    return f"right {right}/{n}; " + ", ".join(f"{label(b)}: {c[0]}/{c[1]}" for b, c in counts.items() if c[1])


if __name__ == "__main__":
    main()
