"""Onboard every mesh of a folder (PLY, OBJ with its MTL and textures, glTF, GLB), each
as the object named by its file name, with progress.

    python onboard_folder.py --server localhost:50051 --folder models/ --units mm [--level 2] [--replace]
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import b2tfpose

MESHES = (".ply", ".obj", ".gltf", ".glb")


def object_id(path: Path) -> str:
    """The file name as an object id (A-Z a-z 0-9 . _ -, at most 64)."""
    return re.sub(r"[^A-Za-z0-9._-]", "_", path.stem).lstrip(".")[:64] or "object"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--server", required=True)
    ap.add_argument("--api-key")
    ap.add_argument("--ca-cert")
    ap.add_argument("--folder", required=True, type=Path)
    ap.add_argument("--units", required=True, choices=["mm", "cm", "m"], help="unit of the PLY / OBJ files (glTF is metres)")
    ap.add_argument("--level", type=int, default=None, help="template viewpoints 0-3 (server default 2)")
    ap.add_argument("--in-plane", type=int, default=None)
    ap.add_argument("--replace", action="store_true")
    a = ap.parse_args()

    paths = sorted(p for p in a.folder.iterdir() if p.suffix.lower() in MESHES)
    if not paths:
        raise SystemExit(f"no meshes in {a.folder}")
    failed = 0
    with b2tfpose.Client(a.server, api_key=a.api_key, ca_cert=a.ca_cert) as client:
        for path in paths:
            oid = object_id(path)
            units = None if path.suffix.lower() in (".gltf", ".glb") else a.units

            def progress(s: b2tfpose.OperationStatus, oid: str = oid) -> None:
                print(f"  {oid}: {s.state.lower()} {s.templates_done}/{s.templates_total}", flush=True)

            # retry=True: the server refuses at once (RESOURCE_EXHAUSTED) while its
            # onboarding slots are busy, before starting anything, so retrying is safe.
            try:
                info = client.onboard(oid, path, units=units, level=a.level, in_plane=a.in_plane, replace=a.replace, progress=progress, retry=True)
            except (b2tfpose.B2TFPoseError, ValueError, OSError) as e:
                print(f"{path.name}: {e}")
                failed += 1
                continue
            print(json.dumps({"file": path.name, "object": info.id, "templates": info.templates, "diameter_m": info.diameter_m}))
    if failed:
        raise SystemExit(f"{failed} of {len(paths)} meshes failed")


if __name__ == "__main__":
    main()
