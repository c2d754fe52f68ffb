"""Session fixtures: one `b2tf serve` (small estimate limit, so that concurrent estimates
really meet RESOURCE_EXHAUSTED), the generated sample object onboarded once through the
client, a rendered scene of it at a known pose with its mask and camera file, and a short
rendered video of it moving."""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, Iterator, List

import cv2
import numpy as np
import pytest

import b2tfpose
from servers import Server, run_cli

SAMPLE_ID = "sample"
# The scene's camera (320x240) and the truth T_cam_obj (R row-major, t metres).
K = np.array([[500.0, 0.0, 159.5], [0.0, 500.0, 119.5], [0.0, 0.0, 1.0]])
TRUTH_R = np.array([[0.8, 0.6, 0.0], [-0.36, 0.48, 0.8], [0.48, -0.64, 0.6]])
TRUTH_T = np.array([0.01, -0.02, 0.5])


@dataclass
class Scene:
    dir: Path
    rgb_path: Path
    mask_path: Path
    camera_path: Path
    K: np.ndarray
    truth: b2tfpose.Pose

    @property
    def bgr(self) -> np.ndarray:
        return cv2.imread(str(self.rgb_path), cv2.IMREAD_COLOR)

    @property
    def rgb(self) -> np.ndarray:
        return cv2.cvtColor(self.bgr, cv2.COLOR_BGR2RGB)

    @property
    def mask(self) -> np.ndarray:
        return cv2.imread(str(self.mask_path), cv2.IMREAD_GRAYSCALE) > 0

    @property
    def box(self) -> List[int]:
        ys, xs = np.nonzero(self.mask)
        m = 6  # a detector's box: a little larger than the object
        return [int(xs.min()) - m, int(ys.min()) - m, int(xs.max() - xs.min()) + 1 + 2 * m, int(ys.max() - ys.min()) + 1 + 2 * m]


def render_scene(out: Path, mesh: Path, R: np.ndarray, t: np.ndarray) -> Scene:
    out.mkdir(parents=True, exist_ok=True)
    cam = out / "camera.json"
    cam.write_text(json.dumps({"K": K.tolist(), "resolution": [240, 320]}))
    pose = ",".join(repr(float(v)) for v in [*R.reshape(-1), *t])
    run_cli("render", "--mesh", str(mesh), "--units", "m", "--camera", str(cam), "--pose", pose, "--out", str(out))
    return Scene(out, out / "rgb.png", out / "mask.png", cam, K, b2tfpose.Pose(R, t))


@pytest.fixture(scope="session")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("b2tfpose")


@pytest.fixture(scope="session")
def sample_dir(work: Path) -> Path:
    """The generated sample object: sample_box.obj + .mtl + texture PNG, metres."""
    d = work / "sample"
    run_cli("sample", "--out", str(d))
    return d


@pytest.fixture(scope="session")
def sample_obj(sample_dir: Path) -> Path:
    return sample_dir / "sample_box.obj"


@pytest.fixture(scope="session")
def scene(work: Path, sample_obj: Path) -> Scene:
    return render_scene(work / "scene", sample_obj, TRUTH_R, TRUTH_T)


# A short video: the object moves a few millimetres a frame, turning a little about the
# camera's axis (dx, dy in metres, degrees), then stands still.
VIDEO_STEPS = [(0.004, 0.0, 2.0), (0.008, 0.002, 4.0), (0.012, 0.004, 6.0)]


def turned(R: np.ndarray, deg: float) -> np.ndarray:
    a = np.radians(deg)
    Rz = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    return Rz @ R


@pytest.fixture(scope="session")
def video(scene: Scene, sample_obj: Path, work: Path) -> List[Scene]:
    """Six frames: the scene, three frames moving, then the last one twice more (still)."""
    moved = [render_scene(work / f"video{i}", sample_obj, turned(TRUTH_R, deg), TRUTH_T + [dx, dy, 0.0]) for i, (dx, dy, deg) in enumerate(VIDEO_STEPS, 1)]
    return [scene, *moved, moved[-1], moved[-1]]


@pytest.fixture(scope="session")
def store(work: Path) -> str:
    return f"dir://{work / 'store'}"


@pytest.fixture(scope="session")
def server(work: Path, store: str) -> Iterator[Server]:
    """The shared server: one estimate at a time, so any two concurrent estimates collide."""
    s = Server(store, work / "server.log", ["--max-estimates", "1", "--max-onboardings", "1"])
    yield s
    s.stop()


@pytest.fixture(scope="session")
def client(server: Server) -> Iterator[b2tfpose.Client]:
    with b2tfpose.Client(server.address, timeout=120) as c:
        yield c


@dataclass
class Onboarded:
    info: b2tfpose.ObjectInfo
    progress: List[b2tfpose.OperationStatus]


@pytest.fixture(scope="session")
def onboarded(client: b2tfpose.Client, sample_obj: Path) -> Onboarded:
    """The sample onboarded once from its path (level 0: 12 views x 12 in-plane).

    Onboardings that must succeed pass retry=True throughout the tests: the server
    publishes an operation's final state a moment before it frees its onboarding slot, so
    an onboarding started right after another one ends may be refused (RESOURCE_EXHAUSTED)."""
    progress: List[b2tfpose.OperationStatus] = []
    info = client.onboard(SAMPLE_ID, sample_obj, units="m", level=0, progress=progress.append, replace=True, retry=True)
    return Onboarded(info, progress)


def cli_estimate(store: str, scene: Scene, out: Path, *extra: str) -> Dict[str, Any]:
    """`b2tf estimate` on the same store, image and camera: its first pose (R, t)."""
    run_cli("estimate", "--store", store, "--object", SAMPLE_ID, "--image", str(scene.rgb_path), "--camera", str(scene.camera_path), "--out", str(out), *extra)
    doc = json.loads(out.read_text())
    assert doc["poses"], f"the CLI found no pose: {doc}"
    result: Dict[str, Any] = doc["poses"][0]
    return result


@pytest.fixture(scope="session")
def cli_mask_pose(onboarded: Onboarded, store: str, scene: Scene, work: Path) -> b2tfpose.Pose:
    p = cli_estimate(store, scene, work / "cli_mask.json", "--mask", str(scene.mask_path))
    return b2tfpose.Pose(p["R"], p["t"])


@pytest.fixture(scope="session")
def cli_box_pose(onboarded: Onboarded, store: str, scene: Scene, work: Path) -> b2tfpose.Pose:
    p = cli_estimate(store, scene, work / "cli_box.json", "--box", ",".join(map(str, scene.box)))
    return b2tfpose.Pose(p["R"], p["t"])


def assert_same_pose(a: b2tfpose.Pose, b: b2tfpose.Pose, rot_deg: float = 1e-3, trans_m: float = 1e-6) -> None:
    assert a.rotation_error_deg(b) <= rot_deg and a.translation_error_m(b) <= trans_m, f"{a} != {b}"


PYTHON = sys.executable
