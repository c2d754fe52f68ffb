"""What the reliability tools send, made once with the CLI and kept as bytes: the generated
sample box (`b2tf sample`: OBJ + MTL + PNG texture, metres), a 320x240 photo of it at a
known pose with its mask (`b2tf render`), and the HTTP bodies built from them, so that a
load generator spends its time sending, not encoding.

Every object the tools onboard is this box, so any stored object must give the known pose
for the photo: a cheap check that what a request got back (or what a store holds after a
crash) is whole and right."""

from __future__ import annotations

import base64
import json
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Sequence, Tuple

from .server import run_cli

# The photo's camera and the truth T_cam_obj (R row-major, t metres), as the Python
# client's tests use them.
K = [[500.0, 0.0, 159.5], [0.0, 500.0, 119.5], [0.0, 0.0, 1.0]]
INTRINSICS = {"fx": 500.0, "fy": 500.0, "cx": 159.5, "cy": 119.5, "width": 320, "height": 240}
TRUTH_R = [0.8, 0.6, 0.0, -0.36, 0.48, 0.8, 0.48, -0.64, 0.6]
TRUTH_T = [0.01, -0.02, 0.5]
# A pose within this of the truth's translation counts as right (the server's is ~1 mm
# off with or without RRC).
TOLERANCE_M = 0.01


def b64(data: bytes) -> str:
    return base64.b64encode(data).decode()


@dataclass
class Fixtures:
    obj: bytes
    mtl: bytes
    texture: bytes
    rgb_png: bytes
    mask_png: bytes

    @classmethod
    def make(cls, folder: Path) -> "Fixtures":
        run_cli("sample", "--out", str(folder / "sample"))
        cam = folder / "camera.json"
        cam.write_text(json.dumps({"K": K, "resolution": [240, 320]}))
        pose = ",".join(repr(v) for v in TRUTH_R + TRUTH_T)
        run_cli("render", "--mesh", str(folder / "sample/sample_box.obj"), "--units", "m", "--camera", str(cam), "--pose", pose, "--out", str(folder / "scene"))
        s, sc = folder / "sample", folder / "scene"
        return cls((s / "sample_box.obj").read_bytes(), (s / "sample_box.mtl").read_bytes(), (s / "sample_box_m0.png").read_bytes(), (sc / "rgb.png").read_bytes(), (sc / "mask.png").read_bytes())

    @property
    def resources(self) -> Dict[str, bytes]:
        return {"sample_box.mtl": self.mtl, "sample_box_m0.png": self.texture}

    def estimate_json(self, object_id: str, **options: object) -> bytes:
        """POST /v1/estimate body: the photo as PNG, the mask as the detection."""
        return json.dumps(
            {
                "image": {"encoded": b64(self.rgb_png)},
                "intrinsics": INTRINSICS,
                "detections": [{"object_id": object_id, "mask_png": b64(self.mask_png), "score": 0.9}],
                "options": options,
            }
        ).encode()

    def onboard_json(self, object_id: str, level: int, in_plane: int, replace: bool = False) -> bytes:
        """POST /v1/objects body, the files base64 in JSON."""
        return json.dumps(
            {
                "object_id": object_id,
                "mesh": {"data": b64(self.obj), "format": "obj", "units": "m", "resources": [{"name": n, "data": b64(d)} for n, d in self.resources.items()]},
                "options": {"level": level, "in_plane": in_plane},
                "replace": replace,
            }
        ).encode()

    def onboard_multipart(self, object_id: str, level: int, in_plane: int) -> Tuple[bytes, str]:
        """POST /v1/objects as multipart/form-data (the files as they are): (body, content type)."""
        fields: List[Tuple[str, str, bytes]] = [
            ("object_id", "", object_id.encode()),
            ("units", "", b"m"),
            ("level", "", str(level).encode()),
            ("in_plane", "", str(in_plane).encode()),
            ("mesh", "sample_box.obj", self.obj),
        ]
        fields += [("resource", n, d) for n, d in self.resources.items()]
        return multipart(fields)


def multipart(fields: Sequence[Tuple[str, str, bytes]]) -> Tuple[bytes, str]:
    """A multipart/form-data body of (name, file name or "", bytes) parts."""
    boundary = uuid.uuid4().hex
    out = bytearray()
    for name, filename, data in fields:
        disp = f'form-data; name="{name}"' + (f'; filename="{filename}"' if filename else "")
        out += f"--{boundary}\r\nContent-Disposition: {disp}\r\n\r\n".encode() + data + b"\r\n"
    out += f"--{boundary}--\r\n".encode()
    return bytes(out), f"multipart/form-data; boundary={boundary}"


def pose_is_right(t: Sequence[float]) -> bool:
    """Whether a translation is the photo's truth within TOLERANCE_M."""
    return sum((a - b) ** 2 for a, b in zip(t, TRUTH_T)) ** 0.5 <= TOLERANCE_M
