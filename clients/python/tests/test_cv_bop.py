"""`b2tfpose.cv.draw_pose` checked by its pixels, and `b2tfpose.bop` rows."""

from __future__ import annotations

import io
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh

import b2tfpose
from b2tfpose import bop
from b2tfpose.cv import box_corners, draw_pose, project
from conftest import Scene

SIZE = (0.10, 0.06, 0.16)  # the sample box, metres


def test_box_edges_and_axes_land_on_the_projected_points(scene: Scene) -> None:
    black = np.zeros((240, 320, 3), np.uint8)
    out = draw_pose(black, scene.truth, scene.K, SIZE, color=(0, 255, 0), thickness=1, axes=False)
    assert not black.any(), "the input is not drawn on"
    uv, _ = project(box_corners(SIZE), scene.truth, scene.K)
    edges = [(0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (0, 4), (1, 5), (2, 6), (3, 7)]
    for i, j in edges:
        for f in (0.25, 0.5, 0.75):
            x, y = np.round(uv[i] + f * (uv[j] - uv[i])).astype(int)
            patch = out[y - 1 : y + 2, x - 1 : x + 2]
            assert patch[..., 1].max() > 100 and patch[..., 0].max() == 0, f"edge {i}-{j} at {f}"
    assert (out[..., 1] > 0).mean() < 0.1  # lines, not fills

    # Axes: x red, y green, z blue (RGB); with bgr=True the channels swap.
    L = 0.05
    ends, _ = project(np.array([[L, 0, 0], [0, L, 0], [0, 0, L]]), scene.truth, scene.K)
    origin, _ = project(np.zeros((1, 3)), scene.truth, scene.K)
    for bgr in (False, True):
        out = draw_pose(black, scene.truth, scene.K, axis_length=L, thickness=1, bgr=bgr)
        for axis, end in enumerate(ends):
            x, y = np.round(origin[0] + 0.6 * (end - origin[0])).astype(int)
            px = out[y - 1 : y + 2, x - 1 : x + 2].reshape(-1, 3).max(axis=0)
            channel = 2 - axis if bgr else axis
            assert px[channel] > 100 and px.sum() - px[channel] < 60, f"axis {axis} bgr={bgr}: {px}"


def test_mesh_outline_follows_the_rendered_silhouette(scene: Scene, sample_obj: Path) -> None:
    mesh = trimesh.load(sample_obj, force="mesh")
    out = draw_pose(np.zeros((240, 320, 3), np.uint8), scene.truth, scene.K, mesh, color=(255, 0, 255), thickness=1, axes=False)
    drawn = (out[..., 0] > 100) & (out[..., 2] > 100)
    m = scene.mask.astype(np.uint8)
    boundary = m - cv2.erode(m, np.ones((3, 3), np.uint8))
    dist_to_boundary = cv2.distanceTransform((1 - boundary).astype(np.uint8), cv2.DIST_L2, 3)
    dist_to_drawn = cv2.distanceTransform((~drawn).astype(np.uint8), cv2.DIST_L2, 3)
    assert drawn.sum() > 200
    assert np.mean(dist_to_boundary[drawn] <= 2.0) > 0.97  # the outline lies on the silhouette's edge
    assert np.mean(dist_to_drawn[boundary > 0] <= 2.0) > 0.97  # and goes all the way round
    # A mesh path, in other units, and a Result work too.
    result = b2tfpose.Result("x", 0, scene.truth, 1.0, 0, None)
    scaled = mesh.copy()
    scaled.apply_scale(1000.0)
    out_mm = draw_pose(np.zeros((240, 320, 3), np.uint8), result, scene.K, scaled, units="mm", color=(255, 0, 255), thickness=1, axes=False)
    assert np.array_equal(out_mm, out)
    out_path = draw_pose(np.zeros((240, 320, 3), np.uint8), scene.truth, scene.K, str(sample_obj), color=(255, 0, 255), thickness=1, axes=False)
    assert np.array_equal(out_path, out)
    with pytest.raises(ValueError, match="no pose"):
        draw_pose(out, b2tfpose.Result("x", 0, None, 0.0, None, "no mask"), scene.K)


def test_bop_rows(scene: Scene, tmp_path: Path) -> None:
    result = b2tfpose.Result("obj_000001", 0, scene.truth, 0.75, 0, None)
    rows = [bop.row(3, 17, 1, result, time=0.52), bop.row(3, 17, 2, scene.truth.inverse().inverse())]
    text = bop.format_rows(rows)
    lines = text.splitlines()
    assert lines[0] == "scene_id,im_id,obj_id,score,R,t,time"
    fields = lines[1].split(",")
    assert fields[:4] == ["3", "17", "1", "0.75"] and fields[6] == "0.52"
    assert np.allclose([float(v) for v in fields[4].split(" ")], scene.truth.R.reshape(-1))
    assert np.allclose([float(v) for v in fields[5].split(" ")], [10.0, -20.0, 500.0])  # millimetres
    assert lines[2].split(",")[3] == "1.0" and lines[2].split(",")[6] == "-1.0"
    path = tmp_path / "results.csv"
    bop.write_csv(path, rows[:1])
    bop.write_csv(path, rows[1:], append=True)
    assert path.read_text() == text
    back = bop.read_csv(path)
    assert [(r.scene_id, r.im_id, r.obj_id) for r in back] == [(3, 17, 1), (3, 17, 2)]
    assert back[0].pose.rotation_error_deg(scene.truth) < 1e-6 and back[0].pose.translation_error_m(scene.truth) < 1e-12
    buf = io.StringIO()
    bop.write_csv(buf, rows)
    assert buf.getvalue() == text
    with pytest.raises(ValueError, match="no pose"):
        bop.row(1, 1, 1, b2tfpose.Result("x", 0, None, 0.0, None, "none found"))
