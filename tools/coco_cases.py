"""Random bbox cases scored by pycocotools' COCOeval, the fixture of src/bop/coco_ap.rs's
`agrees_with_pycocotools` test (src/bop/testdata/coco_cases.json).

The BOP toolkit installs pycocotools from MartinSmeyer/cocoapi, which differs from
upstream in one line of COCOeval._prepare: a ground truth's 'ignore' flag is kept
(upstream overwrites it with 'iscrowd'). Patch an installed pycocotools (2.0.11 was used)
the same way before running:

    sed -i "s/gt\['ignore'\] = 'iscrowd' in gt and gt\['iscrowd'\]/gt['iscrowd'] = 'iscrowd' in gt and gt['iscrowd']/" .../pycocotools/cocoeval.py
    python tools/coco_cases.py 8 > src/bop/testdata/coco_cases.json

Scores are rounded to 0.1 or 0.01 so that equal scores (and their tie-breaking) occur;
every fifth seed puts 110 false positives in one image (maxDets 100).
"""

import json, random, sys, io, contextlib
import numpy as np
from pycocotools.coco import COCO
from pycocotools.cocoeval import COCOeval


def rbox(rng, lo, hi):
    w, h = rng.uniform(lo, hi), rng.uniform(lo, hi)
    return [round(rng.uniform(0, 600), 2), round(rng.uniform(0, 400), 2), round(w, 2), round(h, 2)]


def jitter(rng, b, f):
    x, y, w, h = b
    return [round(x + rng.uniform(-f, f) * w, 2), round(y + rng.uniform(-f, f) * h, 2), round(w * (1 + rng.uniform(-f, f)), 2), round(h * (1 + rng.uniform(-f, f)), 2)]


def case(seed):
    rng = random.Random(seed)
    n_img = rng.randint(1, 6)
    images = []
    for i in range(n_img):
        gts, dts = [], []
        for _ in range(rng.randint(0, 6)):
            b = rbox(rng, 8, 220)
            g = {"cat": rng.randint(1, 3), "bbox": b, "area": round(b[2] * b[3] * rng.uniform(0.3, 1.0)), "ignore": rng.random() < 0.15}
            gts.append(g)
            for _ in range(rng.choice([0, 1, 1, 1, 2])):
                dts.append({"cat": g["cat"] if rng.random() < 0.9 else rng.randint(1, 3), "bbox": jitter(rng, b, rng.choice([0.0, 0.05, 0.15, 0.3])), "score": round(rng.random(), 1)})
        n_fp = rng.randint(0, 3) if not (seed % 5 == 0 and i == 0) else 110
        for _ in range(n_fp):
            dts.append({"cat": rng.randint(1, 3), "bbox": rbox(rng, 5, 150), "score": round(rng.random(), 2)})
        images.append({"gts": gts, "dts": dts})
    return images


def score(images):
    gt = {"images": [], "annotations": [], "categories": [{"id": c} for c in (1, 2, 3)]}
    res = []
    aid = 1
    for i, im in enumerate(images):
        gt["images"].append({"id": i + 1, "width": 800, "height": 600})
        for g in im["gts"]:
            gt["annotations"].append({"id": aid, "image_id": i + 1, "category_id": g["cat"], "bbox": g["bbox"], "area": g["area"], "iscrowd": 0, "ignore": g["ignore"]})
            aid += 1
        for d in im["dts"]:
            res.append({"image_id": i + 1, "category_id": d["cat"], "bbox": d["bbox"], "score": d["score"]})
    with contextlib.redirect_stdout(io.StringIO()):
        cg = COCO()
        cg.dataset = gt
        cg.createIndex()
        if not res:
            return None
        cd = cg.loadRes(res)
        e = COCOeval(cg, cd, "bbox")
        e.params.imgIds = sorted(cg.getImgIds())
        e.evaluate()
        e.accumulate()
        e.summarize()
    prec = e.eval["precision"]
    per_cat = {}
    for k, c in enumerate(e.params.catIds):
        p = prec[:, :, k, 0, 2]
        per_cat[str(c)] = float(np.mean(p[p > -1])) if (p > -1).any() else -1.0
    return [float(v) for v in e.stats], per_cat


cases = []
seed = 0
while len(cases) < int(sys.argv[1]):
    seed += 1
    ims = case(seed)
    r = score(ims)
    if r is None:
        continue
    cases.append({"seed": seed, "images": ims, "stats": r[0], "per_category": r[1]})
json.dump({"generator": "pycocotools 2.0.11 COCOeval, 'ignore' kept as in MartinSmeyer/cocoapi", "cases": cases}, sys.stdout, separators=(",", ":"))
