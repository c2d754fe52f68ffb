"""The two halves of tools/bench/objects_searched.sh.

objects_searched.py views YCBV HOPE OUT        one models folder and a dataset view per number of objects searched
objects_searched.py report CSV YCBV NAME SECONDS   seconds per frame, poses answered, false ones
"""

import csv
import json
import os
import sys


class Truth:
    """The objects in each real frame, from the scenes' scene_gt.json (read once per scene)."""

    def __init__(self, ycbv: str) -> None:
        self.ycbv = ycbv
        self.scenes: dict[int, dict] = {}

    def present(self, scene: int, im: int) -> list[int]:
        if scene not in self.scenes:
            self.scenes[scene] = json.load(open(os.path.join(self.ycbv, "test", f"{scene:06d}", "scene_gt.json")))
        return [g["obj_id"] for g in self.scenes[scene][str(im)]]


def link(src: str, dst: str) -> None:
    if not os.path.lexists(dst):
        os.symlink(src, dst)


def views(ycbv: str, hope: str, out: str) -> None:
    """The YCB-V meshes under their ids and the HOPE meshes as 101, 102, ... in OUT/models
    (their textures keep their names: no YCB-V mesh has one), and a dataset view per setting
    (OUT/onboard, OUT/n1, OUT/n8, OUT/n17) whose targets name the objects searched."""
    ycbv, hope, out = (os.path.realpath(p) for p in (ycbv, hope, out))
    models = os.path.join(out, "models")
    os.makedirs(models, exist_ok=True)
    info = json.load(open(os.path.join(ycbv, "models", "models_info.json")))
    ycb_ids = sorted(int(k) for k in info)
    hope_info = json.load(open(os.path.join(hope, "models", "models_info.json")))
    hope_ids = []
    for k, v in sorted(hope_info.items(), key=lambda kv: int(kv[0])):
        ply = os.path.join(hope, "models", f"obj_{int(k):06d}.ply")
        if not os.path.exists(ply):
            continue
        new = 100 + int(k)
        link(ply, os.path.join(models, f"obj_{new:06d}.ply"))
        png = ply[:-4] + ".png"
        if os.path.exists(png):
            link(png, os.path.join(models, os.path.basename(png)))
        info[str(new)] = v
        hope_ids.append(new)
    for i in ycb_ids:
        link(os.path.join(ycbv, "models", f"obj_{i:06d}.ply"), os.path.join(models, f"obj_{i:06d}.ply"))
    json.dump(info, open(os.path.join(models, "models_info.json"), "w"))
    frames = sorted({(t["scene_id"], t["im_id"]) for t in json.load(open(os.path.join(ycbv, "test_targets_bop19.json")))})
    truth = Truth(ycbv)
    searched = {"onboard": (ycb_ids + hope_ids, frames[:1]), "n1": (None, frames), "n8": (ycb_ids + hope_ids[:1], frames), f"n{len(ycb_ids) + len(hope_ids)}": (ycb_ids + hope_ids, frames)}
    for name, (objs, fr) in searched.items():
        view = os.path.join(out, name)
        os.makedirs(view, exist_ok=True)
        link(os.path.join(ycbv, "test"), os.path.join(view, "test"))
        link(models, os.path.join(view, "models"))
        targets = [{"scene_id": s, "im_id": i, "obj_id": o, "inst_count": 1} for s, i in fr for o in (objs if objs is not None else truth.present(s, i)[:1])]
        json.dump(targets, open(os.path.join(view, "test_targets_bop19.json"), "w"))


def report(path: str, ycbv: str, name: str, seconds: str) -> None:
    """One line for a `bop run` of view NAME that took SECONDS and wrote the CSV at PATH."""
    rows = list(csv.DictReader(open(path)))
    truth = Truth(ycbv)
    false = sum(int(r["obj_id"]) not in truth.present(int(r["scene_id"]), int(r["im_id"])) for r in rows)
    targets = json.load(open(os.path.join(os.path.dirname(path), name, "test_targets_bop19.json")))
    frames = len({(t["scene_id"], t["im_id"]) for t in targets})
    per_frame = len(targets) // max(1, frames)
    print(
        f"{name}: {per_frame} objects searched per frame, {float(seconds) / max(1, frames):.2f} s per frame ({float(seconds):.1f} s for {frames} frames, loading the objects included), {len(rows)} poses answered, {false} of them of objects not in their frame"
    )


if __name__ == "__main__":
    command, args = sys.argv[1], sys.argv[2:]
    if command == "views" and len(args) == 3:
        views(*args)
    elif command == "report" and len(args) == 4:
        report(*args)
    else:
        sys.exit(__doc__)
