"""Many concurrent estimates with the asyncio client. The server runs a bounded number at
once, queues more, and refuses the rest (RESOURCE_EXHAUSTED) saying when to come back; the
client retries those after that wait, within its retry budget.

    python async_many.py --server localhost:50051 --object bbq --image photo.png \
        --mask mask.png --camera camera.json [--count 32]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import time
from pathlib import Path
from typing import Any, List

import cv2
import numpy as np

import b2tfpose


def read_K(path: Path) -> List[List[float]]:
    doc: Any = json.loads(path.read_text())
    K = doc["K"] if "K" in doc else np.asarray(doc["cam_K"], dtype=float).reshape(3, 3).tolist()
    return [[float(v) for v in row] for row in K]


class CountRetries(logging.Handler):
    def __init__(self) -> None:
        super().__init__()
        self.count = 0

    def emit(self, record: logging.LogRecord) -> None:
        self.count += 1


async def run(a: argparse.Namespace) -> None:
    K = read_K(a.camera)
    bgr = cv2.imread(str(a.image), cv2.IMREAD_COLOR)
    mask = cv2.imread(str(a.mask), cv2.IMREAD_GRAYSCALE)
    if bgr is None or mask is None:
        raise SystemExit(f"cannot read {a.image} or {a.mask}")
    rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    detections = [b2tfpose.Detection(a.object, mask=np.asarray(mask) > 0)]
    # Retries may go on for as long as the whole batch may take.
    retry = b2tfpose.RetryPolicy(budget=300)
    t0 = time.perf_counter()
    async with b2tfpose.AsyncClient(a.server, api_key=a.api_key, ca_cert=a.ca_cert, retry=retry, timeout=300) as client:
        all_results = await asyncio.gather(*(client.estimate(rgb, K, detections) for _ in range(a.count)))
    wall = time.perf_counter() - t0
    poses = [r.best(a.object) for r in all_results]
    found = [p for p in poses if p is not None and p.pose is not None]
    print(json.dumps({"estimates": a.count, "with_pose": len(found), "wall_s": round(wall, 3), "per_estimate_s": round(wall / a.count, 3)}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--server", required=True)
    ap.add_argument("--api-key")
    ap.add_argument("--ca-cert")
    ap.add_argument("--object", required=True)
    ap.add_argument("--image", required=True, type=Path)
    ap.add_argument("--mask", required=True, type=Path)
    ap.add_argument("--camera", required=True, type=Path)
    ap.add_argument("--count", type=int, default=16)
    a = ap.parse_args()
    retries = CountRetries()
    logging.getLogger("b2tfpose").addHandler(retries)
    logging.getLogger("b2tfpose").setLevel(logging.INFO)
    asyncio.run(run(a))
    print(json.dumps({"retries": retries.count}))


if __name__ == "__main__":
    main()
