"""Estimating through the client from the inputs users hold (numpy RGB / BGR, encoded
bytes, paths; masks, RLE, boxes; K in both forms), compared with `b2tf estimate` on the
same inputs and with the truth the scene was rendered at."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import b2tfpose
from b2tfpose.masks import compress_rle, mask_to_rle, rle_to_mask
from conftest import SAMPLE_ID, Onboarded, Scene, assert_same_pose


@pytest.fixture(scope="module")
def rgb_result(client: b2tfpose.Client, onboarded: Onboarded, scene: Scene) -> b2tfpose.Result:
    results = client.estimate(scene.rgb, scene.K, [b2tfpose.Detection(SAMPLE_ID, mask=scene.mask)])
    assert len(results) == 1 and results.total_ms > 0
    return results[0]


def test_numpy_rgb_with_mask_matches_the_cli(rgb_result: b2tfpose.Result, cli_mask_pose: b2tfpose.Pose, scene: Scene) -> None:
    r = rgb_result
    assert r.ok and r.pose is not None and r.object_id == SAMPLE_ID and r.instance == 0 and r.detection_index == 0
    assert r.reason is None and 0.5 < r.score <= 1.0
    assert_same_pose(r.pose, cli_mask_pose)
    # And it is right: the scene was rendered at the truth.
    assert r.pose.rotation_error_deg(scene.truth) < 3.0 and r.pose.translation_error_m(scene.truth) < 0.01
    assert {"retrieval", "matching", "pnp", "total"} <= set(r.timings_ms) and all(v >= 0 for v in r.timings_ms.values())
    assert isinstance(r.diagnostics, list) and r.diagnostics[0]["inliers"] > 0
    # The sample box's textured faces all differ: symmetries found from the mesh, none.
    assert r.symmetries == b2tfpose.Symmetries("mesh") and not r.arbitrary_rotation_about_axis
    # The best other answer the server judged on the photo, and by how much it lost.
    u = r.runner_up
    assert isinstance(u, b2tfpose.RunnerUp) and u.margin >= 0.0 and u.distance_over_diameter > 0.1
    assert u.pose.rotation_error_deg(r.pose) > 1.0 or u.pose.translation_error_m(r.pose) > 0.0
    assert r.close_call(below=u.margin + 1e-6) and not r.close_call(below=u.margin)
    # Without a threshold of its own the client takes the server's verdict (below 0.03).
    assert r.close_call() == u.close_call == (u.margin < 0.03)


def test_bgr_frame_gives_the_same_pose(client: b2tfpose.Client, rgb_result: b2tfpose.Result, scene: Scene) -> None:
    [r] = client.estimate(scene.bgr, scene.K, [b2tfpose.Detection(SAMPLE_ID, mask=scene.mask.astype(np.uint8) * 255)], bgr=True)
    assert r.pose is not None and rgb_result.pose is not None
    assert_same_pose(r.pose, rgb_result.pose)
    # Without bgr=True the colours are swapped: the server sees another image.
    [swapped] = client.estimate(scene.bgr, scene.K, [b2tfpose.Detection(SAMPLE_ID, mask=scene.mask)])
    assert swapped.diagnostics != r.diagnostics


@pytest.mark.parametrize("form", ["rle", "compressed-rle", "dict", "png-path", "png-bytes"])
def test_mask_forms_agree(client: b2tfpose.Client, rgb_result: b2tfpose.Result, scene: Scene, form: str) -> None:
    rle = mask_to_rle(scene.mask)
    assert np.array_equal(rle_to_mask(rle), scene.mask) and np.array_equal(rle_to_mask(compress_rle(rle)), scene.mask)
    det = {
        "rle": b2tfpose.Detection(SAMPLE_ID, rle=rle),
        "compressed-rle": b2tfpose.Detection(SAMPLE_ID, rle=compress_rle(rle)),
        "dict": {"object_id": SAMPLE_ID, "segmentation": rle, "score": 1.0},
        "png-path": b2tfpose.Detection(SAMPLE_ID, mask=scene.mask_path),
        "png-bytes": b2tfpose.Detection(SAMPLE_ID, mask=scene.mask_path.read_bytes()),
    }[form]
    [r] = client.estimate(scene.rgb, scene.K, [det])
    assert r.pose is not None and rgb_result.pose is not None
    assert_same_pose(r.pose, rgb_result.pose)


def test_encoded_image_path_and_fx_fy_cx_cy(client: b2tfpose.Client, rgb_result: b2tfpose.Result, scene: Scene) -> None:
    fx, fy, cx, cy = scene.K[0, 0], scene.K[1, 1], scene.K[0, 2], scene.K[1, 2]
    for image in (scene.rgb_path, str(scene.rgb_path), scene.rgb_path.read_bytes()):
        [r] = client.estimate(image, (fx, fy, cx, cy), [b2tfpose.Detection(SAMPLE_ID, mask=scene.mask)])
        assert r.pose is not None and rgb_result.pose is not None
        assert_same_pose(r.pose, rgb_result.pose)
    ok, jpg = cv2.imencode(".jpg", scene.bgr, [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    [r] = client.estimate(jpg.tobytes(), scene.K, [b2tfpose.Detection(SAMPLE_ID, mask=scene.mask)])
    assert r.pose is not None and r.pose.rotation_error_deg(scene.truth) < 5 and r.pose.translation_error_m(scene.truth) < 0.02


def test_box_only_matches_the_cli(client: b2tfpose.Client, scene: Scene, cli_box_pose: b2tfpose.Pose) -> None:
    [r] = client.estimate(scene.rgb, scene.K, [{"object_id": SAMPLE_ID, "bbox": scene.box}])
    assert r.pose is not None
    assert_same_pose(r.pose, cli_box_pose)
    assert r.pose.rotation_error_deg(scene.truth) < 5 and r.pose.translation_error_m(scene.truth) < 0.02


def test_options_reach_the_server(client: b2tfpose.Client, rgb_result: b2tfpose.Result, scene: Scene) -> None:
    results = client.estimate(scene.rgb, scene.K, [b2tfpose.Detection(SAMPLE_ID, mask=scene.mask)], rrc=False, refiner="none", verify=False, k=20, overlay=True)
    [r] = results
    d = r.diagnostics[0]
    assert r.pose is not None and d["rrc_used"] is False and d["retrieved_templates"] == 20 and "verified" not in d
    assert r.pose.rotation_error_deg(scene.truth) < 10
    # The photo with the pose drawn on it, only when asked for.
    overlay = cv2.imdecode(np.frombuffer(results.overlay_png or b"", np.uint8), cv2.IMREAD_COLOR)
    assert overlay is not None and overlay.shape == scene.bgr.shape and (overlay != scene.bgr).any()
    assert client.estimate(scene.rgb, scene.K, [b2tfpose.Detection(SAMPLE_ID, mask=scene.mask)], rrc=False, verify=False).overlay_png is None


def test_rrc_always_runs_rrc_where_the_server_may_skip_it(client: b2tfpose.Client, scene: Scene) -> None:
    det = [b2tfpose.Detection(SAMPLE_ID, mask=scene.mask)]
    [always] = client.estimate(scene.rgb, scene.K, det, verify=False, rrc_always=True)
    assert "rrc_skipped" not in always.diagnostics[0] and always.diagnostics[0]["rrc_matches"] > 0
    # By default RRC is skipped only where the first matches are sure, and then not matched.
    [default] = client.estimate(scene.rgb, scene.K, det, verify=False)
    d = default.diagnostics[0]
    assert (d.get("rrc_skipped", False), d["rrc_matches"] == 0) in [(True, True), (False, False)]


def test_verification_hypotheses_follow_the_options(client: b2tfpose.Client, scene: Scene) -> None:
    det = [b2tfpose.Detection(SAMPLE_ID, mask=scene.mask)]
    [r] = client.estimate(scene.rgb, scene.K, det, rrc=False, verify_templates=0, spin_steps=0, verify_matched=0)
    # "replaced": the pipeline's pose re-placed at the mask, where its outline disagrees with
    # it; "nudge": the winner tilted a little (test_the_nudge_follows_its_option).
    assert {"pipeline", "flip"} <= {v["source"]["kind"] for v in r.diagnostics[0]["verified"]} <= {"pipeline", "replaced", "flip", "nudge"}
    [r] = client.estimate(scene.rgb, scene.K, det, rrc=False, verify_templates=2, spin_steps=12, verify_matched=3)
    kinds = [v["source"]["kind"] for v in r.diagnostics[0]["verified"]]
    # 30° steps: 8 angles that are not quarter turns, about each of three axes.
    assert 0 < kinds.count("template") <= 2 and 0 < kinds.count("spin") <= 24 and 0 < kinds.count("matched") <= 3
    with pytest.raises(b2tfpose.InvalidArgument, match="options.spin_steps"):
        client.estimate(scene.rgb, scene.K, det, spin_steps=1000)
    with pytest.raises(b2tfpose.InvalidArgument, match="options.verify_matched"):
        client.estimate(scene.rgb, scene.K, det, verify_matched=1000)


def test_the_box_prior_brings_a_pose_to_its_box_when_asked(client: b2tfpose.Client, scene: Scene) -> None:
    # A box drawn a quarter too large on each side: the prior moves poses nearer until
    # their outline covers it, which is why a caller with loose boxes says False. Unsaid,
    # it holds only for meshes without colours, and the sample is textured.
    x, y, w, h = scene.box
    loose = [x - w // 4, y - h // 4, w + w // 2, h + h // 2]
    det = [b2tfpose.Detection(SAMPLE_ID, box=loose)]

    def moved(r: b2tfpose.Result) -> bool:
        return any(v["refinement"].get("moved_to_box", False) for d in r.diagnostics for v in d["verified"])

    [on] = client.estimate(scene.rgb, scene.K, det, rrc=False, nudge_degrees=0, box_prior=True)
    [off] = client.estimate(scene.rgb, scene.K, det, rrc=False, nudge_degrees=0, box_prior=False)
    [unsaid] = client.estimate(scene.rgb, scene.K, det, rrc=False, nudge_degrees=0)
    assert on.pose is not None and off.pose is not None and unsaid.pose is not None
    assert moved(on) and not moved(off) and not moved(unsaid)
    assert on.pose.t[2] < off.pose.t[2]


def test_the_nudge_follows_its_option(client: b2tfpose.Client, scene: Scene) -> None:
    det = [b2tfpose.Detection(SAMPLE_ID, mask=scene.mask)]
    [r] = client.estimate(scene.rgb, scene.K, det, rrc=False, nudge_degrees=0)
    assert "nudge" not in {v["source"]["kind"] for v in r.diagnostics[0]["verified"]}
    # Four tilts, refined; those the refiner brings back to the winner are not rendered.
    [r] = client.estimate(scene.rgb, scene.K, det, rrc=False, nudge_degrees=15)
    assert [v["source"]["kind"] for v in r.diagnostics[0]["verified"]].count("nudge") == 4
    with pytest.raises(b2tfpose.InvalidArgument, match="options.nudge_degrees: 90 is outside 0–45 degrees"):
        client.estimate(scene.rgb, scene.K, det, nudge_degrees=90)


def test_two_detections_one_instance_and_a_low_score_mask(client: b2tfpose.Client, scene: Scene) -> None:
    empty_corner = np.zeros_like(scene.mask)
    empty_corner[:20, :20] = True
    dets = [b2tfpose.Detection(SAMPLE_ID, mask=empty_corner, score=0.2), b2tfpose.Detection(SAMPLE_ID, mask=scene.mask, score=0.9)]
    results = client.estimate(scene.rgb, scene.K, dets, instances_per_object=1)
    assert len(results) == 1
    best = results.best(SAMPLE_ID)
    assert best is not None and best.detection_index == 1 and best.pose is not None
    assert best.pose.rotation_error_deg(scene.truth) < 3


def test_pose_forms(rgb_result: b2tfpose.Result) -> None:
    p = rgb_result.pose
    assert p is not None
    assert np.allclose(p.R @ p.R.T, np.eye(3), atol=1e-9) and np.isclose(np.linalg.det(p.R), 1.0)
    assert p.T.shape == (4, 4) and np.allclose(p.T[:3, :3], p.R) and np.allclose(p.T[:3, 3], p.t) and np.allclose(p.T[3], [0, 0, 0, 1])
    R_cv, _ = cv2.Rodrigues(p.rvec)
    assert np.allclose(R_cv, p.R, atol=1e-9)
    rvec_cv, _ = cv2.Rodrigues(p.R)
    assert np.allclose(rvec_cv, p.rvec, atol=1e-9) and p.tvec.shape == (3, 1) and np.allclose(p.tvec.ravel(), p.t)
    w, x, y, z = p.quaternion_wxyz
    Rq = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    assert np.allclose(Rq, p.R, atol=1e-9) and w >= 0
    assert np.allclose(b2tfpose.Pose.from_matrix(p.T).T, p.T) and np.allclose(b2tfpose.Pose.from_rvec_tvec(p.rvec, p.tvec).R, p.R)
    assert np.allclose((p @ p.inverse()).T, np.eye(4), atol=1e-12)
    # OpenCV projects with rvec / tvec exactly as the pose transforms.
    pts = np.array([[0.05, 0.03, 0.08], [-0.05, 0.0, 0.0]])
    K = np.array([[500.0, 0, 159.5], [0, 500.0, 119.5], [0, 0, 1]])
    uv_cv, _ = cv2.projectPoints(pts, p.rvec, p.tvec, K, None)
    cam = p.transform(pts)
    uv = (cam @ K.T)[:, :2] / cam[:, 2:]
    assert np.allclose(uv_cv.reshape(-1, 2), uv, atol=1e-6)


def test_bad_inputs_are_refused_before_sending(client: b2tfpose.Client, scene: Scene) -> None:
    det = [b2tfpose.Detection(SAMPLE_ID, mask=scene.mask)]
    with pytest.raises(ValueError, match="uint8"):
        client.estimate(scene.rgb.astype(np.float32), scene.K, det)
    with pytest.raises(ValueError, match="K"):
        client.estimate(scene.rgb, [1, 2, 3], det)
    with pytest.raises(ValueError, match="mask is"):
        client.estimate(scene.rgb, scene.K, [b2tfpose.Detection(SAMPLE_ID, mask=scene.mask[:10])])
    with pytest.raises(ValueError, match="at least one"):
        client.estimate(scene.rgb, scene.K, [])
    with pytest.raises(ValueError, match="refiner"):
        client.estimate(scene.rgb, scene.K, det, refiner="magic")
    with pytest.raises(ValueError, match="mask, an rle or a box"):
        b2tfpose.Detection(SAMPLE_ID)


def test_depth_fits_the_pose_to_the_measured_surface(client: b2tfpose.Client, scene: Scene) -> None:
    # The render's depth PNG: uint16 tenths of a millimetre, 0 off the object.
    depth = cv2.imread(str(scene.dir / "depth.png"), cv2.IMREAD_ANYDEPTH)
    assert depth is not None and depth.dtype == np.uint16
    det = [b2tfpose.Detection(SAMPLE_ID, box=scene.box)]
    [r] = client.estimate(scene.rgb, scene.K, det, rrc=False, depth=depth, depth_scale=0.1)
    assert r.pose is not None and np.linalg.norm(np.asarray(r.pose.t) - scene.truth.t) < 0.005, r.pose.t
    fits = [h["refinement"]["depth_fit"] for h in r.diagnostics if "depth_fit" in h.get("refinement", {})]
    assert fits and fits[0]["inlier_share"] > 0.8, fits
    # The views found in the depth are judged beside the other hypotheses, unless turned off.
    kinds = lambda r: {v["source"]["kind"] for h in r.diagnostics for v in h.get("verified", [])}  # noqa: E731
    assert "depth-view" in kinds(r), kinds(r)
    [off] = client.estimate(scene.rgb, scene.K, det, rrc=False, depth=depth, depth_scale=0.1, depth_views=0)
    assert off.pose is not None and "depth-view" not in kinds(off), kinds(off)
    with pytest.raises(b2tfpose.InvalidArgument, match="options.depth_views is 13, over the limit of 12"):
        client.estimate(scene.rgb, scene.K, det, depth=depth, depth_scale=0.1, depth_views=13)
    # The same depth as float metres, and as the PNG file: the same answer.
    [m] = client.estimate(scene.rgb, scene.K, det, rrc=False, depth=depth.astype(np.float32) / 10000.0)
    [p] = client.estimate(scene.rgb, scene.K, det, rrc=False, depth=scene.dir / "depth.png", depth_scale=0.1)
    assert m.pose is not None and p.pose is not None
    np.testing.assert_allclose(m.pose.t, r.pose.t, atol=1e-3)
    np.testing.assert_allclose(p.pose.t, r.pose.t, atol=1e-6)
    # Bad depth: refused in the client where it can tell, by the server otherwise.
    with pytest.raises(ValueError, match="depth_scale is needed with uint16 depth"):
        client.estimate(scene.rgb, scene.K, det, depth=depth)
    with pytest.raises(ValueError, match="must be registered to the colour image"):
        client.estimate(scene.rgb, scene.K, det, depth=depth[:100], depth_scale=0.1)
    with pytest.raises(ValueError, match="float depth is metres"):
        client.estimate(scene.rgb, scene.K, det, depth=depth.astype(np.float32), depth_scale=0.1)
    nan = depth.astype(np.float32) / 10000.0
    nan[0, 3] = np.nan
    with pytest.raises(b2tfpose.InvalidArgument, match=r"depth.raw_f32: depth value at pixel \(3, 0\) is NaN"):
        client.estimate(scene.rgb, scene.K, det, depth=nan)
    with pytest.raises(b2tfpose.InvalidArgument, match="outside 0.05–20 m"):
        client.estimate(scene.rgb, scene.K, det, depth=depth, depth_scale=100.0)
