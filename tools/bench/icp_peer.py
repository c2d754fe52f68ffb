"""Open3D's point-to-plane ICP on the cases `b2tf bench depth-fit --dump DIR` wrote: the same
model points (the surface the start pose's render shows, moved to the start pose) against
the measured points of the same depth image, from the same start, with the same gate (a
quarter of the diameter, at least 2 cm) and a Tukey loss at the same inlier tolerance (5 %
of the diameter within 5-15 mm). Prints the errors after each fit beside ours (the fitted
pose the dump recorded) on the same cases, and the time of each.

    python3 tools/bench/icp_peer.py DIR

Open3D pairs by nearest neighbour in 3D (a KD-tree over the measured points, their normals
estimated from 20 neighbours); ours pairs projectively (one lookup per point) and takes the
normals of the rendered model surface. The measured points are those in the window the
start's model points project to, 10 pixels wider each side.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
import open3d as o3d


def rotation_error_deg(a: np.ndarray, b: np.ndarray) -> float:
    c = (np.trace(a[:3, :3].T @ b[:3, :3]) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def centre_error_mm(a: np.ndarray, b: np.ndarray, centre: np.ndarray) -> float:
    return float(np.linalg.norm((a[:3, :3] @ centre + a[:3, 3]) - (b[:3, :3] @ centre + b[:3, 3])) * 1000.0)


def peer_fit(case: dict, depth_m: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Open3D's fit of one case: the fitted pose, ms for the target's normals, ms for ICP."""
    fx, fy, cx, cy = case["k"]
    start = np.array(case["start"]).reshape(4, 4)
    pts = np.array(case["points"]) @ start[:3, :3].T + start[:3, 3]
    u, v = fx * pts[:, 0] / pts[:, 2] + cx, fy * pts[:, 1] / pts[:, 2] + cy
    h, w = depth_m.shape
    x0, x1 = int(max(0, np.floor(u.min()) - 10)), int(min(w, np.ceil(u.max()) + 11))
    y0, y1 = int(max(0, np.floor(v.min()) - 10)), int(min(h, np.ceil(v.max()) + 11))
    ys, xs = np.nonzero(depth_m[y0:y1, x0:x1] > 0)
    z = depth_m[y0:y1, x0:x1][ys, xs]
    xs, ys = xs + x0, ys + y0
    measured = np.stack([(xs - cx) * z / fx, (ys - cy) * z / fy, z], axis=1)
    target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(measured))
    t = time.perf_counter()
    target.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(20))
    target.orient_normals_towards_camera_location(np.zeros(3))
    normals_ms = (time.perf_counter() - t) * 1e3
    source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    d = case["diameter"]
    gate, tol = max(0.25 * d, 0.02), min(max(0.05 * d, 0.005), 0.015)
    loss = o3d.pipelines.registration.TukeyLoss(k=tol)
    t = time.perf_counter()
    r = o3d.pipelines.registration.registration_icp(
        source, target, gate, np.eye(4), o3d.pipelines.registration.TransformationEstimationPointToPlane(loss), o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=30)
    )
    icp_ms = (time.perf_counter() - t) * 1e3
    return r.transformation @ start, normals_ms, icp_ms


def summary(v: list[float]) -> str:
    a = np.sort(np.array(v))
    return f"{np.quantile(a, 0.5):.2f} | {np.quantile(a, 0.9):.2f}"


def main() -> None:
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    folder = Path(sys.argv[1])
    cases = sorted(folder.glob("case_*.json"))
    if not cases:
        sys.exit(f"no case_*.json in {folder}: run `b2tf bench depth-fit --dump {folder}` first")
    rows: dict[str, dict[str, list[float]]] = {k: {"rot": [], "mm": [], "ms": []} for k in ("ours", "open3d")}
    within = {"ours": 0, "open3d": 0}
    normals_ms = []
    for path in cases:
        case = json.loads(path.read_text())
        depth = np.asarray(o3d.io.read_image(str(folder / case["depth_png"]))).astype(np.float64) / 1e4
        truth, centre = np.array(case["truth"]).reshape(4, 4), np.array(case["centre"])
        peer, n_ms, icp_ms = peer_fit(case, depth)
        normals_ms.append(n_ms)
        for name, pose, ms in (("ours", np.array(case["fitted"]).reshape(4, 4), case["fit_ms"]), ("open3d", peer, icp_ms)):
            r, m = rotation_error_deg(pose, truth), centre_error_mm(pose, truth, centre)
            rows[name]["rot"].append(r)
            rows[name]["mm"].append(m)
            rows[name]["ms"].append(ms)
            within[name] += r < 1.0 and m < 2.0
    print(f"{len(cases)} cases from {folder} (Open3D {o3d.__version__}; its target normals took {summary(normals_ms)} ms, median | p90, not counted below)\n")
    print("| fit | rotation error °, median | p90 | centre error mm, median | p90 | within 1° and 2 mm | ms, median | p90 |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for name, label in (("ours", "b2tf depth fit (projective, rendered normals)"), ("open3d", "Open3D point-to-plane ICP (KD-tree, Tukey)")):
        r = rows[name]
        print(f"| {label} | {summary(r['rot'])} | {summary(r['mm'])} | {within[name]} of {len(cases)} | {summary(r['ms'])} |")


if __name__ == "__main__":
    main()
