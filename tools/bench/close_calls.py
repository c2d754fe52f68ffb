#!/usr/bin/env python3
"""Does the answer's runner-up verdict mean the same from a box as from a true mask?

On a BOP dataset with ground truth and box detections (default ../shared/data/ycbv-rgbd),
estimates every instance with `b2tf estimate` twice, from its true visible mask and from
its box (the box path's default proposals), and reports per input how many answers are
right, how many come flagged `runner_up.close_call`, and how well the runner-up's margin
separates right answers from wrong ones (AUC: 1 = every right answer has a larger margin
than every wrong one, 0.5 = no better than chance).

"Right" is rough and stated: the centre within 0.1 of the object's diameter and the
rotation within 20° (symmetries not forgiven), and, separately, the centre alone.

    python3 tools/bench/close_calls.py [--dataset DS] [--store URL] [--out DIR] [--bin B2TF]

The store must hold the dataset's objects as obj_NNNNNN (tools/bench/real_boxes.sh
onboards them into out/real-boxes/objects, the default). Answers are kept in OUT
(default out/close-calls) and reused; delete them to rerun. A benchmark, not a test:
about 2 minutes on 2 cores for the 35 real instances with a release build.
"""

import argparse
import glob
import json
import math
import os
import subprocess


def auc(high, low):
    """Share of (high, low) pairs where the first is larger (ties count half)."""
    if not high or not low:
        return float("nan")
    return sum((a > b) + 0.5 * (a == b) for a in high for b in low) / (len(high) * len(low))


def rotation_deg(a, b):
    trace = sum(x * y for x, y in zip(a, b))
    return math.degrees(math.acos(max(-1.0, min(1.0, (trace - 1) / 2))))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dataset", default="../shared/data/ycbv-rgbd")
    ap.add_argument("--store", default="dir://out/real-boxes/objects")
    ap.add_argument("--out", default="out/close-calls")
    ap.add_argument("--bin", default="target/release/b2tf")
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    info = json.load(open(f"{a.dataset}/models/models_info.json"))
    boxes = {(d["scene_id"], d["image_id"], d["category_id"]): d["bbox"] for d in json.load(open(f"{a.dataset}/detections_box.json"))}
    answers = {"mask": [], "box": []}
    for scene in sorted(glob.glob(f"{a.dataset}/test/*/")):
        sid = int(os.path.basename(scene.rstrip("/")))
        gt = json.load(open(scene + "scene_gt.json"))
        cams = json.load(open(scene + "scene_camera.json"))
        for im, instances in gt.items():
            k = cams[im]["cam_K"]
            camera = f"{a.out}/camera-{sid}-{im}.json"
            json.dump({"K": [k[0:3], k[3:6], k[6:9]], "resolution": [480, 640]}, open(camera, "w"))
            for j, inst in enumerate(instances):
                box = boxes.get((sid, int(im), inst["obj_id"]))
                if box is None:
                    continue
                for kind in answers:
                    out = f"{a.out}/{sid}-{im}-{j}-{kind}.json"
                    if not os.path.exists(out):
                        given = ["--mask", f"{scene}mask_visib/{int(im):06d}_{j:06d}.png"] if kind == "mask" else ["--box", ",".join(str(v) for v in box)]
                        subprocess.run(
                            [a.bin, "estimate", "--store", a.store, "--object", f"obj_{inst['obj_id']:06d}", "--image", f"{scene}rgb/{int(im):06d}.png", "--camera", camera, *given, "--out", out],
                            capture_output=True,
                            check=True,
                        )
                    pose = json.load(open(out))["poses"][0]
                    truth_t = [v / 1000 for v in inst["cam_t_m2c"]]
                    placed = math.dist(pose["t"], truth_t) / (info[str(inst["obj_id"])]["diameter"] / 1000) < 0.1
                    turned_right = rotation_deg(pose["R"], inst["cam_R_m2c"]) < 20
                    runner = pose.get("runner_up") or {}
                    answers[kind].append((placed and turned_right, placed, bool(runner.get("close_call")), runner.get("margin", 0.0)))
    print("| input | answers | right (centre < 0.1·d, rotation < 20°) | close calls among right / wrong | margin AUC right > wrong | placed (centre < 0.1·d) | margin AUC placed > not |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for kind, rows in answers.items():
        right = [r for r in rows if r[0]]
        wrong = [r for r in rows if not r[0]]
        placed = [r[3] for r in rows if r[1]]
        missed = [r[3] for r in rows if not r[1]]
        print(
            f"| {kind} | {len(rows)} | {len(right)} | {sum(r[2] for r in right)} / {sum(r[2] for r in wrong)} | "
            f"{auc([r[3] for r in right], [r[3] for r in wrong]):.2f} | {len(placed)} | {auc(placed, missed):.2f} |"
        )


if __name__ == "__main__":
    main()
