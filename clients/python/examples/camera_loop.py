"""Estimate poses frame after frame from a camera (cv2.VideoCapture), or, when no camera
opens, from a folder of images; write each frame with its overlay.

    python camera_loop.py --server localhost:50051 --object bbq --camera camera.json \
        --box 120,80,200,260 [--device 0] [--folder frames/] [--frames 100] [--out overlays/]

The detection is a box (x, y, width, height) in every frame: the server segments the
object inside it. A real cell would take boxes or masks from its detector instead.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any, Iterator, List, Tuple

import cv2
import numpy as np
import numpy.typing as npt

import b2tfpose
import b2tfpose.cv

Frame = npt.NDArray[np.uint8]


def read_K(path: Path) -> List[List[float]]:
    doc: Any = json.loads(path.read_text())
    K = doc["K"] if "K" in doc else np.asarray(doc["cam_K"], dtype=float).reshape(3, 3).tolist()
    return [[float(v) for v in row] for row in K]


def frames(device: int, folder: Path | None) -> Iterator[Tuple[str, Frame]]:
    """BGR frames from the camera, else from the folder's images in name order."""
    cap = cv2.VideoCapture(device)
    if cap.isOpened():
        try:
            n = 0
            while True:
                ok, frame = cap.read()
                if not ok:
                    return
                yield f"camera{device}-{n:06d}", np.asarray(frame, dtype=np.uint8)
                n += 1
        finally:
            cap.release()
    if folder is None:
        raise SystemExit(f"camera {device} does not open and no --folder was given")
    print(f"camera {device} does not open: reading {folder}")
    for path in sorted(p for p in folder.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg")):
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is not None:
            yield path.stem, np.asarray(image, dtype=np.uint8)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--server", required=True)
    ap.add_argument("--api-key")
    ap.add_argument("--ca-cert")
    ap.add_argument("--object", required=True)
    ap.add_argument("--camera", required=True, type=Path)
    ap.add_argument("--box", required=True, help="X,Y,W,H in pixels")
    ap.add_argument("--device", type=int, default=0)
    ap.add_argument("--folder", type=Path)
    ap.add_argument("--frames", type=int, default=0, help="stop after this many (0: all)")
    ap.add_argument("--out", type=Path, help="folder for the overlays")
    a = ap.parse_args()

    K = read_K(a.camera)
    box = [float(v) for v in a.box.split(",")]
    if a.out:
        a.out.mkdir(parents=True, exist_ok=True)
    with b2tfpose.Client(a.server, api_key=a.api_key, ca_cert=a.ca_cert) as client:
        for n, (name, frame) in enumerate(frames(a.device, a.folder)):
            if a.frames and n >= a.frames:
                break
            t0 = time.perf_counter()
            results = client.estimate(frame, K, [b2tfpose.Detection(a.object, box=box)], bgr=True)
            ms = (time.perf_counter() - t0) * 1e3
            best = results.best()
            if best is None or best.pose is None:
                print(json.dumps({"frame": name, "pose": None, "reason": results[0].reason if results else None}))
                continue
            pose = best.pose
            print(json.dumps({"frame": name, "score": best.score, "R": pose.R.reshape(-1).tolist(), "t": pose.t.tolist(), "ms": ms}))
            if a.out:
                overlay = b2tfpose.cv.draw_pose(frame, pose, K, bgr=True)
                cv2.imwrite(str(a.out / f"{name}.png"), overlay)


if __name__ == "__main__":
    main()
