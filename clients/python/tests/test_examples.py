"""Each example in examples/ run as a user would, against the shared server."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any, Dict, List

import cv2
import numpy as np

import b2tfpose
from conftest import SAMPLE_ID, TRUTH_T, Onboarded, Scene, assert_same_pose, render_scene
from servers import Server, run_cli
from test_onboard import textured_box_mm

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def run_example(name: str, *args: str, timeout: float = 180) -> List[Dict[str, Any]]:
    """Runs examples/NAME with this interpreter; its JSON output lines."""
    p = subprocess.run([sys.executable, str(EXAMPLES / name), *args], capture_output=True, text=True, timeout=timeout)
    assert p.returncode == 0, f"{name} failed ({p.returncode}):\n{p.stdout}\n{p.stderr}"
    return [json.loads(line) for line in p.stdout.splitlines() if line.startswith("{")]


def test_estimate_image(server: Server, onboarded: Onboarded, scene: Scene, sample_obj: Path, cli_mask_pose: b2tfpose.Pose, tmp_path: Path) -> None:
    overlay = tmp_path / "overlay.png"
    [out] = run_example(
        "estimate_image.py",
        "--server",
        server.address,
        "--object",
        SAMPLE_ID,
        "--image",
        str(scene.rgb_path),
        "--mask",
        str(scene.mask_path),
        "--camera",
        str(scene.camera_path),
        "--mesh",
        str(sample_obj),
        "--units",
        "m",
        "--overlay",
        str(overlay),
    )
    assert_same_pose(b2tfpose.Pose(out["R"], out["t"]), cli_mask_pose)
    drawn = cv2.imread(str(overlay), cv2.IMREAD_COLOR)
    assert drawn.shape == (240, 320, 3) and not np.array_equal(drawn, scene.bgr)
    # The outline is green (BGR (0, 255, 0)) where it was drawn.
    assert ((drawn[..., 1] == 255) & (drawn[..., 0] < 50) & (drawn[..., 2] < 50)).sum() > 100


def test_camera_loop_falls_back_to_a_folder(server: Server, onboarded: Onboarded, scene: Scene, sample_obj: Path, work: Path, tmp_path: Path) -> None:
    frames = tmp_path / "frames"
    frames.mkdir()
    for i, dx in enumerate((-0.02, 0.0, 0.02)):
        s = render_scene(work / f"frame{i}", sample_obj, scene.truth.R, TRUTH_T + [dx, 0.0, 0.0])
        (frames / f"frame{i}.png").write_bytes(s.rgb_path.read_bytes())
    out_dir = tmp_path / "overlays"
    x, y, w, h = scene.box
    box = f"{x - 30},{y},{w + 60},{h}"  # wide enough for every frame
    lines = run_example(
        "camera_loop.py",
        "--server",
        server.address,
        "--object",
        SAMPLE_ID,
        "--camera",
        str(scene.camera_path),
        "--box",
        box,
        "--device",
        "97",
        "--folder",
        str(frames),
        "--out",
        str(out_dir),
    )
    assert [line["frame"] for line in lines] == ["frame0", "frame1", "frame2"]
    xs = [line["t"][0] for line in lines]
    assert np.allclose(xs, [TRUTH_T[0] - 0.02, TRUTH_T[0], TRUTH_T[0] + 0.02], atol=0.01) and xs == sorted(xs)
    assert sorted(p.name for p in out_dir.iterdir()) == ["frame0.png", "frame1.png", "frame2.png"]


def test_track_video_matches_the_cli(server: Server, onboarded: Onboarded, video: List[Scene], store: str, sample_obj: Path, tmp_path: Path) -> None:
    frames = tmp_path / "frames"
    frames.mkdir()
    for i, s in enumerate(video):
        (frames / f"frame{i:03d}.png").write_bytes(s.rgb_path.read_bytes())
    first = video[0]
    overlays = tmp_path / "overlays"
    lines = run_example(
        "track_video.py",
        "--server",
        server.address,
        "--object",
        SAMPLE_ID,
        "--video",
        str(frames),
        "--camera",
        str(first.camera_path),
        "--mask",
        str(first.mask_path),
        "--mesh",
        str(sample_obj),
        "--overlay-dir",
        str(overlays),
    )
    # `b2tf track` runs the same tracking session on the same frames.
    cli_out = tmp_path / "cli.jsonl"
    run_cli("track", "--store", store, "--object", SAMPLE_ID, "--video", str(frames), "--camera", str(first.camera_path), "--mask", str(first.mask_path), "--out", str(cli_out))
    cli = [json.loads(line) for line in cli_out.read_text().splitlines()]
    assert [line["frame"] for line in lines] == list(range(len(video))) and len(cli) == len(video)
    assert [line["mode"] for line in lines] == [c["mode"] for c in cli] == ["estimated"] + ["tracked"] * (len(video) - 1)
    for line, c, s in zip(lines, cli, video):
        assert line["file"] == c["file"] and abs(line["quality"] - c["quality"]) < 1e-6
        pose = b2tfpose.Pose(line["R"], line["t"])
        assert_same_pose(pose, b2tfpose.Pose(c["R"], c["t"]))
        assert pose.rotation_error_deg(s.truth) < 3.0 and pose.translation_error_m(s.truth) < 0.005
    assert sorted(p.name for p in overlays.iterdir()) == sorted(p.name for p in frames.iterdir())


def test_onboard_folder(server: Server, client: b2tfpose.Client, sample_dir: Path, tmp_path: Path) -> None:
    folder = tmp_path / "models"
    folder.mkdir()
    for p in sample_dir.iterdir():
        (folder / p.name).write_bytes(p.read_bytes())
    mesh = textured_box_mm()
    mesh.apply_scale(0.001)
    (folder / "small box.glb").write_bytes(mesh.export(file_type="glb"))
    lines = run_example("onboard_folder.py", "--server", server.address, "--folder", str(folder), "--units", "m", "--level", "0", "--in-plane", "1", "--replace")
    assert [line["object"] for line in lines] == ["sample_box", "small_box"]
    assert all(line["templates"] == 12 for line in lines)
    assert abs(lines[1]["diameter_m"] - float(np.linalg.norm([0.04, 0.06, 0.08]))) < 1e-3
    for oid in ("sample_box", "small_box"):
        assert client.get_object(oid).templates == 12
        client.delete_object(oid)


def test_async_many(server: Server, onboarded: Onboarded, scene: Scene) -> None:
    exhausted = 'route="/b2tfpose.v1.PoseService/Estimate",status="RESOURCE_EXHAUSTED"'
    waited = "b2tf_estimate_queue_wait_seconds_count"
    before, waited_before = server.metric(exhausted), server.metric(waited)
    summary, retries = run_example(
        "async_many.py",
        "--server",
        server.address,
        "--object",
        SAMPLE_ID,
        "--image",
        str(scene.rgb_path),
        "--mask",
        str(scene.mask_path),
        "--camera",
        str(scene.camera_path),
        "--count",
        "6",
    )
    assert summary["estimates"] == 6 and summary["with_pose"] == 6
    # The server (one estimate at a time) queues the burst; every retry the client made
    # answers one of its refusals, if any.
    assert server.metric(waited) - waited_before == 6
    assert retries["retries"] == server.metric(exhausted) - before
