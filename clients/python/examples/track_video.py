"""Track an object through a video given as a folder of frames: the first frame's mask
starts the track (a full estimate on the server), later frames are followed from the last
pose in milliseconds, and a lost frame is re-initialised by searching near its last pose.

    python track_video.py --server localhost:50051 --object bbq --video frames/ \
        --camera camera.json --mask first_mask.png [--mesh bbq.ply --units mm] \
        [--overlay-dir overlays/]

Frames are the folder's PNG / JPEG files in name order (sent encoded, as they are);
camera.json: {"K": [[fx,0,cx],[0,fy,cy],[0,0,1]], ...} or BOP's {"cam_K": [9 values], ...}.
Prints one JSON line per frame, as `b2tf track` writes them: frame, file, R (row-major), t
(metres), quality, mode (estimated, tracked, reinitialised, lost), ms (the server's time on
the object), or error when the server refused the frame.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path
from typing import Any, Dict, Iterator, List

import cv2
import numpy as np

import b2tfpose
import b2tfpose.cv


def read_K(path: Path) -> List[List[float]]:
    doc: Any = json.loads(path.read_text())
    K = doc["K"] if "K" in doc else np.asarray(doc["cam_K"], dtype=float).reshape(3, 3).tolist()
    return [[float(v) for v in row] for row in K]


def frame_paths(folder: Path) -> List[Path]:
    paths = sorted(p for p in folder.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg"))
    if not paths:
        raise SystemExit(f"no PNG or JPEG frames in {folder}")
    return paths


def frames(paths: List[Path], detection: b2tfpose.Detection) -> Iterator[b2tfpose.TrackFrame]:
    """The frames, taken lazily: the first one with the object's detection, the others
    without (the server follows the track)."""
    for i, path in enumerate(paths):
        yield b2tfpose.TrackFrame(path, detections=[detection] if i == 0 else [], frame_index=i)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--server", required=True, help="host:port, grpc:// or grpcs://")
    ap.add_argument("--api-key")
    ap.add_argument("--ca-cert", help="PEM certificate to trust (TLS)")
    ap.add_argument("--object", required=True)
    ap.add_argument("--video", required=True, type=Path, help="folder of frames")
    ap.add_argument("--camera", required=True, type=Path)
    ap.add_argument("--mask", required=True, type=Path, help="the object's mask in the first frame")
    ap.add_argument("--mesh", help="mesh file: the overlays draw its outline")
    ap.add_argument("--units", default="m", help="the mesh's unit (mm, cm, m)")
    ap.add_argument("--overlay-dir", type=Path)
    a = ap.parse_args()

    K = read_K(a.camera)
    paths = frame_paths(a.video)
    mask = cv2.imread(str(a.mask), cv2.IMREAD_GRAYSCALE)
    if mask is None:
        raise SystemExit(f"cannot read {a.mask}")
    if a.overlay_dir:
        a.overlay_dir.mkdir(parents=True, exist_ok=True)
    modes: Counter[str] = Counter()
    detection = b2tfpose.Detection(a.object, mask=mask > 0)
    with b2tfpose.Client(a.server, api_key=a.api_key, ca_cert=a.ca_cert) as client:
        # raise_errors=False: a refused frame (e.g. unreadable) is reported and the video goes on.
        for result in client.track(frames(paths, detection), K=K, drop_after_lost=len(paths), raise_errors=False):
            assert result.frame is not None and result.frame.frame_index is not None
            i = int(result.frame.frame_index)
            line: Dict[str, Any] = {"frame": i, "file": paths[i].name}
            if result.error is not None:
                line["error"] = str(result.error)
                modes["error"] += 1
                print(json.dumps(line), flush=True)
                continue
            obj = result.best(a.object) or next((o for o in result.objects if o.object_id == a.object), None)
            if obj is None:
                raise SystemExit(f"frame {paths[i].name}: no track of {a.object!r} (no pose from the first mask?)")
            pose = obj.pose
            line.update(
                {
                    "R": pose.R.reshape(-1).tolist() if pose else None,
                    "t": pose.t.tolist() if pose else None,
                    "quality": obj.quality,
                    "mode": str(obj.mode),
                    "ms": obj.ms,
                    "server_ms": result.total_ms,
                }
            )
            modes[str(obj.mode)] += 1
            print(json.dumps(line), flush=True)
            image = cv2.imread(str(paths[i]), cv2.IMREAD_COLOR) if a.overlay_dir and pose is not None else None
            if image is not None and pose is not None:
                overlay = b2tfpose.cv.draw_pose(image, pose, K, a.mesh, units=a.units, bgr=True)
                cv2.imwrite(str(a.overlay_dir / f"{paths[i].stem}.png"), overlay)
    print(f"{len(paths)} frames: " + ", ".join(f"{n} {m}" for m, n in sorted(modes.items())), file=sys.stderr)


if __name__ == "__main__":
    main()
