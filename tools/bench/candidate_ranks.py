#!/usr/bin/env python3
"""How well each score ranks the depth detector's candidates, from a debug log of
`b2tf bop run --depth` (no --detections) on a BOP dataset with its truth:

    B2TF_LOG=debug b2tf bop run --dataset DS --out run.csv --store STORE --depth > run.log 2>&1
    tools/bench/candidate_ranks.py run.log [DS]

A candidate is right when its estimated centre lies within 30 mm of the true instance of
its object. For every (image, object) with a right candidate, prints where the retrieval
cosine (`cosine`), the estimate's score (`estimate_score`) and the confirmation
(`confirmation`) rank the first right one (0 = first); then the confirmations of the right
and of the wrong candidates, and how many candidates an object would estimate if it
stopped at its first confirmation of 0.7 or more (the order of the log is the order of
estimation). Where the log carries the candidates' screen scores (`screened`, the best of
their placed templates' confirmations before the estimate), how many of the right ones, of
the wrong ones of an object in the image and of the objects not in it a screen would keep
at each threshold. docs/detection.md ("With depth", "What the screen sees") quotes its
figures.
"""

import json, re, sys
from collections import defaultdict

import numpy as np

log = sys.argv[1]
ds = sys.argv[2] if len(sys.argv) > 2 else "../shared/data/ycbv-rgbd"
RIGHT_MM = 30.0
STOP = 0.7

cands = defaultdict(list)
for line in open(log):
    if "candidate confirmed" not in line:
        continue
    f = dict(re.findall(r"(\w+)=([-0-9.e]+)", line.split("candidate confirmed")[1]))
    key = (int(f["scene_id"]), int(f["im_id"]), int(f["obj_id"]))
    cands[key].append(
        {
            "t": np.array([float(f["x_mm"]), float(f["y_mm"]), float(f["z_mm"])]),
            "cosine": float(f["cosine"]),
            "estimate_score": float(f["estimate_score"]),
            "confirmation": float(f["confirmation"]),
            "screened": float(f["screened"]) if "screened" in f else None,
        }
    )

ranks = {k: defaultdict(int) for k in ("cosine", "estimate_score", "confirmation")}
right_c, wrong_c, none_right = [], [], 0
# (screen score, confirmation) of the right candidates, the wrong ones of an object in the
# image, and those of an object not in it.
screened = {"right": [], "wrong place": [], "object absent": []}
gts = {}
for (scene, im, obj), cs in sorted(cands.items()):
    if scene not in gts:
        gts[scene] = json.load(open(f"{ds}/test/{scene:06d}/scene_gt.json"))
    truths = [np.array(g["cam_t_m2c"]) for g in gts[scene][str(im)] if g["obj_id"] == obj]
    right = [any(np.linalg.norm(c["t"] - t) < RIGHT_MM for t in truths) for c in cs]
    for c, r in zip(cs, right):
        (right_c if r else wrong_c).append(c["confirmation"])
        if c["screened"] is not None:
            kind = "right" if r else ("wrong place" if truths else "object absent")
            screened[kind].append((c["screened"], c["confirmation"]))
    if not any(right):
        none_right += 1
        continue
    for key in ranks:
        order = sorted(range(len(cs)), key=lambda i: -cs[i][key])
        ranks[key][min([order.index(i) for i in range(len(cs)) if right[i]])] += 1

objects = sum(sum(r.values()) for r in ranks.values()) // 3
print(f"{len(cands)} (image, object) pairs, {sum(len(c) for c in cands.values())} candidates estimated; {objects} with a right candidate, {none_right} without")
for key, r in ranks.items():
    print(f"  {key:15s} ranks the right one first for {r[0]} of {objects}; second {r[1]}; later {objects - r[0] - r[1]}")
print(f"confirmations, right candidates: {len(right_c)}, {sum(c >= STOP for c in right_c)} at {STOP} or more; wrong: {len(wrong_c)}, highest {max(wrong_c, default=0):.2f}")
needed = sum(next((i + 1 for i, c in enumerate(cs) if c["confirmation"] >= STOP), len(cs)) for cs in cands.values())
print(f"stopping each object at its first confirmation of {STOP} or more would estimate {needed} of these candidates")

if any(screened.values()):
    print("screen scores (best placed template's confirmation) against what the estimate confirmed:")
    for kind, pairs in screened.items():
        if pairs:
            s_, c_ = np.array(pairs).T
            print(f"  {kind:14s} {len(pairs):3d}: screen median {np.median(s_):.2f} (lowest {s_.min():.2f}), confirmation median {np.median(c_):.2f}")
    for t in (0.06, 0.1, 0.15, 0.2, 0.3):
        kept = ", ".join(f"{kind} {sum(s >= t for s, _ in pairs)}/{len(pairs)}" for kind, pairs in screened.items())
        print(f"  a screen at {t:.2f} keeps: {kept}")
