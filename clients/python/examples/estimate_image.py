"""Estimate an object's pose in an image file from a mask file; print it, draw an overlay.

    python estimate_image.py --server localhost:50051 --object bbq \
        --image photo.png --mask mask.png --camera camera.json [--mesh bbq.ply --units mm] \
        [--overlay overlay.png]

camera.json: {"K": [[fx,0,cx],[0,fy,cy],[0,0,1]], ...} or BOP's {"cam_K": [9 values], ...}.
Prints one JSON line: object, score, R (row-major), t (metres), rvec, quaternion.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any, List

import cv2
import numpy as np

import b2tfpose
import b2tfpose.cv


def read_K(path: Path) -> List[List[float]]:
    doc: Any = json.loads(path.read_text())
    K = doc["K"] if "K" in doc else np.asarray(doc["cam_K"], dtype=float).reshape(3, 3).tolist()
    return [[float(v) for v in row] for row in K]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--server", required=True, help="host:port, grpc:// or grpcs://")
    ap.add_argument("--api-key")
    ap.add_argument("--ca-cert", help="PEM certificate to trust (TLS)")
    ap.add_argument("--object", required=True)
    ap.add_argument("--image", required=True, type=Path)
    ap.add_argument("--mask", required=True, type=Path)
    ap.add_argument("--camera", required=True, type=Path)
    ap.add_argument("--mesh", help="mesh file: the overlay draws its outline")
    ap.add_argument("--units", default="m", help="the mesh's unit (mm, cm, m)")
    ap.add_argument("--overlay", type=Path)
    a = ap.parse_args()

    K = read_K(a.camera)
    bgr = cv2.imread(str(a.image), cv2.IMREAD_COLOR)
    mask = cv2.imread(str(a.mask), cv2.IMREAD_GRAYSCALE)
    if bgr is None or mask is None:
        raise SystemExit(f"cannot read {a.image} or {a.mask}")
    with b2tfpose.Client(a.server, api_key=a.api_key, ca_cert=a.ca_cert) as client:
        results = client.estimate(bgr, K, [b2tfpose.Detection(a.object, mask=mask > 0)], bgr=True)
    best = results.best(a.object)
    if best is None or best.pose is None:
        raise SystemExit(f"no pose: {results[0].reason if results else 'no result'}")
    pose = best.pose
    print(
        json.dumps(
            {
                "object": a.object,
                "score": best.score,
                "R": pose.R.reshape(-1).tolist(),
                "t": pose.t.tolist(),
                "rvec": pose.rvec.ravel().tolist(),
                "quaternion_wxyz": pose.quaternion_wxyz.tolist(),
                "server_ms": results.total_ms,
            }
        )
    )
    if a.overlay:
        overlay = b2tfpose.cv.draw_pose(bgr, pose, K, a.mesh, units=a.units, bgr=True)
        cv2.imwrite(str(a.overlay), overlay)


if __name__ == "__main__":
    main()
