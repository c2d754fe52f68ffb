#!/usr/bin/env python3
"""The smoke test's scene and requests, so the shell script stays plain.

scene.py camera DIR                  writes DIR/camera.json, prints the true pose for --pose
scene.py estimate-body SCENE_DIR     prints the POST /v1/estimate body (rgb.png + mask.png)
scene.py check RESPONSE_JSON         checks the pose against the truth, prints the errors
"""

import base64
import json
import math
import sys

K = {"fx": 500.0, "fy": 500.0, "cx": 159.5, "cy": 119.5, "width": 320, "height": 240}


def truth():
    """R = Ry(40°)·Rx(30°), t 0.5 m in front of the camera, slightly off-centre."""
    a, b = math.radians(30), math.radians(40)
    rx = [[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]]
    ry = [[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]]
    r = [[sum(ry[i][k] * rx[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
    return [v for row in r for v in row], [0.01, -0.01, 0.5]


def b64(path):
    with open(path, "rb") as f:
        return base64.b64encode(f.read()).decode()


def main(cmd, arg):
    if cmd == "camera":
        k = [[K["fx"], 0, K["cx"]], [0, K["fy"], K["cy"]], [0, 0, 1]]
        with open(f"{arg}/camera.json", "w") as f:
            json.dump({"K": k, "resolution": [K["height"], K["width"]]}, f)
        r, t = truth()
        print(",".join(f"{v:.9f}" for v in r + t))
    elif cmd == "estimate-body":
        print(json.dumps({"image": {"encoded": b64(f"{arg}/rgb.png")}, "intrinsics": K, "detections": [{"object_id": "box", "mask_png": b64(f"{arg}/mask.png"), "score": 0.9}]}))
    elif cmd == "check":
        with open(arg) as f:
            pose = json.load(f)["results"][0]["pose"]
        r, t = truth()
        # Geodesic angle between the two rotations: trace of R_estᵀ·R_true.
        tr = sum(pose["R"][i] * r[i] for i in range(9))
        rot = math.degrees(math.acos(max(-1.0, min(1.0, (tr - 1) / 2))))
        trans = math.dist(pose["t"], t)
        print(f"pose error: rotation {rot:.1f}°, translation {trans * 1e3:.1f} mm")
        if rot > 15 or trans > 0.03:
            sys.exit("pose too far from the truth")
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(*sys.argv[1:])
